"""A generic OpenSim model scaled to a person's height and mass (no static trial): uniform anthropometric scaling.

Without markers of the person, the simplest defensible individualisation is the one OpenSim's ScaleTool applies
with manual scale factors (Delp et al. 2007, IEEE TBME 54:1940): every body scaled by one factor, the stature
ratio ``s = height / standing height of the generic model``, segment lengths being close to proportional to
stature (Winter 2009, "Biomechanics and motor control of human movement", 4th ed., Fig. 4.1: Drillis & Contini's
segment lengths as fractions of height H). Masses are then scaled to the person's total mass preserving the
generic mass distribution (OpenSim's ``Model::scale(..., preserveMassDist=true, finalMass)``); inertias follow
(times ``s^2`` for the geometry and the mass ratio, `biomotion.body.scaling`). PG-BIG (Sec. 4.1, A.2) scales the
Rajagopal 2016 model per subject the OpenSim way; this is its marker-free special case for ``biomotion generate``.

Standing height of a model (`standing_height`): vertical distance, with every coordinate at zero (upright,
arms by the sides), from the foot bottom to the top of the head:

- foot bottom: the lowest of the model's foot contact points (`biomotion.body.contact.foot_points`: heel, first
  and fifth metatarsal heads, toe tip on the sole plane of ``calcn``/``toes``); for a model without ``calcn``
  bodies, the lowest body origin or marker;
- top of the head: the highest marker named like a head-top marker (``HEAD``, ``TopHead``, ``HeadTop``,
  ``Vertex`` ...). Rajagopal 2016 has none (its highest markers, C7 and the acromia, lie about 26 cm below where
  its vertex would be, and its skull mesh is not shipped with the model files here), so for such a model the top
  is a virtual vertex: the point on the head-carrying body (``torso`` in Rajagopal 2016) that lies
  ``generic_height`` above the foot bottom in the model as loaded, with ``generic_height`` = 1.70 m, the generic
  subject of Rajagopal et al. 2016 (IEEE TBME 63:2068: 170 cm, 75 kg; the model's total mass is 75.337 kg). That
  point is scaled with its body (``BodyModel.body_scales``), so a model scaled in memory measures its new height
  by forward kinematics. A scaled model re-read from its file has no scaling history: without a head marker it
  would be measured as the generic height again.

The scaled model file is written by `biomotion.body.scaling.osim_file.write_scaled_osim` (bodies, joints, markers,
meshes, wrap objects, muscle paths and fibre/tendon lengths), so OpenSim loads it.
"""

from __future__ import annotations

import json
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import torch

from biomotion.body.contact import foot_points
from biomotion.body.kinematics import (
    apply_couplers,
    forward_kinematics,
    points_in_ground,
)
from biomotion.body.model import BodyModel
from biomotion.body.scaling.bodies import scale_model
from biomotion.body.scaling.osim_file import ScaleResult, write_scaled_osim
from biomotion.body.scaling.segments import body_factors, measures_of, segment_factors
from biomotion.errors import BiomotionWarning, ConfigError, ModelError
from biomotion.io.atomic import atomic_write
from biomotion.profile import Profile

RAJAGOPAL_2016_HEIGHT = 1.70
"""m: stature of the generic subject of Rajagopal et al. (2016), the canonical model."""
HEAD_MARKERS = ("head", "tophead", "headtop", "topofhead", "vertex")
"""Marker names (lower case, letters only) taken as the top of the head."""
HEAD_BODIES = ("head", "skull", "torso", "thorax", "trunk")
"""Bodies that carry the virtual vertex, first present wins (else the root body)."""
HEIGHT_RANGE = (0.3, 2.8)  # m, as `biomotion.profile.Profile`
MASS_RANGE = (2.0, 400.0)  # kg

_F64 = torch.float64


@dataclass(frozen=True)
class StandingHeight:
    """A model's standing height (m) with every coordinate at zero: ``top - bottom`` (heights in ground, m), and
    what the top is (``"marker HEAD"`` or ``"virtual vertex on torso, generic height 1.70 m"``)."""

    height: float
    top: float
    bottom: float
    reference: str


def standing_height(model: BodyModel, *, generic_height: float | None = None) -> StandingHeight:
    """The standing height of ``model`` (see the module docstring for the foot and head references).

    ``generic_height`` (m) is the stature of the unscaled model, used only when the model has no head-top
    marker; None means `RAJAGOPAL_2016_HEIGHT` (with a `BiomotionWarning` for a model not named Rajagopal*).
    """
    model = model.to(_F64)
    up = _up(model)
    poses = forward_kinematics(model, apply_couplers(model, torch.zeros(model.n_q, dtype=_F64)))
    bottom = _foot_bottom(model, poses, up)
    markers = _head_markers(model)
    if markers:
        heights = points_in_ground(poses, model.marker_bodies[markers], model.marker_offsets[markers]) @ up
        best = int(torch.argmax(heights))
        top = float(heights[best])
        reference = f"marker {model.marker_names[markers[best]]}"
    else:
        stated = _generic_height(model, generic_height)
        body, offset = _virtual_vertex(model, stated, up)
        point = points_in_ground(poses, torch.tensor([body]), (offset * model.body_scales[body])[None])[0]
        top = float(point @ up)
        reference = f"virtual vertex on {model.body_names[body]}, generic height {stated:.3f} m"
    return StandingHeight(top - bottom, top, bottom, reference)


def scale_to_profile(
    generic_osim: str | Path,
    height: float | None,
    mass: float | None,
    out_osim: str | Path,
    *,
    measures: Mapping[str, float] | None = None,
    generic_height: float | None = None,
    name: str | None = None,
) -> BodyModel:
    """Scale the model in ``generic_osim`` to ``height`` (m), ``mass`` (kg) and optionally ANSUR II segment
    ``measures`` (mm); write it to ``out_osim``.

    Every body gets the factor ``height / standing_height(generic)`` on all three axes, except the bodies of a
    segment whose measures are given, which get that segment's factor (`biomotion.body.scaling.segments`); then all
    masses and inertias are multiplied by ``mass / total mass`` (mass distribution preserved). A None ``height``
    or ``mass`` leaves that aspect as in the generic model. The file is the generic one edited by
    `biomotion.body.scaling.osim_file.write_scaled_osim` (OpenSim loads it); ``name`` renames the model in it.

    Returns:
        The scaled model, as written (masses, inertias, joint frames, markers), in float64; its ``spec`` is the
        generic file's and ``body_scales`` holds the factors, so `standing_height` of it is ``height`` when every
        body has the stature ratio (with segment measures, the sum of the measured segments).
    """
    _check_range("height", height, HEIGHT_RANGE, "m")
    _check_range("mass", mass, MASS_RANGE, "kg")
    generic_osim = Path(generic_osim)
    generic = BodyModel.from_osim(generic_osim).to(_F64)
    stature = standing_height(generic, generic_height=generic_height).height
    factor = 1.0 if height is None else height / stature
    segments = segment_factors(measures, stature) if measures else {}
    per_body = body_factors(generic.body_names, segments, factor)
    factors = {body: (f, f, f) for body, f in per_body.items()}
    scaled = scale_model(
        generic,
        torch.tensor([factors[b] for b in generic.body_names], dtype=_F64),
        mass=mass,
        preserve_mass_distribution=True,
    )
    measured = ({} if height is None else {"standing_height": factor}) | segments
    result = ScaleResult(
        factors=factors,
        measurements=measured,
        mass=mass,
        preserve_mass_distribution=True,
        model=scaled,
        placement=None,
        generic=generic,
    )
    write_scaled_osim(generic_osim, out_osim, result, name=name)
    return scaled


def scale_to_person(generic_osim: str | Path, profile: Profile, out_osim: str | Path, **options) -> BodyModel:
    """`scale_to_profile` with a `Profile`'s height and mass (either may be None) and the ANSUR II segment
    measures (mm) among its extra fields (an ANSUR II table row has them all)."""
    return scale_to_profile(
        generic_osim, profile.height, profile.mass, out_osim, measures=measures_of(profile.extra), **options
    )


def write_person_model(
    generic_osim: str | Path, profile: Profile, out: str | Path, name: str
) -> tuple[Path, Path, dict]:
    """`scale_to_person` into ``out/<name>.osim``, with ``out/<name>_scale.json``: the factor of every body, the
    ANSUR II measures used, the mass and the standing height of the result. Returns (model file, summary file,
    summary)."""
    out = Path(out)
    model = scale_to_person(generic_osim, profile, out / f"{name}.osim", name=name)
    summary = {
        "generic_model": str(generic_osim),
        "height_m": profile.height,
        "mass_kg": float(model.total_mass),
        "ansur_measures_mm": measures_of(profile.extra),
        "scale_factors": {body: round(float(model.body_scales[i, 0]), 6) for i, body in enumerate(model.body_names)},
        "standing_height_m": round(standing_height(model).height, 4),
        "model": f"{name}.osim",
    }
    summary_file = out / f"{name}_scale.json"
    with atomic_write(summary_file) as handle:
        json.dump(summary, handle, indent=1)
    return out / f"{name}.osim", summary_file, summary


# ---- helpers ---------------------------------------------------------------------------------------------------


def _check_range(what: str, value: float | None, bounds: tuple[float, float], unit: str) -> None:
    if value is None:
        return
    if not bounds[0] <= float(value) <= bounds[1]:
        raise ConfigError(
            f"{what}={value} {unit} is outside [{bounds[0]}, {bounds[1]}] {unit}: give SI units "
            f"(height in metres, mass in kilograms)"
        )


def _up(model: BodyModel) -> torch.Tensor:
    """Unit vector against gravity (OpenSim: +y)."""
    norm = torch.linalg.vector_norm(model.gravity)
    if float(norm) == 0.0:
        return torch.tensor([0.0, 1.0, 0.0], dtype=_F64)
    return -model.gravity / norm


def _foot_bottom(model: BodyModel, poses, up: torch.Tensor) -> float:
    try:
        feet = foot_points(model)
        points = points_in_ground(poses, feet.bodies, feet.offsets)
    except ModelError:  # no calcn bodies: the lowest point the model defines
        points = torch.cat([poses.positions, points_in_ground(poses, model.marker_bodies, model.marker_offsets)])
    return float((points @ up).min())


def _head_markers(model: BodyModel) -> list[int]:
    return [m for m, name in enumerate(model.marker_names) if re.sub(r"[^a-z]", "", name.lower()) in HEAD_MARKERS]


def _generic_height(model: BodyModel, generic_height: float | None) -> float:
    if generic_height is not None:
        _check_range("generic_height", generic_height, HEIGHT_RANGE, "m")
        return float(generic_height)
    if not model.name.lower().startswith("rajagopal"):
        warnings.warn(
            f"model {model.name!r} has no head-top marker and no generic_height was given: its standing "
            f"height is taken as {RAJAGOPAL_2016_HEIGHT} m, the generic subject of Rajagopal 2016",
            BiomotionWarning,
            stacklevel=3,
        )
    return RAJAGOPAL_2016_HEIGHT


def _virtual_vertex(model: BodyModel, stated: float, up: torch.Tensor) -> tuple[int, torch.Tensor]:
    """(body, offset in that body as loaded, before scaling) of the point ``stated`` above the foot bottom,
    straight above the body's origin, in the model as its file describes it (unscaled)."""
    body = next(
        (model.body_index(n) for n in HEAD_BODIES if n in model.body_names),
        next(b for b in range(model.n_bodies) if model.parent[b] < 0),
    )
    loaded = BodyModel.from_spec(model.spec, _F64)
    poses = forward_kinematics(loaded, apply_couplers(loaded, torch.zeros(loaded.n_q, dtype=_F64)))
    bottom = _foot_bottom(loaded, poses, up)
    origin = poses.positions[body]
    vertex = origin + (bottom + stated - float(origin @ up)) * up
    return body, poses.rotations[body].T @ (vertex - origin)
