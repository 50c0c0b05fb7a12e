"""TRC marker files (Motion Analysis track row column format, as OpenSim reads and writes them).

Layout: ``PathFileType`` line; a line of keys (``DataRate CameraRate NumFrames NumMarkers Units ...``) and a line of
their values; a line ``Frame# Time <marker> <tab> <tab> <marker> ...``; a line ``X1 Y1 Z1 X2 ...``; then one row
per frame. Missing samples are empty fields or NaN. Units (``mm``, ``cm``, ``m``) are converted to metres here.

Every data row must hold exactly ``2 + 3 x NumMarkers`` tab-separated fields (trailing empty fields beyond them
are ignored): a row with fewer is refused, naming its line and both counts, since a value left out (rather than
left empty) would shift every later value into the wrong marker. Infinite values are refused too (NaN and empty
fields are the format's gaps).

Parsing the numbers is most of the cost of reading (about 0.3 us a number with numpy's C parser: 0.13 s for a
4500-frame, 32-marker Fukuchi trial), so a ``time_range`` reads only the times of every row and parses the rows
inside the window: an IK setup's window of 1057 of those 4500 frames reads in 0.045 s instead of 0.14 s.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from biomotion.errors import DataFormatError
from biomotion.io.atomic import atomic_write
from biomotion.motion import Markers, within_window

UNIT_SCALE = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
RATE_TOLERANCE = 0.1
"""How far (relative) DataRate may differ from the rate of the Time column before the file is refused."""


def read_trc(path: str | Path, time_range: tuple[float, float] | None = None) -> Markers:
    """Read a ``.trc`` file as `Markers` in metres (NaN where a marker is missing).

    ``time_range`` (start, end) in seconds keeps the frames with ``start <= t <= end`` (as `Markers.slice` and
    OpenSim's ``time_range``), parsing only those rows; the header and every row's time are still checked."""
    path = Path(path)
    if path.is_dir():
        raise DataFormatError(path, "is a directory, not a TRC file")
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except FileNotFoundError:
        raise DataFormatError(path, "no such file") from None
    except OSError as error:
        raise DataFormatError(path, f"cannot read: {error.strerror}") from None
    if not any(line.strip() for line in lines):  # stops at the first line with text
        raise DataFormatError(path, "empty file", line=1)
    if len(lines) < 5:
        raise DataFormatError(path, f"only {len(lines)} lines: a TRC file has 5 header lines then data")
    if not lines[0].startswith("PathFileType"):
        raise DataFormatError(path, "first line must start with 'PathFileType'", line=1)
    keys = lines[1].split()
    values = lines[2].split()
    if len(values) < len(keys):
        raise DataFormatError(path, f"{len(keys)} header keys but {len(values)} values", line=3)
    meta = dict(zip(keys, values))
    try:
        rate = float(meta["DataRate"])
        declared_frames = int(float(meta["NumFrames"]))
        declared_markers = int(float(meta["NumMarkers"]))
    except (KeyError, ValueError) as error:
        raise DataFormatError(path, f"bad header value ({error})", line=3) from None
    units = meta.get("Units", "")
    if units not in UNIT_SCALE:
        raise DataFormatError(path, f"unknown units {units!r} (expected mm, cm or m)", line=3, field="Units")
    if not np.isfinite(rate) or rate <= 0:
        raise DataFormatError(path, f"DataRate must be positive, got {meta['DataRate']}", line=3, field="DataRate")
    label_fields = lines[3].rstrip().split("\t")
    if len(label_fields) < 2 or label_fields[0].strip() != "Frame#":
        raise DataFormatError(path, "marker label line must start with 'Frame#\\tTime'", line=4)
    names = [name.strip() for name in label_fields[2:] if name.strip()]
    if len(names) != declared_markers:
        raise DataFormatError(path, f"header says {declared_markers} markers, label line names {len(names)}", line=4)
    body = lines[5:]
    numbers = [number + 6 for number, text in enumerate(body) if text and not text.isspace()]  # no copies
    if not numbers:
        raise DataFormatError(path, "no data rows", line=6)
    if len(numbers) < declared_frames:
        raise DataFormatError(
            path, f"truncated: header declares {declared_frames} frames, file has {len(numbers)}", line=numbers[-1]
        )
    if time_range is not None:
        times = _times(path, body, numbers)
        _check_rate(path, rate, times)
        start, end = time_range
        keep = np.flatnonzero(within_window(times, start, end))
        if not len(keep):
            raise DataFormatError(
                path,
                f"no frame within time range {start}-{end} s (the file spans {times[0]}-{times[-1]} s)",
                field="time_range",
            )
        numbers = [numbers[k] for k in keep]
    data = _data_rows(path, [body[number - 6] for number in numbers], numbers, 2 + 3 * len(names), len(names))
    infinite = np.isinf(data[:, 2:])
    if infinite.any():
        row, column = (int(i) for i in np.argwhere(infinite)[0])
        raise DataFormatError(
            path,
            f"infinite value {data[row, 2 + column]} (a missing sample is an empty field or NaN)",
            line=numbers[row],
            field=f"{names[column // 3]}.{'XYZ'[column % 3]}",
        )
    times = data[:, 1]
    if time_range is None:  # a window's times were checked, over the whole file, by `_times`
        _check_times(path, times, numbers)
        _check_rate(path, rate, times)
    positions = data[:, 2:].reshape(len(data), len(names), 3) * UNIT_SCALE[units]
    return Markers(times=times, names=tuple(names), positions=positions)


def _times(path: Path, body: list[str], numbers: list[int]) -> np.ndarray:
    """The time (second field) of the data rows on file lines ``numbers``, checked to be finite and increasing."""
    tokens = [_second_field(body[number - 6]) for number in numbers]
    try:
        times = np.array(tokens, dtype=float)
    except ValueError:
        for token, number in zip(tokens, numbers):
            try:
                float(token)
            except ValueError:
                raise DataFormatError(path, f"not a number: {token!r}", line=number) from None
        raise
    _check_times(path, times, numbers)
    return times


def _second_field(text: str) -> str:
    """The second tab-separated field of a row ("nan" when it has none), found without splitting the whole row:
    a TRC row holds thousands of characters after it."""
    start = text.find("\t")
    if start < 0:
        return "nan"
    end = text.find("\t", start + 1)
    return text[start + 1 :] if end < 0 else text[start + 1 : end]


def _check_times(path: Path, times: np.ndarray, numbers: list[int]) -> None:
    if not np.all(np.isfinite(times)):
        raise DataFormatError(path, "time is missing", line=numbers[int(np.flatnonzero(~np.isfinite(times))[0])])
    steps = np.diff(times)
    if np.any(steps <= 0):
        row = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise DataFormatError(path, f"time does not increase ({times[row - 1]} then {times[row]})", line=numbers[row])


def _data_rows(path: Path, rows: list[str], numbers: list[int], width: int, markers: int) -> np.ndarray:
    """The data ``rows`` (text, from file lines ``numbers``) as floats [frames, width], NaN for empty fields.

    Full rows go through numpy's C parser at once (2.5x faster than field by field on a 4500-frame, 32-marker
    file); a file with empty fields, trailing tabs or a bad token takes the field-by-field path, which checks every
    row's field count and names the line of a short row, a long one or a bad token."""
    try:
        data = np.loadtxt([text.rstrip() for text in rows], delimiter="\t", dtype=float, ndmin=2)
        if data.shape == (len(numbers), width):  # a stripped row only loses empty fields: each has >= width
            return data
    except ValueError:
        pass
    expected = f"expected {width} (frame, time and 3 x {markers} markers)"
    # rows written with a trailing tab: one that lost a value still has `width` fields, its last one empty
    usual = Counter(text.count("\t") + 1 for text in rows).most_common(1)[0][0]
    table_rows = []
    for text, number in zip(rows, numbers):
        fields = text.split("\t")
        if len(fields) > width and any(field.strip() for field in fields[width:]):
            raise DataFormatError(path, f"{len(fields)} fields, {expected}", line=number)
        if len(fields) < width:
            raise DataFormatError(
                path,
                f"{len(fields)} fields, {expected}: a value is missing, so the values "
                "after it would land in the wrong columns (leave a missing sample as an "
                "empty field, keeping its tab)",
                line=number,
            )
        if len(fields) < usual:
            raise DataFormatError(
                path,
                f"{len(fields)} fields where the other rows have {usual} (frame, time, 3 x {markers} markers and a "
                "trailing tab): a value is missing, so the values after it would land in the wrong columns",
                line=number,
            )
        table_rows.append([field.strip() or "nan" for field in fields[:width]])
    table = np.array(table_rows, dtype=object)
    try:
        return table.astype(float)
    except ValueError:
        for fields, number in zip(table_rows, numbers):
            for token in fields:
                try:
                    float(token)
                except ValueError:
                    raise DataFormatError(path, f"not a number: {token!r}", line=number) from None
        raise


def _check_rate(path: Path, rate: float, times: np.ndarray) -> None:
    """The header's DataRate against the Time column: they differ a little in real files (subject01_walk1.trc says
    60 Hz and steps 0.017 s, 2 %), but a rate several times off is a header that belongs to another file."""
    if len(times) < 3:
        return
    step = float(np.median(np.diff(times)))
    if abs(rate * step - 1.0) > RATE_TOLERANCE:
        raise DataFormatError(
            path,
            f"DataRate says {rate:g} Hz but the Time column steps {step:g} s ({1 / step:.4g} Hz)",
            line=3,
            field="DataRate",
        )


def write_trc(path: str | Path, markers: Markers, *, units: str = "m", rate: float | None = None) -> Path:
    """Write `Markers` as a ``.trc`` file OpenSim reads; occluded samples are written as ``NaN`` (OpenSim 4.6
    rejects rows whose trailing cells are empty).

    ``rate`` (Hz) defaults to the markers' own; a single frame has none, so it must then be given.
    """
    if units not in UNIT_SCALE:
        raise ValueError(f"units must be one of {sorted(UNIT_SCALE)}, got {units!r}")
    path = Path(path)
    rate = markers.rate if rate is None else float(rate)
    if not np.isfinite(rate) or rate <= 0:
        raise ValueError("a single-frame marker set has no rate: pass rate=")
    count = len(markers.names)
    header = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate!r}\t{rate!r}\t{markers.n_frames}\t{count}\t{units}\t{rate!r}\t1\t{markers.n_frames}",
        "Frame#\tTime\t" + "\t".join(f"{name}\t\t" for name in markers.names),
        "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, count + 1)),
        "",
    ]
    values = markers.positions.reshape(markers.n_frames, -1) / UNIT_SCALE[units]
    body = []
    for frame, (time, row) in enumerate(zip(markers.times, values), start=1):
        cells = ["NaN" if not np.isfinite(v) else repr(float(v)) for v in row]
        body.append("\t".join([str(frame), repr(float(time)), *cells]))
    with atomic_write(path) as handle:
        handle.write("\n".join(header) + "\n" + "\n".join(body) + "\n")
    return path
