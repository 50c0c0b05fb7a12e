"""`adapt`: a motion of one body moved onto another body the way that body would move (HUMOS, ``humos.md``), as a
request end to end: the two bodies, the shape adapter, the motion on the target's scaled model, and its files.

HUMOS ("Method Summary") decodes an identity-agnostic motion latent conditioned on the target identity; here the
trained `biomotion.models.shape_vae.ShapeAdapter` does it for a gait (its module docstring: which coordinates it
moves, how the stride time follows the target's shape). This module wraps it for a user:

- **Bodies** (`read_body`): a scaled OpenSim model (``.osim``: its `Shape` by `Shape.from_model`, segment lengths
  in metres as the adapter reads them) or a shape file (YAML/JSON, `SHAPE_FILE_KEYS`): explicit measures
  ``height`` (m) and ``mass`` (kg), optionally ``sex``, through the ANSUR II segment lines
  (`Shape.from_measures`), or the fields of a `Shape` itself (``reference``, ``scales``, ``mass``, ``masses``,
  ``height``, ``lengths``, ``sex``, as `Shape.as_dict` writes them). A shape file's scaled model is its generic
  model (``generic``, a path relative to the file; default the caller's ``generic``, else Rajagopal 2016 under the
  data root) scaled by `Shape.to_model`, the round trip `Shape.write_osim` writes. A model without a head or a
  torso (a lower-limb model) has no standing height, which the adapter needs: give it (``height``).
- **Knee sign**: the motion's knee flexion sign is read from its values
  (`biomotion.generation.pipeline.knee_flexion_negative`: Fukuchi ``_simple`` and Hamner models flex negative);
  the target model's from its knee range (`knee_negative`: a range within (-inf, 0] flexes negative). The output
  carries the target's sign.
- **On the target model**: the adapted columns are put in the target model's coordinate order; coordinates the
  motion lacks take the model's defaults (named in `Adapted.filled`), couplers are applied.
- **Floor**: the adapter keeps the pelvis translations, so on a longer or shorter body the feet would sink or hover.
  ``pelvis_ty`` is shifted so the 5th percentile over frames of the lowest foot contact point
  (`biomotion.body.contact.lowest_foot_heights`, `biomotion.body.contact.GROUND_PERCENTILE`) is where the source
  motion's is on the source model: the adapted body stands on the source's floor (`Adapted.floor_shift_m`).
- **Ground and foot planting** (``planting``, default on): the adapted runner is on the same ground as the source,
  a treadmill belt or the floor. The adapter re-decodes the leg angles and sets a new stride time while the pelvis
  translations keep the source's, so a stance foot no longer moves with the ground under it: it skates (HUMOS
  "skate", ``humos.md`` "Why This Works", Mechanism 3). Two steps fix that without any constant fitted on
  evaluated motions:

  1. `ground_velocity`: the velocity of the ground under the source's stance feet, estimated from the source
     motion on the source model as the median horizontal velocity (x, z) of each foot's lowest contact point
     (`biomotion.body.contact.foot_points`) over the frames in which it is within the planting stage's stance
     height (`biomotion.guidance.planting.PlantingConfig.stance_height`, 3 cm) of the floor. On a treadmill it is
     minus the belt speed along the running direction (a Fukuchi T35 run gives about -3.5 m/s along x); overground
     it is about 0. Recorded as `Adapted.ground_velocity_m_s`.
  2. `plant_on_ground`: the adapted motion is moved into the frame of that ground (its velocity times time is
     subtracted from ``pelvis_tx``/``pelvis_tz``, as `biomotion.data.placement.place_clip` adds a belt speed, and
     its floor is put at y = 0) and each foot is held still on the floor through each of its stance phases
     (`stance_phases`, `stance_targets`): one phase per step, the frames its lowest contact point spends below the
     contact height (`biomotion.metrics.contact.CONTACT_HEIGHT`, 5 cm) around frames below the stance height
     (3 cm); in a phase the foot is translated, as a rigid whole, by minus the integral of the slip of the point it
     rolls on (about the phase's mean, the least change), and lowered onto the floor inside ramps at the phase's
     edges, so its roll (heel, sole, forefoot) and its touchdown and lift-off are kept. The planting stage's leg
     solve (`biomotion.guidance.planting.reach_targets`, the solve of Kovar et al. 2002 footskate cleanup that
     ends PG-BIG guidance, PG-BIG Sec. 3.3) meets these targets by changing only hip, knee, ankle and subtalar
     angles within the model's ranges (so either knee sign), and the pelvis translations are put back: the output
     is a treadmill motion if the input was one. Why not the guidance stage's own targets
     (`biomotion.guidance.planting.plant_targets`, a target per point and run of frames near the floor): the
     adapter's stance feet slide by up to 10 cm along the belt, so those runs break up mid-stance and each point
     gets its own, inconsistent target; the legs then jump between them and skate more than A's angles copied
     onto B (``docs/results/eval_shape.md``). Thresholds and fade are `PlantingConfig`'s defaults (stance height,
     ``band`` for the rolling point, ``ramp`` for fades and ramps); the fade, defined as 3 frames at the canonical
     30 Hz (`biomotion.body.canonical.DEFAULT_RATE`), is kept at the same 0.1 s at the motion's rate.
     `Adapted.planted` says whether it ran (off with ``planting=False``; skipped for a model without pelvis
     translations).

`write_adapted` writes ``motion.mot`` (degrees), ``model.osim`` (the target's scaled model), ``motion.bvh``
(`biomotion.body.bvh_export.motion_to_bvh`), ``viewer.html`` (the adapted motion on the target beside the source on
its own body, `biomotion.viz.viewer.write_viewer`) and ``record.json`` (inputs, both shapes, the adapter's file and
SHA-256, stride times, the ground velocity and whether the feet were planted, versions). Contract: inputs are not
changed; bad bodies and motions raise a one-line `biomotion.errors.ConfigError` or `biomotion.errors.DataFormatError`
naming the file.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage

from biomotion.body.canonical import DEFAULT_RATE, KNEE_COORDINATES
from biomotion.body.contact import GROUND_PERCENTILE, foot_points, lowest_foot_heights
from biomotion.body.kinematics import apply_couplers, forward_kinematics, points_in_ground
from biomotion.body.model import BodyModel
from biomotion.body.shape import Shape, segment_lengths
from biomotion.errors import ConfigError, DataFormatError
from biomotion.guidance.planting import PlantingConfig, reach_targets
from biomotion.io.atomic import atomic_write
from biomotion.io.mappings import read_mapping
from biomotion.metrics.contact import CONTACT_HEIGHT
from biomotion.motion import Motion

ADAPTER_FILE = "shape_adapter.safetensors"
OSIM_SUFFIXES = (".osim",)
SHAPE_SUFFIXES = (".yaml", ".yml", ".json")
SHAPE_FILE_KEYS = (
    "height",
    "mass",
    "sex",
    "generic",
    "generic_height",
    "reference",
    "scales",
    "masses",
    "lengths",
)
"""Keys a shape file may hold (module docstring)."""
PELVIS_TRANSLATIONS = ("pelvis_tx", "pelvis_ty", "pelvis_tz")


@dataclass(frozen=True)
class Body:
    """A body a motion is moved from or onto: its `Shape`, its scaled model, and where they came from: ``osim`` the
    scaled model file given, or ``generic`` the generic model file a shape file is scaled from (one is set)."""

    shape: Shape
    model: BodyModel
    source: Path
    osim: Path | None = None
    generic: Path | None = None

    def write_osim(self, out: str | Path) -> Path:
        """The scaled model as an .osim at ``out``: a copy of the file given, or the generic model scaled by the
        shape (`Shape.write_osim`, named after the shape file)."""
        out = Path(out)
        if self.osim is not None:
            with atomic_write(out, "wb") as handle:
                handle.write(self.osim.read_bytes())
        else:
            self.shape.write_osim(self.generic, out, name=self.source.stem)
        return out

    @property
    def geometry(self) -> list[Path]:
        """Folders holding the model's meshes (`biomotion.viz.scene.geometry_folders` of its file)."""
        from biomotion.viz.scene import geometry_folders

        return geometry_folders(self.osim or self.generic)


@dataclass(frozen=True)
class Adapted:
    """A motion moved onto ``target`` (module docstring): ``motion`` in the target model's coordinate order,
    ``source_motion`` as given; the adapter's file and SHA-256; what was done to fit the target:
    ``ground_velocity_m_s`` (x, z) the ground under the source's stance feet (None without pelvis translations),
    ``planted`` whether the feet were planted on it (module docstring)."""

    motion: Motion
    source_motion: Motion
    source: Body
    target: Body
    adapter_file: Path
    adapter_sha256: str
    knee_negative: dict[str, bool]
    filled: tuple[str, ...]
    floor_shift_m: float | None
    stride_time_s: dict[str, float]
    ground_velocity_m_s: tuple[float, float] | None = None
    planted: bool = False


def knee_negative(model: BodyModel) -> bool:
    """True when ``model``'s knee flexion is negative: its knee coordinates' ranges lie within (-inf, 0]
    (Fukuchi ``_simple``: [-120°, 0]; Rajagopal 2016: [0, 120°])."""
    knees = [model.coordinate_index(n) for n in KNEE_COORDINATES if n in model.coordinate_names]
    return bool(knees) and all(float(model.ranges[k, 1]) <= 0.0 for k in knees)


def _default_generic(data_root: str | Path | None) -> Path:
    from biomotion.data.clips import MODEL_FILE
    from biomotion.settings import default_data_root

    return Path(data_root if data_root is not None else default_data_root()) / MODEL_FILE


def _read_mapping(path: Path) -> dict:
    data = read_mapping(path, "shape file", "a shape file holds a mapping: height and mass, or the fields of a Shape")
    unknown = sorted(set(data) - set(SHAPE_FILE_KEYS))
    if unknown:
        raise DataFormatError(path, f"unknown keys {unknown}; a shape file holds {list(SHAPE_FILE_KEYS)}")
    return data


def _shape_file(path: Path, height: float | None, generic: Path | None, data_root: str | Path | None) -> Body:
    data = _read_mapping(path)
    generic_file = (path.parent / data["generic"]) if data.get("generic") else generic or _default_generic(data_root)
    if not Path(generic_file).is_file():
        raise ConfigError(f"{path}: its generic model {generic_file} is not a file (give `generic:` in the file)")
    generic_model = BodyModel.from_osim(generic_file)
    try:
        if "scales" in data:
            fields = {k: data.get(k) for k in ("scales", "mass", "masses", "height", "sex")}
            shape = Shape(
                reference=data.get("reference") or generic_model.name, lengths=data.get("lengths") or {}, **fields
            )
        else:
            missing = [k for k in ("height", "mass") if data.get(k) is None]
            if missing:
                raise ConfigError(f"no {' or '.join(missing)}: give height (m) and mass (kg), or a Shape's scales")
            shape = Shape.from_measures(
                data["height"],
                data["mass"],
                data.get("sex"),
                generic=generic_model,
                generic_height=data.get("generic_height"),
            )
        if height is not None:
            shape = dataclasses.replace(shape, height=height)
        model = shape.to_model(generic_model)
        shape = dataclasses.replace(shape, lengths={**segment_lengths(model), **shape.lengths})
    except (ConfigError, TypeError) as error:
        raise DataFormatError(path, str(error)) from None
    return Body(shape, model, path, generic=Path(generic_file))


def read_body(
    path: str | Path,
    *,
    height: float | None = None,
    generic: str | Path | None = None,
    data_root: str | Path | None = None,
    what: str = "body",
) -> Body:
    """The `Body` of a scaled ``.osim`` or of a shape file (module docstring). ``height`` (m) sets or replaces the
    body's standing height; ``generic`` is the generic .osim a shape file without ``generic:`` is scaled from
    (default Rajagopal 2016 under ``data_root``); ``what`` names the argument in errors ("--to")."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: {what} is not a file (a scaled .osim or a shape file .yaml/.json)")
    suffix = path.suffix.lower()
    if suffix in OSIM_SUFFIXES:
        model = BodyModel.from_osim(path)
        generic_model = BodyModel.from_osim(generic) if generic is not None else None
        try:
            shape = Shape.from_model(model, generic_model, height=height)
        except ConfigError as error:
            raise ConfigError(f"{path}: {error}") from None
        body = Body(shape, model, path, osim=path)
    elif suffix in SHAPE_SUFFIXES:
        body = _shape_file(path, height, None if generic is None else Path(generic), data_root)
    else:
        raise ConfigError(
            f"{path}: {what} must be a scaled OpenSim model (.osim) or a shape file (.yaml/.yml/.json), "
            f"not {suffix or 'a file without a suffix'}"
        )
    if body.shape.height is None:
        raise ConfigError(
            f"{path}: {what} has no head or torso to measure a standing height from; give its height in metres "
            f"({what}-height)"
        )
    if not any(name.startswith("calcn") for name in body.model.body_names):
        raise ConfigError(f"{path}: {what} has no calcn_r/calcn_l body: the shape adapter reads feet")
    return body


def _on_model(motion: Motion, model: BodyModel) -> tuple[Motion, tuple[str, ...]]:
    """``motion`` in ``model``'s coordinate order, absent coordinates at the model's defaults, couplers applied;
    and the names of those filled in (coupled ones excepted)."""
    selected = motion.select(model.coordinate_names)
    dependent = {model.coordinate_names[c.dependent] for c in model.couplers}
    values = torch.as_tensor(selected.values, dtype=model.dtype)
    absent = ~torch.as_tensor(selected.mask)
    values[:, absent] = model.defaults[absent]
    values = apply_couplers(model, values)
    filled = tuple(n for n, a in zip(model.coordinate_names, absent.tolist()) if a and n not in dependent)
    mask = np.ones(len(model.coordinate_names), dtype=bool)
    return Motion(times=selected.times, names=selected.names, values=values.numpy(), mask=mask), filled


def _floor(model: BodyModel, motion: Motion) -> float:
    return float(np.percentile(lowest_foot_heights(model, motion.values.astype(np.float64)), GROUND_PERCENTILE))


def _foot_positions(model: BodyModel, q: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    """[T, K, 3] ground positions (m) of ``model``'s foot contact points for coordinates q [T, n] (all present),
    and each point's foot ("r"/"l")."""
    feet = foot_points(model)
    with torch.no_grad():
        poses = forward_kinematics(model, torch.as_tensor(q, dtype=model.dtype))
        return points_in_ground(poses, feet.bodies, feet.offsets).double().numpy(), feet.feet


def ground_velocity(
    model: BodyModel, motion: Motion, stance_height: float = PlantingConfig.stance_height
) -> tuple[float, float] | None:
    """(x, z) velocity (m/s) of the ground under the stance feet of ``motion`` on ``model`` (coordinates in the
    model's order, all present: `_on_model`): per foot and frame, the velocity of that foot's lowest contact point
    (central differences of that point's own path), kept where it is within ``stance_height`` of the floor (the 5th
    percentile of the lowest point over frames, as `place_clip` puts a clip on the floor); the median over the kept
    samples. Minus the belt speed on a treadmill, about 0 overground; None when no frame is kept or the motion has
    fewer than 3 frames. ``stance_height`` is the planting stage's stance threshold, so "on the ground" means the
    same here as where the feet are planted (module docstring)."""
    if motion.n_frames < 3:
        return None
    points, feet = _foot_positions(model, motion.values.astype(np.float64))
    velocity = np.gradient(points, motion.times, axis=0)
    height = points[..., 1]
    floor = np.percentile(height.min(-1), GROUND_PERCENTILE)
    samples = []
    for side in sorted(set(feet)):
        own = np.flatnonzero(np.array(feet) == side)
        lowest = own[height[:, own].argmin(-1)]
        frames = np.arange(len(lowest))
        down = height[frames, lowest] < floor + stance_height
        samples.append(velocity[frames, lowest][down][:, [0, 2]])
    kept = np.concatenate(samples)
    if not len(kept):
        return None
    vx, vz = np.median(kept, axis=0)
    return float(vx), float(vz)


def stance_phases(heights: np.ndarray, config: PlantingConfig, contact_height: float = CONTACT_HEIGHT) -> list[slice]:
    """The stance phases of one foot from ``heights`` [T] of its lowest contact point above the floor (m): runs of
    frames below ``contact_height`` (`biomotion.metrics.contact.CONTACT_HEIGHT`, 5 cm: a low point) that reach
    below ``config.stance_height`` (3 cm: a planted foot) somewhere, at least 2 frames long. One run per step, so a
    foot that rolls and rises a few millimetres above the stance threshold mid-stance is still one phase (the
    hysteresis of a contact detector)."""
    labels, _ = ndimage.label(heights < contact_height)
    planted = np.unique(labels[heights < config.stance_height])
    runs = ndimage.find_objects(labels)
    return [runs[k - 1][0] for k in planted[planted > 0] if runs[k - 1][0].stop - runs[k - 1][0].start >= 2]


def stance_targets(
    points: np.ndarray, feet: tuple[str, ...], times: np.ndarray, config: PlantingConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Targets [T, K, 3] and weights [T, K] for the contact ``points`` [T, K, 3] (m, y up, floor y = 0, in the frame
    of the ground) of the feet labelled ``feet`` [K] at ``times`` [T] (s): each foot moved as a rigid whole so that
    it rests on the ground through each of its `stance_phases` (module docstring, "Ground and foot planting").

    - **Slip**: per stance frame, the horizontal velocity (x, z) of the foot's material contact points, weighted by
      how near each is to the foot's lowest point (1 at it, 0 at ``config.band`` above it): the velocity of the
      point the foot rolls on, 0 for a foot that does not skate (heel, then whole sole, then forefoot).
    - **Horizontal**: the foot is translated by minus the integral of its slip, offset so that the translation's
      mean over the phase is 0 (the least change that stops it); the foot's orientation, and so its roll, is kept.
    - **Vertical**: the foot is lowered or raised by its lowest point's height, so the point it rolls on is on the
      floor, ramped in and out over ``config.ramp`` frames inside the phase, so a foot still moving at touchdown or
      lift-off is not pulled to the floor (HUMOS "skate": a low point moving fast).
    - **Fades**: ``config.ramp`` frames before and after a phase carry a linearly fading share of its translation at
      that edge (`biomotion.guidance.planting.plant_targets`' rule; the larger share wins where fades meet).

    All five points of a foot share one translation, so the targets are consistent with the rigid foot and the
    leg solve (`biomotion.guidance.planting.reach_targets`) can meet them; weight 0 (target NaN) elsewhere."""
    n_frames, n_points, _ = points.shape
    target = np.full((n_frames, n_points, 3), np.nan)
    weight = np.zeros((n_frames, n_points))
    velocity = np.gradient(points[..., [0, 2]], times, axis=0)
    ramp = config.ramp
    for side in sorted(set(feet)):
        own = np.flatnonzero(np.array(feet) == side)
        height = points[:, own, 1]
        lowest = height.min(-1)
        for phase in stance_phases(lowest, config):
            near = np.clip(1.0 - (height[phase] - lowest[phase, None]) / config.band, 0.0, 1.0)
            slip = (near[..., None] * velocity[phase][:, own]).sum(1) / near.sum(1)[:, None]
            step = 0.5 * (slip[1:] + slip[:-1]) * np.diff(times[phase])[:, None]
            drift = np.concatenate([np.zeros((1, 2)), np.cumsum(step, 0)])
            shift = np.zeros((len(drift), 3))
            shift[:, [0, 2]] = drift.mean(0) - drift
            inside = np.arange(len(drift))
            shift[:, 1] = -lowest[phase] * np.clip(np.minimum(inside + 1, len(drift) - inside) / (ramp + 1), 0, 1)
            target[phase, own] = points[phase][:, own] + shift[:, None, :]
            weight[phase, own] = 1.0
            for d in range(1, ramp + 1):
                share = 1.0 - d / (ramp + 1)
                for frame, edge in ((phase.start - d, shift[0]), (phase.stop - 1 + d, shift[-1])):
                    if 0 <= frame < n_frames and weight[frame, own[0]] < share:
                        target[frame, own] = points[frame, own] + share * edge
                        weight[frame, own] = share
    return target, weight


def plant_on_ground(
    model: BodyModel, motion: Motion, velocity: tuple[float, float], config: PlantingConfig | None = None
) -> Motion:
    """``motion`` on ``model`` (model order, all present, pelvis translations among them) with its feet planted on
    a ground moving at ``velocity`` (x, z) m/s (module docstring): in the ground's frame, with the floor at y = 0,
    each foot is held still on the floor through its stance phases (`stance_targets`) by the planting stage's leg
    solve (`biomotion.guidance.planting.reach_targets`); the pelvis translations are returned unchanged.
    ``config`` defaults to `PlantingConfig` with its fade (3 frames at the canonical 30 Hz) kept at the same
    duration at the motion's rate."""
    if config is None:
        default = PlantingConfig()
        config = dataclasses.replace(default, ramp=max(1, round(default.ramp * motion.rate / DEFAULT_RATE)))
    values = motion.values.astype(np.float64)
    tx, ty, tz = (motion.index(n) for n in PELVIS_TRANSLATIONS)
    elapsed = motion.times - motion.times[0]
    moving = values.copy()
    moving[:, tx] -= velocity[0] * elapsed
    moving[:, tz] -= velocity[1] * elapsed
    moving[:, ty] -= _floor(model, motion)
    points, sides = _foot_positions(model, moving)
    target, weight = stance_targets(points, sides, motion.times, config)
    feet = foot_points(model)
    q = torch.as_tensor(moving, dtype=model.dtype)[None]
    planted = reach_targets(
        model, q, feet.bodies, feet.offsets, target[None], weight[None], model.ranges[:, 0], model.ranges[:, 1], config
    )[0]
    out = planted.double().numpy().copy()
    out[:, [tx, ty, tz]] = values[:, [tx, ty, tz]]
    return motion.with_values(out.astype(motion.values.dtype))


@functools.lru_cache(maxsize=4)
def _read_adapter(path: Path, modified_ns: int, size: int):
    """The adapter at ``path`` and its SHA-256, read once per file version (an evaluation adapts many clips)."""
    from biomotion.models.shape_vae import ShapeAdapter

    return ShapeAdapter.load(path), hashlib.sha256(path.read_bytes()).hexdigest()


def load_adapter(adapter: str | Path | None = None) -> tuple:
    """The shape adapter at ``adapter`` (default the shipped weights), its path and SHA-256; a one-line
    `ConfigError` when the file is missing. Loaded once per file version (cached on path, mtime and size)."""
    from biomotion.generation.pipeline import CHECKPOINTS

    path = Path(CHECKPOINTS / ADAPTER_FILE if adapter is None else adapter)
    if not path.is_file():
        raise ConfigError(f"{path}: no shape adapter weights (`biomotion train shape-adapter` writes them)")
    stat = path.stat()
    model, sha256 = _read_adapter(path.resolve(), stat.st_mtime_ns, stat.st_size)
    return model, path, sha256


def adapt(
    motion: Motion,
    source: Body | str | Path,
    target: Body | str | Path,
    *,
    adapter: str | Path | None = None,
    source_height: float | None = None,
    target_height: float | None = None,
    generic: str | Path | None = None,
    data_root: str | Path | None = None,
    planting: bool = True,
) -> Adapted:
    """``motion`` of the body ``source`` moved onto the body ``target`` (each a `Body`, a scaled .osim or a shape
    file, `read_body`) by the shape adapter at ``adapter`` (default the shipped
    ``checkpoints/shape_adapter.safetensors``); see the module docstring for the knee sign, the coordinates, the
    floor and the ground. ``source_height`` / ``target_height`` (m) give a body's standing height where its model
    has none; ``planting`` False leaves the adapter's leg angles as decoded (the ground velocity is still
    estimated and recorded)."""
    from biomotion.generation.pipeline import knee_flexion_negative
    from biomotion.models.shape_vae import motion_features, stride_time

    if not isinstance(source, Body):
        source = read_body(source, height=source_height, generic=generic, data_root=data_root, what="--from")
    if not isinstance(target, Body):
        target = read_body(target, height=target_height, generic=generic, data_root=data_root, what="--to")
    model, path, sha256 = load_adapter(adapter)
    flipped = knee_flexion_negative(motion)
    moved = model.adapt(motion, source.shape, target.shape, knee_flipped=flipped)
    negative = knee_negative(target.model)
    if negative != flipped:
        values = moved.values.copy()
        for name in (n for n in KNEE_COORDINATES if n in moved.names):
            values[:, moved.index(name)] *= -1.0
        moved = moved.with_values(values)
    on_target, filled = _on_model(moved, target.model)
    on_source, _ = _on_model(motion, source.model)
    shift = None
    if "pelvis_ty" in target.model.coordinate_names and "pelvis_ty" in motion.names:
        shift = _floor(source.model, on_source) - _floor(target.model, on_target)
        values = on_target.values.copy()
        values[:, on_target.index("pelvis_ty")] += shift
        on_target = on_target.with_values(values)
    velocity = None
    if all(n in motion.names for n in PELVIS_TRANSLATIONS) and all(
        n in target.model.coordinate_names for n in PELVIS_TRANSLATIONS
    ):
        velocity = ground_velocity(source.model, on_source)
    planted = planting and velocity is not None
    if planted:
        on_target = plant_on_ground(target.model, on_target, velocity)
    strides = {  # as the adapter's stride detector measures them in the source and in the output
        "source": stride_time(motion_features(motion, knee_flipped=flipped), motion.rate),
        "adapted": stride_time(motion_features(moved, knee_flipped=negative), moved.rate),
    }
    return Adapted(
        motion=on_target,
        source_motion=motion,
        source=source,
        target=target,
        adapter_file=path,
        adapter_sha256=sha256,
        knee_negative={"source": flipped, "target": negative},
        filled=filled,
        floor_shift_m=shift,
        stride_time_s=strides,
        ground_velocity_m_s=velocity,
        planted=planted,
    )


def _finite(value):
    """JSON-ready: non-finite floats as None, containers walked."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def write_adapted(
    adapted: Adapted,
    out: str | Path,
    *,
    viewer: bool = True,
    inputs: dict | None = None,
    command: str | None = None,
) -> dict[str, Path]:
    """Write ``adapted``'s files into the folder ``out`` (module docstring); returns them by role. ``inputs`` (what
    the user gave) and ``command`` are copied into ``record.json``."""
    from biomotion.body.bvh_export import motion_to_bvh
    from biomotion.generation.request import versions
    from biomotion.io.bvh import write_bvh
    from biomotion.io.mot import write_motion

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "motion": write_motion(out / "motion.mot", adapted.motion, name="adapted"),
        "model": adapted.target.write_osim(out / "model.osim"),
    }
    write_bvh(out / "motion.bvh", motion_to_bvh(adapted.target.model, adapted.motion))
    files["bvh"] = out / "motion.bvh"
    if viewer:
        from biomotion.viz.scene import model_scene
        from biomotion.viz.viewer import write_viewer

        source_motion, _ = _on_model(adapted.source_motion, adapted.source.model)
        ours = model_scene(adapted.target.model, adapted.motion, folders=adapted.target.geometry, name="adapted")
        theirs = model_scene(adapted.source.model, source_motion, folders=adapted.source.geometry, name="source")
        files["viewer"] = write_viewer(
            ours, out / "viewer.html", compare=theirs, compare_mode="side", title="biomotion adapt"
        )
    record = {
        "inputs": inputs or {},
        "command": command,
        "adapter": {"weights": adapted.adapter_file.name, "sha256": adapted.adapter_sha256},
        "source_shape": adapted.source.shape.as_dict(),
        "target_shape": adapted.target.shape.as_dict(),
        "target_model": adapted.target.model.name,
        "knee_flexion_negative": adapted.knee_negative,
        "coordinates_at_model_defaults": list(adapted.filled),
        "floor_shift_m": adapted.floor_shift_m,
        "stride_time_s": adapted.stride_time_s,
        "ground_velocity_m_s": None
        if adapted.ground_velocity_m_s is None
        else dict(zip(("x", "z"), adapted.ground_velocity_m_s)),
        "feet_planted": adapted.planted,
        "frames": adapted.motion.n_frames,
        "rate_hz": adapted.motion.rate,
        "versions": versions(),
        "files": sorted(p.name for p in (*files.values(), out / "record.json")),
    }
    with atomic_write(out / "record.json") as handle:
        json.dump(_finite(record), handle, indent=1)
    files["record"] = out / "record.json"
    return files
