"""`Shape`: a body's build — segment scale factors and lengths, total mass, mass distribution, height — as a value.

HUMOS (``humos.md``, "Method Summary" and its Sec. 3.2) decodes an identity-agnostic motion latent conditioned on
the target body's identity (an SMPL body there) and trains by cycle consistency, A → B → A, without paired data.
Here the identity is the OpenSim counterpart: how a generic musculoskeletal model is scaled to the person. A
`Shape` holds

- ``scales``: per body of the ``reference`` model, the (sx, sy, sz) factors OpenSim's ScaleTool would apply to it
  (Delp et al. 2007, IEEE TBME 54:1940; `biomotion.body.scaling.bodies`), relative to that generic model;
- ``masses``: per body, its mass (kg), or None for the reference model's mass distribution at ``mass``;
- ``mass``: the total mass (kg), ``height``: the standing height (m) when known;
- ``lengths``: per body with a distal joint, the distance (m) between its proximal joint centre and its farthest
  distal joint centre in the scaled body, a readable summary of ``scales`` (derived, not used to rebuild).

Contract: ``Shape.from_model(scaled, generic).to_model(generic)`` rebuilds the scaled model's joint frames, centres
of mass, body scale factors and body masses exactly (to float precision) when ``scaled`` was made from ``generic``
the way OpenSim's ``Model::scale`` makes it (mesh scale factors and joint offsets scaled by the body's factors), and
`Shape.write_osim` writes that model as an .osim through `biomotion.body.scaling.osim_file.write_scaled_osim`.
Inertias follow the geometric scaling of `biomotion.body.scaling.bodies.scale_model` and the per-body mass ratio;
a tool that scales inertias otherwise (AddBiomechanics) is rebuilt in everything but its inertias.

Where the factors come from (`from_model`): a model scaled in memory carries them (``BodyModel.body_scales``); a
scaled model read from a file does not, so they are recovered against its ``generic`` model per body from the ratio
of the mesh scale factors (OpenSim multiplies them by the body's factors) and, for a body without meshes, by
per-axis least squares over the vectors fixed on the body (joint frame origins, centre of mass); an axis no such
vector spans takes the mean of the others.

`from_measures` uses the ANSUR II segment-on-stature lines the package ships (`biomotion.body.scaling.segments`):
a person of height H gets, per segment, ``E[L | H] / E[L | H_generic]``, and every other body the stature ratio
``H / H_generic``. `biomotion.ik.shape.shape_from_bvh` builds a Shape from a BVH skeleton (``body`` may not import
``ik``).

Bad shapes (a non-finite or non-positive factor, length or total mass, a negative body mass, a body of the model the
Shape has no factors for) raise `biomotion.errors.ConfigError` with a one-line message naming the field.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import torch

from biomotion.body.canonical import CANONICAL_BODIES
from biomotion.body.model import BodyModel
from biomotion.body.scaling.bodies import scale_model
from biomotion.body.scaling.osim_file import ScaleResult, write_scaled_osim
from biomotion.body.scaling.segments import SEGMENTS, body_factors, shipped_lines
from biomotion.body.scaling.stature import (
    HEAD_BODIES,
    HEIGHT_RANGE,
    RAJAGOPAL_2016_HEIGHT,
    standing_height,
)
from biomotion.errors import ConfigError

_F64 = torch.float64

RAJAGOPAL_2016_BODIES = CANONICAL_BODIES
"""BodySet of the canonical model (Rajagopal et al. 2016, IEEE TBME 63:2068), the reference of `Shape.from_measures`
when no generic model is given."""
RAJAGOPAL_2016_NAME = "Rajagopal2016"
SEXES = ("male", "female")


@dataclass(frozen=True)
class Shape:
    """A body's build relative to a generic ``reference`` model (module docstring). Immutable; validated on
    construction (`ConfigError` naming the field)."""

    reference: str
    scales: Mapping[str, tuple[float, float, float]]
    mass: float
    masses: Mapping[str, float] | None = None
    height: float | None = None
    lengths: Mapping[str, float] = field(default_factory=dict)
    sex: str | None = None

    def __post_init__(self) -> None:
        if not self.scales:
            raise ConfigError("Shape.scales is empty: a shape needs the scale factors of every body")
        scales = {}
        for body, value in self.scales.items():
            try:
                triple = tuple(float(v) for v in value)
            except (TypeError, ValueError):
                raise ConfigError(f"Shape.scales[{body!r}] = {value!r} is not three numbers") from None
            if len(triple) != 3 or not all(math.isfinite(v) and v > 0.0 for v in triple):
                raise ConfigError(f"Shape.scales[{body!r}] = {value!r} must be three finite positive factors")
            scales[str(body)] = triple
        object.__setattr__(self, "scales", MappingProxyType(scales))
        mass = _positive("Shape.mass", self.mass, "kg")
        object.__setattr__(self, "mass", mass)
        if self.masses is not None:
            masses = {}
            for body, value in self.masses.items():
                m = _number(f"Shape.masses[{body!r}]", value)
                if m < 0.0:
                    raise ConfigError(f"Shape.masses[{body!r}] = {value!r} kg is negative")
                masses[str(body)] = m
            if set(masses) != set(scales):
                odd = sorted(set(masses) ^ set(scales))
                raise ConfigError(f"Shape.masses and Shape.scales name different bodies: {odd}")
            total = math.fsum(masses.values())
            if abs(total - mass) > 1e-9 * max(mass, 1.0):
                raise ConfigError(f"Shape.mass = {mass} kg is not the sum of Shape.masses ({total} kg)")
            object.__setattr__(self, "masses", MappingProxyType(masses))
        if self.height is not None:
            height = _positive("Shape.height", self.height, "m")
            if not HEIGHT_RANGE[0] <= height <= HEIGHT_RANGE[1]:
                raise ConfigError(f"Shape.height = {height} m is outside {list(HEIGHT_RANGE)} m (give metres)")
            object.__setattr__(self, "height", height)
        lengths = {str(body): _positive(f"Shape.lengths[{body!r}]", v, "m") for body, v in self.lengths.items()}
        object.__setattr__(self, "lengths", MappingProxyType(lengths))
        if self.sex is not None and self.sex not in SEXES:
            raise ConfigError(f"Shape.sex = {self.sex!r} must be one of {list(SEXES)} or None")

    # ---- constructors ------------------------------------------------------------------------------------------
    @classmethod
    def from_model(
        cls,
        model: BodyModel,
        generic: BodyModel | None = None,
        *,
        height: float | None = None,
        sex: str | None = None,
    ) -> Shape:
        """The shape of ``model``, relative to ``generic`` (the model it was scaled from); without ``generic``,
        relative to the model it was loaded as (its in-memory ``body_scales``; ones for a file read as is).

        ``height`` (m) is kept as given; None measures the standing height
        (`biomotion.body.scaling.stature.standing_height`, on ``generic`` scaled by the factors when given) when the
        model carries a head-top marker or a torso or head body, and leaves it unknown otherwise (a lower-limb model
        has no stature).
        """
        model = model.to(_F64)
        if generic is None:
            factors = model.body_scales
            reference = model.spec.name
        else:
            generic = generic.to(_F64)
            factors = recovered_factors(model, generic)
            reference = generic.name
        if height is None:  # on a model that carries its factors: a file read as is has no scaling history
            named = {b: factors[i] for i, b in enumerate(model.body_names)}
            height = _measured_height(model if generic is None else scale_model(generic, named))
        return cls(
            reference=reference,
            scales={b: tuple(float(v) for v in factors[i]) for i, b in enumerate(model.body_names)},
            mass=float(model.masses.sum()),
            masses={b: float(model.masses[i]) for i, b in enumerate(model.body_names)},
            height=height,
            lengths=segment_lengths(model),
            sex=sex,
        )

    @classmethod
    def from_osim(
        cls, path: str | Path, generic: str | Path | BodyModel | None = None, *, height: float | None = None
    ) -> Shape:
        """`from_model` of the scaled model file ``path`` against ``generic`` (a model or its file)."""
        if generic is not None and not isinstance(generic, BodyModel):
            generic = BodyModel.from_osim(generic)
        return cls.from_model(BodyModel.from_osim(path), generic, height=height)

    @classmethod
    def from_measures(
        cls,
        height: float,
        mass: float,
        sex: str | None = None,
        *,
        generic: BodyModel | None = None,
        generic_height: float | None = None,
    ) -> Shape:
        """The expected shape of a person of ``height`` (m) and ``mass`` (kg) through the ANSUR II segment lines
        (module docstring), relative to ``generic`` (default: Rajagopal 2016 by body name, 1.70 m).

        The shipped lines are fitted on the ANSUR II men (`biomotion.body.scaling.segments`); ``sex`` is recorded
        but does not change the segments. Masses follow the generic model's distribution.
        """
        height = _positive("height", height, "m")
        if not HEIGHT_RANGE[0] <= height <= HEIGHT_RANGE[1]:
            raise ConfigError(f"height = {height} m is outside {list(HEIGHT_RANGE)} m (give metres)")
        if generic is None:
            bodies, reference = RAJAGOPAL_2016_BODIES, RAJAGOPAL_2016_NAME
            stature = RAJAGOPAL_2016_HEIGHT if generic_height is None else float(generic_height)
        else:
            generic = generic.to(_F64)
            bodies, reference = generic.body_names, generic.name
            stature = standing_height(generic, generic_height=generic_height).height
        lines = shipped_lines()["segments"]
        segments = {
            s.name: (lines[s.name]["intercept_mm"] + lines[s.name]["slope"] * 1000.0 * height)
            / (lines[s.name]["intercept_mm"] + lines[s.name]["slope"] * 1000.0 * stature)
            for s in SEGMENTS
        }
        per_body = body_factors(tuple(bodies), segments, height / stature)
        masses = None
        if generic is not None:
            ratio = _positive("mass", mass, "kg") / float(generic.masses.sum())
            masses = {b: float(generic.masses[i]) * ratio for i, b in enumerate(generic.body_names)}
            mass = math.fsum(masses.values())
        return cls(
            reference=reference,
            scales={b: (f, f, f) for b, f in per_body.items()},
            mass=mass,
            masses=masses,
            height=height,
            sex=sex,
        )

    # ---- use ---------------------------------------------------------------------------------------------------
    def to_model(self, generic: BodyModel) -> BodyModel:
        """``generic`` scaled to this shape (float64): `scale_model` by ``scales``; body masses set to ``masses``
        (inertias times each body's mass ratio), or the generic distribution at ``mass`` when ``masses`` is None.
        A body of ``generic`` the shape has no factors for is a `ConfigError` (missing segments)."""
        generic = generic.to(_F64)
        missing = [b for b in generic.body_names if b not in self.scales]
        if missing:
            raise ConfigError(
                f"Shape (reference {self.reference!r}) has no scale factors for bodies {missing} of model "
                f"{generic.name!r}: missing segments"
            )
        factors = torch.tensor([self.scales[b] for b in generic.body_names], dtype=_F64)
        if self.masses is None:
            return scale_model(generic, factors, mass=self.mass, preserve_mass_distribution=True)
        scaled = scale_model(generic, factors, preserve_mass_distribution=True)
        target = torch.tensor([self.masses[b] for b in generic.body_names], dtype=_F64)
        ratio = torch.where(scaled.masses > 0.0, target / scaled.masses.clamp(min=1e-300), torch.ones_like(target))
        return dataclasses.replace(scaled, masses=target, inertias=scaled.inertias * ratio[:, None, None])

    def write_osim(self, generic_osim: str | Path, out: str | Path, *, name: str | None = None) -> BodyModel:
        """Write the generic model file ``generic_osim`` scaled to this shape as ``out`` (an .osim OpenSim loads,
        `biomotion.body.scaling.osim_file.write_scaled_osim`); returns the scaled model (`to_model`)."""
        generic = BodyModel.from_osim(generic_osim).to(_F64)
        model = self.to_model(generic)
        result = ScaleResult(
            factors=dict(self.scales),
            measurements={},
            mass=self.mass,
            preserve_mass_distribution=self.masses is None,
            model=model,
            placement=None,
            generic=generic,
        )
        write_scaled_osim(generic_osim, out, result, name=name)
        return model

    def factor(self, body: str) -> tuple[float, float, float]:
        """The (sx, sy, sz) of ``body`` (a `ConfigError` naming it when absent)."""
        try:
            return self.scales[body]
        except KeyError:
            raise ConfigError(f"Shape (reference {self.reference!r}) has no body {body!r}") from None

    def as_dict(self) -> dict:
        """Plain JSON-ready fields."""
        return {
            "reference": self.reference,
            "scales": {b: list(v) for b, v in self.scales.items()},
            "mass": self.mass,
            "masses": None if self.masses is None else dict(self.masses),
            "height": self.height,
            "lengths": dict(self.lengths),
            "sex": self.sex,
        }


# ---- helpers ---------------------------------------------------------------------------------------------------


def _number(what: str, value: object) -> float:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ConfigError(f"{what} = {value!r} is not a number") from None
    if not math.isfinite(number):
        raise ConfigError(f"{what} = {value!r} is not finite")
    return number


def _positive(what: str, value: object, unit: str) -> float:
    number = _number(what, value)
    if number <= 0.0:
        raise ConfigError(f"{what} = {value!r} {unit} must be positive")
    return number


def _measured_height(model: BodyModel) -> float | None:
    head = any(n in model.body_names for n in HEAD_BODIES)
    marker = any(n.lower().replace("_", "") in ("head", "tophead", "headtop", "vertex") for n in model.marker_names)
    if not (head or marker):
        return None
    height = standing_height(model, generic_height=RAJAGOPAL_2016_HEIGHT).height
    return height if HEIGHT_RANGE[0] <= height <= HEIGHT_RANGE[1] else None


def segment_lengths(model: BodyModel) -> dict[str, float]:
    """Body -> distance (m) from its proximal joint centre to its farthest distal joint centre, both in the body
    (joint frame origins, as scaled); bodies without a distal joint are left out."""
    proximal = {j.child: j.child_translation for j in model.joints}
    out: dict[str, float] = {}
    for j in model.joints:
        if j.parent < 0:
            continue
        origin = proximal.get(j.parent)
        if origin is None:
            continue
        length = float(torch.linalg.vector_norm(j.parent_translation - origin))
        name = model.body_names[j.parent]
        if length > 0.0 and length > out.get(name, 0.0):
            out[name] = length
    return out


def _mesh_factors(scaled: BodyModel, generic: BodyModel) -> dict[str, torch.Tensor]:
    """Body -> factors from the ratio of its meshes' scale factors (scaled / generic, each times its in-memory
    ``body_scales``), where both have meshes."""
    generic_meshes = {b.name: b.meshes for b in generic.spec.bodies}
    out = {}
    for body in scaled.spec.bodies:
        pairs = [
            (m.scale_factors, g.scale_factors)
            for m, g in zip(body.meshes, generic_meshes.get(body.name, ()), strict=False)
            if m.mesh_file == g.mesh_file and all(v != 0.0 for v in g.scale_factors)
        ]
        if pairs:
            ratios = torch.tensor([[a / b for a, b in zip(m, g, strict=True)] for m, g in pairs], dtype=_F64)
            # a model scaled in memory keeps its file's meshes: its factors since loading are in body_scales
            history = (
                scaled.body_scales[scaled.body_index(body.name)] / generic.body_scales[generic.body_index(body.name)]
            )
            out[body.name] = ratios.mean(0) * history
    return out


def _landmark_vectors(model: BodyModel) -> dict[str, dict[str, torch.Tensor]]:
    """Body -> named vectors fixed on it: joint frame origins (by joint name) and the centre of mass."""
    out: dict[str, dict[str, torch.Tensor]] = {b: {"com": model.coms[i]} for i, b in enumerate(model.body_names)}
    for j in model.joints:
        out[model.body_names[j.child]][f"child:{j.name}"] = j.child_translation
        if j.parent >= 0:
            out[model.body_names[j.parent]][f"parent:{j.name}"] = j.parent_translation
    return out


def recovered_factors(scaled: BodyModel, generic: BodyModel) -> torch.Tensor:
    """[B, 3] per-body factors that scale ``generic`` into ``scaled`` (module docstring): mesh ratios, else
    per-axis least squares over the vectors fixed on the body. A body of ``scaled`` that ``generic`` lacks is a
    `ConfigError`."""
    missing = [b for b in scaled.body_names if b not in generic.body_names]
    if missing:
        raise ConfigError(f"bodies {missing} of {scaled.name!r} are not in the generic model {generic.name!r}")
    meshes = _mesh_factors(scaled, generic)
    ours, theirs = _landmark_vectors(scaled), _landmark_vectors(generic)
    rows = []
    for body in scaled.body_names:
        if body in meshes:
            rows.append(meshes[body])
            continue
        names = sorted(set(ours[body]) & set(theirs[body]))
        x = torch.stack([theirs[body][n] for n in names]) if names else torch.zeros(0, 3, dtype=_F64)
        y = torch.stack([ours[body][n] for n in names]) if names else torch.zeros(0, 3, dtype=_F64)
        denominator = (x * x).sum(0)
        spanned = denominator > 1e-12
        factors = torch.where(spanned, (x * y).sum(0) / denominator.clamp(min=1e-300), torch.nan)
        fill = factors[spanned].mean() if bool(spanned.any()) else torch.tensor(1.0, dtype=_F64)
        rows.append(torch.where(spanned, factors, fill))
    return torch.stack(rows)


def shape_of_factors(
    generic: BodyModel,
    factors: Mapping[str, Sequence[float]],
    *,
    mass: float | None = None,
    height: float | None = None,
    sex: str | None = None,
) -> Shape:
    """A `Shape` relative to ``generic`` from per-body factors (bodies not named keep 1), at total ``mass`` (default:
    the generic model's) with the generic mass distribution; its ``lengths`` are those of the scaled model."""
    generic = generic.to(_F64)
    scales = {b: tuple(float(v) for v in factors.get(b, (1.0, 1.0, 1.0))) for b in generic.body_names}
    total = float(generic.masses.sum()) if mass is None else _positive("mass", mass, "kg")
    probe = Shape(reference=generic.name, scales=scales, mass=total, height=height, sex=sex)
    return Shape(
        reference=generic.name,
        scales=scales,
        mass=total,
        height=height,
        lengths=segment_lengths(probe.to_model(generic)),
        sex=sex,
    )
