"""Scaling a `BodyModel` by per-body x, y, z factors, as OpenSim's ScaleTool applies a ScaleSet.

What scales follows OpenSim 4's ``Model::scale(state, scaleSet, preserveMassDist, finalMass)`` (Delp et al.
2007, IEEE TBME 54:1940; the OpenSim 4 API documentation of Body, PhysicalOffsetFrame, Marker and
SpatialTransform):

- joint offset frames and markers: their translation times the factors of the body they are fixed on;
- CustomJoint translation functions: multiplied by ``axis · factors`` of the joint's parent body (OpenSim wraps
  them in a MultiplierFunction);
- centres of mass: times the body's factors;
- masses: times ``|sx sy sz|`` unless the mass distribution is preserved; then, if a total mass is given, all
  masses and inertias times ``total / current total``;
- inertias (about the COM): times ``s^2`` (and the mass factor) for uniform factors; otherwise the body is
  treated as a cylinder along its smallest diagonal moment, whose radius and length are scaled, and products
  of inertia are multiplied by ``s_i s_j`` (and the mass factor) (OpenSim's ``Body::scaleInertialProperties``;
  the product rule was measured against OpenSim 4.6).

Everything is a differentiable function of the factor tensor, so scale factors can be optimised.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path

import torch

from biomotion.body.model import BodyModel
from biomotion.errors import ModelError
from biomotion.io.osim import GROUND, ScaleSpec, read_scale_set

#: SimTK's "numerically equal" tolerance (``SignificantReal`` for double precision).
_EQUAL_TOLERANCE = 1.8e-14


def scale_factors(
    model: BodyModel, scales: Mapping[str, Sequence[float] | torch.Tensor] | Sequence[ScaleSpec]
) -> torch.Tensor:
    """[B, 3] factors per body (ones for bodies not named) from a name mapping or a parsed ScaleSet.

    Segments that name no body are ignored, as OpenSim does: the ScaleTool writes entries for ground and for
    every offset frame, but factors are looked up by body name only. A name mapping must name bodies.
    """
    if not isinstance(scales, Mapping):
        scales = {s.segment: s.scales for s in reversed(scales) if s.apply and s.segment in model.body_names}
    rows = [torch.ones(3, dtype=model.dtype) for _ in model.body_names]
    for segment, value in scales.items():
        rows[model.body_index(segment)] = torch.as_tensor(value, dtype=model.dtype).reshape(3)
    return torch.stack(rows)


def scale_model(
    model: BodyModel,
    factors: torch.Tensor | Mapping[str, Sequence[float] | torch.Tensor] | Sequence[ScaleSpec],
    mass: float | torch.Tensor | None = None,
    preserve_mass_distribution: bool = True,
) -> BodyModel:
    """A new model scaled by ``factors`` ([B, 3] in BodySet order, a name mapping or a ScaleSet), optionally to a
    total ``mass`` (kg), as OpenSim's ``Model::scale``."""
    if not isinstance(factors, torch.Tensor):
        factors = scale_factors(model, factors)
    factors = factors.to(model.dtype)
    if factors.shape != (model.n_bodies, 3):
        raise ModelError(f"scale factors must have shape ({model.n_bodies}, 3), got {tuple(factors.shape)}")
    _check_offsets_on_bodies(model)
    ones = torch.ones(3, dtype=model.dtype)

    def of(body: int) -> torch.Tensor:
        return ones if body < 0 else factors[body]

    joints = []
    for joint in model.joints:
        axes = tuple(
            dataclasses.replace(axis, scale=axis.scale * torch.dot(axis.axis, of(joint.parent)))
            if not axis.rotation and joint.type == "CustomJoint"
            else axis
            for axis in joint.axes
        )
        joints.append(
            dataclasses.replace(
                joint,
                parent_translation=joint.parent_translation * of(joint.parent),
                child_translation=joint.child_translation * factors[joint.child],
                axes=axes,
            )
        )
    marker_scale = torch.where((model.marker_bodies < 0)[:, None], ones, factors[model.marker_bodies.clamp(min=0)])
    masses, inertias = _scale_inertial(model.masses, model.inertias, factors, not preserve_mass_distribution)
    if mass is not None:
        ratio = torch.as_tensor(mass, dtype=model.dtype) / masses.sum()
        masses, inertias = masses * ratio, inertias * ratio
    return dataclasses.replace(
        model,
        joints=tuple(joints),
        masses=masses,
        inertias=inertias,
        coms=model.coms * factors,
        marker_offsets=model.marker_offsets * marker_scale,
        body_scales=model.body_scales * factors,
    )


def scale_model_from_file(
    model: BodyModel, path: str | Path, mass: float | None = None, preserve_mass_distribution: bool = True
) -> BodyModel:
    """`scale_model` with the factors of an OpenSim ScaleSet file."""
    return scale_model(model, read_scale_set(path), mass, preserve_mass_distribution)


def _scale_inertial(
    masses: torch.Tensor, inertias: torch.Tensor, factors: torch.Tensor, scale_mass: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """OpenSim's ``Body::scaleInertialProperties`` for every body (inertia about the COM, body frame)."""
    new_masses, new_inertias = [], []
    for b in range(masses.shape[0]):
        m0, inertia, s = masses[b], inertias[b], factors[b]
        mass_factor = torch.abs(s.prod())
        m = m0 * mass_factor if scale_mass else m0
        a = s.abs()
        uniform = bool(
            (a[0] - a[1]).abs() <= _EQUAL_TOLERANCE * a.max() and (a[0] - a[2]).abs() <= _EQUAL_TOLERANCE * a.max()
        )
        if float(m) <= 2.2e-16:
            scaled = torch.zeros_like(inertia)
        elif uniform:
            scaled = inertia * s[0] * s[0] * (mass_factor if scale_mass else 1.0)
        else:
            scaled = _cylinder(m0, m, inertia, s)
        new_masses.append(m)
        new_inertias.append(scaled)
    return torch.stack(new_masses), torch.stack(new_inertias)


def _cylinder(m0: torch.Tensor, m: torch.Tensor, inertia: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Non-uniform scaling: the body as a cylinder about its smallest diagonal moment (OpenSim's rule)."""
    d = inertia.diagonal()
    if d[0] <= d[1]:
        axis = 0 if d[0] <= d[2] else 2
    else:
        axis = 1 if d[1] <= d[2] else 2
    other = 1 if axis == 0 else 0
    third = 3 - axis - other
    radius = torch.sqrt(torch.clamp(2.0 * d[axis] / m0, min=0.0))
    length = torch.sqrt(torch.clamp(12.0 * (d[other] - 0.25 * m0 * radius * radius) / m0, min=0.0))
    length = length * s[axis]
    across = [i for i in range(3) if i != axis]
    radius_sq = radius * s[across[0]] * radius * s[across[1]]
    diagonal = [None, None, None]
    diagonal[axis] = 0.5 * m * radius_sq
    diagonal[other] = m * (length * length / 12.0 + 0.25 * radius_sq)
    diagonal[third] = diagonal[other]
    rows = [[None] * 3 for _ in range(3)]
    for i in range(3):
        rows[i][i] = diagonal[i]
    for i, j in ((0, 1), (0, 2), (1, 2)):  # products of inertia: times s_i s_j and the mass factor
        rows[i][j] = rows[j][i] = inertia[i, j] * s[i] * s[j] * (m / m0)
    return torch.stack([torch.stack(r) for r in rows])


def _check_offsets_on_bodies(model: BodyModel) -> None:
    """Scaling composed offset-frame chains elementwise is only exact when each frame sits on a body."""
    bodies = {GROUND} | {b.path for b in model.spec.bodies}
    for frame in model.spec.frames:
        if frame.parent not in bodies:
            raise ModelError(
                f"{model.spec.path}: offset frame {frame.path!r} is attached to another offset frame "
                f"({frame.parent!r}); scaling such chains is not supported"
            )
