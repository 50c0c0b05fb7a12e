"""``biomotion eval shape``: motion moved onto another body, scored against that body's own motion: the real-pairs
protocol of issue 48 for HUMOS-style shape-conditioned motion (``humos.md``: a motion retargeted to a target
identity should move the way that body moves, "Executive Summary").

Protocol. The same task done by two real people: Fukuchi runners at the same treadmill speed (2.5, 3.5, 4.5 m/s).
Runners with a scaled model (``<r>/<r>_simple.osim``) and IK at a speed (``ik/<speed>/<r>_<speed>_ik_simple.mot``)
are sorted by name; runner i (A) is paired with runners i+1 … i+``partners`` (B), cyclically, at every speed both
have: deterministic, every runner is an A and a B equally often. A's IK motion is adapted onto B's `Shape`
(``adapt(motion, shape_A, shape_B) -> motion``, or a `BodyAdapter` called with both bodies; the default, None, is
the **copy baseline**: A's coordinates as they are, the trivial solution HUMOS's physics terms exist to rule out,
``humos.md`` "Why This Works", Mechanism 3) and compared with B's real IK motion on B's scaled model:

- **DTW** (`dtw_distance`): the ten hip, knee and ankle angles (deg) of both clips resampled to `DTW_RATE`, aligned
  by dynamic time warping (Sakoe & Chiba 1978) with the RMS over the angles as the frame distance; the figure is
  the mean frame distance along the optimal path (deg), 0 for a clip against itself.
- **Stride time, cadence, stride length** (`gait_timing`): right foot strikes from the height of the right foot's
  lowest contact point (`biomotion.body.contact.foot_points`) by forward kinematics on B's model: a strike is where
  that height falls below 20 % of its 5th-95th percentile span above the 5th percentile, strikes closer than
  `MIN_STRIDE_S` merged; stride time = median interval, cadence = 120 / stride time (steps/min). On a treadmill
  the body stays in place, so stride length = belt speed × stride time (the distance the belt carries a planted
  foot per stride). Relative errors are ``|adapted − real| / real``.

- **HUMOS physics and dynamic stability** (`biomotion.evaluation.shape_physics.clip_physics`, ``humos.md``
  "Why This Works", Mechanisms 2 and 3): penetrate, float and skate, and the share of frames whose ZMP lies inside
  the base of support (the convex hull of slow, low contact points; frames in flight are not counted stable), each
  computed on B's model for the copy, for the adapted motion and for B's real motion (the treadmill clip made
  overground at the belt speed and put on the floor first, as every evaluated clip). Per method, the mean of each
  over the pairs against the mean of B's real clips over the same pairs: ``*_physics_worst_ratio_to_real`` is the
  largest of the three ratios method / real (1 is as plausible as the real motion; lower is better), and
  ``*_dyn_stability_gap_points`` is the real share minus the method's share, in percentage points.

Trials with a known defect (`KNOWN_BAD`, from ``fukuchi-running/SOURCE.md``) are left out and named. Figures are
means over pairs (medians beside them) and per speed. ``shape_dtw_gain_vs_copy`` (1 − adapted DTW / copy DTW),
``shape_stride_rel_err``, ``shape_physics_worst_ratio_to_real`` and ``shape_dyn_stability_gap_points`` of an
adapter are reported when ``adapt`` is given; with the copy baseline alone they are None (the copy's own figures,
``shape_copy_*``, are always reported).

The adapted motion is the one ``biomotion adapt`` writes: `load_adapter` returns a `BodyAdapter`, which calls
`biomotion.generation.adapt.adapt` on A's and B's scaled models (knee sign, B's coordinate order, A's floor, and the
feet planted on the ground A ran on, the treadmill belt here, estimated from A's motion: that module's docstring).

Held-out pairs. A learned adapter is scored only on runners it never saw: ``trained`` names the runners of its
training set (`load_adapter` reads them from the weights), who are left out before pairing, so every pair (and its
copy baseline, on the same pairs) has two unseen runners. ``shape_adapted_self_dtw`` is the DTW of each scored
clip adapted to its own runner's Shape against itself: how far the adapter moves a motion that should stay put.

Works on any folder laid out like ``../shared/data``: absent sources and runners without files are named in
``skipped``.
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.body.contact import foot_points
from biomotion.body.kinematics import apply_couplers, forward_kinematics, points_in_ground
from biomotion.body.model import BodyModel
from biomotion.body.shape import Shape
from biomotion.errors import BiomotionError, ConfigError
from biomotion.evaluation.shape_physics import PHYSICS, STABILITY, clip_physics
from biomotion.generation.adapt import Body
from biomotion.generation.adapt import adapt as adapt_motion
from biomotion.io.atomic import atomic_write
from biomotion.io.mot import read_motion
from biomotion.io.tables import read_subject_table
from biomotion.motion import Motion

FUKUCHI = "fukuchi-running"
GENERIC = "generic-models/Denton2023_LowerLimb_Fukuchi2017.osim"
SUBJECTS = "participantInfo.csv"
SPEEDS = {"T25": 2.5, "T35": 3.5, "T45": 4.5}  # m/s, treadmill belt
#: sources the issue names for real pairs that this protocol does not read yet
NOT_YET = {"SchreiberMoissenet2019": "walkers at the same instruction: not in this protocol yet"}
ANGLES = tuple(
    f"{joint}_{side}"
    for side in ("r", "l")
    for joint in ("hip_flexion", "hip_adduction", "hip_rotation", "knee_angle", "ankle_angle")
)
DTW_RATE = 50.0  # Hz: running content lies below 10 Hz
PARTNERS = 3  # B runners per A and speed (default)
MIN_STRIDE_S = 0.4  # s: strikes closer than this are one strike (running strides last 0.6-0.8 s)
CONTACT_FRACTION = 0.2  # of the 5th-95th percentile span of the foot height: below it the foot is down
KNOWN_BAD = {("RBDS001", "T35"): "R.MT1/R.MT5 swapped in the C3D: right-foot IK unreliable (SOURCE.md)"}
BARS = {
    "shape_dtw_gain_vs_copy": ">= 0.15",
    "shape_stride_rel_err": "<= 0.05",
    "shape_physics_worst_ratio_to_real": "<= 1.0",
    "shape_dyn_stability_gap_points": "<= 5",
}
_PASSES = {
    "shape_dtw_gain_vs_copy": lambda v: v >= 0.15,
    "shape_stride_rel_err": lambda v: v <= 0.05,
    "shape_physics_worst_ratio_to_real": lambda v: v <= 1.0,
    "shape_dyn_stability_gap_points": lambda v: v <= 5.0,
}
NEEDS_ADAPTER = "needs the shape-conditioned adapter: pass one (`--adapter`, `load_adapter`)"

Adapter = Callable[[Motion, Shape, Shape], Motion]
"""A shape-only hook: (A's motion, A's Shape, B's Shape) -> the motion on B."""


@dataclass(frozen=True)
class Runner:
    """A runner's scaled model, `Shape` and IK motions by speed code."""

    name: str
    model: BodyModel
    shape: Shape
    motions: dict[str, Motion]
    model_file: Path | None = None

    @property
    def body(self) -> Body:
        """The runner as a `biomotion.generation.adapt.Body`: scaled model, Shape and model file."""
        source = self.model_file or Path(f"{self.name}_simple.osim")
        return Body(self.shape, self.model, source, osim=self.model_file)


@dataclass(frozen=True)
class BodyAdapter:
    """The shape adapter at ``weights`` as ``biomotion adapt`` runs it (`biomotion.generation.adapt.adapt`, foot
    planting on unless ``planting`` is False), called with A's motion and both runners' bodies: planting needs the
    models, not only the Shapes."""

    weights: Path
    planting: bool = True

    def __call__(self, motion: Motion, source: Body, target: Body) -> Motion:
        return adapt_motion(motion, source, target, adapter=self.weights, planting=self.planting).motion


def _adapt(adapt: Adapter | BodyAdapter, motion: Motion, source: Runner, target: Runner) -> Motion:
    """``adapt`` applied to ``motion`` from ``source`` onto ``target``: bodies for a `BodyAdapter`, Shapes for a
    shape-only hook."""
    if isinstance(adapt, BodyAdapter):
        return adapt(motion, source.body, target.body)
    return adapt(motion, source.shape, target.shape)


# ---- metrics ---------------------------------------------------------------------------------------------------


def dtw_distance(x: np.ndarray, y: np.ndarray) -> float:
    """Mean frame distance along the optimal DTW path between ``x`` [N, D] and ``y`` [M, D] (frame distance: RMS
    over D): `dtw_cost`'s total over its path length."""
    total, steps = dtw_cost(x, y)
    return total / steps


def dtw_cost(x: np.ndarray, y: np.ndarray) -> tuple[float, int]:
    """(total cost, path length) of the optimal DTW alignment of ``x`` [N, D] and ``y`` [M, D] (steps (1, 1), (1, 0),
    (0, 1); frame distance: RMS over D). Rows of the cumulative cost are computed at once:
    D[i, j] = S[j] + min_{k<=j}(a[k] − S[k]) with S the running sum of row i's costs and
    a[k] = c[i, k] + min(D[i−1, k−1], D[i−1, k])."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if x.ndim != 2 or y.ndim != 2 or x.shape[1] != y.shape[1] or not len(x) or not len(y):
        raise ConfigError(f"dtw_distance needs two [frames, features] arrays of equal width, got {x.shape}, {y.shape}")
    cost = np.sqrt(((x[:, None, :] - y[None, :, :]) ** 2).mean(-1))
    n, m = cost.shape
    total = np.empty((n, m))
    total[0] = np.cumsum(cost[0])
    for i in range(1, n):
        previous = total[i - 1]
        a = cost[i] + np.minimum(np.concatenate(([np.inf], previous[:-1])), previous)
        running = np.cumsum(cost[i])
        total[i] = running + np.minimum.accumulate(a - running)
    i, j, steps = n - 1, m - 1, 1
    while i > 0 or j > 0:  # backtrack for the path length
        if i == 0:
            j -= 1
        elif j == 0:
            i -= 1
        else:
            options = (total[i - 1, j - 1], total[i - 1, j], total[i, j - 1])
            move = int(np.argmin(options))
            i, j = (i - 1, j - 1) if move == 0 else (i - 1, j) if move == 1 else (i, j - 1)
        steps += 1
    return float(total[-1, -1]), steps


def joint_angles(motion: Motion, rate: float = DTW_RATE) -> np.ndarray:
    """[T, 10] hip, knee and ankle angles (deg) of ``motion`` resampled at ``rate`` from its first frame."""
    times = np.arange(motion.times[0], motion.times[-1] + 1e-9, 1.0 / rate)
    values = motion.select(list(ANGLES)).values
    return np.degrees(np.stack([np.interp(times, motion.times, values[:, k]) for k in range(values.shape[1])], -1))


def _coordinates(model: BodyModel, motion: Motion) -> torch.Tensor:
    q = np.tile(model.defaults.numpy(), (motion.n_frames, 1))
    for k, name in enumerate(model.coordinate_names):
        if name in motion.names:
            q[:, k] = motion[name]
    return apply_couplers(model, torch.from_numpy(q).to(model.dtype))


def right_foot_height(model: BodyModel, motion: Motion) -> np.ndarray:
    """[T] height (m) of the right foot's lowest contact point, by forward kinematics of ``motion`` on ``model``."""
    feet = foot_points(model)
    right = torch.tensor([k for k, side in enumerate(feet.feet) if side == "r"])
    with torch.no_grad():
        poses = forward_kinematics(model, _coordinates(model, motion))
        points = points_in_ground(poses, feet.bodies[right], feet.offsets[right])
    return (points @ (-model.gravity / torch.linalg.vector_norm(model.gravity))).amin(-1).numpy()


def gait_timing(model: BodyModel, motion: Motion, speed: float) -> dict:
    """Right foot strikes, stride time (s), cadence (steps/min) and stride length (m, belt ``speed`` × stride time)
    of ``motion`` on ``model`` (module docstring); None figures when fewer than two strikes are found."""
    height = right_foot_height(model, motion)
    low, high = np.percentile(height, [5.0, 95.0])
    down = height < low + CONTACT_FRACTION * (high - low)
    onsets = np.flatnonzero(down[1:] & ~down[:-1]) + 1
    strikes: list[float] = []
    for t in motion.times[onsets]:
        if not strikes or t - strikes[-1] >= MIN_STRIDE_S:
            strikes.append(float(t))
    if len(strikes) < 2:
        return {"strikes": len(strikes), "stride_time_s": None, "cadence_spm": None, "stride_length_m": None}
    stride = float(np.median(np.diff(strikes)))
    return {
        "strikes": len(strikes),
        "stride_time_s": stride,
        "cadence_spm": 120.0 / stride,
        "stride_length_m": speed * stride,
    }


def _relative(value: float | None, reference: float | None) -> float | None:
    return None if value is None or not reference else abs(value - reference) / reference


def compare(adapted: Motion, real: Motion, model: BodyModel, speed: float, real_timing: dict | None = None) -> dict:
    """DTW (deg) of the joint angles, and stride length and cadence relative errors of ``adapted`` against ``real``,
    both on ``model`` (B's)."""
    ours = gait_timing(model, adapted, speed)
    theirs = real_timing or gait_timing(model, real, speed)
    return {
        "dtw_deg": dtw_distance(joint_angles(adapted), joint_angles(real)),
        "stride_length_m": ours["stride_length_m"],
        "stride_length_real_m": theirs["stride_length_m"],
        "cadence_spm": ours["cadence_spm"],
        "cadence_real_spm": theirs["cadence_spm"],
        "stride_rel_err": _relative(ours["stride_length_m"], theirs["stride_length_m"]),
        "cadence_rel_err": _relative(ours["cadence_spm"], theirs["cadence_spm"]),
    }


# ---- data ------------------------------------------------------------------------------------------------------


def runner_pairs(names: Sequence[str], partners: int = PARTNERS) -> list[tuple[str, str]]:
    """(A, B) pairs: names sorted, A = i paired with i+1 … i+partners cyclically (module docstring)."""
    ordered = sorted(names)
    n = len(ordered)
    return [(ordered[i], ordered[(i + k) % n]) for i in range(n) for k in range(1, min(partners, n - 1) + 1)]


def load_runners(data_root: Path, speeds: Sequence[str] = tuple(SPEEDS)) -> tuple[list[Runner], list[str]]:
    """Every Fukuchi runner under ``data_root`` with a scaled model and IK at one of ``speeds`` at least; and what
    was skipped (absent sources, runners, trials), one line each."""
    base = Path(data_root) / FUKUCHI
    skipped = [
        f"{name}: {why}" if (Path(data_root) / name).is_dir() else f"{name}: absent from the data root"
        for name, why in NOT_YET.items()
    ]
    if not base.is_dir():
        return [], [f"{FUKUCHI}: absent from the data root", *skipped]
    generic = BodyModel.from_osim(base / GENERIC) if (base / GENERIC).is_file() else None
    if generic is None:
        skipped.append(f"{FUKUCHI}/{GENERIC}: absent, shapes are relative to each runner's own model")
    table = read_subject_table(base / SUBJECTS) if (base / SUBJECTS).is_file() else {}
    runners = []
    for folder in sorted(p for p in base.iterdir() if p.is_dir() and p.name.startswith("RBDS")):
        name = folder.name
        model_file = folder / f"{name}_simple.osim"
        if not model_file.is_file():
            skipped.append(f"{name}: no {model_file.name}")
            continue
        motions = {}
        for speed in speeds:
            mot = base / "ik" / speed / f"{name}_{speed}_ik_simple.mot"
            if (name, speed) in KNOWN_BAD:
                skipped.append(f"{name} {speed}: {KNOWN_BAD[(name, speed)]}")
            elif mot.is_file():
                motions[speed] = read_motion(mot)
            else:
                skipped.append(f"{name} {speed}: no {mot.name}")
        if not motions:
            continue
        model = BodyModel.from_osim(model_file)
        profile = table.get(name)
        shape = Shape.from_model(model, generic, height=None if profile is None else profile.height)
        runners.append(Runner(name, model, shape, motions, model_file))
    return runners, skipped


# ---- the evaluation --------------------------------------------------------------------------------------------


def _mean(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def _median(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(statistics.median(kept)) if kept else None


def _summary(rows: list[dict], prefix: str) -> dict:
    return {
        f"{prefix}_dtw": _mean([r["dtw_deg"] for r in rows]),
        f"{prefix}_dtw_median": _median([r["dtw_deg"] for r in rows]),
        f"{prefix}_stride_rel_err": _mean([r["stride_rel_err"] for r in rows]),
        f"{prefix}_stride_rel_err_median": _median([r["stride_rel_err"] for r in rows]),
        f"{prefix}_cadence_rel_err": _mean([r["cadence_rel_err"] for r in rows]),
        f"{prefix}_cadence_rel_err_median": _median([r["cadence_rel_err"] for r in rows]),
    }


def eval_shape(
    data_root: Path,
    json_path: Path | None = None,
    md_path: Path | None = None,
    *,
    adapt: Adapter | BodyAdapter | None = None,
    partners: int = PARTNERS,
    speeds: Sequence[str] = tuple(SPEEDS),
    progress: bool = True,
    command: str | None = None,
    trained: Collection[str] = (),
    adapter_info: dict | None = None,
) -> dict:
    """The real-pairs evaluation (module docstring); writes ``json_path`` / ``md_path`` when given; returns the
    report. ``adapt`` (A's motion, A's Shape, B's Shape) -> motion on B is scored beside the copy baseline; runners
    named in ``trained`` (the adapter's training runners) are left out before pairing; ``adapter_info`` (weights,
    SHA-256) is copied into the report."""
    started = time.time()
    unknown = [s for s in speeds if s not in SPEEDS]
    if unknown:
        raise ConfigError(f"eval shape: unknown speeds {unknown}; known: {list(SPEEDS)}")
    if partners < 1:
        raise ConfigError(f"eval shape: partners = {partners} must be at least 1")
    runners, skipped = load_runners(Path(data_root), speeds)
    seen = sorted(r.name for r in runners if r.name in set(trained))
    runners = [r for r in runners if r.name not in set(trained)]
    by_name = {r.name: r for r in runners}
    jobs = []
    for speed in speeds:
        names = [r.name for r in runners if speed in r.motions]
        jobs += [(speed, a, b) for a, b in runner_pairs(names, partners)]
    if not jobs:  # a report of nothing would read as a result
        why = "; ".join(skipped[:3]) or "fewer than two runners at any speed"
        raise ConfigError(f"{data_root}: no pair of runners to compare ({why})")
    real: dict[tuple[str, str], dict] = {}
    real_physics: dict[tuple[str, str], dict | None] = {}
    rows = []
    for speed, a, b in tqdm(jobs, desc="shape pairs", unit="pair", disable=not progress):
        runner_a, runner_b = by_name[a], by_name[b]
        if (b, speed) not in real:
            real[(b, speed)] = gait_timing(runner_b.model, runner_b.motions[speed], SPEEDS[speed])
            real_physics[(b, speed)] = _physics(runner_b, runner_b.motions[speed], speed, f"{b} {speed}", skipped)
        source, target = runner_a.motions[speed], runner_b.motions[speed]
        row = {"speed": speed, "a": a, "b": b}
        row |= compare(source, target, runner_b.model, SPEEDS[speed], real[(b, speed)])
        row["physics"] = _physics(runner_b, source, speed, f"{a} -> {b} {speed} (copy)", skipped)
        row["physics_real"] = real_physics[(b, speed)]
        if adapt is not None:
            try:
                adapted = _adapt(adapt, source, runner_a, runner_b)
            except BiomotionError as error:
                skipped.append(f"{a} -> {b} {speed}: the adapter failed: {error}")
                adapted = None
            if adapted is not None:
                scores = compare(adapted, target, runner_b.model, SPEEDS[speed], real[(b, speed)])
                scores["physics"] = _physics(runner_b, adapted, speed, f"{a} -> {b} {speed} (adapted)", skipped)
                row["adapted"] = scores
        rows.append(row)
    report = _report(rows, runners, real, skipped, adapt is not None, partners, speeds)
    if adapt is not None:
        report["shape_adapted_self_dtw"] = _self_dtw(adapt, runners, skipped)
    report["held_out"] = {
        "rule": "runners in the adapter's training set are left out before pairing: every pair is of two unseen "
        "runners, the copy baseline on the same pairs"
        if trained
        else "no adapter training set given: every runner is paired",
        "left_out_training_runners": seen,
        "runners": sorted(r.name for r in runners),
    }
    report["adapter"] = adapter_info
    report["command"] = command
    report["seconds"] = round(time.time() - started, 1)
    if json_path is not None:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(json_path) as handle:
            json.dump(report, handle, indent=1)
    if md_path is not None:
        Path(md_path).parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(md_path) as handle:
            handle.write(markdown(report))
    return report


def _physics(runner: Runner, motion: Motion, speed: str, what: str, skipped: list[str]) -> dict | None:
    """`clip_physics` of ``motion`` on ``runner``'s model at the belt speed of ``speed``; None (named in
    ``skipped``) when the clip cannot be scored."""
    try:
        return clip_physics(runner.model, motion, SPEEDS[speed])
    except BiomotionError as error:
        skipped.append(f"{what}: no physics: {error}")
        return None


def _ratio(value: float | None, real: float | None) -> float | None:
    """``value / real``; 1 when both are 0 (as plausible as the real motion), None when undefined."""
    if value is None or real is None:
        return None
    if real == 0.0:
        return 1.0 if value == 0.0 else None
    return value / real


def physics_summary(pairs: Sequence[tuple[dict | None, dict | None]]) -> dict:
    """HUMOS physics and dynamic stability of a method against the real motion over (method, real) `clip_physics`
    records of the same pairs (pairs where either is missing are left out): the means of both, each ratio
    method / real, the worst of the physics ratios (``worst_ratio_to_real``) and the stability gap, real share
    minus method share in percentage points (``dyn_stability_gap_points``); None figures without pairs."""
    kept = [(ours, theirs) for ours, theirs in pairs if ours is not None and theirs is not None]
    keys = (*PHYSICS, STABILITY)
    method = {k: _mean([ours[k] for ours, _ in kept]) for k in keys}
    real = {k: _mean([theirs[k] for _, theirs in kept]) for k in keys}
    ratios = {k: _ratio(method[k], real[k]) for k in PHYSICS}
    worst = None if not kept or any(r is None for r in ratios.values()) else max(ratios.values())
    gap = None
    if method[STABILITY] is not None and real[STABILITY] is not None:
        gap = 100.0 * (real[STABILITY] - method[STABILITY])
    return {
        "pairs": len(kept),
        "method": method,
        "real": real,
        "ratio_to_real": ratios,
        "worst_ratio_to_real": worst,
        "dyn_stability_gap_points": gap,
    }


def _self_dtw(adapt: Adapter | BodyAdapter, runners: list[Runner], skipped: list[str]) -> float | None:
    """Mean DTW (deg) of A's motion adapted to A's own Shape against A's motion, over the scored runners' clips:
    how far the adapter moves a motion that should stay put (0 for the copy)."""
    distances = []
    for runner in runners:
        for speed, motion in runner.motions.items():
            try:
                same = _adapt(adapt, motion, runner, runner)
            except BiomotionError as error:
                skipped.append(f"{runner.name} -> itself {speed}: the adapter failed: {error}")
                continue
            distances.append(dtw_distance(joint_angles(same), joint_angles(motion)))
    return _mean(distances)


def _report(
    rows: list[dict],
    runners: list[Runner],
    real: dict,
    skipped: list[str],
    adapted: bool,
    partners: int,
    speeds: Sequence[str],
) -> dict:
    subjects = sorted({r["a"] for r in rows} | {r["b"] for r in rows})
    report: dict = {
        "protocol": (
            f"Fukuchi runners at the same treadmill speed, each paired with the next {partners} by name "
            "(cyclic); A's IK coordinates on B's scaled model against B's IK: DTW of the ten hip/knee/ankle "
            f"angles at {DTW_RATE:g} Hz (mean frame RMS along the path, deg), stride length (belt speed x stride "
            "time) and cadence from right-foot strikes by forward kinematics on B's model"
        ),
        "pairs": len(rows),
        "subjects": len(subjects),
        "speeds": list(speeds),
        **_summary(rows, "shape_copy"),
    }
    copy_physics = physics_summary([(r["physics"], r["physics_real"]) for r in rows])
    report["shape_copy_physics_worst_ratio_to_real"] = copy_physics["worst_ratio_to_real"]
    report["shape_copy_dyn_stability_gap_points"] = copy_physics["dyn_stability_gap_points"]
    report["physics"] = {
        "definition": (
            "HUMOS penetrate (m) and float (m) on the absolute ground, skate (share of frame pairs) and dynamic "
            "stability (share of frames with the ZMP inside the convex hull of contact points below 0.05 m and "
            "slower than 0.5 m/s; flight frames count as not stable), each clip on B's model made overground at "
            "the belt speed and put on the floor, at 30 Hz; means over pairs, real = B's own clip of each pair"
        ),
        "copy": copy_physics,
    }
    adapted_rows = [r["adapted"] for r in rows if "adapted" in r]
    if adapted and adapted_rows:
        ours = _summary(adapted_rows, "shape_adapted")
        report |= ours
        copy_dtw = _mean([r["dtw_deg"] for r in rows if "adapted" in r])
        report["shape_dtw_gain_vs_copy"] = (
            1.0 - ours["shape_adapted_dtw"] / copy_dtw if copy_dtw and ours["shape_adapted_dtw"] is not None else None
        )
        report["shape_stride_rel_err"] = ours["shape_adapted_stride_rel_err"]
        physics = physics_summary([(r["adapted"]["physics"], r["physics_real"]) for r in rows if "adapted" in r])
        report["physics"]["adapted"] = physics
        report["shape_physics_worst_ratio_to_real"] = physics["worst_ratio_to_real"]
        report["shape_dyn_stability_gap_points"] = physics["dyn_stability_gap_points"]
        report["not_measured"] = {
            key: "undefined: a real clip scores 0 where the adapted one does not, or no pair could be scored"
            for key in ("shape_physics_worst_ratio_to_real", "shape_dyn_stability_gap_points")
            if report[key] is None
        }
    else:
        for key in BARS:
            report[key] = None
        report["not_measured"] = dict.fromkeys(BARS, NEEDS_ADAPTER)
    report["bars"] = {key: None if report[key] is None else _PASSES[key](report[key]) for key in BARS}
    report["bar_thresholds"] = BARS
    report["per_speed"] = {
        speed: {
            "pairs": len(chosen),
            **_summary(chosen, "shape_copy"),
            **(_summary([r["adapted"] for r in chosen if "adapted" in r], "shape_adapted") if adapted else {}),
        }
        for speed in speeds
        if (chosen := [r for r in rows if r["speed"] == speed])
    }
    report["real_gait"] = {f"{name} {speed}": timing for (name, speed), timing in sorted(real.items())}
    report["shapes"] = {
        r.name: {"mass_kg": r.shape.mass, "height_m": r.shape.height, "reference": r.shape.reference}
        for r in runners
        if r.name in subjects
    }
    report["pair_rows"] = rows
    report["skipped"] = skipped
    return report


def _fmt(value: float | None, digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _physics_lines(physics: dict) -> list[str]:
    """The HUMOS physics table of the report: B's real clips, the copy and the adapted motion on B's model."""
    copy = physics["copy"]
    rows = [("B's real motion", copy["real"], None), ("copy A's angles onto B", copy["method"], copy)]
    if physics.get("adapted") is not None:
        rows.append(("adapted to B's shape", physics["adapted"]["method"], physics["adapted"]))
    lines = [
        "",
        f"HUMOS physics and dynamic stability on B's model ({physics['definition']}):",
        "",
        "| clip | penetrate (mm) | float (mm) | skate (%) | dynamic stability (%) | worst physics ratio to real "
        "| stability gap (points) |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, values, summary in rows:
        scaled = [None if values[k] is None else f * values[k] for k, f in (*zip(PHYSICS, (1e3, 1e3, 100.0)),)]
        stability = None if values[STABILITY] is None else 100.0 * values[STABILITY]
        worst = "–" if summary is None else _fmt(summary["worst_ratio_to_real"], 2)
        gap = "–" if summary is None else _fmt(summary["dyn_stability_gap_points"], 2)
        lines.append(
            f"| {label} | {_fmt(scaled[0], 3)} | {_fmt(scaled[1], 2)} | {_fmt(scaled[2], 1)} | "
            f"{_fmt(stability, 1)} | {worst} | {gap} |"
        )
    lines += [
        "",
        "The Fukuchi `_simple` models have no trunk, whose accelerations the whole-body ZMP needs, so few real "
        "frames are stable (docs/metrics.md, Stability) and the stability gap cannot exceed B's real share.",
    ]
    return lines


def markdown(report: dict) -> str:
    """The report's tables, for docs/results/."""
    lines = [
        "# biomotion eval shape: motion moved onto another runner's body (real pairs)",
        "",
        f"Protocol: {report['protocol']}.",
        "",
        f"{report['pairs']} pairs of {report['subjects']} runners; speeds {', '.join(report['speeds'])}.",
        "",
        "| method | DTW (deg, mean / median) | stride length rel. err. (mean / median) | cadence rel. err. "
        "(mean / median) |",
        "|---|---|---|---|",
    ]
    methods = [("copy A's angles onto B (baseline)", "shape_copy")]
    if report.get("shape_adapted_dtw") is not None:
        methods.append(("adapted to B's shape", "shape_adapted"))
    for label, prefix in methods:
        lines.append(
            f"| {label} | {_fmt(report[f'{prefix}_dtw'], 2)} / {_fmt(report[f'{prefix}_dtw_median'], 2)} | "
            f"{_fmt(report[f'{prefix}_stride_rel_err'])} / {_fmt(report[f'{prefix}_stride_rel_err_median'])} | "
            f"{_fmt(report[f'{prefix}_cadence_rel_err'])} / {_fmt(report[f'{prefix}_cadence_rel_err_median'])} |"
        )
    held = report.get("held_out") or {}
    if held.get("left_out_training_runners"):
        lines += [
            "",
            f"Held-out pairs only: {held['rule']}. Runners scored: {', '.join(held['runners'])}; left out (seen in "
            f"training): {', '.join(held['left_out_training_runners'])}.",
        ]
    if report.get("adapter"):
        lines += ["", "Adapter: " + ", ".join(f"{k} `{v}`" for k, v in report["adapter"].items()) + "."]
    lines += [
        "",
        "Per speed (copy baseline; adapted where scored):",
        "",
        "| speed | pairs | DTW (deg) | stride rel. err. | cadence rel. err. |",
    ]
    lines.append("|---|---|---|---|---|")
    for speed, row in report["per_speed"].items():
        for label, prefix in (("copy", "shape_copy"), ("adapted", "shape_adapted")):
            if row.get(f"{prefix}_dtw") is None:
                continue
            lines.append(
                f"| {speed} {label} | {row['pairs']} | {_fmt(row[f'{prefix}_dtw'], 2)} | "
                f"{_fmt(row[f'{prefix}_stride_rel_err'])} | {_fmt(row[f'{prefix}_cadence_rel_err'])} |"
            )
    lines += _physics_lines(report["physics"])
    lines += ["", "Bars of issue 48 (held-out pairs):", ""]
    for key, bar in report["bar_thresholds"].items():
        value = report.get(key)
        met = report["bars"].get(key)
        verdict = "–" if met is None else "met" if met else "NOT met"
        why = report["not_measured"].get(key)
        lines.append(f"- `{key}` {bar}: {_fmt(value)} ({verdict})" + (f": {why}" if why else ""))
    if report.get("shape_adapted_self_dtw") is not None:
        lines += [
            "",
            f"A → A (each scored runner's clips adapted to their own Shape, against themselves): DTW "
            f"{report['shape_adapted_self_dtw']:.2f} deg (0 for the copy).",
        ]
    if report["skipped"]:
        lines += ["", "Skipped:", ""] + [f"- {line}" for line in report["skipped"]]
    if report.get("command"):
        lines += ["", f"Command: `{report['command']}`"]
    return "\n".join(lines) + "\n"


def load_adapter(path: Path, *, planting: bool = True) -> tuple[BodyAdapter, list[str], dict]:
    """The shape adapter saved at ``path`` (`biomotion.models.shape_vae.ShapeAdapter`) as a `BodyAdapter`: the
    motion ``biomotion adapt`` writes (knee sign read from the motion, feet planted unless ``planting`` is False),
    the Fukuchi runners it was trained on (left out of the pairs), and its file name, SHA-256 and planting for the
    report."""
    import hashlib

    from biomotion.models.shape_vae import ShapeAdapter

    adapter = ShapeAdapter.load(path)
    trained = sorted(key.split("/", 1)[1] for key in adapter.subjects if key.startswith("fukuchi/"))
    info = {
        "weights": Path(path).name,
        "sha256": hashlib.sha256(Path(path).read_bytes()).hexdigest(),
        "feet_planted": planting,
    }
    return BodyAdapter(Path(path), planting), trained, info
