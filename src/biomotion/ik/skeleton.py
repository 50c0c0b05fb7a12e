"""Joint-position retargeting: a skeleton's joint centres (BVH, or any joint-position capture with a joint map) →
coordinates of a musculoskeletal model (PG-BIG appendix A.5, Eq. 4).

A skeleton without markers says where its joints are, not where skin markers would be, so the model is fitted to
its joint centres. Steps, each a documented rule rather than a fitted constant:

1. **Heading.** The source is turned about the vertical (y-up, as every source here) so that the subject faces
   +x on average, OpenSim's forward, with right = +z: forward = up × (mean right hip − left hip). The first frame's
   joint centroid is put at the origin horizontally. Both undo nothing of the motion; they only pick the frame.
2. **Segment scales** (per subject): each pair of mapped joints that bounds a chain of bodies (hip → knee: femur;
   knee → ankle: tibia; shoulder → elbow: humerus ...) gives those bodies the ratio of the median source distance
   to the model's distance in the default pose. A body bounded by several pairs (pelvis: both hips and the lumbar
   joint; torso: lumbar joint and both shoulders) gets per-axis factors fitted to all its pair distances by least
   squares, drawn towards a uniform factor where the pairs leave an axis free. Bodies no pair bounds (hands, toes,
   patellae) take their parent's mean factor. Masses follow OpenSim's scaling (distribution preserved).
3. **Toe point.** Skeletons disagree with anatomy most at the foot (the Bandai-Namco toe joint sits ~40° below
   the ankle when the foot is flat, the model's metatarsophalangeal centre ~19°), so the toe joint is not equated
   with the model's toe joint. It is registered on the hind foot instead, as PG-BIG A.2 Eq. 1 registers markers
   on their bodies: in the frames where the source foot is flat (ankle and toe both within 1 cm of their lowest
   5th-percentile heights), the median horizontal and vertical toe-from-ankle offset is placed ahead of the
   model's ankle along the model foot, whose sole is flat in the default pose; the foot's scale is that
   horizontal distance over the model's.
4. **IK on joint centres** (PG-BIG A.5 Eq. 4): `biomotion.ik.markers.solve_ik` with one virtual marker per mapped
   joint, at the origin of the joint's child frame on the child body (the toe at its registered point), all
   weights 1, every joint coordinate held in its range. The root joint's coordinates are not clamped: a walk
   leaves the model's ±5 m pelvis_tx range and a turn its ±90° pelvis_rotation, and neither is anatomy.
5. **Filter**: 10 Hz zero-lag 4th-order Butterworth on the coordinates, then clamped back into the coordinate
   ranges (a filter overshoots at a limit). Only when the frame rate is at least 4 × the cutoff: at 30 fps
   (Bandai-Namco, already cleaned by the studio) a 10 Hz cutoff sits at 2/3 of Nyquist and removes nothing but the
   sharpness of foot strikes, so planted feet slide more than in the capture (`biomotion validate ik` reports
   the filtered figures beside the default ones).
6. **Floor**: pelvis_ty is lowered so the 5th percentile over frames of the lowest foot contact point is at
   y = 0 (the rule of `biomotion.body.contact.lowest_foot_heights`), so the feet rest on the floor.

Figures per clip (`SkeletonRetarget`): joint-centre errors of the final, filtered motion against the source (the
floor shift applied to both), and the ankle and toe points of both, from which `biomotion.validation.bvh` scores
foot skating.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.optimize
import torch

from biomotion.body.contact import GROUND_PERCENTILE, lowest_foot_heights
from biomotion.body.kinematics import forward_kinematics, joint_centers, points_in_ground
from biomotion.body.model import BodyModel
from biomotion.body.scaling.bodies import scale_model
from biomotion.body.scaling.osim_file import ScaleResult, write_scaled_osim
from biomotion.errors import ConfigError, DataFormatError
from biomotion.ik.markers import solve_ik
from biomotion.io.bvh import BVHMotion
from biomotion.motion import Markers, Motion

_F64 = torch.float64
FILTER_HZ = 10.0
MIN_RATE_PER_CUTOFF = 4.0  # the coordinates are filtered only when rate >= 4 x cutoff (module docstring, step 5)
FLAT_FOOT_TOLERANCE = 0.01  # m above the 5th-percentile height at which a joint still counts as down
RETRY_ERROR = 0.01  # m: mean joint error of a frame above which IK is tried again
RESTART_FRACTIONS = (0.0, 0.5, -0.5)  # restarts of such frames: joint coordinates at middle + f x half range
NEIGHBOUR_PASSES = 2  # then passes from the nearest frame below the error
UNIFORM_PULL = 0.1  # weight of the pull towards a uniform factor in a multi-pair body fit


@dataclass(frozen=True)
class JointMap:
    """Which source joint stands for which model joint.

    Attributes:
        centres: model joint name (JointSet) -> source joint at that joint's centre. Must include the two hips
            (``hip_r``, ``hip_l``), which set the heading.
        toes: model toe joint name (``mtp_r``) -> source toe joint, registered on the hind foot (module
            docstring, step 3) rather than equated with the model's joint centre.
    """

    centres: Mapping[str, str]
    toes: Mapping[str, str] = dataclasses.field(default_factory=dict)

    @classmethod
    def from_file(cls, path: str | Path) -> JointMap:
        """A map from a JSON file ``{"centres": {model joint: source joint}, "toes": {...}}``."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except OSError as error:
            raise ConfigError(f"{path}: cannot read the joint map: {error.strerror}") from None
        except json.JSONDecodeError as error:
            raise DataFormatError(path, f"not valid JSON: {error.msg}", line=error.lineno) from None
        if not isinstance(data, dict) or not isinstance(data.get("centres"), dict):
            raise DataFormatError(
                path, 'a joint map is {"centres": {model joint: source joint}, "toes": {...}}', field="centres"
            )
        return cls(dict(data["centres"]), dict(data.get("toes", {})))

    def source_joints(self) -> list[str]:
        return list(self.centres.values()) + list(self.toes.values())


BANDAI_NAMCO = JointMap(
    centres={
        "hip_r": "UpperLeg_R",
        "hip_l": "UpperLeg_L",
        "walker_knee_r": "LowerLeg_R",
        "walker_knee_l": "LowerLeg_L",
        "ankle_r": "Foot_R",
        "ankle_l": "Foot_L",
        "back": "Spine",
        "acromial_r": "UpperArm_R",
        "acromial_l": "UpperArm_L",
        "elbow_r": "LowerArm_R",
        "elbow_l": "LowerArm_L",
        "radius_hand_r": "Hand_R",
        "radius_hand_l": "Hand_L",
    },
    toes={"mtp_r": "Toes_R", "mtp_l": "Toes_L"},
)
"""The Bandai-Namco skeleton (both datasets: one 22-joint hierarchy, ``bandai-namco/SOURCE.md``) on the Rajagopal
2016 model: its ``Spine`` joint, 19 cm above the hip centres as the model's lumbar joint is 18 cm, is the lumbar
joint; ``UpperArm_*`` are the shoulders (glenohumeral), ``Hand_*`` the wrists. Neck, head and the clavicle joints
have no counterpart on the model's rigid torso and are not used."""

KNOWN_MAPS = {"bandai-namco": BANDAI_NAMCO}


def joint_map_for(joint_names: tuple[str, ...] | list[str]) -> JointMap:
    """The built-in map whose source joints the skeleton has all of; a `ConfigError` otherwise."""
    present = set(joint_names)
    for joint_map in KNOWN_MAPS.values():
        if set(joint_map.source_joints()) <= present:
            return joint_map
    raise ConfigError(
        f"no built-in joint map fits a skeleton with joints {sorted(present)}; give one with "
        f'--joint-map FILE (JSON: {{"centres": {{model joint: skeleton joint}}, "toes": {{...}}}})'
    )


@dataclass(frozen=True)
class SkeletonRetarget:
    """One retargeted clip.

    Attributes:
        motion: coordinates of ``model`` (filtered, in range, feet on the floor).
        model: the generic model scaled to the skeleton, with the virtual markers.
        factors: body -> (sx, sy, sz) scale factors applied.
        joint_names: model joints tracked (centres, then toes).
        errors: [T, J] distance between the model's points and the source joints (m), NaN where the source lacks
            the joint.
        feet_source, feet_result: [T, K, 3] the source's and the model's ankle and toe points (m), for the
            skate ratio (`biomotion.metrics.contact.skate_ratio`) of the retargeting's check.
        floor_shift: m the result was lowered to put the feet on y = 0 (the source was shifted the same way for
            the errors).
        ik_motion: the IK solution before filtering and the floor shift.
        tracked: the source points in the model's frame (faced forward), named after the model joints.
    """

    motion: Motion
    model: BodyModel
    factors: dict[str, tuple[float, float, float]]
    joint_names: tuple[str, ...]
    errors: np.ndarray
    feet_source: np.ndarray
    feet_result: np.ndarray
    floor_shift: float
    ik_motion: Motion
    tracked: Markers

    @property
    def mean_error(self) -> float:
        return float(np.nanmean(self.errors))

    @property
    def max_error(self) -> float:
        return float(np.nanmax(self.errors))


def write_scaled_model(
    generic_path: str | Path,
    out: str | Path,
    generic: BodyModel,
    factors: Mapping[str, tuple[float, float, float]],
    name: str | None = None,
) -> Path:
    """Write ``generic`` (read from ``generic_path``) scaled by ``factors`` as an .osim OpenSim loads
    (`biomotion.body.scaling.osim_file.write_scaled_osim`; mass distribution preserved, markers moved with their
    bodies)."""
    generic = generic.to(_F64)
    result = ScaleResult(
        factors=dict(factors),
        measurements={},
        mass=None,
        preserve_mass_distribution=True,
        model=scale_model(generic, factors),
        placement=None,
        generic=generic,
    )
    return write_scaled_osim(generic_path, out, result, name=name)


def joint_positions(motion: BVHMotion) -> Markers:
    """The joints of a BVH motion as named points in metres (End Sites left out)."""
    return motion.to_markers(end_sites=False)


def _check(joint_map: JointMap, model: BodyModel, source: Markers) -> None:
    for joint in (*joint_map.centres, *joint_map.toes):
        if joint not in model.joint_names:
            raise ConfigError(f"joint map names model joint {joint!r}, which model {model.name!r} does not have")
    missing = [j for j in joint_map.source_joints() if j not in source.names]
    if missing:
        raise ConfigError(f"the source has no joint(s) {missing} that the joint map uses")
    if not {"hip_r", "hip_l"} <= set(joint_map.centres):
        raise ConfigError("a joint map must map both hips (hip_r, hip_l): they set the heading")
    if "pelvis_ty" not in model.coordinate_names:
        raise ConfigError(f"model {model.name!r} has no pelvis_ty coordinate to put the feet on the floor with")


def face_forward(source: Markers, joint_map: JointMap) -> Markers:
    """The source turned about y so the subject faces +x on average (right = +z), first-frame centroid at the
    horizontal origin (module docstring, step 1)."""
    right = np.nanmean(source[joint_map.centres["hip_r"]] - source[joint_map.centres["hip_l"]], axis=0)
    right[1] = 0.0
    norm = np.linalg.norm(right)
    if not np.isfinite(norm) or norm < 1e-6:
        raise DataFormatError(None, "the hips coincide: cannot tell which way the subject faces", field="hips")
    right /= norm
    forward = np.cross([0.0, 1.0, 0.0], right)
    rotation = np.stack([forward, [0.0, 1.0, 0.0], right])
    positions = source.positions @ rotation.T
    start = np.nanmean(positions[0], axis=0)
    positions[..., [0, 2]] -= start[[0, 2]]
    return dataclasses.replace(source, positions=positions)


def _distance(source: Markers, a: str, b: str) -> float:
    return float(np.nanmedian(np.linalg.norm(source[a] - source[b], axis=-1)))


def _flat_foot(source: Markers, ankle: str, toe: str) -> tuple[float, float, int]:
    """(horizontal, vertical) median toe-from-ankle offset over the frames where both are down, and the count."""
    a, t = source[ankle], source[toe]
    down = (a[:, 1] < np.nanpercentile(a[:, 1], 5) + FLAT_FOOT_TOLERANCE) & (
        t[:, 1] < np.nanpercentile(t[:, 1], 5) + FLAT_FOOT_TOLERANCE
    )
    offset = (t - a)[down]
    if not len(offset):
        raise DataFormatError(None, f"no frame with {ankle} and {toe} both down: cannot register the toe", field=toe)
    return (
        float(np.median(np.linalg.norm(offset[:, [0, 2]], axis=1))),
        float(np.median(offset[:, 1])),
        int(down.sum()),
    )


def _mapped_above(model: BodyModel, joint: str, mapped: Mapping[str, str] | list[str]) -> str | None:
    """The nearest joint above ``joint`` (towards the root) that is in ``mapped``, or None."""
    by_child = {j.child: j for j in model.joints}
    body = model.joints[model.joint_names.index(joint)].parent
    while body >= 0:
        if by_child[body].name in mapped:
            return by_child[body].name
        body = by_child[body].parent
    return None


def _bodies_between(model: BodyModel, upper: str, lower: str) -> list[int]:
    """The bodies from the child of joint ``upper`` down to the parent of joint ``lower``."""
    by_child = {j.child: j for j in model.joints}
    body = model.joints[model.joint_names.index(lower)].parent
    stop = model.joints[model.joint_names.index(upper)].child
    chain = [body]
    while body != stop:
        body = by_child[body].parent
        chain.append(body)
    return chain


def _ankle(model: BodyModel, toe: str, joint_map: JointMap) -> str:
    ankle = _mapped_above(model, toe, joint_map.centres)
    if ankle is None:
        raise ConfigError(f"no mapped joint above {toe!r} to register the toe on")
    return ankle


def _segment_pairs(model: BodyModel, mapped: list[str]) -> dict[int, list[tuple[str, str]]]:
    """body index -> pairs of mapped joints whose distance the body spans: each joint with the nearest mapped
    joint above it (for every body in between), and mapped joints hanging from the same body with each other."""
    pairs: dict[int, list[tuple[str, str]]] = {}
    siblings: dict[int, list[str]] = {}
    for name in mapped:
        above = _mapped_above(model, name, mapped)
        if above is not None:
            for body in _bodies_between(model, above, name):
                pairs.setdefault(body, []).append((above, name))
        siblings.setdefault(model.joints[model.joint_names.index(name)].parent, []).append(name)
    for body, names in siblings.items():
        pairs.setdefault(body, []).extend((a, b) for i, a in enumerate(names) for b in names[i + 1 :])
    return pairs


def _fit_axes(model_vectors: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """Per-axis factors s [3] with |s ⊙ v_k| ≈ d_k (least squares), pulled towards a uniform factor."""
    uniform = float(np.mean(distances / np.linalg.norm(model_vectors, axis=1)))
    if len(distances) == 1:
        return np.full(3, uniform)

    def residuals(s: np.ndarray) -> np.ndarray:
        fit = np.linalg.norm(model_vectors * s, axis=1) - distances
        return np.concatenate([fit, UNIFORM_PULL * (s - s.mean()) * np.mean(distances)])

    return scipy.optimize.least_squares(residuals, np.full(3, uniform), bounds=(0.2, 5.0)).x


def segment_scales(model: BodyModel, source: Markers, joint_map: JointMap) -> dict[str, tuple[float, float, float]]:
    """Scale factors of every body (module docstring, step 2)."""
    with torch.no_grad():
        centres = joint_centers(model, model.default_q()).numpy()
    where = {name: centres[i] for i, name in enumerate(model.joint_names)}
    factors: dict[int, np.ndarray] = {}
    for body, pairs in _segment_pairs(model, list(joint_map.centres)).items():
        vectors = np.stack([where[b] - where[a] for a, b in pairs])
        distances = np.array([_distance(source, joint_map.centres[a], joint_map.centres[b]) for a, b in pairs])
        factors[body] = _fit_axes(vectors, distances)
    for toe, source_toe in joint_map.toes.items():
        ankle = _ankle(model, toe, joint_map)
        horizontal, _, _ = _flat_foot(source, joint_map.centres[ankle], source_toe)
        span = where[toe] - where[ankle]
        for body in _bodies_between(model, ankle, toe):
            factors[body] = np.full(3, horizontal / float(np.linalg.norm(span[[0, 2]])))
    for joint in (model.joints[i] for i in model.joint_order):  # parents first: inherit the parent's mean
        if joint.child not in factors:
            factors[joint.child] = np.full(3, factors[joint.parent].mean()) if joint.parent in factors else np.ones(3)
    return {model.body_names[b]: tuple(float(x) for x in f) for b, f in sorted(factors.items())}


def _virtual_markers(model: BodyModel, source: Markers, joint_map: JointMap) -> BodyModel:
    """The model with one marker per mapped joint (named after the model joint) and root coordinates unclamped."""
    names, bodies, offsets = [], [], []
    for name in joint_map.centres:
        joint = model.joints[model.joint_names.index(name)]
        names.append(name)
        bodies.append(joint.child)
        offsets.append(joint.child_translation)
    with torch.no_grad():
        q = model.default_q()
        poses = forward_kinematics(model, q)
        centres = joint_centers(model, q, poses)
    for toe, source_toe in joint_map.toes.items():
        ankle = _ankle(model, toe, joint_map)
        horizontal, vertical, _ = _flat_foot(source, joint_map.centres[ankle], source_toe)
        a, t = centres[model.joint_names.index(ankle)], centres[model.joint_names.index(toe)]
        along = (t - a).clone()
        along[1] = 0.0
        target = a + along / torch.linalg.vector_norm(along) * horizontal
        target[1] += vertical
        body = model.joints[model.joint_names.index(toe)].parent
        names.append(toe)
        bodies.append(body)
        offsets.append(poses.rotations[body].T @ (target - poses.positions[body]))
    root = [c for c in range(model.n_q) if model.joints[model.coordinate_joint[c]].parent < 0]
    clamped = model.clamped.clone()
    clamped[root] = False
    return dataclasses.replace(
        model,
        marker_names=tuple(names),
        marker_bodies=torch.tensor(bodies),
        marker_offsets=torch.stack(offsets).to(model.dtype),
        clamped=clamped,
    )


def _nearest(good: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """For each of ``frames``, the index in ``good`` (sorted frame numbers) of the nearest good frame."""
    right = np.clip(np.searchsorted(good, frames), 0, len(good) - 1)
    left = np.clip(right - 1, 0, len(good) - 1)
    return np.where(np.abs(good[left] - frames) <= np.abs(good[right] - frames), left, right)


def _solve(model: BodyModel, tracked: Markers) -> Motion:
    """IK on the virtual markers, then passes over the frames left with a mean joint error above `RETRY_ERROR`:
    solved again with every joint coordinate at the middle of its range, then at a quarter from either end (the
    root where the first solve put it), then from the solution of the nearest frame below the error; each frame
    keeps its lowest objective. A limb can stall at its range limits in a basin the frame-to-frame warm start never
    leaves (an arm held behind the back, solved with the humerus rotated 180° and the elbow straight at its limit)."""
    first = solve_ik(model, tracked)
    values, cost = first.motion.values.copy(), first.cost.copy()
    error = np.nanmean(first.errors, axis=1)
    clamped = model.clamped.numpy()
    middle, half = model.ranges.mean(1).numpy(), 0.5 * (model.ranges[:, 1] - model.ranges[:, 0]).numpy()
    restarts = [np.where(clamped, middle + fraction * half, np.nan) for fraction in RESTART_FRACTIONS]
    for attempt in range(len(restarts) + NEIGHBOUR_PASSES):
        bad = np.flatnonzero(error > RETRY_ERROR)
        good = np.flatnonzero(error <= RETRY_ERROR)
        if not len(bad) or (attempt >= len(restarts) and not len(good)):
            break
        if attempt < len(restarts):
            start = np.where(np.isnan(restarts[attempt]), values[bad], restarts[attempt])
        else:
            start = values[good[_nearest(good, bad)]]
        retry = solve_ik(model, tracked.frames(bad), initial=first.motion.frames(bad).with_values(start))
        better = retry.cost < cost[bad]
        values[bad[better]] = retry.motion.values[better]
        cost[bad[better]] = retry.cost[better]
        error[bad[better]] = np.nanmean(retry.errors[better], axis=1)
    # frames solved apart may land a full turn apart on the unclamped (root) angles: the same pose, unwrapped
    free_angles = ~clamped & np.array([kind == "rotational" for kind in model.motion_types])
    values[:, free_angles] = np.unwrap(values[:, free_angles], axis=0)
    return first.motion.with_values(values)


def filtered_in_range(motion: Motion, model: BodyModel, cutoff_hz: float, *, always: bool = False) -> Motion:
    """Low-passed (module docstring, step 5; ``always`` filters whatever the rate) and clamped into the ranges
    of the clamped coordinates."""
    values = motion.values
    if (always or cutoff_hz * MIN_RATE_PER_CUTOFF <= motion.rate) and motion.n_frames > 15:
        values = motion.filtered(cutoff_hz).values
    lower, upper = model.ranges[:, 0].numpy(), model.ranges[:, 1].numpy()
    clamped = model.clamped.numpy()
    values = np.where(clamped, np.clip(values, lower, upper), values)
    return motion.with_values(values)


def _points(model: BodyModel, q: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        poses = forward_kinematics(model, torch.as_tensor(q, dtype=model.dtype))
        return points_in_ground(poses, model.marker_bodies, model.marker_offsets).numpy()


def retarget_skeleton(
    source: Markers, generic: BodyModel, joint_map: JointMap | None = None, *, cutoff_hz: float = FILTER_HZ
) -> SkeletonRetarget:
    """Fit ``generic`` (scaled to the skeleton) to the joint positions ``source`` (metres, y up); see the module
    docstring for the steps."""
    joint_map = joint_map or joint_map_for(source.names)
    generic = generic.to(_F64)
    _check(joint_map, generic, source)
    source = face_forward(source.select(joint_map.source_joints()), joint_map)
    factors = segment_scales(generic, source, joint_map)
    model = _virtual_markers(scale_model(generic, factors), source, joint_map)
    tracked = source.select([joint_map.centres.get(n) or joint_map.toes[n] for n in model.marker_names])
    tracked = dataclasses.replace(tracked, names=model.marker_names)
    ik_motion = _solve(model, tracked)
    motion = filtered_in_range(ik_motion, model, cutoff_hz)
    errors, feet = score(model, motion, tracked, joint_map)
    shift = float(np.percentile(lowest_foot_heights(model, motion.values), GROUND_PERCENTILE))
    values = motion.values.copy()
    values[:, motion.index("pelvis_ty")] -= shift
    return SkeletonRetarget(
        motion=motion.with_values(values),
        model=model,
        factors=factors,
        joint_names=model.marker_names,
        errors=errors,
        feet_source=tracked.positions[:, _feet(model, joint_map)],
        feet_result=feet,
        floor_shift=shift,
        ik_motion=ik_motion,
        tracked=tracked,
    )


def _feet(model: BodyModel, joint_map: JointMap) -> list[int]:
    """Indices of the ankle and toe virtual markers."""
    foot_joints = set(joint_map.toes) | {_ankle(model, toe, joint_map) for toe in joint_map.toes}
    return [i for i, name in enumerate(model.marker_names) if name in foot_joints]


def score(model: BodyModel, motion: Motion, tracked: Markers, joint_map: JointMap) -> tuple[np.ndarray, np.ndarray]:
    """Joint-centre errors [T, J] (m) of ``motion`` against the ``tracked`` source points, and its ankle and toe
    points [T, K, 3] (m)."""
    points = _points(model, motion.values)
    return np.linalg.norm(points - tracked.positions, axis=-1), points[:, _feet(model, joint_map)]
