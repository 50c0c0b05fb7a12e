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
from biomotion.metrics.base import (Metric, Tensor, as_tensor, column_mask, difference, frame_mask, masked_mean,
                                    pair_mask)

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
        raise DataFormatError(None, f"pred {tuple(pred.shape)} and target {tuple(target.shape)} differ in [T, J, D]",
                              field="target")
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
    """`jerk_index` per sequence. PG-BIG Sec. 4.2 / Table 2 "Jerk"."""

    name = "jerk_index"

    def __init__(self, squared: bool = True) -> None:
        super().__init__()
        self.squared = squared
        self.unit = "(m/s^3)^2" if squared else "m/s^3"

    def score(self, x, rate: float, valid=None, joints=None) -> Tensor:
        return jerk_index(x, rate, valid, joints=joints, squared=self.squared)


class EnergyConsistency(Metric):
    """`energy_consistency` per sequence. PG-BIG Sec. 4.2 / Table 2 "Energy"."""

    name = "energy_consistency"

    def __init__(self, std: bool = False) -> None:
        super().__init__()
        self.std = std
        self.unit = "J" if std else "J^2"

    def score(self, energy, valid=None) -> Tensor:
        return energy_consistency(energy, valid, std=self.std)


class AccelerationError(Metric):
    """`acceleration_error` per sequence. PhysPT Sec. 4 / Table 1 "ACCL"."""

    name = "acceleration_error"

    def __init__(self, per_frame: bool = False) -> None:
        super().__init__()
        self.per_frame = per_frame
        self.unit = "m/frame^2" if per_frame else "m/s^2"

    def score(self, pred, target, rate: float, valid=None, joints=None) -> Tensor:
        return acceleration_error(pred, target, rate, valid, joints=joints, per_frame=self.per_frame)


class VelocityError(Metric):
    """`velocity_error` per sequence. PhysPT Sec. 4 / Table 1 "VEL"."""

    name = "velocity_error"

    def __init__(self, per_frame: bool = False) -> None:
        super().__init__()
        self.per_frame = per_frame
        self.unit = "m/frame" if per_frame else "m/s"

    def score(self, pred, target, rate: float, valid=None, joints=None) -> Tensor:
        return velocity_error(pred, target, rate, valid, joints=joints, per_frame=self.per_frame)
