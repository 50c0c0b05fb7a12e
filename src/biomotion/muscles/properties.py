"""Muscle parameters from an .osim file and the force-length-velocity curves of its muscle type.

Parameters (per muscle, SI): max isometric force F0 (N), optimal fibre length l0 (m), tendon slack length ls (m),
pennation angle at optimal length alpha0 (rad), max contraction velocity vmax (l0/s), control bounds.

Curves, in normalised fibre length l~ = l/l0 and velocity v~ = v/(vmax l0) (positive = lengthening):

- ``Thelen2003Muscle`` (Thelen 2003, "Adjustment of muscle mechanics model parameters to simulate dynamic
  contractions in older adults", J Biomech Eng 125:70-77, Eqs. 3-7, as implemented in OpenSim 4):
  active f_L = exp(-(l~-1)^2 / gamma) (Eq. 4, gamma = KshapeActive); passive
  f_PE = (exp(k_PE (l~-1)/e0_M) - 1)/(exp(k_PE) - 1) for l~ > 1 (Eq. 3); force-velocity from Eqs. 6-7 solved for
  the force at full activation: concentric f_V = (1 + v~)/(1 - v~/A_f), eccentric
  f_V = (1 + c v~ F_len)/(1 + c v~) with c = (2 + 2/A_f)/(F_len - 1), linearly extrapolated (in v~ against f_V)
  beyond v~ = -1 and beyond f_V = ``fv_linear_extrap_threshold`` F_len, as OpenSim does.
- ``Millard2012EquilibriumMuscle`` (Millard et al. 2013, "Flexing computational muscle: modeling and simulation
  of musculotendon dynamics", J Biomech Eng 135:021005): the quintic-Bezier active force-length and
  force-velocity curves of `biomotion.muscles.millard`, built from each muscle's ``ActiveForceLengthCurve`` and
  ``ForceVelocityCurve`` properties (OpenSim's defaults where absent), and its ``FiberForceLengthCurve`` for
  `passive_force`.

Fibres follow the constant-thickness pennation model (l sin(alpha) = l0 sin(alpha0); Zajac 1989, Crit Rev Biomed
Eng 17:359) with a rigid tendon, as OpenSim's static optimization does (``calcInextensibleTendonActiveFiberForce``
at activation 1): fibre length sqrt((L - ls)^2 + (l0 sin alpha0)^2), fibre velocity dL/dt cos(alpha).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch

from biomotion.errors import DataFormatError, ModelError
from biomotion.io import osim
from biomotion.io.osim import MUSCLE_TYPES
from biomotion.muscles import millard

# OpenSim 4 defaults (Thelen2003Muscle::constructProperties, Muscle::constructProperties) for absent elements.
_THELEN_DEFAULTS = {
    "FmaxTendonStrain": 0.033,
    "FmaxMuscleStrain": 0.6,
    "KshapeActive": 0.45,
    "KshapePassive": 5.0,
    "Af": 0.25,
    "Flen": 1.8,
    "fv_linear_extrap_threshold": 0.95,
}
_DEFAULT_MIN_CONTROL = 0.01  # OpenSim's minimum activation of both muscle types
_DEFAULT_MAX_CONTRACTION_VELOCITY = 10.0


@dataclass(frozen=True)
class MuscleParameters:
    """Parameters of every muscle of a model, in ForceSet order; tensors are [M]."""

    source: str
    names: tuple[str, ...]
    kinds: tuple[str, ...]  # muscle class per muscle
    max_isometric_force: torch.Tensor
    optimal_fiber_length: torch.Tensor
    tendon_slack_length: torch.Tensor
    pennation_at_optimal: torch.Tensor
    max_contraction_velocity: torch.Tensor
    min_control: torch.Tensor
    max_control: torch.Tensor
    thelen: dict[str, torch.Tensor]  # Thelen2003 curve parameters (defaults for other types)
    millard: dict[str, torch.Tensor]  # Millard2012 curve parameters (defaults for other types)

    @property
    def n_muscles(self) -> int:
        return len(self.names)

    @property
    def kind(self) -> str:
        """The single muscle type of the model (raises if it mixes types)."""
        kinds = set(self.kinds)
        if len(kinds) != 1:
            raise ModelError(f"{self.source}: mixed muscle types {sorted(kinds)}")
        return kinds.pop()

    def select(self, names: tuple[str, ...] | list[str]) -> MuscleParameters:
        """The parameters of ``names``, in that order."""
        index = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in index]
        if missing:
            raise ModelError(f"{self.source}: no muscles {missing}")
        rows = torch.tensor([index[n] for n in names])
        return MuscleParameters(
            self.source,
            tuple(names),
            tuple(self.kinds[i] for i in rows.tolist()),
            *(getattr(self, f)[rows] for f in _TENSOR_FIELDS),
            {k: v[rows] for k, v in self.thelen.items()},
            {k: v[rows] for k, v in self.millard.items()},
        )


_TENSOR_FIELDS = (
    "max_isometric_force",
    "optimal_fiber_length",
    "tendon_slack_length",
    "pennation_at_optimal",
    "max_contraction_velocity",
    "min_control",
    "max_control",
)


def read_muscles(path: str | Path, dtype: torch.dtype = torch.float64) -> MuscleParameters:
    """Parameters of the enabled muscles of an .osim file (Thelen2003Muscle or Millard2012EquilibriumMuscle)."""
    doc = osim._Doc(Path(path))
    names, kinds, rows, thelen = [], [], [], {k: [] for k in _THELEN_DEFAULTS}
    curves = {
        **{k: ("ActiveForceLengthCurve", v) for k, v in millard.ACTIVE_DEFAULTS.items()},
        **{k: ("ForceVelocityCurve", v) for k, v in millard.VELOCITY_DEFAULTS.items()},
        **{k: ("FiberForceLengthCurve", v) for k, v in millard.PASSIVE_DEFAULTS.items()},
    }
    millard_values = {k: [] for k in curves}
    for elem in doc.root.iter():
        if elem.tag not in MUSCLE_TYPES or elem.get("name") in (None, "default"):
            continue
        if not doc.boolean(elem, "appliesForce", "true"):
            continue
        names.append(elem.get("name"))
        kinds.append(elem.tag)
        rows.append(
            [
                doc.scalar(elem, "max_isometric_force"),
                doc.scalar(elem, "optimal_fiber_length"),
                doc.scalar(elem, "tendon_slack_length"),
                doc.scalar(elem, "pennation_angle_at_optimal", "0"),
                doc.scalar(elem, "max_contraction_velocity", str(_DEFAULT_MAX_CONTRACTION_VELOCITY)),
                doc.scalar(elem, "min_control", str(_DEFAULT_MIN_CONTROL)),
                doc.scalar(elem, "max_control", "1"),
            ]
        )
        for key, default in _THELEN_DEFAULTS.items():
            thelen[key].append(doc.scalar(elem, key, str(default)) if elem.tag == "Thelen2003Muscle" else default)
        for key, (curve, default) in curves.items():
            millard_values[key].append(
                doc.scalar(elem, f"{curve}/{key}", str(default))
                if elem.tag == "Millard2012EquilibriumMuscle"
                else default
            )
    if not names:
        raise DataFormatError(path, f"no enabled muscles of a supported type {MUSCLE_TYPES}", field="ForceSet")
    values = torch.tensor(rows, dtype=dtype)
    for name, row in zip(names, rows):
        if row[0] <= 0 or row[1] <= 0 or row[2] < 0 or not 0 <= row[3] < math.pi / 2:
            raise DataFormatError(path, f"muscle {name!r}: non-physical parameters {row[:4]}", field=name)
    return MuscleParameters(
        str(path),
        tuple(names),
        tuple(kinds),
        *values.T,
        {k: torch.tensor(v, dtype=dtype) for k, v in thelen.items()},
        {k: torch.tensor(v, dtype=dtype) for k, v in millard_values.items()},
    )


# ---- Thelen 2003 curves ---------------------------------------------------------------------------------------


def thelen_active_force_length(norm_length: torch.Tensor, kshape_active: torch.Tensor) -> torch.Tensor:
    """Thelen 2003 Eq. 4: exp(-(l~ - 1)^2 / gamma)."""
    return torch.exp(-((norm_length - 1) ** 2) / kshape_active)


def thelen_passive_force_length(
    norm_length: torch.Tensor, kshape_passive: torch.Tensor, strain: torch.Tensor
) -> torch.Tensor:
    """Thelen 2003 Eq. 3 (zero below optimal length, as OpenSim)."""
    stretched = torch.clamp(norm_length - 1, min=0)
    return (torch.exp(kshape_passive * stretched / strain) - 1) / (torch.exp(kshape_passive) - 1)


def thelen_force_velocity(
    norm_velocity: torch.Tensor, af: torch.Tensor, flen: torch.Tensor, threshold: torch.Tensor
) -> torch.Tensor:
    """Force-velocity multiplier at full activation from Thelen 2003 Eqs. 6-7 (see module docstring)."""
    v = norm_velocity
    c = (2 + 2 / af) / (flen - 1)
    concentric = (1 + v) / (1 - v / af)
    below = (v + 1) / (1 + 1 / af)  # below v~ = -1 (f_V = 0): slope dv/df there is 1 + 1/A_f
    f_end = threshold * flen  # last point of Eq. 7 before linear extrapolation
    v_end = (f_end - 1) / (c * (flen - f_end))
    slope = 1 / (1 / (c * (flen - f_end)) + (f_end - 1) / (c * (flen - f_end) ** 2))  # df/dv at v_end
    eccentric = torch.where(v < v_end, (1 + c * v * flen) / (1 + c * v), f_end + slope * (v - v_end))
    return torch.where(v > 0, eccentric, torch.where(v < -1, below, concentric))


# ---- fibre kinematics and force ---------------------------------------------------------------------------------


def fiber_kinematics(
    muscles: MuscleParameters, lengths: torch.Tensor, speeds: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rigid-tendon fibre length l (m), cos(pennation) and fibre velocity (m/s) from musculotendon lengths and
    lengthening speeds [..., M] (constant-thickness pennation, Zajac 1989)."""
    height = muscles.optimal_fiber_length * torch.sin(muscles.pennation_at_optimal)
    along = torch.clamp(lengths - muscles.tendon_slack_length, min=1e-6)
    fiber = torch.sqrt(along**2 + height**2)
    cos_alpha = along / fiber
    return fiber, cos_alpha, speeds * cos_alpha


def max_active_force(muscles: MuscleParameters, lengths: torch.Tensor, speeds: torch.Tensor) -> torch.Tensor:
    """[..., M] force per unit activation with a rigid tendon, as OpenSim's static optimization uses it (its
    ``calcInextensibleTendonActiveFiberForce`` at activation 1), with the curves of the model's muscle type.

    Thelen 2003: F0 f_L(l~) f_V(v~) cos(alpha), the fibre force along the tendon. Millard 2012: F0 f_L(l~) f_V(v~)
    without the cos(alpha) projection, because that is what OpenSim 4.6 returns for this type (measured against
    ``calcInextensibleTendonActiveFiberForce`` at random poses and speeds of Rajagopal 2016: within 0.4 %, the
    fibre velocity taken along the fibre, dL/dt cos(alpha), in both; tests/muscles/test_millard.py)."""
    kind = muscles.kind
    fiber, cos_alpha, velocity = fiber_kinematics(muscles, lengths, speeds)
    norm_length = fiber / muscles.optimal_fiber_length
    norm_velocity = velocity / (muscles.max_contraction_velocity * muscles.optimal_fiber_length)
    if kind == "Thelen2003Muscle":
        p = muscles.thelen
        active = thelen_active_force_length(norm_length, p["KshapeActive"])
        fv = thelen_force_velocity(norm_velocity, p["Af"], p["Flen"], p["fv_linear_extrap_threshold"])
        return muscles.max_isometric_force * active * fv * cos_alpha
    active = millard.active_force_length_curve(muscles.millard)(norm_length)
    fv = millard.force_velocity_curve(muscles.millard)(norm_velocity)
    return muscles.max_isometric_force * active * fv


def passive_force(muscles: MuscleParameters, lengths: torch.Tensor) -> torch.Tensor:
    """[..., M] passive fibre force along the tendon (N), rigid tendon, with the curve of the model's muscle type
    (not part of static optimization's balance, as in OpenSim)."""
    fiber, cos_alpha, _ = fiber_kinematics(muscles, lengths, torch.zeros_like(lengths))
    if muscles.kind == "Millard2012EquilibriumMuscle":
        curve = millard.passive_force_length_curve(muscles.millard)
        return muscles.max_isometric_force * cos_alpha * curve(fiber / muscles.optimal_fiber_length)
    p = muscles.thelen
    return (
        muscles.max_isometric_force
        * cos_alpha
        * thelen_passive_force_length(fiber / muscles.optimal_fiber_length, p["KshapePassive"], p["FmaxMuscleStrain"])
    )
