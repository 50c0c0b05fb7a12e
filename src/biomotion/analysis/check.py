"""Verdicts on motion: the quality of an analysed lab trial, and the plausibility of any motion.

Two uses, one set of rules:

- `trial_quality` judges a trial `biomotion.analysis.batch` analysed from markers (and plates): marker fit,
  marker labels, missing markers, residual force and moment at the pelvis, suspicious force-plate frames, joint
  limits hit, velocity spikes; `static_quality` judges the static trial scaling solved.
- `check` judges any motion — captured, refined or generated — on its model: residuals, foot sliding, ground
  penetration, velocity spikes, joint-limit violations, ZMP outside the support, activation saturation
  (``biomotion check``).

Every rule flags frames and turns the share of flagged frames into a verdict with the same a-priori rule: a rule
**fails** when its typical (median) frame breaks it — at least `FAIL_SHARE` = 50 % of the frames it applies to —
and **warns** when its 95th-percentile frame does — at least `WARN_SHARE` = 5 %. A trial's verdict is the worst
of its rules'; a trial whose processing raised an error fails with that error. The per-frame thresholds come from
published practice, never from the trials judged (docs/decisions/batch.md):

- markers: OpenSim's best practice for IK ("Simulation with OpenSim — Best practices", OpenSim documentation:
  "Is the maximum marker error less than 4 cm? Is the RMS error less than ~2 cm?"), per frame: max error above
  `MARKER_MAX_M` or RMS above `MARKER_RMS_M`. Static trials: the same page's scaling rule for bony landmarks
  (max < 2 cm, RMS < ~1 cm), judged on the model markers the placement does not move (the landmarks).
- marker labels: two tracked markers on one body whose errors both break `MARKER_RMS_M` while swapping their
  labels brings both under it are reported as swapped (a fail: the IK of that segment is wrong).
- markers matched: a trial fails when fewer than half (`MIN_MATCHED_SHARE`) of the markers IK would track are
  found in the data (after the marker map), naming the unmatched ones with their closest model names.
- residuals at the pelvis: Hicks et al. 2015 (J Biomech Eng 137:020905, "Is my model good enough?"): residual
  force below 5 % of the peak external force, residual moment below 1 % of COM height x peak external force.
  Those bars are for kinematics made consistent by RRA; inverse dynamics of raw kinematics usually exceeds them,
  so residuals only **warn**, never fail.
- force plates, per frame where a plate carries more than `LOAD_N` (20 N, the usual stance threshold): **foot
  off the plate** (a foot the kinematics put on the ground carries under 20 N while a plate is loaded:
  `biomotion.analysis.chain.plate_frames`), **both feet on one plate** (both feet on the ground, the plate's
  centre of pressure outside both feet and between them), **CoP outside the foot** (more than the foot margin
  from the foot the plate was assigned to). The foot margin is 0.1 x foot length (how far the contact model's
  heel points sit in front of the heel) plus `MARKER_RMS_M` (how far the model's foot may be from the real one).
- joint limits: a clamped coordinate at its bound, or any coordinate beyond its range by more than 1e-3.
- velocity spikes: a rotational coordinate faster than `MAX_ANGULAR_SPEED` (160 rad/s: the fastest human joint
  motion measured, shoulder internal rotation in baseball pitching, peaks at 7000-9000 deg/s, Fleisig et al. 1995,
  Am J Sports Med 23:233) or the pelvis faster than `MAX_LINEAR_SPEED` (12.5 m/s, above the fastest sprint).
- foot sliding: GMD / OmniControl's skate test (`biomotion.metrics.contact.skate_ratio`: faster than 0.5 m/s,
  also on average over 0.25 s) on the foot points in contact — below 5 cm and loaded by the contact model, as
  PhysPT's foot-sliding metric takes the points in contact (a swinging foot passes below 5 cm at speed) — over the
  frames with a foot in contact; on a treadmill (``treadmill=True``) relative to the belt, the median horizontal
  velocity of the points in contact.
- ground penetration: a foot contact point more than `MARKER_RMS_M` below the ground plane.
- ZMP outside the support: the zero-moment point outside the support polygon of the loaded contact points, with
  a 1 cm margin (HUMOS Sec. 3.4, `biomotion.analysis.chain.zmp_inside_support`), on frames with a ZMP.
- activation saturation: a muscle at 99 % or more of its maximum control, or a frame static optimization could not
  balance.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from biomotion.analysis.chain import Analysis, plate_frames
from biomotion.body.model import BodyModel
from biomotion.errors import ModelError
from biomotion.motion import GroundReaction, Markers, Motion

VERDICTS = ("ok", "warn", "fail")
WARN_SHARE = 0.05
"""A rule warns when at least this share of its frames break it (its 95th-percentile frame)."""
FAIL_SHARE = 0.5
"""A rule fails when at least this share of its frames break it (its median frame)."""
MARKER_RMS_M = 0.02
"""OpenSim IK best practice: RMS marker error under ~2 cm."""
MARKER_MAX_M = 0.04
"""OpenSim IK best practice: maximum marker error under 4 cm."""
STATIC_RMS_M = 0.01
"""OpenSim scaling best practice: RMS error of the bony landmarks under ~1 cm."""
STATIC_MAX_M = 0.02
"""OpenSim scaling best practice: maximum error of the bony landmarks under 2 cm."""
MIN_MATCHED_SHARE = 0.5
"""A trial fails when fewer than half of the markers IK would track are in the data."""
RESIDUAL_FORCE_SHARE = 0.05
"""Hicks et al. 2015: residual force under 5 % of the peak external force."""
RESIDUAL_MOMENT_SHARE = 0.01
"""Hicks et al. 2015: residual moment under 1 % of COM height x peak external force."""
LOAD_N = 20.0
"""N: a plate or foot carries load above this (the usual force-plate stance threshold)."""
MAX_ANGULAR_SPEED = 160.0
"""rad/s: faster than any measured human joint motion (pitching shoulder internal rotation, ~9000 deg/s)."""
MAX_LINEAR_SPEED = 12.5
"""m/s: faster than the fastest human sprint."""
SATURATION = 0.99
"""Share of a muscle's maximum control at which it is saturated."""
LIMIT_TOLERANCE = 1e-3
"""rad or m beyond a coordinate's range that counts as a violation (numerical noise below)."""


@dataclass(frozen=True)
class Reason:
    """One rule's finding: its verdict, a one-line message (what, how much, against which threshold), the frames
    it flagged out of the frames it applies to, and its figures."""

    rule: str
    verdict: str
    message: str
    flagged: int = 0
    frames: int = 0
    figures: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Verdict:
    """The verdict on a trial or motion: ``ok``, ``warn`` or ``fail``, the reasons (every rule that ran, worst
    first), the frames and how many any rule flagged, and ``flags`` [T] which frames (not serialised)."""

    verdict: str
    reasons: tuple[Reason, ...]
    frames: int
    frames_flagged: int
    flags: np.ndarray | None = None

    @property
    def failed(self) -> bool:
        return self.verdict == "fail"

    def messages(self, at_least: str = "warn") -> list[str]:
        """The messages of the reasons at ``at_least`` or worse."""
        floor = VERDICTS.index(at_least)
        return [r.message for r in self.reasons if VERDICTS.index(r.verdict) >= floor]

    def to_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "frames": self.frames,
            "frames_flagged": self.frames_flagged,
            "reasons": [_jsonable(asdict(r)) for r in self.reasons],
        }


def worst(verdicts: Sequence[str]) -> str:
    """The worst of some verdicts (``ok`` for none)."""
    return max(verdicts, key=VERDICTS.index, default="ok")


def share_verdict(flagged: int, frames: int) -> str:
    """The a-priori rule: fail at `FAIL_SHARE` of the frames, warn at `WARN_SHARE`, else ok."""
    if frames <= 0 or flagged <= 0:
        return "ok"
    share = flagged / frames
    return "fail" if share >= FAIL_SHARE else "warn" if share >= WARN_SHARE else "ok"


def combine(reasons: Sequence[Reason], frames: int, flags: np.ndarray | None = None) -> Verdict:
    """A verdict from the rules' reasons: the worst verdict, reasons worst first."""
    ordered = tuple(sorted(reasons, key=lambda r: -VERDICTS.index(r.verdict)))
    flagged = int(flags.sum()) if flags is not None else max((r.flagged for r in reasons), default=0)
    return Verdict(worst([r.verdict for r in reasons]), ordered, frames, flagged, flags)


def failure(message: str, rule: str = "error") -> Verdict:
    """The verdict of a trial whose processing stopped with ``message``."""
    return Verdict("fail", (Reason(rule, "fail", message),), 0, 0)


def _share(flagged: int, frames: int) -> str:
    return f"{flagged}/{frames} frames ({100 * flagged / max(frames, 1):.0f} %)"


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return None if not math.isfinite(float(value)) else round(float(value), 6)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


# --- markers ------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MarkerMatch:
    """Which markers IK can track: ``matched`` (model and data), ``required`` (what IK would track: the setup's
    weighted markers, else every model marker), ``unmatched_data`` (data markers no model marker is named like)
    with their ``closest`` model names, and ``missing`` (required markers absent from the data)."""

    matched: tuple[str, ...]
    required: tuple[str, ...]
    missing: tuple[str, ...]
    unmatched_data: tuple[str, ...]
    closest: dict[str, list[str]]

    @property
    def enough(self) -> bool:
        return len(self.matched) >= max(3, math.ceil(MIN_MATCHED_SHARE * len(self.required)))

    def message(self) -> str:
        """Why a trial with too few matched markers fails: the unmatched data names and their closest model
        names (the usual cause: another lab's naming; give a marker map)."""
        hints = ", ".join(
            f"{name} (closest: {', '.join(self.closest.get(name, [])) or 'none'})" for name in self.unmatched_data[:12]
        )
        more = f" and {len(self.unmatched_data) - 12} more" if len(self.unmatched_data) > 12 else ""
        return (
            f"only {len(self.matched)} of the {len(self.required)} markers IK tracks are in the data (at least "
            f"{max(3, math.ceil(MIN_MATCHED_SHARE * len(self.required)))} needed); data markers not on the model: "
            f"{hints or 'none'}{more}; give a marker map (--marker-map DATA=MODEL,...)"
        )


def match_markers(model: BodyModel, markers: Markers, weights: dict[str, float] | None = None) -> MarkerMatch:
    """Compare the data's marker names with the model's (see `MarkerMatch`)."""
    from biomotion.analysis.study import closest_names

    model_names = list(model.marker_names)
    if weights:
        required = tuple(n for n in model_names if weights.get(n, 0.0) > 0)
    else:
        required = tuple(model_names)
    seen = set(markers.names)
    matched = tuple(n for n in required if n in seen)
    missing = tuple(n for n in required if n not in seen)
    unmatched = tuple(n for n in markers.names if n not in set(model_names))
    return MarkerMatch(matched, required, missing, unmatched, closest_names(unmatched, model_names))


def marker_fit(errors: np.ndarray, names: Sequence[str], *, static: bool = False) -> tuple[Reason, np.ndarray]:
    """The marker-fit rule on IK errors [T, M] (m, NaN unseen): per frame RMS and max against OpenSim's bars (the
    scaling bars for a static trial), the worst markers by RMS, and the frames flagged [T]."""
    rms_bar, max_bar = (STATIC_RMS_M, STATIC_MAX_M) if static else (MARKER_RMS_M, MARKER_MAX_M)
    with np.errstate(invalid="ignore"), _quiet():
        frame_rms = np.sqrt(np.nanmean(errors**2, axis=1))
        frame_max = np.nanmax(errors, axis=1)
        marker_rms = np.sqrt(np.nanmean(errors**2, axis=0))
    seen = np.isfinite(frame_rms)
    flags = seen & ((frame_rms > rms_bar) | (frame_max > max_bar))
    frames = int(seen.sum())
    order = np.argsort(-np.nan_to_num(marker_rms, nan=-1.0))
    worst_markers = [(names[k], float(marker_rms[k])) for k in order[:3] if np.isfinite(marker_rms[k])]
    with _quiet():
        rms = float(np.sqrt(np.nanmean(errors**2))) if np.isfinite(errors).any() else float("nan")
        peak = float(np.nanmax(errors)) if np.isfinite(errors).any() else float("nan")
        median_max = float(np.nanmedian(frame_max)) if seen.any() else float("nan")
    verdict = share_verdict(int(flags.sum()), frames)
    kind = "static-pose landmark" if static else "marker"
    message = (
        f"{kind} error RMS {100 * rms:.1f} cm, max {100 * peak:.1f} cm (median frame max {100 * median_max:.1f} cm); "
        f"{_share(int(flags.sum()), frames)} over {100 * rms_bar:.0f} cm RMS or {100 * max_bar:.0f} cm max; worst "
        + ", ".join(f"{n} {100 * v:.1f} cm" for n, v in worst_markers)
    )
    figures = {
        "rms_m": rms,
        "max_m": peak,
        "median_frame_max_m": median_max,
        "worst_markers": [{"marker": n, "rms_m": v} for n, v in worst_markers],
    }
    return Reason("markers", verdict, message, int(flags.sum()), frames, figures), flags


def label_swaps(
    model: BodyModel, markers: Markers, motion: Motion, names: Sequence[str], errors: np.ndarray
) -> list[dict[str, Any]]:
    """Pairs of tracked markers on one body that look swapped: both RMS errors over `MARKER_RMS_M`, and both under
    it with the two labels exchanged (model marker a against data marker b and b against a, on the solved poses).
    Returns [{"markers": (a, b), "rms_m": (ea, eb), "swapped_rms_m": (sa, sb)}]."""
    from biomotion.body.kinematics import forward_kinematics, points_in_ground

    with np.errstate(invalid="ignore"), _quiet():
        rms = np.sqrt(np.nanmean(errors**2, axis=0))
    bad = [k for k in range(len(names)) if np.isfinite(rms[k]) and rms[k] > MARKER_RMS_M]
    if len(bad) < 2:
        return []
    index = [model.marker_index(names[k]) for k in bad]
    q = torch.as_tensor(motion.select(model.coordinate_names).values, dtype=model.dtype)
    with torch.no_grad():
        poses = forward_kinematics(model, q)
        placed = points_in_ground(poses, model.marker_bodies[index], model.marker_offsets[index]).numpy()
    frames = np.searchsorted(markers.times, motion.times - 1e-9)
    frames = np.clip(frames, 0, markers.n_frames - 1)
    data = markers.select([names[k] for k in bad]).positions[frames]
    found = []
    for i in range(len(bad)):
        for j in range(i + 1, len(bad)):
            if int(model.marker_bodies[index[i]]) != int(model.marker_bodies[index[j]]):
                continue
            with np.errstate(invalid="ignore"), _quiet():
                a = float(np.sqrt(np.nanmean(np.sum((placed[:, i] - data[:, j]) ** 2, -1))))
                b = float(np.sqrt(np.nanmean(np.sum((placed[:, j] - data[:, i]) ** 2, -1))))
            if a < MARKER_RMS_M and b < MARKER_RMS_M:
                found.append(
                    {
                        "markers": (names[bad[i]], names[bad[j]]),
                        "rms_m": (float(rms[bad[i]]), float(rms[bad[j]])),
                        "swapped_rms_m": (a, b),
                    }
                )
    return found


class _quiet:
    """Silence numpy's warnings about all-NaN slices (unseen markers) inside a block."""

    def __enter__(self):
        import warnings

        self._catch = warnings.catch_warnings()
        self._catch.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)
        return self

    def __exit__(self, *exc):
        return self._catch.__exit__(*exc)


def marker_reasons(
    model: BodyModel,
    markers: Markers,
    motion: Motion,
    names: Sequence[str],
    errors: np.ndarray,
    match: MarkerMatch,
) -> tuple[list[Reason], np.ndarray]:
    """The marker rules of a trial IK solved: fit, swapped labels, missing and occluded markers; frames flagged."""
    fit, flags = marker_fit(errors, names)
    reasons = [fit]
    swaps = label_swaps(model, markers, motion, names, errors)
    if swaps:
        text = "; ".join(
            f"{a}/{b} look swapped (errors {100 * ea:.1f}/{100 * eb:.1f} cm, {100 * sa:.1f}/{100 * sb:.1f} cm with "
            f"the labels exchanged)"
            for (a, b), (ea, eb), (sa, sb) in ((s["markers"], s["rms_m"], s["swapped_rms_m"]) for s in swaps)
        )
        reasons.append(Reason("marker_labels", "fail", text, fit.flagged, fit.frames, {"swaps": swaps}))
    occluded = {}
    if errors.size:
        unseen = ~np.isfinite(errors)
        occluded = {names[k]: float(unseen[:, k].mean()) for k in range(len(names)) if unseen[:, k].any()}
    if match.missing or occluded:
        parts = []
        if match.missing:
            parts.append(f"not in the data: {', '.join(match.missing)}")
        if occluded:
            gaps = sorted(occluded.items(), key=lambda kv: -kv[1])[:5]
            parts.append("occluded: " + ", ".join(f"{n} {100 * v:.0f} %" for n, v in gaps))
        reasons.append(
            Reason(
                "markers_missing",
                "ok",
                "markers " + "; ".join(parts),
                0,
                0,
                {"missing": list(match.missing), "occluded_share": occluded},
            )
        )
    return reasons, flags


# --- dynamics -----------------------------------------------------------------------------------------------------


def _root_columns(model: BodyModel) -> tuple[list[int], list[int]]:
    """(translational, rotational) coordinates of the root joint."""
    from biomotion.body.contact import root_coordinates

    roots = root_coordinates(model)
    translational = [c for c in roots if model.motion_types[c] == "translational"]
    rotational = [c for c in roots if model.motion_types[c] == "rotational"]
    return translational, rotational


def residual_reason(result: Analysis) -> Reason | None:
    """Residual force and moment at the pelvis against Hicks et al. 2015 (module docstring); warn at most.

    With measured or learned forces the residual is the root's generalized force from inverse dynamics; with the
    inferred contact model, what that model could not supply. In % of body weight (force) and of body weight x
    height (moment; height = the COM's mean height x 1/0.55, the COM sitting at about 55 % of stature)."""
    try:
        translational, rotational = _root_columns(result.model)
    except ModelError:
        return None
    if result.torques_source == "inferred":
        residual = result.root_residual
        moments, forces = residual[:, :3], residual[:, 3:]
        external = result.inferred.force.sum(1)
    else:
        forces = result.torques[:, translational]
        moments = result.torques[:, rotational]
        loads = result.learned if result.learned is not None else result.measured
        external = loads.force.sum(1)
    weight = result.body_weight
    force = np.linalg.norm(forces, axis=1)
    moment = np.linalg.norm(moments, axis=1)
    peak_external = float(np.linalg.norm(external, axis=1).max()) if len(external) else 0.0
    com_height = float(np.mean(result.com[:, 1]))
    height = com_height / 0.55
    force_bar = RESIDUAL_FORCE_SHARE * max(peak_external, weight)
    moment_bar = RESIDUAL_MOMENT_SHARE * com_height * max(peak_external, weight)
    flags = (force > force_bar) | (moment > moment_bar)
    frames = len(force)
    verdict = "warn" if share_verdict(int(flags.sum()), frames) != "ok" else "ok"
    figures = {
        "source": result.torques_source,
        "force_rms_bw": float(np.sqrt(np.mean(force**2)) / weight),
        "force_peak_bw": float(force.max() / weight),
        "moment_rms_bw_height": float(np.sqrt(np.mean(moment**2)) / (weight * height)),
        "moment_peak_bw_height": float(moment.max() / (weight * height)),
        "force_bar_n": force_bar,
        "moment_bar_nm": moment_bar,
    }
    message = (
        f"pelvis residual force RMS {100 * figures['force_rms_bw']:.1f} % BW "
        f"(peak {100 * figures['force_peak_bw']:.0f} %), moment RMS {100 * figures['moment_rms_bw_height']:.2f} "
        f"% BW·height (peak {100 * figures['moment_peak_bw_height']:.1f} %); "
        f"{_share(int(flags.sum()), frames)} over Hicks 2015's {force_bar:.0f} N / {moment_bar:.0f} N·m "
        f"({result.torques_source} forces)"
    )
    return Reason("residuals", verdict, message, int(flags.sum()), frames, figures)


def _foot_outline(result: Analysis) -> tuple[np.ndarray, np.ndarray, float]:
    """Contact points per foot [T, 2, K, 2] (horizontal x, z), which points exist [2, K], and the foot margin."""
    from biomotion.body.contact import foot_points

    points = foot_points(result.model)
    feet = np.array(points.feet)
    right, left = np.flatnonzero(feet == "r"), np.flatnonzero(feet == "l")
    size = max(len(right), len(left))
    outline = np.full((result.motion.n_frames, 2, size, 2), np.nan)
    exists = np.zeros((2, size), dtype=bool)
    for side, own in enumerate((right, left)):
        outline[:, side, : len(own)] = result.contact_points[:, own][..., [0, 2]]
        exists[side, : len(own)] = True
    heel, toe = result.contact_points[:, right[0]], result.contact_points[:, right[-1]]
    length = float(np.median(np.linalg.norm((toe - heel)[:, [0, 2]], axis=1)))
    return outline, exists, 0.1 * length + MARKER_RMS_M


def _distance_to_outline(outline: np.ndarray, exists: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Distance (m, 0 inside) of ``query`` [T, 2] from each foot's outline [T, 2, K, 2] -> [T, 2]."""
    from biomotion.metrics.stability import signed_distance_to_hull

    support = torch.as_tensor(np.nan_to_num(outline))
    active = torch.as_tensor(exists).expand(outline.shape[0], *exists.shape)
    q = torch.as_tensor(np.nan_to_num(query))[:, None, :].expand(-1, 2, -1)
    signed = signed_distance_to_hull(support, active, q).numpy()
    return np.maximum(-signed, 0.0)


def force_data_reason(result: Analysis, plates: GroundReaction | None, assignment: dict[str, dict]) -> Reason | None:
    """Suspicious force-plate frames (module docstring): foot off the plate, both feet on one plate, CoP outside
    the foot; warn or fail by the share of loaded frames."""
    if result.measured is None or plates is None:
        return None
    from biomotion.analysis.chain import loads_on_frames

    on_frames = loads_on_frames(plates, result.motion.times)
    vertical = np.nan_to_num(on_frames.force[..., 1])
    loaded = vertical > LOAD_N  # [T, P]
    any_loaded = loaded.any(1)
    frames = int(any_loaded.sum())
    if frames == 0:
        return Reason("force_data", "ok", "no plate carries load", 0, 0, {})
    outline, exists, margin = _foot_outline(result)
    keep = plate_frames(result)
    off_plate = ~keep & any_loaded
    # both feet kinematically on the ground: a contact point near its resting height, slow vertically
    points = result.contact_points
    height = points[..., 1] - np.percentile(points[..., 1], 2.0, axis=0)
    slow = np.abs(np.gradient(points[..., 1], result.motion.times, axis=0)) < 0.2
    from biomotion.body.contact import foot_points

    feet = np.array(foot_points(result.model).feet)
    grounded = np.stack([((height < 0.02) & slow)[:, feet == side].any(1) for side in ("r", "l")], 1)
    both_on_one = np.zeros(len(vertical), dtype=bool)
    outside_foot = np.zeros(len(vertical), dtype=bool)
    for p, name in enumerate(on_frames.names):
        cop = on_frames.cop[:, p][:, [0, 2]]
        valid = loaded[:, p] & np.isfinite(cop).all(1)
        if not valid.any():
            continue
        distance = _distance_to_outline(outline, exists, cop)  # [T, 2]
        given = assignment.get(name, {})
        if given.get("mode") == "given":
            side = 0 if str(given.get("body", "")).endswith("_r") else 1
            assigned = np.full(len(cop), side)
        else:
            assigned = np.argmin(distance, axis=1)
        own = distance[np.arange(len(cop)), assigned]
        outside_both = (distance > margin).all(1)
        between = _between_feet(outline, exists, cop, margin)
        both = valid & grounded.all(1) & outside_both & between
        both_on_one |= both
        outside_foot |= valid & ~both & (own > margin)
    flags = off_plate | both_on_one | outside_foot
    verdict = share_verdict(int(flags.sum()), frames)
    counts = {
        "foot_off_plate": int(off_plate.sum()),
        "both_feet_on_one_plate": int(both_on_one.sum()),
        "cop_outside_foot": int(outside_foot.sum()),
    }
    text = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in counts.items() if v) or "none"
    message = f"suspicious force frames {_share(int(flags.sum()), frames)} of the loaded ones: {text}"
    return Reason("force_data", verdict, message, int(flags.sum()), frames, {**counts, "margin_m": margin})


def _between_feet(outline: np.ndarray, exists: np.ndarray, cop: np.ndarray, margin: float) -> np.ndarray:
    """[T] whether a point lies within ``margin`` of the hull of both feet's contact points."""
    from biomotion.metrics.stability import signed_distance_to_hull

    both = outline.reshape(outline.shape[0], -1, 2)
    active = torch.as_tensor(exists.reshape(-1)).expand(outline.shape[0], -1)
    signed = signed_distance_to_hull(torch.as_tensor(np.nan_to_num(both)), active, torch.as_tensor(np.nan_to_num(cop)))
    return signed.numpy() >= -margin


def joint_limit_reason(motion: Motion, model: BodyModel, *, at_bound: bool = True) -> Reason:
    """Joint limits: frames where a clamped coordinate sits at its bound (``at_bound``: IK stopped there) or any
    coordinate lies beyond its range by more than `LIMIT_TOLERANCE`; the coordinates concerned."""
    values = motion.select(model.coordinate_names).values
    low, high = model.ranges[:, 0].numpy(), model.ranges[:, 1].numpy()
    free = ~model.locked.numpy()
    beyond = ((values < low - LIMIT_TOLERANCE) | (values > high + LIMIT_TOLERANCE)) & free
    clamped = model.clamped.numpy() & free
    at = ((np.abs(values - low) < 1e-6) | (np.abs(values - high) < 1e-6)) & clamped
    if not at_bound:
        at = np.zeros_like(at)
    hit = beyond | at
    flags = hit.any(1)
    names = [model.coordinate_names[c] for c in np.flatnonzero(hit.any(0))]
    counts = {model.coordinate_names[c]: int(hit[:, c].sum()) for c in np.flatnonzero(hit.any(0))}
    verdict = share_verdict(int(flags.sum()), len(flags))
    what = "at or beyond its range" if at_bound else "beyond its range"
    message = (
        f"joint limits: {', '.join(f'{n} ({counts[n]} frames)' for n in names)} {what}"
        if names
        else "joint limits: every coordinate within its range"
    )
    return Reason("joint_limits", verdict, message, int(flags.sum()), len(flags), {"frames_per_coordinate": counts})


def velocity_reason(motion: Motion, model: BodyModel, velocities: np.ndarray | None = None) -> Reason:
    """Velocity spikes: rotational coordinates over `MAX_ANGULAR_SPEED`, root translations over
    `MAX_LINEAR_SPEED` (module docstring)."""
    values = motion.select(model.coordinate_names)
    speed = np.abs(velocities if velocities is not None else values.derivatives()[0])
    rotational = np.array([k == "rotational" for k in model.motion_types]) & ~model.locked.numpy()
    try:
        translational, _ = _root_columns(model)
    except ModelError:
        translational = []
    fast_rotation = speed[:, rotational] > MAX_ANGULAR_SPEED
    linear = np.linalg.norm(speed[:, translational], axis=1) if translational else np.zeros(len(speed))
    flags = fast_rotation.any(1) | (linear > MAX_LINEAR_SPEED)
    verdict = share_verdict(int(flags.sum()), len(flags))
    if flags.any() and verdict == "ok":
        verdict = "warn"  # a spike is a glitch wherever it is
    names = [n for n, hit in zip(np.array(model.coordinate_names)[rotational], fast_rotation.any(0)) if hit]
    message = (
        f"velocity spikes on {_share(int(flags.sum()), len(flags))}: "
        + (", ".join(names) or "pelvis translation")
        + f" (over {MAX_ANGULAR_SPEED:.0f} rad/s or {MAX_LINEAR_SPEED} m/s)"
        if flags.any()
        else "no velocity spike"
    )
    peak = float(speed[:, rotational].max()) if rotational.any() and len(speed) else 0.0
    return Reason("velocity_spikes", verdict, message, int(flags.sum()), len(flags), {"peak_angular_speed_rad_s": peak})


# --- the batch's trial verdict -------------------------------------------------------------------------------------


def static_quality(errors: np.ndarray, names: Sequence[str], landmarks: Sequence[str]) -> Verdict:
    """The static trial's verdict: the scaling rule on the landmarks (model markers the placement does not move),
    tiered as OpenSim's two checklists read: ok within the scaling bars, warn within the IK bars, fail beyond;
    all tracked markers against the IK bars when no marker is fixed."""
    chosen = [k for k, n in enumerate(names) if n in set(landmarks)]
    if chosen:
        reason, flags = marker_fit(errors[:, chosen], [names[k] for k in chosen], static=True)
        if reason.verdict != "ok":
            loose, _ = marker_fit(errors[:, chosen], [names[k] for k in chosen])
            if loose.verdict == "ok":
                reason = dataclasses.replace(
                    reason, verdict="warn", message=reason.message + " (within the IK bars, 2 cm RMS / 4 cm max)"
                )
    else:
        reason, flags = marker_fit(errors, names)
        reason = Reason(
            reason.rule,
            reason.verdict,
            reason.message + " (no fixed landmark markers: judged on all, with the IK bars)",
            reason.flagged,
            reason.frames,
            reason.figures,
        )
    return combine([reason], len(flags), flags)


def trial_quality(
    result: Analysis,
    *,
    markers: Markers | None = None,
    names: Sequence[str] = (),
    errors: np.ndarray | None = None,
    match: MarkerMatch | None = None,
    plates: GroundReaction | None = None,
    assignment: dict[str, dict] | None = None,
) -> Verdict:
    """The verdict of a trial the batch analysed (module docstring): marker rules (when it came from markers:
    ``markers`` the data IK solved, ``names`` the tracked markers, ``errors`` [T, M] their IK errors on the
    analysed frames), residuals, force data (``plates`` as read, ``assignment`` from
    `biomotion.analysis.chain.plate_assignment`), joint limits hit and velocity spikes."""
    frames = result.motion.n_frames
    flags = np.zeros(frames, dtype=bool)
    reasons: list[Reason] = []
    if errors is not None and markers is not None and match is not None:
        marker_list, marker_flags = marker_reasons(result.model, markers, result.motion, names, errors, match)
        reasons += marker_list
        if len(marker_flags) == frames:
            flags |= marker_flags
    residual = residual_reason(result)
    if residual is not None:
        reasons.append(residual)
    force = force_data_reason(result, plates, assignment or {})
    if force is not None:
        reasons.append(force)
    reasons.append(joint_limit_reason(result.motion, result.model))
    reasons.append(velocity_reason(result.motion, result.model, result.velocities))
    return combine(reasons, frames, flags if flags.any() else None)


# --- plausibility of any motion -----------------------------------------------------------------------------------


def _foot_sliding(result: Analysis, treadmill: bool) -> Reason:
    """Foot sliding: a foot contact point in contact — loaded by the contact model (over 10 N) and below
    `biomotion.metrics.contact.CONTACT_HEIGHT` — moving horizontally faster than the skate speed, also on average
    over the skate window (GMD / OmniControl); on a treadmill relative to the belt (the median velocity of the
    points in contact)."""
    from scipy.ndimage import uniform_filter1d

    from biomotion.metrics.contact import CONTACT_HEIGHT, SKATE_SPEED, SKATE_WINDOW

    points = result.contact_points
    contact = result.contact_loaded & (points[..., 1] < CONTACT_HEIGHT)  # [T, K]
    velocity = np.gradient(points[..., [0, 2]], result.motion.times, axis=0)  # [T, K, 2]
    if treadmill and contact.any():
        velocity = velocity - np.median(velocity[contact], axis=0)
    speed = np.linalg.norm(velocity, axis=-1)
    half = max(0, round(SKATE_WINDOW * result.motion.rate / 2))
    averaged = uniform_filter1d(speed, size=2 * half + 1, axis=0, mode="nearest")
    skating = (contact & (speed > SKATE_SPEED) & (averaged > SKATE_SPEED)).any(1)
    frames = int(contact.any(1).sum())
    flagged = int(skating.sum())
    verdict = share_verdict(flagged, frames)
    belt = " relative to the belt" if treadmill else ""
    message = (
        f"foot sliding on {_share(flagged, frames)} with a foot in contact (a loaded point below "
        f"{100 * CONTACT_HEIGHT:.0f} cm moving faster than {SKATE_SPEED} m/s{belt})"
    )
    return Reason("foot_sliding", verdict, message, flagged, frames, {})


def _ground_penetration(result: Analysis) -> Reason:
    lowest = result.contact_points[..., 1].min(1)
    flags = lowest < -MARKER_RMS_M
    verdict = share_verdict(int(flags.sum()), len(flags))
    message = (
        f"ground penetration on {_share(int(flags.sum()), len(flags))} (a foot point over {100 * MARKER_RMS_M:.0f} cm "
        f"below the ground; deepest {100 * max(0.0, -float(lowest.min())):.1f} cm)"
    )
    return Reason(
        "ground_penetration",
        verdict,
        message,
        int(flags.sum()),
        len(flags),
        {"deepest_m": float(max(0.0, -lowest.min()))},
    )


def _zmp_outside(result: Analysis) -> Reason:
    from biomotion.metrics.stability import support_margin

    points = torch.tensor(result.contact_points)
    points = torch.cat([points[..., :1], torch.zeros_like(points[..., 1:2]), points[..., 2:]], dim=-1)
    signed = support_margin(
        torch.tensor(result.zmp), points, contact=torch.tensor(result.contact_loaded), margin=0.01
    ).numpy()
    supported = np.isfinite(signed) & np.isfinite(result.zmp).all(-1)
    flags = supported & (signed < 0)
    frames = int(supported.sum())
    verdict = share_verdict(int(flags.sum()), frames)
    message = f"ZMP outside the support (1 cm margin) on {_share(int(flags.sum()), frames)} with a ZMP and contact"
    return Reason("zmp_outside_support", verdict, message, int(flags.sum()), frames, {})


def _saturation(activations: Any) -> Reason:
    a = activations.activations.numpy()
    saturated = (a >= SATURATION).any(1) | ~activations.converged.numpy()
    verdict = share_verdict(int(saturated.sum()), len(saturated))
    names = [n for n, hit in zip(activations.muscle_names, (a >= SATURATION).any(0)) if hit]
    message = (
        f"activation saturation on {_share(int(saturated.sum()), len(saturated))}"
        + (f": {', '.join(names[:6])}" if names else "")
        + f" (a muscle at {100 * SATURATION:.0f} % of its control or a frame not balanced)"
    )
    return Reason("activation_saturation", verdict, message, int(saturated.sum()), len(saturated), {})


def check(
    motion: Motion,
    model: BodyModel,
    forces: GroundReaction | None = None,
    *,
    muscles: Any = None,
    muscle_model: Any = None,
    cutoff_hz: float = 6.0,
    treadmill: bool = False,
) -> Verdict:
    """A plausibility verdict for any motion on its model (module docstring), with the reasons.

    Args:
        motion: coordinates of ``model`` (captured, refined or generated).
        forces: measured ground reaction (plates are assigned to the feet); default: inferred from the motion.
        muscles: muscle path functions (`biomotion.analysis.activations.load_paths` takes a file or shipped name)
            for the activation-saturation rule; ``muscle_model`` the ``.osim`` of their parameters.
        treadmill: judge foot sliding relative to the belt.

    Contract: reads no file; raises `biomotion.errors.ModelError` when the motion lacks model coordinates.
    """
    from biomotion.analysis.chain import analyze

    result = analyze(motion, model, forces, cutoff_hz=cutoff_hz)
    reasons = []
    residual = residual_reason(result)
    if residual is not None:
        reasons.append(residual)
    reasons += [
        _foot_sliding(result, treadmill),
        _ground_penetration(result),
        velocity_reason(result.motion, model, result.velocities),
        joint_limit_reason(result.motion, model, at_bound=False),
        _zmp_outside(result),
    ]
    if muscles is not None:
        from biomotion.analysis.activations import load_paths, trial_activations

        paths = load_paths(muscles)[0] if not hasattr(muscles, "muscle_names") else muscles
        reasons.append(_saturation(trial_activations(result, muscle_model or model.spec.path, paths)))
    return combine(reasons, result.motion.n_frames)
