"""Plain CSV for time series: one ``time`` column, then one column per channel, SI units.

Coordinates keep their names (rad / m); markers become ``<name>_x, <name>_y, <name>_z`` (m), occluded samples
empty cells. `read_motion_csv` refuses empty and NaN cells unless asked to keep them as gaps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from biomotion.errors import DataFormatError
from biomotion.io.tables import write_csv
from biomotion.motion import Markers, Motion


def write_motion_csv(path: str | Path, motion: Motion) -> Path:
    """Coordinates as CSV (SI units: rad and m), header ``time,<coordinate>...``."""
    rows = np.column_stack([motion.times, motion.values]).tolist()
    return write_csv(path, ["time", *motion.names], rows)


def write_markers_csv(path: str | Path, markers: Markers) -> Path:
    """Markers as CSV in metres, header ``time,<m>_x,<m>_y,<m>_z...``; occluded samples are empty."""
    header = ["time"] + [f"{name}_{axis}" for name in markers.names for axis in "xyz"]
    flat = markers.positions.reshape(markers.n_frames, -1)
    rows = [[float(t)] + ["" if not np.isfinite(v) else float(v) for v in row] for t, row in zip(markers.times, flat)]
    return write_csv(path, header, rows)


def read_motion_csv(path: str | Path, *, allow_gaps: bool = False) -> Motion:
    """Read a CSV written by `write_motion_csv` (or any ``time,...`` table in SI units).

    Every row needs one cell per header column and a finite number in every cell: a row with another cell count,
    a token that is not a number, an infinite value, or (unless ``allow_gaps``) an empty or NaN cell is a
    `DataFormatError` naming the line and column. With ``allow_gaps=True`` empty and NaN cells are kept as NaN
    (a marker CSV from `write_markers_csv` leaves occluded samples empty); the time column never has gaps.
    """
    path = Path(path)
    if path.is_dir():
        raise DataFormatError(path, "is a directory, not a CSV file")
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise DataFormatError(path, "no such file") from None
    except UnicodeDecodeError as error:
        raise DataFormatError(path, f"not UTF-8 text: {error.reason}") from None
    except OSError as error:
        raise DataFormatError(path, f"cannot read: {error.strerror}") from None
    if not "".join(lines).strip():
        raise DataFormatError(path, "empty file", line=1)
    header = [h.strip() for h in lines[0].split(",")]
    if header[0] != "time":
        raise DataFormatError(path, f"first column must be 'time', found {header[0]!r}", line=1)
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != len(header):
            raise DataFormatError(path, f"{len(cells)} cells but {len(header)} columns", line=number)
        row = []
        for column, cell in zip(header, cells):
            try:
                value = float(cell) if cell.strip() else np.nan
            except ValueError:
                raise DataFormatError(path, f"not a number: {cell.strip()!r}", line=number, field=column) from None
            if np.isinf(value) or (np.isnan(value) and (not allow_gaps or column == "time")):
                what = "empty" if not cell.strip() else f"{cell.strip()!r}, not a finite number"
                hint = (
                    ""
                    if np.isinf(value) or column == "time"
                    else " (a caller that handles gaps reads the file with allow_gaps=True)"
                )
                raise DataFormatError(path, f"cell is {what}{hint}", line=number, field=column)
            row.append(value)
        rows.append(row)
    if not rows:
        raise DataFormatError(path, "no data rows", line=2)
    data = np.array(rows)
    return Motion(times=data[:, 0], names=tuple(header[1:]), values=data[:, 1:])
