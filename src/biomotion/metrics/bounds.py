"""Percentile bounds from training data, shared by the plausibility metrics and the generator's guidance.

PG-BIG (Sec. 3.3, Table 1) bounds every guided quantity by percentiles of the training data: joint angular speed
by its 95th percentile per coordinate, COM speed and acceleration magnitude and each muscle activation by their
5th-95th percentiles. `PercentileBounds` holds one (low, high) pair per named column, is computed from tensors with
masks, and is saved as JSON.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from biomotion.errors import DataFormatError
from biomotion.io.atomic import atomic_write
from biomotion.metrics.base import Tensor

FORMAT = "biomotion-percentile-bounds/1"


@dataclass(frozen=True)
class PercentileBounds:
    """Per-column (low, high) percentiles of a quantity.

    Attributes:
        names: one name per column (coordinate, muscle, or a COM term such as ``"com_speed"``).
        low, high: [n] float64 bounds; NaN where a column had no sample (that side is then unbounded).
        percentiles: the (low, high) percentiles the bounds are, e.g. (5, 95).
        quantity: what was measured, e.g. ``"coordinate speed |dq/dt|"``.
        unit: SI unit of the bounds, e.g. ``"rad/s"``.
        counts: [n] number of samples behind each column.
    """

    names: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray
    percentiles: tuple[float, float] = (5.0, 95.0)
    quantity: str = ""
    unit: str = ""
    counts: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        n = len(self.names)
        low = np.asarray(self.low, dtype=np.float64).reshape(-1)
        high = np.asarray(self.high, dtype=np.float64).reshape(-1)
        counts = np.asarray(self.counts, dtype=np.int64).reshape(-1)
        if counts.size == 0:
            counts = np.zeros(n, dtype=np.int64)
        for label, array in (("low", low), ("high", high), ("counts", counts)):
            if array.size != n:
                raise DataFormatError(None, f"has {array.size} entries for {n} names", field=label)
        if len(set(self.names)) != n:
            raise DataFormatError(None, "duplicate column names", field="names")
        if np.any(low > high):
            bad = int(np.flatnonzero(low > high)[0])
            raise DataFormatError(None, f"low {low[bad]} > high {high[bad]}", field=self.names[bad])
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)
        object.__setattr__(self, "counts", counts)
        object.__setattr__(self, "percentiles", tuple(float(p) for p in self.percentiles))

    @classmethod
    def from_samples(
        cls,
        values,
        names: Sequence[str],
        *,
        mask=None,
        percentiles: tuple[float, float] = (5.0, 95.0),
        quantity: str = "",
        unit: str = "",
    ) -> PercentileBounds:
        """Percentiles per column of ``values`` [..., n] over every leading dim, where ``mask`` is True.

        ``mask`` broadcasts to ``values`` ([..., n] per-column, [..., T, 1] per-frame, or full); NaN samples are
        ignored too. Percentiles use linear interpolation between order statistics (``numpy.nanpercentile``).
        """
        array = values.detach().cpu().numpy() if isinstance(values, Tensor) else np.asarray(values)
        array = np.asarray(array, dtype=np.float64)
        if array.ndim < 1 or array.shape[-1] != len(names):
            raise DataFormatError(
                None, f"last dim of shape {array.shape} must match {len(names)} names", field="values"
            )
        if mask is not None:
            keep = mask.detach().cpu().numpy() if isinstance(mask, Tensor) else np.asarray(mask)
            try:
                keep = np.broadcast_to(keep.astype(bool), array.shape)
            except ValueError as err:
                raise DataFormatError(
                    None, f"shape {keep.shape} does not broadcast to {array.shape}", field="mask"
                ) from err
            array = np.where(keep, array, np.nan)
        flat = array.reshape(-1, len(names))
        counts = np.isfinite(flat).sum(axis=0)
        low = np.full(len(names), np.nan)
        high = np.full(len(names), np.nan)
        some = counts > 0
        if some.any():
            low[some], high[some] = np.nanpercentile(flat[:, some], percentiles, axis=0)
        return cls(tuple(names), low, high, percentiles, quantity, unit, counts)

    def select(self, names: Sequence[str]) -> PercentileBounds:
        """The bounds of ``names`` in that order; a name without bounds raises `DataFormatError`."""
        index = {name: i for i, name in enumerate(self.names)}
        missing = [name for name in names if name not in index]
        if missing:
            raise DataFormatError(None, f"no bounds for {', '.join(missing)}", field="names")
        rows = [index[name] for name in names]
        return PercentileBounds(
            tuple(names), self.low[rows], self.high[rows], self.percentiles, self.quantity, self.unit, self.counts[rows]
        )

    def tensors(self, dtype=torch.float64, device=None) -> tuple[Tensor, Tensor]:
        """(low, high) as tensors with NaN replaced by -inf / +inf (an unknown side does not bound)."""
        low = torch.as_tensor(np.nan_to_num(self.low, nan=-np.inf), dtype=dtype, device=device)
        high = torch.as_tensor(np.nan_to_num(self.high, nan=np.inf), dtype=dtype, device=device)
        return low, high

    def excess(self, values: Tensor) -> Tensor:
        """``max(0, x - high, low - x)`` per entry of ``values`` [..., n] (PG-BIG Table 1); 0 inside the bounds."""
        low, high = self.tensors(values.dtype, values.device)
        return bound_excess(values, low, high)

    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "quantity": self.quantity,
            "unit": self.unit,
            "percentiles": list(self.percentiles),
            "columns": [
                {"name": name, "low": _json_float(lo), "high": _json_float(hi), "count": int(count)}
                for name, lo, hi, count in zip(self.names, self.low, self.high, self.counts)
            ],
        }

    @classmethod
    def from_dict(cls, data: dict, path: str | Path | None = None) -> PercentileBounds:
        if data.get("format") != FORMAT:
            raise DataFormatError(path, f"not a {FORMAT} document (format={data.get('format')!r})", field="format")
        try:
            columns = data["columns"]
            names = tuple(str(c["name"]) for c in columns)
            low = [math.nan if c["low"] is None else float(c["low"]) for c in columns]
            high = [math.nan if c["high"] is None else float(c["high"]) for c in columns]
            counts = [int(c.get("count", 0)) for c in columns]
            percentiles = tuple(float(p) for p in data["percentiles"])
        except (KeyError, TypeError, ValueError) as err:
            raise DataFormatError(path, f"malformed bounds: {err}", field="columns") from err
        if len(percentiles) != 2:
            raise DataFormatError(path, f"needs two percentiles, got {percentiles}", field="percentiles")
        try:
            return cls(
                names,
                np.array(low),
                np.array(high),
                percentiles,
                str(data.get("quantity", "")),
                str(data.get("unit", "")),
                np.array(counts, dtype=np.int64),
            )
        except DataFormatError as err:
            raise DataFormatError(path, str(err), field=err.field) from err

    def save(self, path: str | Path) -> None:
        """Write as JSON (atomically); missing bounds are ``null``."""
        with atomic_write(path) as handle:
            json.dump(self.to_dict(), handle, indent=1)

    @classmethod
    def load(cls, path: str | Path) -> PercentileBounds:
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as err:
            raise DataFormatError(path, f"invalid JSON: {err.msg}", line=err.lineno) from err
        return cls.from_dict(data, path)


def bound_excess(values: Tensor, low: Tensor, high: Tensor) -> Tensor:
    """``max(0, x - high, low - x)``: how far each entry lies outside [low, high] (PG-BIG Table 1 losses)."""
    zero = torch.zeros((), dtype=values.dtype, device=values.device)
    return torch.maximum(torch.maximum(values - high, low - values), zero)


def _json_float(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)
