"""Plain CSV for time series: one ``time`` column, then one column per channel, SI units.

Coordinates keep their names (rad / m); markers become ``<name>_x, <name>_y, <name>_z`` (m). Empty cells are NaN.
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
    rows = [[float(t)] + ["" if not np.isfinite(v) else float(v) for v in row]
            for t, row in zip(markers.times, flat)]
    return write_csv(path, header, rows)


def read_motion_csv(path: str | Path) -> Motion:
    """Read a CSV written by `write_motion_csv` (or any ``time,...`` table in SI units)."""
    path = Path(path)
    lines = path.read_text(encoding="utf-8").splitlines()
    if not lines:
        raise DataFormatError(path, "empty file")
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
        try:
            rows.append([float(c) if c.strip() else np.nan for c in cells])
        except ValueError:
            raise DataFormatError(path, "not a number in row", line=number) from None
    if not rows:
        raise DataFormatError(path, "no data rows", line=2)
    data = np.array(rows)
    return Motion(times=data[:, 0], names=tuple(header[1:]), values=data[:, 1:])
