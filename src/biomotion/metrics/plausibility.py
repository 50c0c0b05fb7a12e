"""Biomechanical plausibility: how often, and by how much, motion leaves bounds learnt from data or set by the model.

PG-BIG Table 1 defines five guidance losses against percentile bounds (`biomotion.metrics.bounds`); as metrics they
are reported two ways, chosen by ``statistic``:

- ``"rate"``: share of the bounded entries (frame x coordinate, frame x muscle, or frame for a COM term) outside
  their bounds;
- ``"excess"``: the Table 1 loss itself, ``(1/T) sum_t sum_j max(0, x_tj - high_j, low_j - x_tj)`` (units of x).

FlexMotion's "Muscle Limit" (Sec. 4 and App., after Lee et al. 2019) checks activations against physiological
limits, and joint-range violations check coordinates against the model's ranges of motion; both are the same test
with other bounds.

Inputs: coordinates ``q`` [..., T, n] (rad, or m for translations) with an optional coordinate mask ``mask``
[..., n] per sequence or [..., T, n] per frame (recognised by having as many dims as ``q``); COM [..., T, 3] (m);
activations [..., T, m] in [0, 1]; ``valid`` [..., T].
"""

from __future__ import annotations

import torch

from biomotion.errors import DataFormatError
from biomotion.metrics.base import (
    Metric,
    Tensor,
    as_tensor,
    column_mask,
    difference,
    frame_mask,
    masked_mean,
    masked_sum,
    pair_mask,
)
from biomotion.metrics.bounds import PercentileBounds, bound_excess

STATISTICS = ("rate", "excess")


def coordinate_speed(q, rate: float) -> Tensor:
    """[..., T - 1, n] ``|dq/dt|`` of each coordinate (rad/s or m/s), forward differences."""
    q = as_tensor(q, "q", min_dims=2)
    return difference(q, rate, dim=-2).abs()


def com_speed(com, rate: float) -> Tensor:
    """[..., T - 1, 1] ``||c_dot||`` (m/s), forward differences."""
    com = as_tensor(com, "com", min_dims=2, last=3)
    return torch.linalg.vector_norm(difference(com, rate, dim=-2), dim=-1, keepdim=True)


def com_acceleration(com, rate: float) -> Tensor:
    """[..., T - 2, 1] ``||c_ddot||`` (m/s^2), second forward differences."""
    com = as_tensor(com, "com", min_dims=2, last=3)
    return torch.linalg.vector_norm(difference(com, rate, 2, dim=-2), dim=-1, keepdim=True)


def _limits(values: Tensor, bounds: PercentileBounds | None, low, high) -> tuple[Tensor, Tensor]:
    if bounds is not None:
        if len(bounds.names) != values.shape[-1]:
            raise DataFormatError(None, f"{len(bounds.names)} bounds for {values.shape[-1]} columns", field="bounds")
        return bounds.tensors(values.dtype, values.device)
    inf = float("inf")
    low = torch.as_tensor(-inf if low is None else low, dtype=values.dtype, device=values.device)
    high = torch.as_tensor(inf if high is None else high, dtype=values.dtype, device=values.device)
    return torch.nan_to_num(low, nan=-inf), torch.nan_to_num(high, nan=inf)


def bound_violation(
    values, *, low=None, high=None, bounds: PercentileBounds | None = None, mask=None, statistic: str = "rate"
) -> Tensor:
    """Per sequence [...]: share of the masked entries of ``values`` [..., T, n] outside [low, high] (``"rate"``),
    or ``(1/T) sum_t sum_j excess_tj`` over the T frames with a masked entry (``"excess"``, PG-BIG Table 1).

    ``bounds`` (a `PercentileBounds` whose columns match the last dim) or ``low`` / ``high`` (scalars or [n];
    None or NaN = unbounded) give the limits; ``mask`` is per sequence [..., n] or per frame [..., T, n]. NaN for
    a sequence without masked entries.
    """
    values = as_tensor(values, "values", min_dims=2)
    if statistic not in STATISTICS:
        raise DataFormatError(None, f"statistic must be one of {STATISTICS}, got {statistic!r}", field="statistic")
    lo, hi = _limits(values, bounds, low, high)
    mask = column_mask(mask, values.shape, 0, "mask", values.device)
    excess = bound_excess(values, lo, hi)
    if statistic == "rate":
        return masked_mean((excess > 0).to(values.dtype), mask, (-2, -1))
    return masked_sum(excess, mask, (-2, -1)) / mask.any(-1).sum(-1).to(values.dtype)


def _column_mask(mask, values: Tensor, valid, order: int) -> Tensor:
    """[..., T - order, n] for ``values`` [..., T, n]: frames t..t+order valid and the column present there."""
    frames = pair_mask(frame_mask(valid, values.shape[:-1], values.device), order)[..., None]
    return frames & column_mask(mask, values.shape, order, "mask", values.device)


def angular_velocity_violation(
    q, rate: float, *, bounds: PercentileBounds | None = None, high=None, mask=None, valid=None, statistic: str = "rate"
) -> Tensor:
    """PG-BIG Table 1 L_omega: ``|dq_j/dt|`` above its 95th-percentile bound ``high_j`` (upper side only: the low
    side of ``bounds`` is ignored). Table 1 takes ``||q_dot_tj||`` per joint; biomotion bounds each coordinate (each
    degree of freedom of a joint) on its own, the Rajagopal coordinates being scalars."""
    q = as_tensor(q, "q", min_dims=2)
    speed = coordinate_speed(q, rate)
    upper = _limits(speed, bounds, None, high)[1]
    return bound_violation(speed, high=upper, mask=_column_mask(mask, q, valid, 1), statistic=statistic)


def com_velocity_violation(
    com,
    rate: float,
    *,
    bounds: PercentileBounds | None = None,
    low=None,
    high=None,
    valid=None,
    statistic: str = "rate",
) -> Tensor:
    """PG-BIG Table 1 L_v: ``||c_dot||`` outside its 5-95th percentile bounds (one column, e.g. ``"com_speed"``)."""
    com = as_tensor(com, "com", min_dims=2, last=3)
    speed = com_speed(com, rate)
    return bound_violation(
        speed,
        low=low,
        high=high,
        bounds=bounds,
        mask=pair_mask(frame_mask(valid, com.shape[:-1], com.device))[..., None],
        statistic=statistic,
    )


def com_acceleration_violation(
    com,
    rate: float,
    *,
    bounds: PercentileBounds | None = None,
    low=None,
    high=None,
    valid=None,
    statistic: str = "rate",
) -> Tensor:
    """PG-BIG Table 1 L_a: ``||c_ddot||`` outside its 5-95th percentile bounds (one column)."""
    com = as_tensor(com, "com", min_dims=2, last=3)
    accel = com_acceleration(com, rate)
    return bound_violation(
        accel,
        low=low,
        high=high,
        bounds=bounds,
        mask=pair_mask(frame_mask(valid, com.shape[:-1], com.device), 2)[..., None],
        statistic=statistic,
    )


def activation_violation(
    activations,
    *,
    bounds: PercentileBounds | None = None,
    low=0.0,
    high=1.0,
    mask=None,
    valid=None,
    statistic: str = "rate",
) -> Tensor:
    """PG-BIG Table 1 L_act with 5-95th percentile ``bounds`` per muscle; without bounds, FlexMotion's "Muscle
    Limit" against the physiological range [0, 1]."""
    a = as_tensor(activations, "activations", min_dims=2)
    return bound_violation(
        a, low=low, high=high, bounds=bounds, mask=_column_mask(mask, a, valid, 0), statistic=statistic
    )


def joint_range_violation(
    q, *, low=None, high=None, bounds: PercentileBounds | None = None, mask=None, valid=None, statistic: str = "rate"
) -> Tensor:
    """Coordinates outside their range of motion [low_j, high_j] (the model's coordinate ranges, or percentile
    ``bounds`` of q)."""
    q = as_tensor(q, "q", min_dims=2)
    return bound_violation(
        q, low=low, high=high, bounds=bounds, mask=_column_mask(mask, q, valid, 0), statistic=statistic
    )


class _BoundMetric(Metric):
    """A bound violation metric: ``statistic`` "rate" (share, unit 1, printed in %) or "excess" (Table 1 loss, unit
    of x; named ``<name>_excess``, labelled "... (excess)"). ``equation`` is the rate's, ``excess_equation`` the
    excess's."""

    excess_unit = ""
    excess_equation = ""
    higher_is_better = False

    def __init__(self, bounds: PercentileBounds | None = None, *, low=None, high=None, statistic: str = "rate") -> None:
        super().__init__()
        if statistic not in STATISTICS:
            raise DataFormatError(None, f"statistic must be one of {STATISTICS}, got {statistic!r}", field="statistic")
        self.bounds, self.low, self.high, self.statistic = bounds, low, high, statistic
        if statistic == "rate":
            self.unit, self.display_unit, self.display_scale = "1", "%", 100.0
        else:
            self.unit, self.equation = self.excess_unit, self.excess_equation
            self.name, self.label = f"{self.name}_excess", f"{self.label} (excess)"


class AngularVelocityViolation(_BoundMetric):
    """`angular_velocity_violation` per sequence (PG-BIG Table 1 "Angular Velocity")."""

    name, label, excess_unit = "angular_velocity_violation", "Angular velocity violations", "rad/s"
    paper = "PG-BIG Sec. 3.3, Table 1 L_omega"
    equation = "share of frames x coordinates with |dq_j/dt| > qdot_j^high"
    excess_equation = "L_omega = (1/T) sum_t sum_j max(0, |dq_tj/dt| - qdot_j^high)"

    def score(self, q, rate: float, mask=None, valid=None) -> Tensor:
        return angular_velocity_violation(
            q, rate, bounds=self.bounds, high=self.high, mask=mask, valid=valid, statistic=self.statistic
        )


class ComVelocityViolation(_BoundMetric):
    """`com_velocity_violation` per sequence (PG-BIG Table 1 "COM Velocity")."""

    name, label, excess_unit = "com_velocity_violation", "COM velocity violations", "m/s"
    paper = "PG-BIG Sec. 3.3, Table 1 L_v"
    equation = "share of frames with ||c_dot_t|| outside [c_dot^low, c_dot^high]"
    excess_equation = "L_v = (1/T) sum_t max(0, ||c_dot_t|| - c_dot^high, c_dot^low - ||c_dot_t||)"

    def score(self, com, rate: float, valid=None) -> Tensor:
        return com_velocity_violation(
            com, rate, bounds=self.bounds, low=self.low, high=self.high, valid=valid, statistic=self.statistic
        )


class ComAccelerationViolation(_BoundMetric):
    """`com_acceleration_violation` per sequence (PG-BIG Table 1 "COM Acceleration")."""

    name, label, excess_unit = "com_acceleration_violation", "COM acceleration violations", "m/s^2"
    paper = "PG-BIG Sec. 3.3, Table 1 L_a"
    equation = "share of frames with ||c_ddot_t|| outside [c_ddot^low, c_ddot^high]"
    excess_equation = "L_a = (1/T) sum_t max(0, ||c_ddot_t|| - c_ddot^high, c_ddot^low - ||c_ddot_t||)"

    def score(self, com, rate: float, valid=None) -> Tensor:
        return com_acceleration_violation(
            com, rate, bounds=self.bounds, low=self.low, high=self.high, valid=valid, statistic=self.statistic
        )


class ActivationViolation(_BoundMetric):
    """`activation_violation` per sequence (PG-BIG Table 1 "Muscle Activation"; FlexMotion "Muscle Limit")."""

    name, label, excess_unit = "activation_violation", "Muscle activation violations", "1"
    paper = 'PG-BIG Sec. 3.3, Table 1 L_act; FlexMotion Sec. 4 and App. "Muscle Limit" (after Lee et al. 2019)'
    equation = "share of frames x muscles with a_tm outside [a_m^low, a_m^high] ([0, 1] without bounds)"
    excess_equation = "L_act = (1/T) sum_t sum_m max(0, a_tm - a_m^high, a_m^low - a_tm)"

    def __init__(self, bounds: PercentileBounds | None = None, *, low=0.0, high=1.0, statistic: str = "rate") -> None:
        super().__init__(bounds, low=low, high=high, statistic=statistic)

    def score(self, activations, mask=None, valid=None) -> Tensor:
        return activation_violation(
            activations,
            bounds=self.bounds,
            low=self.low,
            high=self.high,
            mask=mask,
            valid=valid,
            statistic=self.statistic,
        )


class JointRangeViolation(_BoundMetric):
    """`joint_range_violation` per sequence (coordinates outside their range of motion)."""

    name, label, excess_unit = "joint_range", "Out of range", "rad or m"
    paper = "range-of-motion check, no paper metric (ranges of the body model, e.g. Rajagopal et al. 2016)"
    equation = "share of frames x coordinates with q_j outside [q_j^low, q_j^high]"
    excess_equation = "(1/T) sum_t sum_j max(0, q_tj - q_j^high, q_j^low - q_tj)"

    def score(self, q, mask=None, valid=None) -> Tensor:
        return joint_range_violation(
            q, low=self.low, high=self.high, bounds=self.bounds, mask=mask, valid=valid, statistic=self.statistic
        )
