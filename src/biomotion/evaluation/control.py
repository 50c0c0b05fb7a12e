"""`biomotion eval control`: control targets sampled from held-out real clips, generated, and measured again.

Issue 47's protocol for FlexMotion Sec. 3.3's spatial control, run on PG-BIG's guidance path
(`biomotion.guidance.control`, `PGBIGRunner`) and on FlexMotion's control module (`biomotion.models.control_net`
through `biomotion.generation.flexmotion_control`, `FlexMotionRunner`), side by side on the same targets
(``generator`` "both"). Targets come from clips of the subjects the shipped generators never trained on
(`biomotion.evaluation.generation.unseen_targets` on ``--data-root``: with the shared data the val and test
subjects; a folder of new people in the same layout makes every subject unseen). Each target clip (cut to
``max_seconds``) gives the request (PG-BIG: its action labels, its subject's profile and other clips as
references, as `biomotion eval generation` asks; FlexMotion: its label text and its subject's profile) and one
target, in turn:

- ``path`` (OmniControl's joint control, Xie et al. 2024, Sec. 4.1): the real clip's origin of one body over the
  first ``path_seconds`` (every ``path_stride``-th frame) as a ``joint_position`` path; bodies taken in turn from
  `PATH_BODIES` among those the clip measures (the hand only where the clip has arm coordinates). Measured: the
  distance between the generated body origin (forward kinematics of the canonical model) and each path point at its
  frame. ``control_joint_mean_err_m`` is the mean over every point of every path target (OmniControl's average
  error), ``control_joint_max_err_m`` the largest; OmniControl's trajectory error (share of targets with a point
  farther than 0.5 m) and location error (share of points farther than 0.2 m) are given beside them.
- ``grf`` (a vertical GRF peak cap): the uncontrolled clip (the same request and seed without control, of the
  generator evaluated) is analysed, and the cap is ``cap_fraction`` (0.9) x its peak total vertical ground reaction
  in body weights.
- ``torque`` (a knee-moment cap): the same with the right knee's extension moment (``knee_angle_r``, N·m/kg, a
  ``joint_torque`` lower bound at ``cap_fraction`` x the uncontrolled clip's most negative moment).
- ``activation`` (a muscle-activation cap, FlexMotion Sec. 3.3's activation control): the same with one lower-limb
  muscle's activation (a ``muscle_activation`` ``max`` bound over the whole clip at ``cap_fraction`` x the
  uncontrolled clip's peak), the muscles taken in turn from `ACTIVATION_MUSCLES`: the right gluteus medius'
  anterior bundle, vastus lateralis and soleus, Rajagopal 2016 names shared by the muscle surrogate and the shipped
  path functions, each with a clear stance-phase peak in walking and running.

Bounds are measured by recomputing them from the generated kinematics with the project's analysis on the canonical
model (`biomotion.analysis.chain.analyze`: 6 Hz low-pass, inverse dynamics with the inferred ground reaction of
the contact model, PhysPT Eq. 4-5), never from the guidance's own estimates; activations by static optimization of
those inverse-dynamics torques, the path `biomotion analyze --muscles rajagopal2016` runs
(`biomotion.analysis.activations.trial_activations`: the shipped Rajagopal 2016 path functions, fitted on the very
model file, the muscle parameters read from it, weak reserves), not by the muscle surrogate that the generators steer
with. A bound is met when the recomputed peak is within it. ``control_bounds_met_share`` is the share of GRF, torque
and activation targets met.

``control_fid_ratio``: the motion-text evaluator's FID (T2M, Guo et al. 2022; `biomotion.evaluation.distribution`)
of the controlled clips against the real target clips, over the FID of the uncontrolled clips (same prompts and
seeds) against the same real clips, every clip read through its real target's coordinate mask. With a dozen clips
FID is dominated by its small-set bias; read the ratio, not the values.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.errors import BiomotionError
from biomotion.guidance.measured_bounds import analysed_series
from biomotion.motion import Motion

PATH_BODIES = ("pelvis", "calcn_r", "hand_r")
#: coordinates a clip must measure for a body's path to be its own
BODY_NEEDS = {
    "pelvis": ("pelvis_tx", "pelvis_ty", "pelvis_tz", "pelvis_tilt", "pelvis_list", "pelvis_rotation"),
    "calcn_r": ("hip_flexion_r", "hip_adduction_r", "hip_rotation_r", "knee_angle_r", "ankle_angle_r"),
    "hand_r": ("lumbar_extension", "arm_flex_r", "arm_add_r", "arm_rot_r", "elbow_flex_r"),
}
TORQUE_COORDINATE = "knee_angle_r"
#: muscles of the activation caps, taken in turn (module docstring); names of the shipped ``rajagopal2016`` paths
ACTIVATION_MUSCLES = ("glmed1_r", "vaslat_r", "soleus_r")
#: the shipped muscle path functions static optimization measures activations with (fitted on the canonical model)
MUSCLE_PATHS = "rajagopal2016"
#: default weight of a path target: 1e5 makes a 1 cm error weigh 10, the size of the other guidance terms near
#: their bounds (`Settings.path_weight`)
PATH_WEIGHT = 100000.0
KINDS = ("path", "grf", "torque", "activation")
BOUND_KINDS = ("grf", "torque", "activation")
TRAJECTORY_FAIL_M = 0.5  # OmniControl's trajectory error threshold
LOCATION_FAIL_M = 0.2  # OmniControl's location error threshold
BARS = {
    "control_joint_mean_err_m": ("<=", 0.02),
    "control_joint_max_err_m": ("<=", 0.2),
    "control_bounds_met_share": (">=", 0.9),
    "control_fid_ratio": ("<=", 1.2),
}


@dataclass(frozen=True)
class Settings:
    """Sizes of the evaluation: ``paths``, ``grf_caps``, ``torque_caps`` and ``activation_caps`` targets (taken from
    the held-out clips in turn), clips cut to ``max_seconds``, path windows of ``path_seconds`` sampled every
    ``path_stride`` frames, caps at ``cap_fraction`` of the uncontrolled peak, path targets weighted ``path_weight``
    (on their mean squared distance, m^2; chosen on the generator's training subjects, never the evaluated ones:
    ``docs/decisions/control_path_weight.py``)."""

    paths: int = 6
    grf_caps: int = 3
    torque_caps: int = 3
    activation_caps: int = 3
    max_seconds: float = 2.0
    path_seconds: float = 1.0
    path_stride: int = 3
    cap_fraction: float = 0.9
    seed: int = 0
    path_weight: float = PATH_WEIGHT


def _motion(q: torch.Tensor | np.ndarray, rate: float) -> Motion:
    values = q.detach().double().numpy() if isinstance(q, torch.Tensor) else np.asarray(q, dtype=np.float64)
    return Motion(times=np.arange(len(values)) / rate, values=values, names=CANONICAL_COORDINATES)


def canonical_values(motion: Motion, model) -> np.ndarray:
    """[T, 39] canonical coordinates of a cached clip, the ones it lacks at the model's defaults."""
    order = [motion.names.index(n) for n in CANONICAL_COORDINATES]
    values, mask = motion.values[:, order], motion.mask[order]
    return np.where(mask[None], values, model.defaults.numpy()[None, :])


def origins(model, values: np.ndarray, body: str) -> np.ndarray:
    """[T, 3] origin of ``body`` in ground for canonical coordinates [T, 39] (forward kinematics of ``model``)."""
    from biomotion.guidance.control import body_origins

    with torch.no_grad():
        positions = body_origins(model, torch.as_tensor(values, dtype=model.dtype))
    return positions[:, model.body_index(body)].numpy()


def recomputed(model, q: torch.Tensor | np.ndarray, rate: float, muscles: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """Per frame, from the kinematics alone (`biomotion.analysis.chain.analyze` on the canonical model): the total
    vertical ground reaction in body weights (``grf_bw``), `TORQUE_COORDINATE`'s moment in N·m/kg
    (``torque_nm_per_kg``) and, for each of ``muscles``, its static-optimization activation (``activation:NAME``,
    0-1; `so_activations`) balancing the same analysis's torques."""
    from biomotion.analysis.chain import analyze

    result = analyze(_motion(q, rate), model)
    out = {
        "grf_bw": analysed_series(result, "grf_vertical"),
        "torque_nm_per_kg": analysed_series(result, "joint_torque", TORQUE_COORDINATE),
    }
    if muscles:
        out |= {f"activation:{m}": a for m, a in so_activations(result, muscles).items()}
    return out


def so_activations(result, muscles: Sequence[str]) -> dict[str, np.ndarray]:
    """Per frame, the static-optimization activation of each of ``muscles`` for an analysis ``result`` on the
    canonical model: `biomotion.analysis.activations.trial_activations` (what ``biomotion analyze --muscles``
    runs) with the shipped `MUSCLE_PATHS`, the muscle parameters read from the model's own .osim file. Refuses
    paths made for other coordinates (`check_paths`)."""
    from biomotion.analysis.activations import check_paths, load_paths, trial_activations

    model_file = result.model.spec.path
    paths, label = load_paths(MUSCLE_PATHS)
    check_paths(paths, label, model_file, tuple(result.model.coordinate_names))
    solution = trial_activations(result, model_file, paths)
    names = list(solution.muscle_names)
    unknown = [m for m in muscles if m not in names]
    if unknown:
        raise BiomotionError(f"muscles {unknown} are not among the {len(names)} of the muscle paths {label}")
    values = solution.activations.numpy()
    return {m: values[:, names.index(m)] for m in muscles}


def path_target(model, motion: Motion, body: str, rate: float, seconds: float, stride: int) -> list[list[float]]:
    """The real clip's ``body`` origin over its first ``seconds``, every ``stride`` frames: [[t, x, y, z], ...]."""
    values = canonical_values(motion, model)
    frames = list(range(0, min(len(values), round(seconds * rate) + 1), stride))
    xyz = origins(model, values, body)
    return [[f / rate, *map(float, xyz[f])] for f in frames]


def measurable_bodies(motion: Motion) -> list[str]:
    """`PATH_BODIES` whose coordinates (`BODY_NEEDS`) the clip measures."""
    have = {n for n, m in zip(motion.names, motion.mask) if m}
    return [b for b in PATH_BODIES if all(c in have for c in BODY_NEEDS[b])]


def surrogate_peak(surrogate, q: torch.Tensor | np.ndarray, muscle: str) -> float | None:
    """Diagnostic only, never the measure: the peak of ``muscle``'s activation as the muscle surrogate the
    generators steer with predicts it (its left-right symmetric prediction, the one ``activations.sto`` holds) on
    canonical coordinates [T, 39]; None without a surrogate."""
    if surrogate is None:
        return None
    q = torch.as_tensor(np.asarray(q.detach() if isinstance(q, torch.Tensor) else q), dtype=torch.float32)
    every = torch.ones(1, q.shape[-1], dtype=torch.bool)
    with torch.no_grad():
        activations = surrogate.predict_symmetric(q[None], every)[0][0]  # (activations, COM): [T, M]
    return float(activations[:, list(surrogate.names).index(muscle)].max())


def plan(clips: list[Motion], settings: Settings) -> list[tuple[str, int, str | None]]:
    """(kind, clip index, body or muscle) per target: path targets first, then GRF, torque and activation caps,
    each kind walking the clips from a different start so that one clip rarely serves twice; the path bodies go in
    turn over those each clip measures, the activation caps' muscles in turn over `ACTIVATION_MUSCLES`."""
    if not clips:
        raise BiomotionError("no held-out clip to sample control targets from")
    out: list[tuple[str, int, str | None]] = []
    n = len(clips)
    step = max(1, n // max(1, settings.paths))
    for k in range(settings.paths):
        i = (k * step) % n
        bodies = measurable_bodies(clips[i])
        if not bodies:
            continue
        out.append(("path", i, bodies[k % len(bodies)]))
    for kind, count, start in (
        ("grf", settings.grf_caps, 1),
        ("torque", settings.torque_caps, 2),
        ("activation", settings.activation_caps, 3),
    ):
        step = max(1, n // max(1, count))
        for k in range(count):
            muscle = ACTIVATION_MUSCLES[k % len(ACTIVATION_MUSCLES)] if kind == "activation" else None
            out.append((kind, (start + k * step) % n, muscle))
    return out


def path_errors(model, q: torch.Tensor | np.ndarray, body: str, path: list[list[float]], rate: float) -> np.ndarray:
    """Distance (m) from the generated ``body`` origin to each path point at its frame (nearest)."""
    values = q.detach().double().numpy() if isinstance(q, torch.Tensor) else np.asarray(q, dtype=np.float64)
    xyz = origins(model, values, body)
    frames = [min(round(p[0] * rate), len(xyz) - 1) for p in path]
    return np.linalg.norm(xyz[frames] - np.asarray([p[1:] for p in path]), axis=-1)


def _spec(kind: str, body: str | None, path: list[list[float]] | None, cap: float | None, path_weight: float) -> dict:
    if kind == "path":
        return {"quantity": "joint_position", "body": body, "kind": "path", "path": path, "weight": path_weight}
    if kind == "grf":
        return {"quantity": "grf_vertical", "kind": "max", "value": cap}
    if kind == "activation":
        return {"quantity": "muscle_activation", "muscle": body, "kind": "max", "value": cap}
    return {"quantity": "joint_torque", "coordinate": TORQUE_COORDINATE, "kind": "min", "value": cap}


class PGBIGRunner:
    """PG-BIG's side of the evaluation: the request of a held-out clip generated without and with control
    (guidance, planting, then the coordinate-space stage)."""

    name = "pgbig"

    def __init__(self, generator) -> None:
        self.generator, self.rate = generator, generator.rate
        self.train_subjects = list(generator.bundle.train_subjects)

    def _personal(self, cache, target, seed: int) -> tuple:
        from biomotion.evaluation.generation import _request

        request = _request(cache, target.index)
        personal = {
            "profile": cache.profile(target.index),
            "references": target.references,
            "reference_actions": target.reference_actions,
            "reference_speeds": target.reference_speeds,
            "seconds": target.motion.n_frames / self.rate,
            "seed": seed,
        }
        return request, personal

    def action(self, cache, target) -> str:
        from biomotion.evaluation.generation import _request

        return _request(cache, target.index).action

    def free(self, cache, target, seed: int) -> torch.Tensor:
        request, personal = self._personal(cache, target, seed)
        return self.generator.generate(request, **personal).q[0]

    def controlled(self, cache, target, seed: int, control, free: torch.Tensor) -> tuple:
        """(controlled coordinates, the uncontrolled ones the errors are compared with, the controlled ones before
        the coordinate-space stage or None)."""
        request, personal = self._personal(cache, target, seed)
        return self.generator.generate(request, **personal, control=control).q[0], free, None


class FlexMotionRunner:
    """FlexMotion's side: the held-out clip's label text and subject profile, one window cut to the clip's length,
    without and with the control module (`biomotion.generation.flexmotion_control.generate_controlled`: bounds as
    value targets where the sample breaks them, paths through the module and then the coordinate-space stage; with
    a path the clip is placed on the target points by a rigid heading turn and shift, and the uncontrolled clip
    with it)."""

    name = "flexmotion"

    def __init__(self, generator, net) -> None:
        self.generator, self.net, self.rate = generator, net, generator.model.config.rate
        self.train_subjects = list(generator.model.metadata.get("train_subjects", []))

    def action(self, cache, target) -> str:
        from biomotion.models.motion_text_evaluator import clip_text

        return clip_text(cache.records[target.index]["labels"])

    def free(self, cache, target, seed: int) -> torch.Tensor:
        from biomotion.models.motion_text_evaluator import clip_text

        text = clip_text(cache.records[target.index]["labels"])
        decoded = self.generator.sample([text], [cache.profile(target.index)], seed=seed)
        every = torch.ones(len(CANONICAL_COORDINATES), dtype=torch.bool)
        return self.generator.refiner.full(decoded["q"][0, : target.motion.n_frames].float(), every)

    def controlled(self, cache, target, seed: int, control, free: torch.Tensor) -> tuple:
        from biomotion.generation.flexmotion_control import generate_controlled
        from biomotion.models.motion_text_evaluator import clip_text

        text = clip_text(cache.records[target.index]["labels"])
        out = generate_controlled(self.generator, self.net, text, cache.profile(target.index), control, seed=seed,
                                  frames=target.motion.n_frames)  # fmt: skip
        return out.decoded["q"][0], out.uncontrolled, out.sampled


def held_out_targets(cache, exclude: Sequence[str], settings: Settings) -> tuple[list, list]:
    """(held-out clips, planned targets) of ``cache``'s subjects outside ``exclude`` (module docstring)."""
    from biomotion.evaluation.generation import unseen_targets

    held_out = unseen_targets(cache, exclude, settings.max_seconds)
    return held_out, plan([t.motion for t in held_out], settings)


def control_targets(
    generator, cache, settings: Settings, *, progress: bool = True, exclude: Sequence[str] | None = None,
    targets: tuple[list, list] | None = None,
) -> tuple[list[dict], list[Motion], list[Motion], list[Motion]]:  # fmt: skip
    """Generate and measure every target (module docstring) from the clips of ``cache``'s subjects outside
    ``exclude`` ("source/subject" keys; default the generator's training subjects), or of ``targets`` (from
    `held_out_targets`) when given. ``generator``: PG-BIG's `Generator` or a runner (`PGBIGRunner`,
    `FlexMotionRunner`). Returns per-target records and the real, uncontrolled and controlled motions (aligned)."""
    from tqdm import tqdm

    from biomotion.guidance.control import Control

    runner = generator if hasattr(generator, "controlled") else PGBIGRunner(generator)
    model = runner.generator.refiner.body if runner.name == "flexmotion" else runner.generator.body
    model = model.to(torch.float64)
    exclude = runner.train_subjects if exclude is None else exclude
    held_out, planned = targets if targets is not None else held_out_targets(cache, exclude, settings)
    records, real, free, controlled = [], [], [], []
    desc = f"control targets ({runner.name})"
    for k, (kind, i, body) in enumerate(tqdm(planned, desc=desc, disable=not progress)):
        target = held_out[i]
        seed = settings.seed + k
        seconds = target.motion.n_frames / runner.rate
        uncontrolled = runner.free(cache, target, seed)
        record = {
            "kind": kind,
            "clip": cache.records[target.index]["clip_id"],
            "action": runner.action(cache, target),
            "seconds": seconds,
            "seed": seed,
        }
        path = cap = None
        if kind == "path":
            path = path_target(model, target.motion, body, runner.rate, settings.path_seconds, settings.path_stride)
            record |= {"body": body, "points": len(path)}
        else:
            muscles = (body,) if kind == "activation" else ()
            before = recomputed(model, uncontrolled, runner.rate, muscles)
            if kind == "grf":
                peak = float(before["grf_bw"].max())
                record |= {"quantity": "grf_vertical (BW)", "uncontrolled_peak": peak}
            elif kind == "activation":
                peak = float(before[f"activation:{body}"].max())
                record |= {
                    "quantity": f"{body} activation (static optimization)",
                    "muscle": body,
                    "uncontrolled_peak": peak,
                    "surrogate_uncontrolled_peak": surrogate_peak(runner.generator.surrogate, uncontrolled, body),
                }
            else:
                peak = float(before["torque_nm_per_kg"].min())
                record |= {"quantity": f"{TORQUE_COORDINATE} moment (N·m/kg)", "uncontrolled_peak": peak}
            cap = settings.cap_fraction * peak
            record["cap"] = cap
        control = Control.from_dict(
            {"targets": [_spec(kind, body, path, cap, settings.path_weight)]}, f"eval target {k + 1}"
        )
        q, placed, sampled = runner.controlled(cache, target, seed, control, uncontrolled)
        if kind == "path":
            errors, before = (path_errors(model, x, body, path, runner.rate) for x in (q, placed))
            record |= {"errors_m": errors.tolist(), "uncontrolled_errors_m": before.tolist()}
            if sampled is not None:
                record["module_errors_m"] = path_errors(model, sampled, body, path, runner.rate).tolist()
        else:
            after = recomputed(model, q, runner.rate, muscles)
            if kind == "torque":
                peak = float(after["torque_nm_per_kg"].min())
            else:
                peak = float(after["grf_bw" if kind == "grf" else f"activation:{body}"].max())
            record |= {"controlled_peak": peak, "met": bool(peak >= cap if kind == "torque" else peak <= cap)}
            if kind == "activation":
                record["surrogate_controlled_peak"] = surrogate_peak(runner.generator.surrogate, q, body)
        records.append(record)
        real.append(target.motion)
        free.append(_motion(placed, runner.rate))
        controlled.append(_motion(q, runner.rate))
    return records, real, free, controlled


def fid_ratio(evaluator, records: list[dict], real: list[Motion], free: list[Motion], controlled: list[Motion]):
    """(FID controlled to real, FID uncontrolled to real) through the motion-text evaluator, every clip read
    through its real target's mask and labelled with its target's text."""
    from biomotion.evaluation.distribution import embed, text_clip
    from biomotion.metrics.distribution import fid
    from biomotion.models.motion_text_evaluator import clip_text

    texts = [clip_text({"action": r["action"]}) for r in records]
    reals = [text_clip(m, t) for m, t in zip(real, texts)]
    sets = [[text_clip(m, t, mask=c.mask) for m, t, c in zip(ms, texts, reals)] for ms in (controlled, free)]
    real_m, _ = embed(evaluator, reals)
    return tuple(fid(embed(evaluator, s)[0], real_m) for s in sets)


def summary(records: list[dict]) -> dict:
    """The report's figures from the per-target records."""
    errors = [e for r in records if r["kind"] == "path" for e in r["errors_m"]]
    before = [e for r in records if r["kind"] == "path" for e in r["uncontrolled_errors_m"]]
    paths = [r for r in records if r["kind"] == "path"]
    bounds = [r for r in records if r["kind"] in BOUND_KINDS]
    out = {
        "control_joint_mean_err_m": float(np.mean(errors)) if errors else None,
        "control_joint_max_err_m": float(np.max(errors)) if errors else None,
        "control_traj_err_share": (
            float(np.mean([max(r["errors_m"]) > TRAJECTORY_FAIL_M for r in paths])) if paths else None
        ),
        "control_loc_err_share": float(np.mean(np.asarray(errors) > LOCATION_FAIL_M)) if errors else None,
        "uncontrolled_joint_mean_err_m": float(np.mean(before)) if before else None,
        "uncontrolled_joint_max_err_m": float(np.max(before)) if before else None,
        "control_bounds_met_share": float(np.mean([r["met"] for r in bounds])) if bounds else None,
    }
    module = [e for r in records if r["kind"] == "path" for e in r.get("module_errors_m", ())]
    if module:  # FlexMotion: the control module's sample, placed, before the coordinate-space stage
        out["module_joint_mean_err_m"] = float(np.mean(module))
        out["module_joint_max_err_m"] = float(np.max(module))
    for kind in BOUND_KINDS:
        chosen = [r for r in bounds if r["kind"] == kind]
        out[f"control_{kind}_bounds_met_share"] = float(np.mean([r["met"] for r in chosen])) if chosen else None
    return out


def bars(figures: dict) -> dict[str, dict]:
    """Issue 47's done-when bars against the figures (met None where a figure is missing)."""
    out = {}
    for key, (sense, bar) in BARS.items():
        value = figures.get(key)
        met = None if value is None else (value <= bar if sense == "<=" else value >= bar)
        out[key] = {"value": value, "bar": f"{sense} {bar:g}", "met": met}
    return out


GENERATORS = ("pgbig", "flexmotion", "both")


def eval_control(
    data_root: str | Path,
    json_path: str | Path,
    md_path: str | Path | None = None,
    *,
    checkpoints: str | Path | None = None,
    settings: Settings = Settings(),
    fid: bool = True,
    progress: bool = True,
    command: str = "",
    generator: str = "pgbig",
) -> dict:
    """Run the evaluation on ``data_root``'s held-out subjects (module docstring) with ``generator`` (`GENERATORS`:
    PG-BIG's guidance path, FlexMotion's control module, or both side by side on the same targets); write the JSON
    (and Markdown) report and return it.

    The targets are the clips of the subjects outside PG-BIG's training subjects (and, when FlexMotion is
    evaluated, outside FlexMotion's too) among the sources PG-BIG trained on, so ``pgbig`` alone reproduces the
    earlier figures. The report's top-level figures are the first column's (PG-BIG's when evaluated);
    ``columns`` holds each generator's figures, bars and per-target records."""
    from biomotion.data.clips import build_temporary_cache
    from biomotion.evaluation.harness import write_json, write_text
    from biomotion.generation.pipeline import CHECKPOINTS, Generator

    if generator not in GENERATORS:
        raise BiomotionError(f"--generator {generator!r}: choose one of {', '.join(GENERATORS)}")
    checkpoints = Path(checkpoints or CHECKPOINTS)
    pgbig = Generator.load(data_root, checkpoints)
    runners: list = [PGBIGRunner(pgbig)] if generator in ("pgbig", "both") else []
    exclude = list(pgbig.bundle.train_subjects)
    if generator in ("flexmotion", "both"):
        from biomotion.generation.flexmotion import FlexMotionGenerator
        from biomotion.generation.flexmotion_control import load_control_net

        flex = FlexMotionGenerator.load(data_root, checkpoints)
        runner = FlexMotionRunner(flex, load_control_net(checkpoints, flex.model))
        runners.append(runner)
        exclude = sorted(set(exclude) | set(runner.train_subjects))
    trained_sources = sorted({key.split("/", 1)[0] for key in pgbig.bundle.train_subjects})
    try:
        handle, cache = build_temporary_cache(data_root, sources=trained_sources, exclude_subjects=exclude)
    except BiomotionError as error:
        raise BiomotionError(f"no held-out subject under {data_root}: {error}") from error
    columns = {}
    with handle:
        targets = held_out_targets(cache, exclude, settings)
        evaluator = None
        evaluator_file = checkpoints / "evaluator.safetensors"
        if fid and evaluator_file.is_file():
            from biomotion.models.motion_text_evaluator import MotionTextEvaluator

            evaluator = MotionTextEvaluator.load(evaluator_file)
        for runner in runners:
            records, real, free, controlled = control_targets(
                runner, cache, settings, progress=progress, exclude=exclude, targets=targets
            )
            figures = summary(records)
            fids = None
            if evaluator is not None:
                fids = fid_ratio(evaluator, records, real, free, controlled)
                figures["control_fid_ratio"] = fids[0] / fids[1] if fids[1] > 0 else None
            columns[runner.name] = {
                **figures,
                "fid_controlled_to_real": None if fids is None else fids[0],
                "fid_uncontrolled_to_real": None if fids is None else fids[1],
                "bars": bars(figures),
                "per_target": records,
            }
    first = columns[runners[0].name]
    report = {
        "command": command,
        "generator": generator,
        "generators": {
            "pgbig": "PG-BIG: guidance (Sec. 3.3) with the control loss, foot planting, coordinate-space stage; "
            "bounds missed by the analysis's measure guided again (biomotion.guidance.measured_bounds), caps still "
            "missed damped in coordinate space (biomotion.guidance.bound_fit)",
            "flexmotion": "FlexMotion: control module (Sec. 3.3, biomotion.models.control_net) with bounds as "
            "value targets where the sample breaks them, then the coordinate-space stages (paths and values; "
            "caps the sample misses, biomotion.guidance.bound_fit)",
        },
        "settings": asdict(settings),
        "targets": len(first["per_target"]),
        "subjects": len({r["clip"].rsplit("/", 1)[0] for r in first["per_target"]}),
        "excluded_subjects": len(exclude),
        **first,
        "columns": columns,
    }
    write_json(json_path, report)
    if md_path is not None:
        write_text(md_path, markdown(report))
    return report


def _fmt(value, digits: str = ".3f") -> str:
    return "–" if value is None else format(value, digits)


def markdown(report: dict) -> str:
    """The report as a Markdown page: one column per evaluated generator."""
    s = report["settings"]
    columns = report.get("columns") or {report["generator"]: report}
    names = list(columns)
    label = {"pgbig": "PG-BIG guidance", "flexmotion": "FlexMotion control net"}
    lines = [
        "# biomotion eval control: targets from held-out clips, met by " + " and ".join(label.get(n, n) for n in names),
        "",
        f"Command: `{report['command']}`",
        "",
        f"Generator: **{report['generator']}**. "
        + " ".join(report.get("generators", {}).get(n, "") + "." for n in names),
        "",
        f"{report['targets']} targets from {report['subjects']} held-out subjects (clips cut to "
        f"{s['max_seconds']:g} s; seeds {s['seed']}-{s['seed'] + report['targets'] - 1}): joint paths of the real "
        f"clip's body origins over its first {s['path_seconds']:g} s (every {s['path_stride']} frames), vertical "
        f"GRF caps, right-knee extension-moment caps and muscle-activation caps ({', '.join(ACTIVATION_MUSCLES)} in "
        f"turn) at {s['cap_fraction']:g} x each generator's own uncontrolled clip's peak (same request and seed). "
        "Bounds are recomputed from the generated kinematics by the analysis (6 Hz low-pass, inverse dynamics with "
        "the contact model's ground reaction), activations by static optimization of those torques with the "
        f"shipped {MUSCLE_PATHS} muscle paths (as `biomotion analyze --muscles {MUSCLE_PATHS}`), not read from the "
        "generator or its muscle surrogate.",
        "",
        "| figure | " + " | ".join(label.get(n, n) for n in names) + " | issue 47 bar |",
        "|---|" + "---|" * len(names) + "---|",
    ]
    for key, row in columns[names[0]]["bars"].items():
        cells = []
        for n in names:
            r = columns[n]["bars"][key]
            met = "–" if r["met"] is None else "met" if r["met"] else "NOT met"
            cells.append(f"{_fmt(r['value'])} ({met})")
        lines.append(f"| `{key}` | " + " | ".join(cells) + f" | {row['bar']} |")
    for key in (
        "control_traj_err_share",
        "control_loc_err_share",
        "uncontrolled_joint_mean_err_m",
        "uncontrolled_joint_max_err_m",
        "module_joint_mean_err_m",
        "module_joint_max_err_m",
        "control_grf_bounds_met_share",
        "control_torque_bounds_met_share",
        "control_activation_bounds_met_share",
        "fid_controlled_to_real",
        "fid_uncontrolled_to_real",
    ):
        lines.append(f"| `{key}` | " + " | ".join(_fmt(columns[n].get(key)) for n in names) + " | |")
    for n in names:
        lines += [
            "",
            f"Per target, {label.get(n, n)}:",
            "",
            "| # | kind | clip | action | body / quantity | result |",
            "|---|---|---|---|---|---|",
        ]
        for k, r in enumerate(columns[n]["per_target"], 1):
            if r["kind"] == "path":
                what = r["body"]
                module = (
                    f"; module before the coordinate stage: mean {np.mean(r['module_errors_m']):.3f} m"
                    if "module_errors_m" in r
                    else ""
                )
                result = (
                    f"mean {np.mean(r['errors_m']):.3f} m, max {np.max(r['errors_m']):.3f} m over {r['points']} "
                    f"points (uncontrolled: mean {np.mean(r['uncontrolled_errors_m']):.3f} m{module})"
                )
            else:
                what = r["quantity"]
                result = (
                    f"uncontrolled peak {r['uncontrolled_peak']:.3f}, cap {r['cap']:.3f}, controlled peak "
                    f"{r['controlled_peak']:.3f} ({'met' if r['met'] else 'NOT met'})"
                )
                if r.get("surrogate_controlled_peak") is not None:
                    result += (
                        f"; muscle surrogate on the same coordinates (not the measure): "
                        f"{r['surrogate_uncontrolled_peak']:.3f} to {r['surrogate_controlled_peak']:.3f}"
                    )
            lines.append(f"| {k} | {r['kind']} | {r['clip']} | {r['action']} | {what} | {result} |")
    lines += [
        "",
        "Path errors: OmniControl's average error (mean distance over controlled points), the largest distance, "
        f"trajectory error (share of targets with a point farther than {TRAJECTORY_FAIL_M} m) and location error "
        f"(share of points farther than {LOCATION_FAIL_M} m). FlexMotion generates in its window's own frame: with "
        "a path target its clip (and the uncontrolled one it is compared with) is placed on the target points by a "
        "heading turn, a horizontal shift and a constant horizontal drift of the pelvis (its autoencoder does not "
        "hold a window's forward travel; `biomotion.generation.flexmotion_control`); `module_joint_*` are the "
        "control module's placed sample before the coordinate-space stage. `control_fid_ratio`: FID of the "
        "controlled clips over FID of the uncontrolled ones (same prompts and seeds) against the real target clips; "
        "with this few clips both FIDs carry a large small-set bias.",
        "",
    ]
    return "\n".join(lines)
