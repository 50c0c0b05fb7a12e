"""Smoothness and energy: PG-BIG's jerk index and energy consistency, PhysPT's ACCL and VEL errors.

Trajectories are ``x`` [..., T, J, D]: joint centres (D = 3, metres) or generalized coordinates given as
``q.unsqueeze(-1)`` (D = 1, rad or m). ``joints`` is an optional mask of the joints present, per sequence [..., J]
or per frame [..., T, J] (recognised by having one dim less than ``x``), e.g. the mask of the coordinates a source
lacks; ``valid`` is the per-frame mask [..., T]. Derivatives are forward finite differences
(`biomotion.metrics.base.difference`), the finite-difference scheme PhysPT Sec. 3.2.4 uses.
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
    pair_mask,
)

GRAVITY = 9.80665
"""m/s^2, standard gravity (potential energy m g y)."""


def _trajectory(x, name: str = "x") -> Tensor:
    return as_tensor(x, name, min_dims=3)


def _entry_mask(x: Tensor, valid, joints, order: int) -> Tensor:
    """[..., T - order, J] mask of the derivative entries: frames t..t+order valid and the joint present."""
    frames = pair_mask(frame_mask(valid, x.shape[:-2], x.device), order)[..., None]
    return frames & column_mask(joints, x.shape[:-1], order, "joints", x.device)


def jerk_index(x, rate: float, valid=None, *, joints=None, squared: bool = True) -> Tensor:
    """PG-BIG Sec. 4.2 "Jerk Index": mean over frames and joints of ``||d^3 x / dt^3||^2`` ((m/s^3)^2), or of
    ``||d^3 x / dt^3||`` (m/s^3, the unit of PG-BIG Table 2) with ``squared=False``."""
    x = _trajectory(x)
    jerk = torch.linalg.vector_norm(difference(x, rate, 3, dim=-3), dim=-1)
    return masked_mean(jerk.square() if squared else jerk, _entry_mask(x, valid, joints, 3), (-2, -1))


def mechanical_energy(positions, masses, rate: float) -> Tensor:
    """[..., T - 1] translational kinetic plus potential energy (J) of point masses.

    ``positions`` [..., T, B, 3] are segment centres of mass (y up, m) and ``masses`` [B] or [..., B] (kg); the
    whole-body COM with the total mass (B = 1) gives ``0.5 M |c_dot|^2 + M g c_y``. Velocities are forward
    differences, so frame t holds the energy between frames t and t + 1 (heights averaged over the pair).
    Segment rotational energy is left out: with a body model, `biomotion.body.balance.mechanical_energy` gives the
    full kinetic (with rotation) and potential energy per frame, whose sum goes to `energy_consistency` directly.
    """
    positions = as_tensor(positions, "positions", min_dims=3, last=3)
    masses = torch.as_tensor(masses, dtype=positions.dtype, device=positions.device)
    velocity = difference(positions, rate, dim=-3)
    mid_height = 0.5 * (positions[..., 1:, :, 1] + positions[..., :-1, :, 1])
    kinetic = 0.5 * (masses[..., None, :] * velocity.square().sum(-1)).sum(-1)
    potential = (masses[..., None, :] * GRAVITY * mid_height).sum(-1)
    return kinetic + potential


def energy_consistency(energy, valid=None, *, std: bool = False) -> Tensor:
    """PG-BIG Sec. 4.2 "Energy Consistency" E_var: variance over valid frames of the total mechanical energy
    ``energy`` [..., T] (J^2), or its standard deviation (J, the unit printed in PG-BIG Table 2) with ``std=True``.
    For the output of `mechanical_energy` (one value per frame pair) pass ``pair_mask(valid)`` as ``valid``.
    """
    energy = as_tensor(energy, "energy", min_dims=1)
    valid = frame_mask(valid, energy.shape, energy.device)
    mean = masked_mean(energy, valid, -1)
    variance = masked_mean((energy - mean[..., None]).square(), valid, -1)
    return variance.sqrt() if std else variance


def _paired(pred, target) -> tuple[Tensor, Tensor]:
    pred, target = _trajectory(pred, "pred"), _trajectory(target, "target")
    if pred.shape[-3:] != target.shape[-3:]:
        raise DataFormatError(
            None, f"pred {tuple(pred.shape)} and target {tuple(target.shape)} differ in [T, J, D]", field="target"
        )
    return pred, target


def acceleration_error(pred, target, rate: float, valid=None, *, joints=None, per_frame: bool = False) -> Tensor:
    """PhysPT Sec. 4 "ACCL": mean over frames and joints of ``||a_pred - a_target||`` with a the second finite
    difference; m/s^2, or m/frame^2 as in the paper (printed in mm/frame^2) with ``per_frame=True``."""
    pred, target = _paired(pred, target)
    scale = 1.0 if per_frame else float(rate)
    error = torch.linalg.vector_norm(difference(pred - target, 1.0, 2, dim=-3), dim=-1) * scale**2
    return masked_mean(error, _entry_mask(pred, valid, joints, 2), (-2, -1))


def velocity_error(pred, target, rate: float, valid=None, *, joints=None, per_frame: bool = False) -> Tensor:
    """PhysPT Sec. 4 "VEL": mean over frames and joints of ``||v_pred - v_target||`` with v the first finite
    difference; m/s, or m/frame as in the paper (printed in mm/frame) with ``per_frame=True``."""
    pred, target = _paired(pred, target)
    scale = 1.0 if per_frame else float(rate)
    error = torch.linalg.vector_norm(difference(pred - target, 1.0, 1, dim=-3), dim=-1) * scale
    return masked_mean(error, _entry_mask(pred, valid, joints, 1), (-2, -1))


class JerkIndex(Metric):
    """`jerk_index` per sequence. PG-BIG Sec. 4.2 / Table 2 "Jerk": the squared index (``jerk_index``) is the
    paper's definition, the unsquared one (``jerk``, m/s^3) the unit Table 2 prints."""

    name, label = "jerk_index", "Jerk index"
    higher_is_better = False
    paper = 'PG-BIG Sec. 4.2 "Jerk Index", Table 2 "Jerk"'

    def __init__(self, squared: bool = True) -> None:
        super().__init__()
        self.squared = squared
        if squared:
            self.unit, self.display_unit = "(m/s^3)^2", "(m/s³)²"
            self.equation = "mean over frames and joints of ||d^3 x / dt^3||^2"
        else:
            self.name, self.label, self.unit, self.display_unit = "jerk", "Jerk", "m/s^3", "m/s³"
            self.equation = "mean over frames and joints of ||d^3 x / dt^3||"

    def score(self, x, rate: float, valid=None, joints=None) -> Tensor:
        return jerk_index(x, rate, valid, joints=joints, squared=self.squared)


ENERGIES = {"com": "COM", "body": "body"}
"""Energies `EnergyConsistency` names a variant after: the whole-body COM as a point mass (`mechanical_energy`) and
the full-body energy of the body model (`biomotion.body.balance.mechanical_energy`)."""


class EnergyConsistency(Metric):
    """`energy_consistency` per sequence. PG-BIG Sec. 4.2 / Table 2 "Energy".

    ``energy`` says which energy the caller passes (a key of `ENERGIES`) and names the variant: with ``std=True``
    ``energy_com`` / "Energy std (COM)", with the variance ``energy_var_com``; None keeps ``energy_consistency``."""

    name, label = "energy_consistency", "Energy consistency"
    higher_is_better = False
    paper = 'PG-BIG Sec. 4.2 "Energy Consistency" E_var, Table 2 "Energy"'

    def __init__(self, std: bool = False, energy: str | None = None) -> None:
        super().__init__()
        if energy is not None and energy not in ENERGIES:
            raise DataFormatError(None, f"energy must be one of {tuple(ENERGIES)}, got {energy!r}", field="energy")
        self.std, self.energy = std, energy
        self.unit, self.display_unit = ("J", "J") if std else ("J^2", "J²")
        self.equation = f"{'std' if std else 'variance'} over frames of E = E_kin + E_pot"
        if energy is not None:
            self.name = f"energy_{energy}" if std else f"energy_var_{energy}"
            self.label = f"Energy {'std' if std else 'variance'} ({ENERGIES[energy]})"

    def score(self, energy, valid=None) -> Tensor:
        return energy_consistency(energy, valid, std=self.std)


class AccelerationError(Metric):
    """`acceleration_error` per sequence. PhysPT Sec. 4 / Table 1 "ACCL" (``per_frame=True``: the paper's
    per-frame unit, printed in mm/frame^2)."""

    name, label = "accl", "ACCL"
    higher_is_better = False
    paper = 'PhysPT Sec. 4 "ACCL", Table 1'
    equation = "mean over frames and joints of ||a_pred - a_target||, a the second finite difference"

    def __init__(self, per_frame: bool = False) -> None:
        super().__init__()
        self.per_frame = per_frame
        self.unit, self.display_unit = "m/s^2", "m/s²"
        if per_frame:
            self.name, self.label = "accl_per_frame", "ACCL (per frame)"
            self.unit, self.display_unit, self.display_scale = "m/frame^2", "mm/frame²", 1000.0

    def score(self, pred, target, rate: float, valid=None, joints=None) -> Tensor:
        return acceleration_error(pred, target, rate, valid, joints=joints, per_frame=self.per_frame)


class VelocityError(Metric):
    """`velocity_error` per sequence. PhysPT Sec. 4 / Table 1 "VEL" (``per_frame=True``: the paper's per-frame
    unit, printed in mm/frame)."""

    name, label, unit = "vel", "VEL", "m/s"
    higher_is_better = False
    paper = 'PhysPT Sec. 4 "VEL", Table 1'
    equation = "mean over frames and joints of ||v_pred - v_target||, v the first finite difference"

    def __init__(self, per_frame: bool = False) -> None:
        super().__init__()
        self.per_frame = per_frame
        if per_frame:
            self.name, self.label = "vel_per_frame", "VEL (per frame)"
            self.unit, self.display_unit, self.display_scale = "m/frame", "mm/frame", 1000.0

    def score(self, pred, target, rate: float, valid=None, joints=None) -> Tensor:
        return velocity_error(pred, target, rate, valid, joints=joints, per_frame=self.per_frame)
