"""Writing marker trajectories as C3D, byte by byte after the C3D standard.

Layout (Motion Lab Systems, *The C3D File Format User Guide*, c3d.org, chapters 2-4): 512-byte blocks of
little-endian words (processor type 84, Intel). Block 1 is the header; the parameter section starts at block 2
with a 4-byte preamble (byte 2 the 0x50 key, byte 3 the section's block count, byte 4 the processor type),
then one record per group (negative id) and per parameter (its group's positive id, a type: -1 char, 2 int16,
4 float32, its dimensions, its data), each holding the offset of the next; an offset of 0 ends the section.
The 3D data follows from ``POINT:DATA_START``: per frame, per point X, Y, Z and a fourth word, all float32 (the
negative ``POINT:SCALE`` of a floating-point file); the fourth word is -1 for an invalid point, else the camera
mask (high byte) and residual (low byte), both 0 here.

Why not ezc3d's own writer (ezc3d reads every C3D here): ``ezc3d.c3d.write`` passes integer parameters to C++ as
``ezc3d.VecInt``, which SWIG stops accepting once an OpenSim function has taken a ``std::vector<int>`` in the
process (both bindings wrap that type; ezc3d 1.7.2, opensim 4.6), as the body-model oracle does: ezc3d's write
then raises TypeError. This writer has no binding to clash with (`tests/io/test_c3d_writer.py`).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from biomotion.errors import ConfigError
from biomotion.io.atomic import atomic_write
from biomotion.motion import Markers

BLOCK = 512
KEY = 0x50
INTEL = 84
MAX_ENTRIES = 255  # a dimension is one byte: longer label lists continue in LABELS2, LABELS3 ...
MAX_FRAMES = 0xFFFF  # the header's first and last frame numbers are 16-bit
INVALID = -1.0
ROUNDING_S = 5e-4  # s: half a millisecond, the rounding of a time column written to 3 decimals


def _block_count(size: int) -> int:
    return -(-size // BLOCK)


def _words(values: list[int]) -> list[int]:
    """Unsigned 16-bit words as the signed int16 values that hold the same bits."""
    return [(v & 0xFFFF) - 0x10000 if v & 0x8000 else v & 0xFFFF for v in values]


def _char_parameter(texts: list[str]) -> bytes:
    """A character parameter's type, dimensions and data: one string [width], or several [width, count]."""
    width = max([1, *(len(text) for text in texts)])
    data = "".join(text.ljust(width) for text in texts).encode("ascii", errors="replace")
    dims = bytes([width, len(texts)]) if len(texts) != 1 else bytes([width])
    return struct.pack("<bB", -1, len(dims)) + dims + data


def _int_parameter(values: list[int]) -> bytes:
    """An int16 parameter: a scalar (no dimension) or a vector [n]."""
    dims = bytes([len(values)]) if len(values) != 1 else b""
    return struct.pack("<bB", 2, len(dims)) + dims + struct.pack(f"<{len(values)}h", *_words(values))


def _float_parameter(value: float) -> bytes:
    return struct.pack("<bBf", 4, 0, value)


def _record(name: str, group_id: int, body: bytes, *, last: bool = False) -> bytes:
    """One group (``group_id`` < 0, empty ``body``) or parameter record: name, the offset from its own word to
    the next record (0 after the last: the end of the section), ``body``, an empty description."""
    encoded = name.upper().encode("ascii")
    rest = body + b"\x00"
    return struct.pack("<bb", len(encoded), group_id) + encoded + struct.pack("<h", 0 if last else 2 + len(rest)) + rest


def _off_grid(times: np.ndarray, rate: float) -> tuple[int, np.ndarray]:
    """The 0-based number of the first frame on the ``rate`` grid from t = 0, and which times lie off that grid
    by more than the rounding of a time column written to the millisecond (TRC files) or 1 % of a frame."""
    frames = times * rate
    first = int(np.rint(frames[0]))
    tolerance = max(0.01, ROUNDING_S * rate)
    return first, np.abs(frames - (first + np.arange(len(times)))) > tolerance


def _frame_grid(markers: Markers, rate: float | None, path: Path) -> tuple[float, int]:
    """The rate and first frame the file records: ``rate`` if given, else the markers' rate rounded to a whole
    number of Hz where the times fit that grid too (a TRC's 60.00 Hz whose times were rounded to 3 decimals
    measures 60.004 Hz), else the markers' own; ConfigError where a time is off the grid or t0 < 0."""
    if rate is None:
        rate = markers.rate
        if not np.isfinite(rate) or rate <= 0:
            raise ConfigError(f"{path}: a single-frame marker set has no rate: pass rate=")
        whole = float(round(rate))
        if whole > 0 and not _off_grid(markers.times, whole)[1].any():
            rate = whole
    first, off_grid = _off_grid(markers.times, float(rate))
    if first < 0 or off_grid.any():
        frame = int(np.flatnonzero(off_grid)[0]) if off_grid.any() else 0
        raise ConfigError(
            f"{path}: frame {frame} at t = {markers.times[frame]:g} s is not on the {rate:g} Hz grid "
            "from t >= 0 that C3D frame numbers need (resample the markers first)"
        )
    if first + markers.n_frames > MAX_FRAMES:
        raise ConfigError(
            f"{path}: frames {first + 1}-{first + markers.n_frames} run past C3D's 16-bit frame numbers ({MAX_FRAMES})"
        )
    return float(rate), first


def _parameters(markers: Markers, rate: float, first: int, data_start: int) -> bytes:
    """The parameter records: POINT (with LABELS2 ... past 255 markers), ANALOG (none used) and TRIAL."""
    names = list(markers.names)
    chunks = [names[i : i + MAX_ENTRIES] for i in range(0, len(names), MAX_ENTRIES)] or [[]]
    labels = []
    for k, chunk in enumerate(chunks):
        suffix = "" if k == 0 else str(k + 1)
        labels += [
            (f"LABELS{suffix}", 1, _char_parameter(chunk)),
            (f"DESCRIPTIONS{suffix}", 1, _char_parameter([""] * len(chunk))),
        ]
    start, end = first + 1, first + markers.n_frames  # 1-based frame numbers
    records = [
        ("POINT", -1, b""),
        ("USED", 1, _int_parameter([len(names)])),
        ("SCALE", 1, _float_parameter(-1.0)),
        ("RATE", 1, _float_parameter(rate)),
        ("DATA_START", 1, _int_parameter([data_start])),
        ("FRAMES", 1, _int_parameter([markers.n_frames])),
        ("UNITS", 1, _char_parameter(["mm"])),
        *labels,
        ("ANALOG", -2, b""),
        ("USED", 2, _int_parameter([0])),
        ("RATE", 2, _float_parameter(rate)),
        # frame numbers as two 16-bit words (low, high), the standard's way past 65535
        ("TRIAL", -3, b""),
        ("ACTUAL_START_FIELD", 3, _int_parameter([start & 0xFFFF, start >> 16])),
        ("ACTUAL_END_FIELD", 3, _int_parameter([end & 0xFFFF, end >> 16])),
    ]
    return b"".join(_record(*r, last=i == len(records) - 1) for i, r in enumerate(records))


def write_c3d(path: str | Path, markers: Markers, *, rate: float | None = None) -> Path:
    """Write `Markers` as a C3D file (3D points only, millimetres, float32, the markers' own frame), atomically.

    An occluded sample (NaN) is stored as zeros with the fourth word -1, the standard's invalid point; the first
    time as the first frame number ``round(t0 rate) + 1`` (header and ``TRIAL:ACTUAL_START_FIELD``), so that
    `biomotion.io.c3d.read_c3d_markers` gives the times back. The times must lie on the grid of ``rate`` (default:
    the markers' own, a whole number of Hz where the times fit it; a single frame has none, so it must then be
    given) from t0 >= 0, within half a millisecond (times written to 3 decimals) or 1 % of a frame.
    """
    path = Path(path)
    if rate is not None and not (np.isfinite(rate) and rate > 0):
        raise ConfigError(f"{path}: rate must be positive, got {rate}")
    rate, first = _frame_grid(markers, rate, path)
    parameter_blocks = _block_count(4 + len(_parameters(markers, rate, first, 0)))  # DATA_START's value: same size
    data_start = 2 + parameter_blocks
    section = struct.pack("<BBBB", 1, KEY, parameter_blocks, INTEL) + _parameters(markers, rate, first, data_start)
    header = np.zeros(BLOCK // 2, dtype="<i2")
    header[:6] = _words([2 | KEY << 8, len(markers.names), 0, first + 1, first + markers.n_frames, 0])
    header[6:8] = np.frombuffer(struct.pack("<f", -1.0), dtype="<i2")
    header[8:10] = [data_start, 0]
    header[10:12] = np.frombuffer(struct.pack("<f", rate), dtype="<i2")
    missing = ~np.isfinite(markers.positions).all(axis=-1)  # [T, M]
    points = np.empty((markers.n_frames, len(markers.names), 4), dtype="<f4")
    points[..., :3] = np.where(missing[..., None], 0.0, markers.positions * 1000.0)
    points[..., 3] = np.where(missing, INVALID, 0.0)
    data = points.tobytes()
    with atomic_write(path, "wb") as handle:
        handle.write(header.tobytes())
        handle.write(section.ljust(parameter_blocks * BLOCK, b"\x00"))
        handle.write(data.ljust(_block_count(len(data)) * BLOCK, b"\x00"))
    return path
