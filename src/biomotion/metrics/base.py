"""What every metric shares: the ``update()`` / ``compute()`` protocol, the per-sequence result, masked reductions and
finite differences.

Protocol. A metric scores whole sequences: ``score(...)`` is a pure, differentiable function of tensors with any
leading batch dims ``[...]`` and returns one value per sequence (shape ``[...]``, NaN where the metric is undefined
for that sequence, e.g. a sliding metric on a clip without contact). ``update(...)`` calls ``score`` and keeps the
values; ``compute()`` returns their mean and standard deviation over all sequences seen, ignoring NaN. This is the
protocol of PG-BIG Sec. 4.2 ("All metrics are computed per motion sequence and averaged across the test set",
reported as mean ± std in Table 2).

Units are SI throughout (m, s, rad, J); papers that print cm or mm are converted only when reporting.

Description. Like torchmetrics' ``higher_is_better``, every metric object carries what a report needs to print and
judge it, so no table elsewhere restates it (`DESCRIPTION` lists the fields): ``name`` (the key of JSON records),
``label`` (the human name of a table header), ``unit`` (SI unit of ``score``), ``higher_is_better`` (True, False,
or None for "closer to the reference is better", e.g. entropy and diversity), ``paper`` and ``equation`` (where the
metric is defined and its formula), and how reports print it: ``display_scale`` times the value in
``display_unit`` (e.g. m printed as cm: 100, "cm"; empty ``display_unit`` prints ``unit``). A configured variant
derives its name and label from the configuration that changes what it measures (``Penetration(ground=
"clip_median")`` is ``penetration_median``, "Penetration (clip median)"); thresholds and joint indices do not.

Masks. ``valid`` is an optional per-frame validity mask ``[..., T]`` (False on padding of a batch); it removes
frames from every average, and a finite difference is valid only where all frames it uses are valid.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import torch

from biomotion.errors import DataFormatError

Tensor = torch.Tensor


@dataclass(frozen=True)
class MetricResult:
    """The result of `Metric.compute`: mean ± std over the sequences where the metric is defined.

    Attributes:
        name: metric name.
        unit: SI unit of the values ("m", "m/s", "1" for ratios ...).
        mean: mean over defined (finite) per-sequence values; NaN when none is defined.
        std: population standard deviation of the same values (0 for one value).
        count: number of sequences with a defined value.
        values: [N] every per-sequence value in update order, NaN where undefined (float64, CPU).
    """

    name: str
    unit: str
    mean: float
    std: float
    count: int
    values: Tensor

    def __float__(self) -> float:
        return self.mean


DESCRIPTION = ("name", "label", "unit", "higher_is_better", "paper", "equation", "display_unit", "display_scale")
"""The fields with which a metric describes itself (module docstring, "Description")."""

ARROWS = {True: "↑", False: "↓", None: "→"}
"""Direction mark of a report header per ``higher_is_better`` (PG-BIG Table 2 prints ↓ and →)."""


class Metric(ABC):
    """A per-sequence metric with ``update()`` / ``compute()`` that describes itself (see the module docstring).

    ``higher_is_better`` has no default: a metric that does not declare its direction fails when asked for it.
    """

    name: str = ""
    label: str = ""
    unit: str = ""
    higher_is_better: bool | None
    paper: str = ""
    equation: str = ""
    display_unit: str = ""
    display_scale: float = 1.0

    @property
    def arrow(self) -> str:
        """The report's direction mark, from ``higher_is_better``: ↑ higher, ↓ lower, → closer to the reference."""
        return ARROWS[self.higher_is_better]

    def __init__(self) -> None:
        self._values: list[Tensor] = []

    def reset(self) -> None:
        """Forget every value seen so far."""
        self._values = []

    @abstractmethod
    def score(self, *args, **kwargs) -> Tensor:
        """One value per sequence, shape ``[...]`` (the leading dims of the inputs)."""

    def update(self, *args, **kwargs) -> Tensor:
        """Score a batch, keep its values and return them."""
        values = self.score(*args, **kwargs)
        self._values.append(values.detach().reshape(-1).to("cpu", torch.float64))
        return values

    def compute(self) -> MetricResult:
        """Mean ± std over every sequence seen since the last `reset`."""
        values = torch.cat(self._values) if self._values else torch.zeros(0, dtype=torch.float64)
        return summarize(self.name, self.unit, values)


def summarize(name: str, unit: str, values: Tensor) -> MetricResult:
    """`MetricResult` of per-sequence ``values`` (NaN = undefined, excluded from mean and std)."""
    values = values.detach().reshape(-1).to("cpu", torch.float64)
    finite = values[torch.isfinite(values)]
    if finite.numel() == 0:
        return MetricResult(name, unit, float("nan"), float("nan"), 0, values)
    return MetricResult(
        name, unit, float(finite.mean()), float(finite.std(unbiased=False)), int(finite.numel()), values
    )


def as_tensor(x, name: str, *, min_dims: int = 1, last: int | tuple[int, ...] | None = None) -> Tensor:
    """``x`` (tensor or array) as a floating tensor, checking its rank and last dim; bad input raises
    `DataFormatError` naming the field."""
    if not isinstance(x, Tensor):
        x = torch.as_tensor(np.asarray(x))
    if not x.is_floating_point():
        x = x.to(torch.get_default_dtype())
    if x.dim() < min_dims:
        raise DataFormatError(None, f"needs at least {min_dims} dims, got shape {tuple(x.shape)}", field=name)
    if last is not None:
        allowed = (last,) if isinstance(last, int) else last
        if x.shape[-1] not in allowed:
            raise DataFormatError(
                None, f"last dim must be {' or '.join(map(str, allowed))}, got shape {tuple(x.shape)}", field=name
            )
    return x


def as_mask(mask, shape: tuple[int, ...] | torch.Size, name: str, device=None) -> Tensor:
    """A boolean mask broadcast to ``shape`` (all True when ``mask`` is None)."""
    if mask is None:
        return torch.ones(shape, dtype=torch.bool, device=device)
    mask = torch.as_tensor(np.asarray(mask) if not isinstance(mask, Tensor) else mask, device=device)
    try:
        return torch.broadcast_to(mask.to(torch.bool), shape)
    except RuntimeError as err:
        raise DataFormatError(
            None, f"shape {tuple(mask.shape)} does not broadcast to {tuple(shape)}", field=name
        ) from err


def frame_mask(valid, batch_time: tuple[int, ...] | torch.Size, device=None) -> Tensor:
    """The per-frame validity mask ``valid`` [..., T] as booleans of shape ``batch_time`` ([..., T])."""
    return as_mask(valid, tuple(batch_time), "valid", device)


def column_mask(mask, shape: tuple[int, ...] | torch.Size, order: int = 0, name: str = "mask", device=None) -> Tensor:
    """Mask of the columns (coordinates, joints, muscles) of a [..., T, n] series, as [..., T - order, n].

    ``mask`` is per sequence, [..., n], or per frame, [..., T, n] (recognised by having as many dims as ``shape``);
    a per-frame mask is True at t where it is True at every frame t .. t + order a difference of that order uses.
    """
    shape = tuple(shape)
    out = shape[:-2] + (shape[-2] - order, shape[-1])
    if mask is None:
        return torch.ones(out, dtype=torch.bool, device=device)
    mask = torch.as_tensor(np.asarray(mask) if not isinstance(mask, Tensor) else mask, device=device).to(torch.bool)
    if mask.dim() == len(shape):
        mask = pair_mask(mask.transpose(-1, -2), order).transpose(-1, -2)
    else:
        mask = mask.unsqueeze(-2)
    return as_mask(mask, out, name, device)


def masked_mean(x: Tensor, mask: Tensor, dim: int | tuple[int, ...]) -> Tensor:
    """Mean of ``x`` over ``dim`` where ``mask`` is True; NaN where no entry is selected."""
    mask = torch.broadcast_to(mask, x.shape)
    total = torch.where(mask, x, torch.zeros((), dtype=x.dtype, device=x.device)).sum(dim)
    count = mask.sum(dim).to(x.dtype)
    return total / count  # 0/0 -> NaN marks "undefined"


def masked_sum(x: Tensor, mask: Tensor, dim: int | tuple[int, ...]) -> Tensor:
    """Sum of ``x`` over ``dim`` where ``mask`` is True."""
    mask = torch.broadcast_to(mask, x.shape)
    return torch.where(mask, x, torch.zeros((), dtype=x.dtype, device=x.device)).sum(dim)


def pair_mask(valid: Tensor, order: int = 1) -> Tensor:
    """[..., T - order]: True where frames t .. t + order are all valid (the frames a difference of that order uses)."""
    out = valid[..., : valid.shape[-1] - order]
    for k in range(1, order + 1):
        out = out & valid[..., k : valid.shape[-1] - order + k]
    return out


def difference(x: Tensor, rate: float, order: int = 1, *, dim: int = -2) -> Tensor:
    """Forward finite difference of ``order`` along the time ``dim``, divided by (1/rate)^order.

    ``d^k x / dt^k`` at frame t is estimated from frames t .. t + k (``torch.diff`` applied k times), so a
    ``[..., T, ...]`` input gives ``[..., T - k, ...]``; pair it with ``pair_mask(valid, k)``.
    """
    if rate <= 0:
        raise DataFormatError(None, f"rate must be positive, got {rate}", field="rate")
    if x.shape[dim] <= order:
        raise DataFormatError(
            None, f"needs more than {order} frames along dim {dim}, got shape {tuple(x.shape)}", field="T"
        )
    return torch.diff(x, n=order, dim=dim) * float(rate) ** order


def ground_plane(points: Tensor) -> Tensor:
    """Horizontal components (x, z) of y-up points [..., 3]; [..., 2] inputs are taken as (x, z) already."""
    return points[..., [0, 2]] if points.shape[-1] == 3 else points
