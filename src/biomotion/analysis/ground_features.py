"""Per-frame features of an analysed motion for a learned ground-reaction model (`biomotion.models.ground_forces`).

Everything is computed through the subject's own model by `biomotion.analysis.chain.analyze` — the Newton baseline
m(g + a_COM), the PhysPT contact model's per-foot forces (Eq. 4-5, `biomotion.body.contact`), foot contact points and
leg geometry by forward kinematics — and made dimensionless, so that people of any size and trials from any lab
read alike (Froude scaling, Alexander 1989, Physiol. Rev. 69:1199): accelerations in g, velocities in √(g L),
lengths in L, forces in body weights, where L is the model's leg length (`leg_length`: hip, knee and ankle joint
centres plus the ankle's height over the sole, in the default pose). Horizontal vectors are taken in the pelvis's
heading frame (forward, right) and foot quantities relative to the COM, so a treadmill (the stance foot moving with
the belt under a still body) and overground walking (a still stance foot under a moving body) give the same
numbers, as do trials facing any direction. No coordinate enters by name or sign convention (the Fukuchi models'
knee flexion is negative, the Rajagopal family's positive): joint angles are geometric angles between segments.
Nothing that depends on how a model distributes its mass enters as a level either: the COM's height over the floor
is left out (the Fukuchi models carry head, arms and trunk in the pelvis, which puts their COM about 8 standard
deviations of the runners' spread below a full-body model's, in leg lengths), only its motion is used.

Contract: `ground_features` takes an `Analysis` of a model with a 6-degree-of-freedom floating base and both legs
(bodies ``femur_*``, ``tibia_*``, ``talus_*``, ``calcn_*``), and finite coordinates; it raises `ModelError` or
`DataFormatError` with one line saying what is missing otherwise (`check_motion`, `leg_bodies`). Features per frame
are in `FEATURE_NAMES` order; `MIRROR` maps each to its left-right mirror image (index and sign), for symmetric
training and test-time averaging.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from biomotion.analysis.chain import STANDARD_GRAVITY, Analysis
from biomotion.body.contact import foot_points, root_coordinates
from biomotion.body.kinematics import forward_kinematics, points_in_ground
from biomotion.body.model import BodyModel
from biomotion.errors import DataFormatError, ModelError
from biomotion.motion import Motion

SIDES = ("r", "l")
#: leg bodies from hip to foot, per side
LEG = ("femur", "tibia", "talus", "calcn")
#: foot landmarks from the contact model's points (`biomotion.body.contact.foot_points` names, side left out)
LANDMARKS = {"heel": ("heel_med", "heel_lat"), "ball": ("met1", "met5"), "toe": ("toe",)}
#: shortest motion a learned ground-reaction model takes (s): its receptive field is about 0.6 s
MIN_SECONDS = 0.5


def _names() -> tuple[tuple[str, ...], tuple[int, ...], tuple[float, ...]]:
    """Feature names, and for each the index of its mirror image and the sign it takes there."""
    names: list[str] = [
        "baseline_vertical_bw",  # 1 + a_COM,y / g: Newton's vertical GRF in body weights
        "com_acc_forward_g",
        "com_acc_right_g",
        "com_vel_vertical",
        "inferred_vertical_bw",
        "inferred_forward_bw",
        "inferred_right_bw",
    ]
    mirror: list[tuple[str, float]] = [
        (n, -1.0 if n.endswith("right_g") or n.endswith("right_bw") else 1.0) for n in names
    ]
    per_side: list[tuple[str, bool]] = [("inferred_vertical_bw", False), ("inferred_forward_bw", False)]
    per_side += [("inferred_right_bw", True)]
    for mark in LANDMARKS:
        per_side += [
            (f"{mark}_height", False),
            (f"{mark}_vel_vertical", False),
            (f"{mark}_acc_vertical_g", False),
            (f"{mark}_rel_forward", False),
            (f"{mark}_rel_right", True),
            (f"{mark}_relvel_forward", False),
            (f"{mark}_relvel_right", True),
        ]
    per_side += [
        ("leg_extension", False),
        ("leg_extension_rate", False),
        ("knee_angle", False),
        ("knee_angle_rate", False),
        ("ankle_angle", False),
        ("ankle_angle_rate", False),
    ]
    for side, other in (("r", "l"), ("l", "r")):
        for name, lateral in per_side:
            names.append(f"{name}_{side}")
            mirror.append((f"{name}_{other}", -1.0 if lateral else 1.0))
    index = {n: i for i, n in enumerate(names)}
    return tuple(names), tuple(index[m] for m, _ in mirror), tuple(s for _, s in mirror)


FEATURE_NAMES, MIRROR_INDEX, MIRROR_SIGN = _names()


@dataclass(frozen=True)
class GroundFeatures:
    """What `ground_features` computes on an analysis's frames.

    Attributes:
        times: [T] s, the analysis's frames.
        values: [T, F] features in `FEATURE_NAMES` order (dimensionless, see the module docstring).
        forward: [T, 3] unit forward direction of the pelvis on the ground (y = 0); right = forward × up.
        baseline: [T, 3] Newton's ground force m(g + a_COM) in body weights, in (forward, up, right).
        heel, toe: [T, 2, 3] ground points (y at each foot's rest level) of the heel centre and toe tip, right then
            left: the foot axis along which a centre of pressure is placed.
        leg_length: L (m). body_weight: m g (N).
    """

    times: np.ndarray
    values: np.ndarray
    forward: np.ndarray
    baseline: np.ndarray
    heel: np.ndarray
    toe: np.ndarray
    leg_length: float
    body_weight: float


def _axes(forward: np.ndarray, ndim: int) -> tuple[np.ndarray, np.ndarray]:
    """Forward and right [T, 1.., 3] broadcast against [T, ..., 3] arrays of ``ndim`` dimensions."""
    right = np.stack([-forward[:, 2], np.zeros(len(forward)), forward[:, 0]], axis=-1)
    shape = forward.shape[:1] + (1,) * (ndim - 2) + (3,)
    return forward.reshape(shape), right.reshape(shape)


def to_heading(forward: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """[T, ..., 3] ground-frame vectors as (forward, up, right) components, for unit ground directions
    ``forward`` [T, 3] (right = forward × up)."""
    f, r = _axes(forward, vectors.ndim)
    return np.stack([(vectors * f).sum(-1), vectors[..., 1], (vectors * r).sum(-1)], axis=-1)


def from_heading(forward: np.ndarray, components: np.ndarray) -> np.ndarray:
    """[T, ..., 3] (forward, up, right) components as ground-frame vectors (inverse of `to_heading`)."""
    f, r = _axes(forward, components.ndim)
    return components[..., :1] * f + components[..., 1:2] * np.array([0.0, 1.0, 0.0]) + components[..., 2:3] * r


def leg_bodies(model: BodyModel) -> dict[str, list[int]]:
    """Body indices of ``femur``, ``tibia``, ``talus``, ``calcn`` per side; `ModelError` naming the first absent one
    (a skeleton without legs and feet cannot stand on the ground this way)."""
    out: dict[str, list[int]] = {}
    for side in SIDES:
        for part in LEG:
            name = f"{part}_{side}"
            if name not in model.body_names:
                raise ModelError(
                    f"model {model.name!r} has no {name} body: learned ground forces need both legs "
                    f"({', '.join(f'{p}_r/l' for p in LEG)})"
                )
        out[side] = [model.body_index(f"{part}_{side}") for part in LEG]
    return out


def leg_length(model: BodyModel) -> float:
    """L (m): hip-knee plus knee-ankle joint-centre distances plus the ankle's height over the foot's contact
    points, in the default pose, averaged over both legs."""
    legs = leg_bodies(model)
    points = foot_points(model)
    with torch.no_grad():
        q = model.defaults[None]
        poses = forward_kinematics(model, q)
        origins = poses.positions[0].numpy()
        feet = points_in_ground(poses, points.bodies, points.offsets)[0].numpy()
    lengths = []
    for side in SIDES:
        hip, knee, ankle, _ = (origins[b] for b in legs[side])
        sole = feet[np.array(points.feet) == side, 1].min()
        lengths.append(np.linalg.norm(knee - hip) + np.linalg.norm(ankle - knee) + (ankle[1] - sole))
    return float(np.mean(lengths))


def check_motion(motion: Motion, model: BodyModel, min_seconds: float = MIN_SECONDS) -> None:
    """Raise a one-line error when a learned ground-reaction model cannot take ``motion`` on ``model``: a model
    without a floating base or without both legs and feet, a motion shorter than ``min_seconds``, or coordinates
    that are not finite (the first bad frame and column named)."""
    root_coordinates(model)
    leg_bodies(model)
    foot_points(model)
    if motion.n_frames < 2 or motion.duration < min_seconds:
        raise DataFormatError(
            None,
            f"the motion lasts {motion.duration:.3f} s ({motion.n_frames} frames); learned ground forces need at "
            f"least {min_seconds} s",
        )
    bad = ~np.isfinite(motion.values)
    if bad.any():
        frame, column = (int(i[0]) for i in np.nonzero(bad))
        raise DataFormatError(
            None,
            "coordinates are not finite (NaN or inf): learned ground forces need every frame",
            frame=frame,
            field=motion.names[column],
        )


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[T] angle (rad) between vectors a, b [T, 3]."""
    cos = (a * b).sum(-1) / np.maximum(np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1), 1e-12)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def ground_features(result: Analysis) -> GroundFeatures:
    """Features of ``result`` on its frames (module docstring); see `GroundFeatures`."""
    model = result.model
    check_motion(result.motion, model)
    times = result.motion.times
    g = STANDARD_GRAVITY
    length = leg_length(model)
    speed = np.sqrt(g * length)
    weight = result.body_weight
    legs = leg_bodies(model)
    points = foot_points(model)
    feet = np.array(points.feet)
    names = np.array([n[:-2] for n in points.names])
    with torch.no_grad():
        poses = forward_kinematics(model, torch.as_tensor(result.motion.values, dtype=model.dtype))
        origins = poses.positions.numpy()
        pelvis = poses.rotations[:, root_body(model)].numpy()
    forward = pelvis[:, :, 0].copy()
    forward[:, 1] = 0.0
    forward /= np.maximum(np.linalg.norm(forward, axis=-1, keepdims=True), 1e-9)
    contact = result.contact_points
    rest = np.percentile(contact[..., 1], 2.0, axis=0)  # [K] each point's resting height, as the contact model
    velocity = np.gradient(contact, times, axis=0)
    acceleration = np.gradient(velocity, times, axis=0)
    heading = lambda vectors: to_heading(forward, vectors)
    com_acc = heading(result.com_acceleration) / g
    inferred = heading(result.inferred.force) / weight  # [T, 2, 3]
    columns: dict[str, np.ndarray] = {
        "baseline_vertical_bw": 1.0 + com_acc[:, 1],
        "com_acc_forward_g": com_acc[:, 0],
        "com_acc_right_g": com_acc[:, 2],
        "com_vel_vertical": result.com_velocity[:, 1] / speed,
        "inferred_vertical_bw": inferred[:, :, 1].sum(1),
        "inferred_forward_bw": inferred[:, :, 0].sum(1),
        "inferred_right_bw": inferred[:, :, 2].sum(1),
    }
    heel = np.zeros((len(times), 2, 3))
    toe = np.zeros((len(times), 2, 3))
    for s, side in enumerate(SIDES):
        columns[f"inferred_vertical_bw_{side}"] = inferred[:, s, 1]
        columns[f"inferred_forward_bw_{side}"] = inferred[:, s, 0]
        columns[f"inferred_right_bw_{side}"] = inferred[:, s, 2]
        for mark, members in LANDMARKS.items():
            pick = (feet == side) & np.isin(names, members)
            position = contact[:, pick].mean(1)
            height = (contact[:, pick, 1] - rest[pick]).mean(1)
            relative = heading(position - result.com) / length
            relative_velocity = heading(velocity[:, pick].mean(1) - result.com_velocity) / speed
            columns[f"{mark}_height_{side}"] = height / length
            columns[f"{mark}_vel_vertical_{side}"] = velocity[:, pick, 1].mean(1) / speed
            columns[f"{mark}_acc_vertical_g_{side}"] = acceleration[:, pick, 1].mean(1) / g
            columns[f"{mark}_rel_forward_{side}"] = relative[:, 0]
            columns[f"{mark}_rel_right_{side}"] = relative[:, 2]
            columns[f"{mark}_relvel_forward_{side}"] = relative_velocity[:, 0]
            columns[f"{mark}_relvel_right_{side}"] = relative_velocity[:, 2]
            if mark in ("heel", "toe"):
                ground = position.copy()
                ground[:, 1] = rest[pick].mean()
                (heel if mark == "heel" else toe)[:, s] = ground
        hip, knee, ankle, calcn = (origins[:, b] for b in legs[side])
        extension = np.linalg.norm(ankle - hip, axis=-1) / length
        knee_angle = np.pi - _angle(hip - knee, ankle - knee)
        ball = contact[:, (feet == side) & np.isin(names, LANDMARKS["ball"])].mean(1)
        ankle_angle = _angle(knee - ankle, ball - calcn)
        columns[f"leg_extension_{side}"] = extension
        columns[f"knee_angle_{side}"] = knee_angle
        columns[f"ankle_angle_{side}"] = ankle_angle
        for name, value in (("leg_extension", extension), ("knee_angle", knee_angle), ("ankle_angle", ankle_angle)):
            columns[f"{name}_rate_{side}"] = np.gradient(value, times) * np.sqrt(length / g)
    values = np.stack([columns[name] for name in FEATURE_NAMES], axis=-1)
    baseline = np.concatenate([com_acc[:, :1], 1.0 + com_acc[:, 1:2], com_acc[:, 2:]], axis=-1)
    if not np.isfinite(values).all():
        frame, column = (int(i[0]) for i in np.nonzero(~np.isfinite(values)))
        raise DataFormatError(None, f"feature {FEATURE_NAMES[column]} is not finite", frame=frame)
    return GroundFeatures(times, values, forward, baseline, heel, toe, length, weight)


def root_body(model: BodyModel) -> int:
    """Index of the body the floating base moves (the pelvis)."""
    return next(j.child for j in model.joints if j.parent < 0)
