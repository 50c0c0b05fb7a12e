"""Fit the ANSUR II segment lines that `biomotion.body.scaling.segments` ships (``ansur_segments.json``): per
segment, the least-squares line of its length against stature over the ANSUR II men (``biomotion train segments``)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from biomotion.body.scaling.segments import ANSUR_MEN, MEASURES, SEGMENTS
from biomotion.errors import DataFormatError


def _number(path: Path, line: int, row: dict, column: str) -> float:
    """A measure of an ANSUR II row, in mm; a row cut short or a cell that is not a finite number names its line."""
    raw = row.get(column)
    if raw is None:
        raise DataFormatError(path, "the row ends early (a file cut short?)", line=line, field=column)
    try:
        value = float(raw)
    except ValueError:
        raise DataFormatError(path, f"not a number: {raw!r}", line=line, field=column) from None
    if not np.isfinite(value):
        raise DataFormatError(path, f"not a finite number: {raw!r}", line=line, field=column)
    return value


def fit_lines(ansur_csv: str | Path) -> dict:
    """Least-squares line ``length = intercept + slope * stature`` (mm) of every segment over the rows of an ANSUR
    II file, with the residual standard deviation."""
    path = Path(ansur_csv)
    try:
        with open(path, newline="", encoding="latin-1") as handle:
            reader = csv.DictReader(handle)
            table = [(reader.line_num, row) for row in reader]
    except OSError as error:
        raise DataFormatError(path, f"cannot read: {error.strerror}") from None
    missing = [m for m in ("stature", *MEASURES) if table and m not in table[0][1]]
    if not table or missing:
        raise DataFormatError(path, f"not an ANSUR II table: no rows or no column {', '.join(missing)}", line=1)
    rows = [{column: _number(path, line, row, column) for column in ("stature", *MEASURES)} for line, row in table]
    stature = np.array([r["stature"] for r in rows])
    lines = {}
    for segment in SEGMENTS:
        length = np.array([segment.length({k: r[k] for k in MEASURES}) for r in rows])
        slope, intercept = np.polyfit(stature, length, 1)
        residual = length - (intercept + slope * stature)
        lines[segment.name] = {
            "top": segment.top,
            "bottom": segment.bottom,
            "intercept_mm": round(float(intercept), 4),
            "slope": round(float(slope), 6),
            "residual_sd_mm": round(float(residual.std()), 3),
        }
    return {"source": ANSUR_MEN, "subjects": len(rows), "segments": lines}
