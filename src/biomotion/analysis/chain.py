"""Analysis of one trial on a model: joint torques, ground forces (measured or inferred), COM, ZMP, energy.

`analyze` is a pure function of (motion, model, optional measured forces); `write_analysis` writes its result as
OpenSim files (torques ``.sto`` with OpenSim's ``<coordinate>_moment|_force`` column names, GRF ``.mot`` with an
ExternalLoads XML, COM/ZMP ``.sto``) plus a JSON summary. The processing follows OpenSim's inverse dynamics tool:
coordinates (with 360° wraps of IK angles removed first, see `unwrapped`) low-pass filtered (default 6 Hz,
3rd-order zero-lag Butterworth after padding half the signal by odd reflection), then differentiated with quintic
splines.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from biomotion.body.balance import (
    MIN_VERTICAL_LOAD_BW,
    body_motion,
    center_of_mass_motion,
    mechanical_energy,
    zero_moment_point,
)
from biomotion.body.contact import ContactSettings, InferredForces, foot_points, infer_ground_reaction
from biomotion.body.dynamics import ExternalLoad, inverse_dynamics
from biomotion.body.kinematics import apply_couplers, forward_kinematics, points_in_ground
from biomotion.body.model import BodyModel
from biomotion.errors import ModelError
from biomotion.io.atomic import atomic_write
from biomotion.io.mot import write_external_loads_xml, write_ground_reaction, write_motion, write_storage
from biomotion.motion import GroundReaction, Motion

STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class Analysis:
    """Everything `analyze` computes, on the motion's frames (numpy, SI)."""

    motion: Motion  # filtered coordinates in model order (couplers applied)
    velocities: np.ndarray  # [T, n_q] their time derivatives (the ones the torques used)
    torques: np.ndarray  # [T, n_q] generalized forces with the loads used
    torques_source: str  # "measured", "inferred" or "learned": the force source of the torques
    inferred: GroundReaction  # per foot, from kinematics only
    measured: GroundReaction | None  # per foot, from the plates (assigned to feet), on the motion's frames
    root_residual: np.ndarray  # [T, 6] root generalized force the inferred contact could not supply
    com: np.ndarray  # [T, 3]
    com_velocity: np.ndarray  # [T, 3]
    com_acceleration: np.ndarray  # [T, 3]
    zmp: np.ndarray  # [T, 3] on y = 0
    kinetic: np.ndarray  # [T] J
    potential: np.ndarray  # [T] J
    contact_points: np.ndarray  # [T, K, 3] foot contact points of the contact model
    contact_loaded: np.ndarray  # [T, K] bool, point carries > 10 N of inferred normal force
    model: BodyModel
    learned: GroundReaction | None = None  # per foot, from a learned estimator (`GroundForceEstimator`) when given

    @property
    def body_weight(self) -> float:
        return float(self.model.total_mass) * STANDARD_GRAVITY


def model_motion(motion: Motion, model: BodyModel) -> Motion:
    """The motion's coordinates in model order; coupled coordinates the file lacks are computed from their
    coupler, other absent coordinates are an error (naming them)."""
    dependent = {model.coordinate_names[c.dependent] for c in model.couplers}
    missing = [
        n
        for n in model.coordinate_names
        if n not in motion.names and n not in dependent and not bool(model.locked[model.coordinate_index(n)])
    ]
    if missing:
        raise ModelError(f"the motion lacks model coordinates: {', '.join(missing)}")
    selected = motion.select(model.coordinate_names)
    values = torch.tensor(selected.values, dtype=model.dtype)
    absent = ~torch.tensor(selected.mask)
    values[:, absent] = model.defaults[absent]
    values = apply_couplers(model, values)
    return selected.with_values(values.numpy())


def unwrapped(motion: Motion, model: BodyModel) -> Motion:
    """The motion with 2π jumps between frames removed from its rotational coordinates.

    IK output can hold angles wrapped into (−180°, 180°]: in OpenCap Subject4's DJAsym1, DJAsym2 and DJAsym3
    ``_ik.mot`` an arm turning through ±180° near gimbal lock jumps by 245°-351° between two frames (DJAsym1
    ``arm_flex_r`` 170° → −176°, a 14° turn). Filtered and differentiated as it is, such a jump becomes an
    acceleration of thousands of rad/s² and a ground force of several body weights. ``numpy.unwrap`` moves only
    steps larger than π (to the same pose, 2π away), so coordinates without a wrap are unchanged.
    """
    rotational = np.array([kind == "rotational" for kind in model.motion_types])
    if not rotational.any() or motion.n_frames < 2:
        return motion
    values = motion.values.copy()
    values[:, rotational] = np.unwrap(values[:, rotational], axis=0)
    return motion.with_values(values)


def _nearest_feet(
    forces: GroundReaction, model: BodyModel, q: torch.Tensor, times: np.ndarray, threshold: float
) -> tuple[GroundReaction, np.ndarray, np.ndarray]:
    """The plates on the motion's frames, and per frame and channel [T, P] whether the plate is loaded (vertical
    force above ``threshold`` N with a defined centre of pressure) and whether the right foot's contact points are
    nearer its centre of pressure than the left's."""
    points = foot_points(model)
    same_clock = forces.n_frames == len(times) and np.allclose(forces.times, times)
    on_frames = forces if same_clock else forces.at(times)
    positions = points_in_ground(forward_kinematics(model, q), points.bodies, points.offsets).numpy()
    feet = np.array(points.feet)
    force = np.nan_to_num(on_frames.force)  # no plate data beyond the recording: no load
    cop = on_frames.cop
    loaded = (np.abs(force[..., 1]) > threshold) & np.isfinite(cop).all(axis=-1)
    distance = np.linalg.norm((positions[:, None] - np.nan_to_num(cop)[:, :, None])[..., [0, 2]], axis=-1)
    nearest_right = distance[..., feet == "r"].min(-1) <= distance[..., feet == "l"].min(-1)
    return on_frames, loaded, nearest_right


def plate_feet(
    forces: GroundReaction, model: BodyModel, q: torch.Tensor, times: np.ndarray, threshold: float = 20.0
) -> dict[str, str]:
    """The foot body (``calcn_r``/``calcn_l``) each plate channel carries: the foot whose contact points are
    nearest the plate's centre of pressure on most of the frames where it bears more than ``threshold`` N (the
    usual stance threshold); channels never loaded so are left out.

    For labs where each foot steps on its own plate, as an ExternalLoads file needs them. On OpenCap Subject4 it
    gives plate 1 the right foot and plate 2 the left in every trial, the mapping opencap/SOURCE.md verified by
    hand (the shipped ``*_external_forces.xml`` put every plate on ``talus_r``)."""
    _, loaded, nearest_right = _nearest_feet(forces, model, q, times, threshold)
    out = {}
    for channel, name in enumerate(forces.names):
        frames = loaded[:, channel]
        if frames.any():
            out[name] = "calcn_r" if 2 * int(nearest_right[frames, channel].sum()) >= int(frames.sum()) else "calcn_l"
    return out


def assign_to_feet(
    forces: GroundReaction, model: BodyModel, q: torch.Tensor, times: np.ndarray, threshold: float = 1.0
) -> GroundReaction:
    """Per-foot loads from plate channels: at every frame each loaded plate goes to the foot whose contact
    points are nearest its centre of pressure (DESIGN.md: plates to feet, per contact, automatically).

    A plate loaded by both feet at once cannot be split and goes to the nearer foot. Loads above ``threshold``
    (N, vertical) with a defined centre of pressure are applied: light loads still move the torques.
    """
    on_frames, loaded_all, nearest_all = _nearest_feet(forces, model, q, times, threshold)
    out_force = np.zeros((len(times), 2, 3))
    out_moment = np.zeros((len(times), 2, 3))
    weighted_cop = np.zeros((len(times), 2, 3))
    for channel in range(on_frames.n_channels):
        force = np.nan_to_num(on_frames.force[:, channel])
        cop = on_frames.cop[:, channel]
        loaded, nearest_right = loaded_all[:, channel], nearest_all[:, channel]
        for foot, chosen in ((0, nearest_right), (1, ~nearest_right)):
            use = loaded & chosen
            out_force[use, foot] += force[use]
            out_moment[use, foot] += np.nan_to_num(on_frames.moment[use, channel])
            weighted_cop[use, foot] += cop[use] * force[use, 1:2]
    vertical = out_force[..., 1:2]
    with np.errstate(invalid="ignore", divide="ignore"):
        cop = np.where(np.abs(vertical) > threshold, weighted_cop / vertical, np.nan)
    bodies = tuple(f"calcn_{side}" for side in ("r", "l"))
    return GroundReaction(times=times, names=("r", "l"), force=out_force, cop=cop, moment=out_moment, bodies=bodies)


def measured_loads(forces: GroundReaction, model: BodyModel, q: torch.Tensor, times: np.ndarray) -> GroundReaction:
    """The plates as loads on the motion's frames: channels that name their body (an ExternalLoads file, a plate
    override) are applied to it, the others go to the feet frame by frame (`assign_to_feet`); both kinds may be
    mixed, e.g. one plate overridden and the rest assigned automatically."""
    named = [name for name, body in zip(forces.names, forces.bodies) if body]
    if len(named) == forces.n_channels:
        return loads_on_frames(forces, times)
    free = [name for name in forces.names if name not in named]
    feet = assign_to_feet(forces.select(free), model, q, times)
    if not named:
        return feet
    given = loads_on_frames(forces.select(named), times)
    return GroundReaction(
        times=times,
        names=given.names + feet.names,
        force=np.concatenate([given.force, feet.force], axis=1),
        cop=np.concatenate([given.cop, feet.cop], axis=1),
        moment=np.concatenate([given.moment, feet.moment], axis=1),
        bodies=given.bodies + feet.bodies,
    )


def plate_assignment(
    forces: GroundReaction, model: BodyModel, q: torch.Tensor, times: np.ndarray, threshold: float = 20.0
) -> dict[str, dict]:
    """How each plate channel was put on the feet, for reports: ``{"mode": "given", "body": ...}`` for a channel
    that names its body, else ``{"mode": "auto", "frames": n, "right": share, "left": share}`` over the ``n``
    frames where it carries more than ``threshold`` N (the usual stance threshold), from the per-frame rule of
    `assign_to_feet` (a treadmill's single plate shows both feet; a floor plate one)."""
    free = [j for j, body in enumerate(forces.bodies) if not body]
    out: dict[str, dict] = {}
    if free:
        _, loaded, nearest_right = _nearest_feet(
            forces.select([forces.names[j] for j in free]), model, q, times, threshold
        )
    for j, (name, body) in enumerate(zip(forces.names, forces.bodies)):
        if body:
            out[name] = {"mode": "given", "body": body}
            continue
        k = free.index(j)
        frames = loaded[:, k]
        count = int(frames.sum())
        right = float(nearest_right[frames, k].mean()) if count else 0.0
        out[name] = {
            "mode": "auto",
            "frames": count,
            "right": right if count else 0.0,
            "left": 1.0 - right if count else 0.0,
        }
    return out


def loads_on_frames(forces: GroundReaction, times: np.ndarray) -> GroundReaction:
    """Loads whose bodies are already known (e.g. from an ExternalLoads file), on the motion's frames; no load
    outside the recording."""
    same_clock = forces.n_frames == len(times) and np.allclose(forces.times, times)
    sampled = forces if same_clock else forces.at(times)
    return GroundReaction(
        times=times,
        names=sampled.names,
        force=np.nan_to_num(sampled.force),
        cop=sampled.cop,
        moment=np.nan_to_num(sampled.moment),
        bodies=sampled.bodies,
    )


def _loads(forces: GroundReaction, dtype: torch.dtype) -> list[ExternalLoad]:
    return [
        ExternalLoad(
            forces.bodies[j] or f"calcn_{forces.names[j]}",
            torch.tensor(forces.force[:, j], dtype=dtype),
            torch.tensor(np.nan_to_num(forces.cop[:, j]), dtype=dtype),
            torch.tensor(np.nan_to_num(forces.moment[:, j]), dtype=dtype),
        )
        for j in range(forces.n_channels)
    ]


def _as_ground_reaction(inferred: InferredForces, times: np.ndarray) -> GroundReaction:
    return GroundReaction(
        times=times,
        names=("r", "l"),
        force=inferred.foot_force.numpy(),
        cop=inferred.foot_cop.numpy(),
        moment=inferred.foot_moment.numpy(),
        bodies=("calcn_r", "calcn_l"),
    )


class GroundForceEstimator(Protocol):
    """A ground reaction estimated from an analysed motion, for the torques (`analyze`'s ``estimator``), such as
    `biomotion.models.ground_forces.LearnedGroundReaction`. ``name`` is recorded as the torques' force source;
    ``cutoff_hz`` is the low-pass of the coordinates the estimator was made for (it is given an analysis filtered
    so, whatever filter the torques use; None: the torques' own); ``check`` raises a one-line
    `biomotion.errors.BiomotionError` for a motion (in model order, before filtering) the estimator cannot take,
    before any work is done; ``ground_reaction`` returns per-foot loads naming their bodies, on the analysis's
    frames."""

    name: str
    cutoff_hz: float | None

    def check(self, motion: Motion, model: BodyModel) -> None: ...

    def ground_reaction(self, result: Analysis) -> GroundReaction: ...


def analyze(
    motion: Motion,
    model: BodyModel,
    forces: GroundReaction | None = None,
    *,
    cutoff_hz: float = 6.0,
    contact: ContactSettings = ContactSettings(),
    estimator: GroundForceEstimator | None = None,
) -> Analysis:
    """Torques, GRF (inferred always; measured plates assigned to feet when given, or applied to the bodies they
    name when every channel has one), COM, ZMP and energy. With an ``estimator`` the torques use its ground
    reaction (kept as ``learned``) and measured plates, when given too, are kept for comparison."""
    coordinates = model_motion(motion, model)
    if estimator is not None:
        estimator.check(coordinates, model)
    coordinates = unwrapped(coordinates, model)
    if cutoff_hz and coordinates.n_frames > 15:
        coordinates, qd_np, qdd_np = coordinates.smoothed(cutoff_hz)
    else:
        qd_np, qdd_np = coordinates.derivatives()
    q, qd, qdd = (torch.tensor(np.ascontiguousarray(a), dtype=model.dtype) for a in (coordinates.values, qd_np, qdd_np))
    inferred = infer_ground_reaction(model, q, qd, qdd, contact)
    measured = None
    with torch.no_grad():
        if forces is not None:
            measured = measured_loads(forces, model, q, coordinates.times)
            torques = inverse_dynamics(model, q, qd, qdd, _loads(measured, model.dtype))
        else:
            torques = inferred.torques
        bodies = body_motion(model, q, qd, qdd)
        com = center_of_mass_motion(model, q, qd, qdd, bodies)
        zmp = zero_moment_point(model, q, qd, qdd, bodies=bodies)
        kinetic, potential = mechanical_energy(model, q, qd)
    result = Analysis(
        motion=coordinates,
        velocities=np.asarray(qd_np),
        torques=torques.numpy(),
        torques_source="measured" if forces is not None else "inferred",
        inferred=_as_ground_reaction(inferred, coordinates.times),
        measured=measured,
        root_residual=inferred.root_residual.numpy(),
        com=com.position.numpy(),
        com_velocity=com.velocity.numpy(),
        com_acceleration=com.acceleration.numpy(),
        zmp=zmp.numpy(),
        kinetic=kinetic.numpy(),
        potential=potential.numpy(),
        contact_points=inferred.point_positions.numpy(),
        contact_loaded=(inferred.point_forces[..., 1] > 10.0).numpy(),
        model=model,
    )
    if estimator is None:
        return result
    wanted = estimator.cutoff_hz
    same = not wanted or wanted == cutoff_hz
    learned = estimator.ground_reaction(result if same else analyze(motion, model, cutoff_hz=wanted, contact=contact))
    with torch.no_grad():
        torques = inverse_dynamics(model, q, qd, qdd, _loads(learned, model.dtype))
    return replace(result, torques=torques.numpy(), torques_source=estimator.name, learned=learned)


def torque_labels(model: BodyModel) -> list[str]:
    """OpenSim's inverse-dynamics column names: ``<coordinate>_moment`` or ``<coordinate>_force``."""
    return [
        f"{name}_{'force' if kind == 'translational' else 'moment'}"
        for name, kind in zip(model.coordinate_names, model.motion_types)
    ]


def vertical_agreement(predicted: np.ndarray, measured: np.ndarray, body_weight: float) -> dict[str, float]:
    """R² and RMSE (in body weights) of a predicted vertical force against a measured one."""
    residual = predicted - measured
    spread = np.sum((measured - measured.mean()) ** 2)
    return {
        "r2": float(1.0 - np.sum(residual**2) / spread) if spread > 0 else float("nan"),
        "rmse_bw": float(np.sqrt(np.mean(residual**2)) / body_weight),
    }


def plate_frames(result: Analysis, rest_tolerance: float = 0.02, speed: float = 0.2, hold: float = 0.1) -> np.ndarray:
    """[T] bool: frames where every foot the kinematics put on a support is loaded on the plates.

    A foot is on the floor when one of its contact points is within ``rest_tolerance`` of its resting height with
    vertical speed below ``speed``. It stands on a raised support (the box a drop jump starts from) where it
    stays still — one of its contact points slower than ``speed`` in every direction for at least ``hold``
    seconds — with < 20 N on the plates; stepping onto or off that support (a contact point within
    ``rest_tolerance`` of a height it had while standing there, vertical speed below ``speed``, in the same
    stretch of frames) counts too. A foot passes through rest for only about 2·``speed``/g = 0.04 s at the top of
    a jump, and a stance foot on a treadmill moves with the belt. If a foot on a support carries < 20 N on the
    plates it stands beside them (overground walking) or on something they do not measure, the plate total is
    incomplete and the frame is left out of comparisons. No fitted quantity enters the rule.
    """
    from scipy.ndimage import binary_opening, label

    points, times = result.contact_points, result.motion.times
    height = points[..., 1] - np.percentile(points[..., 1], 2.0, axis=0)
    velocity = np.gradient(points, times, axis=0)
    slow = np.abs(velocity[..., 1]) < speed
    still = np.linalg.norm(velocity, axis=-1) < speed
    frames = max(1, round(hold * result.motion.rate))
    feet = np.array(foot_points(result.model).feet)
    keep = np.ones(result.motion.n_frames, dtype=bool)
    for side in ("r", "l"):
        channels = [j for j, body in enumerate(result.measured.bodies) if str(body).endswith(f"_{side}")]
        unloaded = result.measured.force[:, channels, 1].sum(1) < 20.0
        own = np.flatnonzero(feet == side)
        on_support = ((height[:, own] < rest_tolerance) & slow[:, own]).any(axis=1)
        raised = binary_opening(still[:, own].any(axis=1), structure=np.ones(frames, dtype=bool)) & unloaded
        if raised.any():
            at_level = np.zeros_like(raised)
            for k in own:
                levels = np.sort(height[raised, k])
                above = np.searchsorted(levels, height[:, k])
                distance = np.minimum(
                    np.abs(height[:, k] - levels[np.clip(above - 1, 0, len(levels) - 1)]),
                    np.abs(height[:, k] - levels[np.clip(above, 0, len(levels) - 1)]),
                )
                at_level |= (distance < rest_tolerance) & slow[:, k]
            stretches, _ = label(at_level | raised)
            on_support |= np.isin(stretches, stretches[raised])
        keep &= ~(on_support & unloaded)
    return keep


def summary(result: Analysis) -> dict:
    """JSON-able figures of an analysis."""
    weight = result.body_weight
    inferred_vertical = result.inferred.force[..., 1].sum(1)
    peaks = {name: float(np.max(np.abs(result.torques[:, i]))) for i, name in enumerate(torque_labels(result.model))}
    out = {
        "frames": result.motion.n_frames,
        "rate_hz": result.motion.rate,
        "duration_s": result.motion.duration,
        "body_mass_kg": float(result.model.total_mass),
        "force_source": result.torques_source,
        "torques_from": result.torques_source,
        "peak_inferred_vertical_grf_bw": float(inferred_vertical.max() / weight),
        "mean_abs_root_residual": dict(
            zip(
                ["moment_1", "moment_2", "moment_3", "force_1", "force_2", "force_3"],
                np.abs(result.root_residual).mean(0).round(3).tolist(),
            )
        ),
        "peak_abs_generalized_force": dict(sorted(peaks.items(), key=lambda kv: -kv[1])[:10]),
        "com_speed_mean_m_s": float(np.linalg.norm(result.com_velocity[:, [0, 2]], axis=1).mean()),
        "mechanical_energy_std_j": float(np.std(result.kinetic + result.potential)),
        "zmp_inside_support_share": zmp_inside_support(result),
    }
    if result.learned is not None:
        out["peak_learned_vertical_grf_bw"] = float(result.learned.force[..., 1].sum(1).max() / weight)
    if result.measured is not None:
        keep = plate_frames(result)
        measured_vertical = result.measured.force[..., 1].sum(1)
        com_estimate = float(result.model.total_mass) * (STANDARD_GRAVITY + result.com_acceleration[:, 1])
        out["grf_comparison_frames"] = {"used": int(keep.sum()), "left_out_foot_off_plates": int((~keep).sum())}
        out["inferred_vs_measured_vertical"] = vertical_agreement(
            inferred_vertical[keep], measured_vertical[keep], weight
        )
        out["com_baseline_vs_measured_vertical"] = vertical_agreement(
            com_estimate[keep], measured_vertical[keep], weight
        )
        if result.learned is not None:
            out["learned_vs_measured_vertical"] = vertical_agreement(
                result.learned.force[keep, :, 1].sum(1), measured_vertical[keep], weight
            )
        out["peak_measured_vertical_grf_bw"] = float(measured_vertical.max() / weight)
        distance = zmp_to_plate_cop(result, keep)
        out["zmp_vs_plate_cop"] = {
            "frames": int(distance.size),
            "rmse_m": float(np.sqrt(np.mean(distance**2))) if distance.size else None,
            "median_m": float(np.median(distance)) if distance.size else None,
        }
    return out


def zmp_to_plate_cop(result: Analysis, keep: np.ndarray | None = None) -> np.ndarray:
    """Horizontal distance (m) between the ZMP from kinematics and the plates' combined centre of pressure, on the
    frames of ``keep`` (default `plate_frames`: every supporting foot on a plate) where the plates carry at least
    `biomotion.body.balance.MIN_VERTICAL_LOAD_BW` body weights (near touch-down and lift-off both points are ratios
    of small numbers, moment over vertical force, and say nothing about either estimate) and the kinematics give
    a ZMP (they ask as much of the ground).

    On level ground the centre of pressure of the total ground reaction is the ZMP (Sardain & Bessonnet 2004,
    IEEE Trans. Syst. Man Cybern. A 34(5):630, "Forces acting on a biped robot. Center of pressure - zero moment
    point"), so the distance measures how well the kinematics (segment masses, inertias, accelerations) predict
    the measured one. The plates' combined CoP is their CoPs weighted by vertical force (plates level with each
    other, as in the sources here)."""
    if result.measured is None:
        raise ModelError("the ZMP-to-CoP distance needs measured forces (analyze with plates)")
    keep = plate_frames(result) if keep is None else keep
    vertical = result.measured.force[..., 1]
    total = vertical.sum(1)
    loaded = keep & (total >= MIN_VERTICAL_LOAD_BW * result.body_weight) & np.isfinite(result.zmp).all(-1)
    cop = (np.nan_to_num(result.measured.cop) * vertical[..., None]).sum(1)[loaded] / total[loaded, None]
    return np.linalg.norm((result.zmp[loaded] - cop)[:, [0, 2]], axis=1)


def zmp_inside_support(result: Analysis) -> float:
    """Share of frames with load whose ZMP lies inside the convex hull of the loaded contact points
    (HUMOS Sec. 3.4 dynamic stability; see `biomotion.metrics.stability`)."""
    from biomotion.metrics.stability import share_inside_support

    points = torch.tensor(result.contact_points)
    points = torch.cat([points[..., :1], torch.zeros_like(points[..., 1:2]), points[..., 2:]], dim=-1)
    share = share_inside_support(
        torch.tensor(result.zmp), points, contact=torch.tensor(result.contact_loaded), margin=0.01
    )
    return float(share)


def support_polygons(points: np.ndarray, loaded: np.ndarray) -> np.ndarray:
    """[T, K, 3] per frame the convex hull of the loaded contact points on the ground (counter-clockwise),
    padded with NaN."""
    from scipy.spatial import ConvexHull, QhullError

    out = np.full(points.shape, np.nan)
    for frame in np.flatnonzero(loaded.sum(1) >= 1):  # output only: a per-frame hull is cheap at K <= 10
        ground = points[frame, loaded[frame]][:, [0, 2]]
        try:
            order = ConvexHull(ground).vertices if len(ground) >= 3 else np.arange(len(ground))
        except QhullError:  # collinear points: keep them as a segment
            order = np.argsort(ground[:, 0])
        out[frame, : len(order)] = np.column_stack([ground[order, 0], np.zeros(len(order)), ground[order, 1]])
    return out


def write_analysis(
    result: Analysis, out: str | Path, *, grf_file: str = "grf_inferred.mot", extra_summary: dict | None = None
) -> dict[str, Path]:
    """Write the analysis files into ``out`` (the inferred ground reaction as ``grf_file``, its ExternalLoads XML
    beside it; ``extra_summary`` sections added to summary.json); returns them by role."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    times = result.motion.times
    files = {
        "coordinates": write_motion(out / "coordinates_filtered.mot", result.motion),
        "torques": write_storage(
            out / "torques.sto",
            torque_labels(result.model),
            times,
            result.torques,
            name=f"Inverse Dynamics ({result.torques_source} ground reaction)",
        ),
        "grf_inferred": write_ground_reaction(out / grf_file, result.inferred, name=Path(grf_file).stem),
    }
    files["grf_inferred_loads"] = write_external_loads_xml(
        out / f"{Path(grf_file).stem}_loads.xml", result.inferred, grf_file
    )
    if result.learned is not None:
        files["grf_learned"] = write_ground_reaction(out / "grf_learned.mot", result.learned, name="grf_learned")
        files["grf_learned_loads"] = write_external_loads_xml(
            out / "grf_learned_loads.xml", result.learned, "grf_learned.mot"
        )
    if result.measured is not None:
        files["grf_measured"] = write_ground_reaction(
            out / "grf_measured_by_foot.mot", result.measured, name="grf_measured_by_foot"
        )
        files["grf_measured_loads"] = write_external_loads_xml(
            out / "grf_measured_loads.xml", result.measured, "grf_measured_by_foot.mot"
        )
    support = support_polygons(result.contact_points, result.contact_loaded)
    balance = np.column_stack(
        [
            result.com,
            result.com_velocity,
            result.com_acceleration,
            result.zmp,
            result.kinetic,
            result.potential,
            support.reshape(len(times), -1),
        ]
    )
    labels = (
        [f"com_{a}" for a in "xyz"]
        + [f"com_{k}_{a}" for k in ("vel", "acc") for a in "xyz"]
        + [f"zmp_{a}" for a in "xyz"]
        + ["kinetic_energy", "potential_energy"]
        + [f"support_{k}_{a}" for k in range(support.shape[1]) for a in "xyz"]
    )
    files["com_zmp"] = write_storage(out / "com_zmp.sto", labels, times, balance, name="COM and ZMP")
    with atomic_write(out / "summary.json") as handle:
        json.dump({**summary(result), **(extra_summary or {})}, handle, indent=1)
    files["summary"] = out / "summary.json"
    return files
