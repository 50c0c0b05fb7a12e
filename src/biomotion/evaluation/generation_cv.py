"""`biomotion eval generation --folds K`: PG-BIG on people it never saw, cross-validated by subject.

Why. The single split of `biomotion.evaluation.generation` scores the shipped models on the 9 subjects they were
not trained on. Figures of one split describe those 9 people: three runners the models never saw gave identity
0.41 for the full model against 0.67 unguided, where the split had read 0.74 against 0.67. Here every subject of
``--data-root`` (of the sources the bundle was trained on) is held out exactly once.

Protocol, per fold f of K (`subject_folds`: subjects dealt to folds source by source, in a hashed order):

1. The fold cache: every clip of the data root; the fold's subjects are ``val`` (held out), everyone else
   ``train`` (`fold_cache`). No subject is on both sides.
2. Trained without the fold's subjects (`biomotion.training.folds.train_fold`, handed in by the CLI): the
   tokenizer (the reference-clip encoder and the probe's embedding), the prior with its subject profiler and
   the per-action guidance bounds and population postures, and the population prior. The training subjects the
   prior's early stopping sets aside (``dev_fraction`` of the config) are the fold's *dev* subjects: the only
   people on whom anything may be chosen inside the fold. The muscle surrogate is the shipped one (it does not
   see who moves). Models are cached under ``<cache-dir>/generation_cv/<key>/fold_<f>/`` (key: the data, the
   folds, the configs, the iterations and the seed), so a second run only generates and scores.
3. Targets: up to four clips of each held-out subject (`biomotion.evaluation.generation.unseen_targets`), each
   generated from the subject's profile, the action label and the subject's *other* clips as references.
4. Variants, same seed per target: ``reference`` (the real clip), ``full`` (PG-BIG with the default guidance),
   ``no_planting`` (the same before foot planting), ``no_guidance`` (the same sample before guidance),
   ``no_personalization`` (profile and references dropped, guided), ``population`` (the fold's action-only
   prior, unguided), plus any named guidance settings passed in ``guidance`` (the experiments of
   docs/decisions/generation-unseen-people.md).
5. Scores: every per-clip metric of the single split (`score_variants`: contacts, jerk, COM and body energy
   fluctuation, ZMP in support, muscle-limit violations, fidelity against the target), and the identity probe
   (`identity_accuracy`): for each target a logistic regression on the fold tokenizer's pooled latents, trained
   on the real clips of the fold's held-out subjects other than the target, tested on the real target and on each
   variant's clip (chance 1 / subjects of the fold). The probe's test clip is never one of the references the
   clip was generated from.
6. ``repeats`` draws per fold (seeds as in the single split), pooled.

Figures (`cv_keys`), per fold and the worst fold, which the bars judge:

- ``identity_cv_gap_points``: real minus full identity, percentage points (bar <= 10);
- ``identity_cv_full_minus_unguided_min``: full minus unguided identity (bar >= 0);
- ``energy_cv_ratio_to_real``: mean COM energy fluctuation (std over a clip, J) of the full model over the real
  clips' (bar <= 1.5);
- reported without a bar: ZMP in support (real, full), the contact metrics, diversity.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.errors import BiomotionError, ConfigError
from biomotion.evaluation.generation import (
    LABELS,
    Target,
    _motion,
    _request,
    combine_identity,
    combine_repeats,
    identity_accuracy,
    score_variants,
    unseen_targets,
)
from biomotion.guidance.refine import GuidanceConfig
from biomotion.io.paths import portable
from biomotion.motion import Motion

#: Variants every fold generates (order of the report); named guidance settings come after them.
CV_VARIANTS = ("reference", "full", "no_planting", "no_guidance", "no_personalization", "population")
CV_LABELS = {**LABELS}
#: The contact metrics reported per fold (no bar).
CONTACT_KEYS = ("foot_contact_velocity", "skate_ratio", "floating", "penetration")
ENERGY_KEY = "energy_com"
ZMP_KEY = "zmp_in_support"
BARS = {
    "identity_cv_gap_points": ("<=", 10.0),
    "identity_cv_full_minus_unguided_min": (">=", 0.0),
    "energy_cv_ratio_to_real": ("<=", 1.5),
}


@dataclass(frozen=True)
class FoldTraining:
    """Iterations of the fold models (`biomotion.training.folds.train_fold`), fewer than the shipped runs so five
    folds fit a 2-core CPU. The shipped tokenizer's validation error was 5.36 degrees at iteration 1500 and 5.43
    at its last (5489; its card's history); the shipped generator kept iteration 500 of 3000 by early stopping
    (dev cross-entropy rose after it), so its first 750 iterations, on the same learning-rate schedule
    (``stop_at``), hold the iteration it kept."""

    tokenizer_iterations: int = 1500
    generator_iterations: int = 750
    population: bool = False
    seed: int = 0


@dataclass(frozen=True)
class CVSettings:
    """What one cross-validated evaluation runs: ``folds``, the fold training, ``repeats`` draws per target,
    targets of at most ``max_seconds`` and ``per_subject`` clips per subject, and (``max_subjects``) the first
    subjects per source in hashed order only (the quick variant)."""

    folds: int = 5
    training: FoldTraining = FoldTraining()
    repeats: int = 2
    max_seconds: float = 6.0
    per_subject: int = 4
    max_subjects: int | None = None
    seed: int = 0
    workers: int = 2


#: The quick variant (tests): two folds of a few subjects, models trained for a handful of iterations, one short
#: target per subject. Its figures say nothing about the method; it proves the protocol runs end to end.
QUICK = CVSettings(
    folds=2,
    training=FoldTraining(tokenizer_iterations=4, generator_iterations=4, population=True),
    repeats=1,
    max_seconds=2.0,
    per_subject=1,
    max_subjects=4,
    workers=1,
)

#: ``train_fold(cache_dir, out, *, data_root, tokenizer_config, generator_config, tokenizer_iterations,
#: generator_iterations, population, seed, progress) -> dict`` (`biomotion.training.folds.train_fold`).
FoldTrainer = Callable[..., dict]


# --- folds ---------------------------------------------------------------------------------------------------------


def _hashed(subject: str, seed: int) -> str:
    return hashlib.sha256(f"cv/{seed}/{subject}".encode()).hexdigest()


def subject_folds(subjects: Sequence[str], k: int, seed: int = 0) -> list[tuple[str, ...]]:
    """``k`` disjoint folds covering ``subjects`` ("source/subject" keys): each source's subjects in an order
    hashed from the seed, dealt round-robin with the count carried from source to source, so every fold holds
    about 1/k of each source and folds differ in size by at most one. Deterministic in the set of subjects (not
    their order). Raises `ConfigError` when there are fewer subjects than folds."""
    unique = sorted(set(subjects))
    if k < 2:
        raise ConfigError(f"--folds must be at least 2, got {k}")
    if len(unique) < k:
        raise ConfigError(f"{k} folds need at least {k} subjects; the data root has {len(unique)}")
    by_source: dict[str, list[str]] = {}
    for s in unique:
        by_source.setdefault(s.split("/", 1)[0], []).append(s)
    folds: list[list[str]] = [[] for _ in range(k)]
    position = 0
    for source in sorted(by_source):
        for s in sorted(by_source[source], key=lambda x: _hashed(x, seed)):
            folds[position % k].append(s)
            position += 1
    return [tuple(sorted(f)) for f in folds]


def fold_cache(cache, held_out: Sequence[str], folder: Path) -> Path:
    """A dataset cache in ``folder`` with the clips of ``cache`` (a `DatasetCache`): the ``held_out`` subjects'
    clips marked ``val``, everyone else's ``train`` (the arrays are copied unchanged). Returns ``folder``."""
    from collections import Counter

    from safetensors.numpy import save_file

    from biomotion.data.registry import ARRAYS, MANIFEST
    from biomotion.io.atomic import atomic_write

    out = set(held_out)
    folder.mkdir(parents=True, exist_ok=True)
    save_file(
        {"values": np.ascontiguousarray(cache.values), "masks": np.ascontiguousarray(cache.masks, dtype=np.uint8)},
        str(folder / ARRAYS),
    )
    manifest = json.loads(json.dumps({**cache.manifest, "clips": cache.records}))
    for record in manifest["clips"]:
        record["split"] = "val" if f"{record['source']}/{record['subject']}" in out else "train"
    manifest["split_rule"] = f"cross-validation fold: {len(out)} held-out subjects val, every other subject train"
    manifest["counts"] = {
        **manifest.get("counts", {}),
        "clips": len(manifest["clips"]),
        "per_split": dict(Counter(r["split"] for r in manifest["clips"])),
        "per_source": dict(Counter(r["source"] for r in manifest["clips"])),
    }
    with atomic_write(folder / MANIFEST) as handle:
        json.dump(manifest, handle, indent=1)
    return folder


def _data_digest(cache) -> str:
    """SHA-256 of a cache's clips (values, masks, ids, subjects, labels): the fold models' cache key."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(cache.values).tobytes())
    digest.update(np.ascontiguousarray(cache.masks).tobytes())
    for r in cache.records:
        digest.update(json.dumps([r["clip_id"], r["source"], r["subject"], r["labels"]], sort_keys=True).encode())
    return digest.hexdigest()


# --- one fold ------------------------------------------------------------------------------------------------------


@dataclass
class FoldModels:
    """A fold's trained parts loaded for generation: the generator (fold tokenizer, prior, shipped surrogate), the
    population prior (None when not trained), the fold's dev subjects and what training reported."""

    generator: object
    population: object | None
    dev_subjects: tuple[str, ...]
    info: dict = field(default_factory=dict)


def _fold_job(
    cache, held_out: Sequence[str], folder: Path, *, data_root: Path, checkpoints: Path, training: FoldTraining
) -> dict:
    """The keyword arguments of a fold's ``trainer`` call: the fold cache written into ``folder/dataset`` and the
    training configs recorded on the cards of ``checkpoints``."""
    configs = {}
    for name in ("tokenizer", "generator"):
        card = checkpoints / f"{name}.json"
        if not card.exists() or "config" not in json.loads(card.read_text()):
            raise ConfigError(f"{card}: the model card with the training config of {checkpoints} is missing")
        configs[name] = json.loads(card.read_text())["config"]
    return {
        "cache_dir": fold_cache(cache, held_out, folder / "dataset"),
        "out": folder,
        "data_root": data_root,
        "tokenizer_config": configs["tokenizer"],
        "generator_config": configs["generator"],
        "tokenizer_iterations": training.tokenizer_iterations,
        "generator_iterations": training.generator_iterations,
        "population": training.population,
        "seed": training.seed,
    }


def _run_job(trainer: FoldTrainer, job: dict, progress: bool) -> tuple[dict, float]:
    """One fold's training (in this process or a worker): what the trainer reports and the seconds it took."""
    started = time.monotonic()
    info = trainer(**job, progress=progress)
    return info, round(time.monotonic() - started, 1)


def train_folds(
    jobs: Mapping[int, dict],
    trainer: FoldTrainer | None,
    *,
    workers: int = 1,
    progress: bool = False,
    log: Callable[[str], None] = print,
) -> None:
    """Train every fold of ``jobs`` (fold index -> `_fold_job` arguments) by ``trainer``, ``workers`` folds at a
    time in separate processes (each single-threaded), and record each finished fold in its folder
    (``fold.json``: the trainer's report, seconds, held-out subjects), where `load_fold` finds it."""
    if not jobs:
        return
    if trainer is None:
        raise ConfigError("fold models to train and no trainer: pass trainer=biomotion.training.folds.train_fold")

    def finish(f: int, info: dict, seconds: float) -> None:
        folder = Path(jobs[f]["out"])
        info["seconds"] = seconds
        with open(folder / "fold.json", "w") as handle:
            json.dump(info, handle, indent=1)
        shutil.rmtree(folder / "dataset", ignore_errors=True)
        log(f"fold {f}: models trained in {seconds:.0f} s")

    if workers > 1 and len(jobs) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        context = multiprocessing.get_context("spawn")  # torch's thread pools do not survive a fork
        with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=context) as pool:
            futures = {f: pool.submit(_run_job, trainer, job, False) for f, job in jobs.items()}
            for f, future in futures.items():
                finish(f, *future.result())
    else:
        for f, job in jobs.items():
            finish(f, *_run_job(trainer, job, progress))


def _with_statistics(bundle, cache, held_out: Sequence[str], dev: Sequence[str], body):
    """``bundle`` with its per-action statistics recomputed (`biomotion.models.bundle.action_bounds`) when it was
    saved before a statistic existed (population amplitudes): over the clips training measures them on, those of
    the fold's training subjects other than its dev subjects (`biomotion.training.train_generator
    .statistics_indices`). Its weights are untouched; the bounds it had come out the same."""
    from biomotion.models.bundle import GeneratorBundle, action_bounds
    from biomotion.models.vqvae import DOWNSAMPLE

    if all(b.amplitude and b.energy for b in bundle.bounds.values()):
        return bundle
    skip = set(held_out) | set(dev)
    indices = [
        i
        for i, r in enumerate(cache.records)
        if f"{r['source']}/{r['subject']}" not in skip
        and f"{r['source']}/{r['subject']}" in set(bundle.train_subjects)
        and r["n_frames"] >= DOWNSAMPLE
    ]
    bounds = action_bounds(cache, body, indices)
    return GeneratorBundle(bundle.prior, bundle.vocabulary, bounds, bundle.tokenizer_sha256, bundle.train_subjects)


def load_fold(
    folder: Path, *, data_root: Path, checkpoints: Path, population: bool, cache=None, held_out: Sequence[str] = ()
) -> FoldModels:
    """A trained fold's models from ``folder`` (`train_folds`), with the shipped surrogate of ``checkpoints``; the
    population prior only when asked for and trained. With the data ``cache`` the fold was trained on (and its
    ``held_out`` subjects), a bundle saved before a per-action statistic existed gets it (`_with_statistics`)."""
    from biomotion.data.clips import body_model
    from biomotion.generation.pipeline import GENERATOR_FILE, POPULATION_FILE, SURROGATE_FILE, TOKENIZER_FILE, Generator
    from biomotion.models.bundle import GeneratorBundle
    from biomotion.models.vqvae import MotionVQVAE
    from biomotion.muscles.surrogate import MuscleSurrogate

    info = json.loads((folder / "fold.json").read_text())
    body = body_model(data_root)
    tokenizer = MotionVQVAE.load(folder / TOKENIZER_FILE)
    surrogate = MuscleSurrogate.load(checkpoints / SURROGATE_FILE, body=body)
    bundle = GeneratorBundle.load(folder / GENERATOR_FILE)
    if cache is not None:
        bundle = _with_statistics(bundle, cache, held_out, info.get("dev_subjects", ()), body)
    generator = Generator(tokenizer, bundle, body, surrogate)
    baseline = None
    if population and (folder / POPULATION_FILE).exists():
        baseline = Generator(
            MotionVQVAE.load(folder / TOKENIZER_FILE), GeneratorBundle.load(folder / POPULATION_FILE), body
        )
    return FoldModels(generator, baseline, tuple(info.get("dev_subjects", ())), info)


def generate_cv_variants(
    targets: list[Target],
    cache,
    models: FoldModels,
    *,
    seed: int,
    guidance: Mapping[str, GuidanceConfig] = {},
    progress: bool = False,
) -> dict[str, list[Motion]]:
    """The motions of every variant (`CV_VARIANTS`, without ``population`` when the fold has none, then the named
    ``guidance`` settings), aligned with ``targets``; target k drawn with seed ``seed + k`` in every variant."""
    generator = models.generator
    names = [v for v in CV_VARIANTS if v != "population" or models.population is not None] + list(guidance)
    out: dict[str, list[Motion]] = {v: [] for v in names}
    for k, t in enumerate(tqdm(targets, desc="generating", unit="clip", disable=not progress)):
        request = _request(cache, t.index)
        seconds = t.motion.n_frames / generator.rate
        personal = {
            "profile": cache.profile(t.index),
            "references": t.references,
            "reference_actions": t.reference_actions,
            "reference_speeds": t.reference_speeds,
            "seconds": seconds,
            "seed": seed + k,
        }
        full = generator.generate(request, **personal)
        generic = generator.generate(request, seconds=seconds, seed=seed + k, personalised=False)
        out["reference"].append(t.motion)
        out["full"].append(_motion(full.q[0], generator.rate))
        out["no_planting"].append(_motion(full.unplanted[0], generator.rate))
        out["no_guidance"].append(_motion(full.unguided[0], generator.rate))
        out["no_personalization"].append(_motion(generic.q[0], generator.rate))
        if models.population is not None:
            baseline = models.population.generate(request, seconds=seconds, seed=seed + k, guidance=False)
            out["population"].append(_motion(baseline.q[0], generator.rate))
        for name, config in guidance.items():
            other = generator.generate(request, **personal, guidance_config=config)
            out[name].append(_motion(other.q[0], generator.rate))
    return out


#: Subject-specific gait features (`person_features`): (name, coordinates it needs).
_SIDES = ("r", "l")
PERSON_FEATURES = (
    ("cadence", ("knee_angle_r", "pelvis_tx", "pelvis_tz")),
    ("stride_length", ("knee_angle_r", "pelvis_tx", "pelvis_tz")),
    *(
        (f"range_{j}", tuple(f"{j}_{s}" for s in _SIDES))
        for j in ("hip_flexion", "hip_adduction", "knee_angle", "ankle_angle")
    ),
    *((f"asymmetry_{j}", tuple(f"{j}_{s}" for s in _SIDES)) for j in ("hip_flexion", "knee_angle", "ankle_angle")),
    *((f"mean_{j}", tuple(f"{j}_{s}" for s in _SIDES)) for j in ("hip_flexion", "knee_angle", "ankle_angle")),
    *((f"range_{j}", (j,)) for j in ("pelvis_tilt", "pelvis_list", "pelvis_rotation")),
    ("pelvis_excursion", ("pelvis_ty",)),
)


def person_features(motion: Motion, rate: float, mask: np.ndarray | None = None) -> dict[str, float]:
    """Gait features that tell people apart, from a canonical clip (generic size): cadence (strides per second,
    knee autocorrelation, `biomotion.evaluation.generation.stride_period`), stride length (m), joint ranges (deg,
    97.5th - 2.5th percentile, mean of both sides), left-right asymmetries of the ranges (deg, right - left), mean
    joint angles (deg, both sides) and the pelvis's ranges and vertical excursion (deg, m). NaN for a feature whose
    coordinates ``mask`` (default the clip's) lacks."""
    from biomotion.body.canonical import CANONICAL_COORDINATES
    from biomotion.evaluation.generation import stride_period

    q = np.asarray(motion.values, dtype=np.float64)
    present = dict(zip(motion.names, motion.mask if mask is None else mask))
    col = lambda n: q[:, CANONICAL_COORDINATES.index(n)]
    rng = lambda n: float(np.degrees(np.percentile(col(n), 97.5) - np.percentile(col(n), 2.5)))
    period = stride_period(q, rate) if len(q) > int(0.8 * rate) else math.nan
    speed = float(
        np.hypot(col("pelvis_tx")[-1] - col("pelvis_tx")[0], col("pelvis_tz")[-1] - col("pelvis_tz")[0])
        / max((len(q) - 1) / rate, 1e-9)
    )
    out = {}
    for name, needs in PERSON_FEATURES:
        if not all(present.get(n, False) for n in needs):
            out[name] = math.nan
            continue
        kind, _, joint = name.partition("_")
        if name == "cadence":
            out[name] = 1.0 / period if period and math.isfinite(period) else math.nan
        elif name == "stride_length":
            out[name] = speed * period
        elif name == "pelvis_excursion":
            out[name] = float(np.percentile(col("pelvis_ty"), 95) - np.percentile(col("pelvis_ty"), 5))
        elif kind == "range":
            out[name] = float(np.mean([rng(n) for n in needs]))
        elif kind == "asymmetry":
            out[name] = rng(needs[0]) - rng(needs[1])
        else:  # mean
            out[name] = float(np.degrees(np.mean([col(n).mean() for n in needs])))
    return out


def feature_errors(
    variants: Mapping[str, list[Motion]], actions: Sequence[str], rate: float
) -> dict[str, dict[str, float]]:
    """Per variant and `person_features` feature: mean over targets of |generated - real| in units of the spread
    of that feature across the real targets of the same action (their standard deviation; the people's spread),
    so 1 means as far from the person as one person is from another. Features the target's coordinates lack are
    left out. ``mean`` is the mean over features. The real clips' own row is 0 by construction and omitted."""
    real = [person_features(m, rate) for m in variants["reference"]]
    masks = [m.mask for m in variants["reference"]]
    names = [n for n, _ in PERSON_FEATURES]
    spread = {}
    for action in set(actions):
        rows = [real[k] for k, a in enumerate(actions) if a == action]
        for n in names:
            values = np.array([r[n] for r in rows], dtype=np.float64)
            values = values[np.isfinite(values)]
            spread[action, n] = float(values.std(ddof=1)) if len(values) >= 2 else math.nan
    out = {}
    for variant, motions in variants.items():
        if variant == "reference":
            continue
        errors: dict[str, list[float]] = {n: [] for n in names}
        for k, m in enumerate(motions):
            own = person_features(m, rate, masks[k])
            for n in names:
                scale = spread[actions[k], n]
                if math.isfinite(own[n]) and math.isfinite(real[k][n]) and math.isfinite(scale) and scale > 0:
                    errors[n].append(abs(own[n] - real[k][n]) / scale)
        row = {n: float(np.mean(e)) if e else math.nan for n, e in errors.items()}
        finite = [v for v in row.values() if math.isfinite(v)]
        row["mean"] = float(np.mean(finite)) if finite else math.nan
        out[variant] = row
    return out


def _nanmean(values: Sequence[float]) -> float:
    """Mean of the finite values, NaN when there is none (without NumPy's warning)."""
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def _mean_of(table: dict, variant: str, key: str) -> float:
    value = table.get(variant, {}).get(key, {}).get("mean")
    return math.nan if value is None else float(value)


def fold_figures(table: dict, identity: dict) -> dict:
    """The figures of one fold that the CV keys take (`cv_keys`), from its pooled table and identity result."""
    real, full, unguided = (identity.get(v, math.nan) for v in ("reference", "full", "no_guidance"))
    energy_real, energy_full = _mean_of(table, "reference", ENERGY_KEY), _mean_of(table, "full", ENERGY_KEY)
    variants = [v for v in table if v != "reference"]
    return {
        "identity": {v: identity.get(v, math.nan) for v in table},
        "identity_gap_points": 100.0 * (real - full),
        "identity_full_minus_unguided": full - unguided,
        "energy": {v: _mean_of(table, v, ENERGY_KEY) for v in table},
        "energy_ratio_to_real": energy_full / energy_real if energy_real > 0 else math.nan,
        "energy_ratio_to_real_by_variant": {
            v: _mean_of(table, v, ENERGY_KEY) / energy_real if energy_real > 0 else math.nan for v in variants
        },
        "zmp_in_support": {v: _mean_of(table, v, ZMP_KEY) for v in table},
        "contacts": {key: {v: _mean_of(table, v, key) for v in table} for key in CONTACT_KEYS},
        "jerk": {v: _mean_of(table, v, "jerk") for v in table},
        "fidelity": {v: _mean_of(table, v, "fidelity") for v in variants},
        "diversity": {v: _mean_of(table, v, "diversity") for v in table},
        "muscle_violations": {v: _mean_of(table, v, "muscle_violations") for v in table},
        "speed_error": {v: _mean_of(table, v, "speed_error") for v in table},
    }


def evaluate_fold(
    cache,
    models: FoldModels,
    train_subjects: Sequence[str],
    *,
    data_root: Path,
    settings: CVSettings,
    guidance: Mapping[str, GuidanceConfig] = {},
    progress: bool = False,
) -> dict:
    """Generate for every subject of ``cache`` not in ``train_subjects`` (`unseen_targets`), ``settings.repeats``
    times, and score: the pooled table, the identity result and `fold_figures`."""
    from biomotion.data.clips import body_model

    targets = unseen_targets(cache, train_subjects, settings.max_seconds, per_subject=settings.per_subject)
    if not targets:
        raise BiomotionError("a fold without targets: every held-out subject's clips are shorter than 8 frames")
    generator = models.generator
    names = [cache.records[t.index]["clip_id"] for t in targets]
    speeds = [cache.records[t.index]["labels"].get("speed") for t in targets]
    heights = [cache.records[t.index]["profile"].get("height") for t in targets]
    model = body_model(data_root)
    actions = [cache.records[t.index]["labels"]["action"] for t in targets]
    tables, identities, features = [], [], []
    for r in range(settings.repeats):
        first = settings.seed + r * len(targets)
        variants = generate_cv_variants(targets, cache, models, seed=first, guidance=guidance, progress=progress)
        tables.append(score_variants(variants, model, generator.surrogate, generator.rate, names, speeds, heights))
        identities.append(identity_accuracy(generator.tokenizer, targets, variants))
        features.append(feature_errors(variants, actions, generator.rate))
    table, identity = combine_repeats(tables), combine_identity(identities)
    return {
        "targets": len(targets),
        "subjects": sorted({t.subject for t in targets}),
        "clips": names,
        "table": table,
        "identity_probe": identity,
        **fold_figures(table, identity),
        "feature_errors": {v: {n: _nanmean([f[v][n] for f in features]) for n in features[0][v]} for v in features[0]},
    }


# --- over folds ----------------------------------------------------------------------------------------------------


def _worst(values: Sequence[float], direction: str) -> float | None:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    if not finite:
        return None
    return max(finite) if direction == "<=" else min(finite)


def cv_keys(folds: Sequence[dict]) -> dict:
    """The cross-validated keys over ``folds`` (each a `fold_figures` result): per fold and the worst, the bars
    on the worst, and the reported figures without a bar (ZMP in support, contacts, diversity) per fold."""
    per_fold = {
        "identity_cv_gap_points": [f["identity_gap_points"] for f in folds],
        "identity_cv_full_minus_unguided_min": [f["identity_full_minus_unguided"] for f in folds],
        "energy_cv_ratio_to_real": [f["energy_ratio_to_real"] for f in folds],
    }
    worst = {key: _worst(values, BARS[key][0]) for key, values in per_fold.items()}
    bars = {
        key: None if worst[key] is None else (worst[key] <= bound if op == "<=" else worst[key] >= bound)
        for key, (op, bound) in BARS.items()
    }
    reported = {
        "identity": {v: [f["identity"].get(v) for f in folds] for v in folds[0]["identity"]},
        "zmp_in_support": {v: [f["zmp_in_support"].get(v) for f in folds] for v in ("reference", "full")},
        "contacts": {
            key: {v: [f["contacts"][key].get(v) for f in folds] for v in ("reference", "full", "no_guidance")}
            for key in CONTACT_KEYS
        },
        "diversity": {v: [f["diversity"].get(v) for f in folds] for v in folds[0]["diversity"]},
        "energy": {v: [f["energy"].get(v) for f in folds] for v in folds[0]["energy"]},
    }
    return {**worst, "per_fold": per_fold, "bars": bars, "reported": reported}


def _key(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def eval_generation_cv(
    data_root: str | Path,
    json_path: str | Path,
    md_path: str | Path | None = None,
    *,
    checkpoints: str | Path | None = None,
    settings: CVSettings = CVSettings(),
    cache_dir: str | Path | None = None,
    trainer: FoldTrainer | None = None,
    guidance: Mapping[str, GuidanceConfig] = {},
    targets: str = "held_out",
    only: Sequence[int] | None = None,
    progress: bool = True,
    command: str = "",
    log: Callable[[str], None] = print,
) -> dict:
    """Cross-validate PG-BIG by subject over the data root (module docstring); write the JSON (and Markdown)
    report and return it.

    ``trainer`` trains a fold's models when the cache has none (`biomotion.training.folds.train_fold`; the CLI
    passes it). ``cache_dir`` (default ``~/.cache/biomotion``) keeps the fold models. ``targets="dev"`` generates
    for each fold's dev subjects instead of its held-out ones (the subjects choices may be made on, inside the
    fold; the probe then tells the dev subjects apart). ``only`` restricts the run to those fold indices (the
    folds are still made from every subject; an experiment on the folds trained so far). Torch runs
    single-threaded for the evaluation."""
    from biomotion.data.clips import build_temporary_cache
    from biomotion.evaluation.harness import write_json, write_text
    from biomotion.generation.pipeline import CHECKPOINTS
    from biomotion.models.bundle import GeneratorBundle

    if targets not in ("held_out", "dev"):
        raise ConfigError(f"targets must be 'held_out' or 'dev', got {targets!r}")
    checkpoints = Path(checkpoints or CHECKPOINTS)
    cache_dir = Path(cache_dir).expanduser() if cache_dir else Path("~/.cache/biomotion").expanduser()
    shipped = GeneratorBundle.load(checkpoints / "generator.safetensors")
    sources = sorted({key.split("/", 1)[0] for key in shipped.train_subjects})
    started = time.monotonic()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        handle, cache = build_temporary_cache(data_root, sources=sources)
        with handle:
            subjects = sorted({f"{r['source']}/{r['subject']}" for r in cache.records})
            if settings.max_subjects is not None:
                kept = []
                for source in sorted({s.split("/")[0] for s in subjects}):
                    own = sorted((s for s in subjects if s.startswith(f"{source}/")), key=lambda s: _hashed(s, 0))
                    kept += own[: settings.max_subjects]
                subjects = sorted(kept)
            folds = subject_folds(subjects, settings.folds, settings.training.seed)
            key = _key(
                _data_digest(cache),
                subjects,
                folds,
                {k: v for k, v in asdict(settings.training).items() if k != "population"},
                json.loads((checkpoints / "tokenizer.json").read_text()).get("config"),
                json.loads((checkpoints / "generator.json").read_text()).get("config"),
            )
            root = cache_dir / "generation_cv" / key
            log(f"{len(subjects)} subjects in {len(folds)} folds; fold models in {root}")
            jobs = {
                f: _fold_job(
                    _subset(cache, subjects),
                    held_out,
                    root / f"fold_{f}",
                    data_root=Path(data_root),
                    checkpoints=checkpoints,
                    training=settings.training,
                )
                for f, held_out in enumerate(folds)
                if not (root / f"fold_{f}" / "fold.json").exists() and (only is None or f in only)
            }
            train_folds(jobs, trainer, workers=settings.workers, progress=progress, log=log)
            results = []
            for f, held_out in enumerate(folds):
                if only is not None and f not in only:
                    continue
                train_subjects = [s for s in subjects if s not in held_out]
                models = load_fold(
                    root / f"fold_{f}",
                    data_root=Path(data_root),
                    checkpoints=checkpoints,
                    population=settings.training.population,
                    cache=cache,
                    held_out=held_out,
                )
                trained = time.monotonic()
                if targets == "dev":
                    if len(models.dev_subjects) < 2:
                        raise BiomotionError(f"fold {f} has fewer than two dev subjects")
                    unseen_for = [s for s in _all_subjects(cache) if s not in models.dev_subjects]
                else:
                    unseen_for = [*train_subjects, *(s for s in _all_subjects(cache) if s not in subjects)]
                result = evaluate_fold(
                    cache,
                    models,
                    unseen_for,
                    data_root=Path(data_root),
                    settings=settings,
                    guidance=guidance,
                    progress=progress,
                )
                result.update(
                    fold=f,
                    held_out=list(held_out),
                    dev_subjects=list(models.dev_subjects),
                    training=models.info,
                    seconds={
                        "train": models.info.get("seconds"),
                        "generate_and_score": round(time.monotonic() - trained, 1),
                    },
                )
                results.append(result)
                log(
                    f"fold {f}: {result['targets']} targets of {len(result['subjects'])} subjects; identity real "
                    f"{result['identity']['reference']:.2f} full {result['identity']['full']:.2f} unguided "
                    f"{result['identity']['no_guidance']:.2f}; energy ratio {result['energy_ratio_to_real']:.2f} "
                    f"({result['seconds']['generate_and_score']:.0f} s generation and scores)"
                )
    finally:
        torch.set_num_threads(threads)
    keys = cv_keys(results)
    pooled = combine_repeats([r["table"] for r in results])
    report = {
        "command": command,
        "protocol": "subject-level cross-validation (biomotion.evaluation.generation_cv)",
        "targets_of": targets,
        "checkpoints": portable(checkpoints),
        "settings": asdict(settings),
        "guidance": {name: _config_dict(c) for name, c in {"full": GuidanceConfig(), **guidance}.items()},
        "subjects": len(subjects),
        "folds": [list(f) for f in folds],
        "fold_models": portable(root),
        "seconds": round(time.monotonic() - started, 1),
        **{k: v for k, v in keys.items()},
        "pooled_table": pooled,
        "per_fold": keys["per_fold"],
        "fold_results": results,
    }
    write_json(json_path, _finite_json(report))
    if md_path is not None:
        write_text(md_path, markdown_cv(report))
    return report


def _all_subjects(cache) -> list[str]:
    return sorted({f"{r['source']}/{r['subject']}" for r in cache.records})


def _subset(cache, subjects: Sequence[str]):
    """``cache`` itself when it holds only ``subjects``, else a view of it without the others' clips (the quick
    variant's subject limit applies to training as well)."""
    keep = set(subjects)
    if all(f"{r['source']}/{r['subject']}" in keep for r in cache.records):
        return cache
    view = object.__new__(type(cache))
    view.__dict__.update(cache.__dict__)
    indices = [i for i, r in enumerate(cache.records) if f"{r['source']}/{r['subject']}" in keep]
    view.records = [cache.records[i] for i in indices]
    view.masks = cache.masks[indices]
    view.manifest = {**cache.manifest, "clips": view.records}
    return view


def _config_dict(config: GuidanceConfig) -> dict:
    return json.loads(json.dumps(asdict(config), default=str))


def _finite_json(value):
    """NaN and inf as null, recursively (JSON has neither)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite_json(v) for v in value]
    return value


# --- report --------------------------------------------------------------------------------------------------------


def _cell(value, digits: str = ".2f") -> str:
    return "–" if value is None or (isinstance(value, float) and not math.isfinite(value)) else f"{value:{digits}}"


def markdown_cv(report: dict) -> str:
    """The report as Markdown: per-fold figures and the worst fold, the bars, the pooled PG-BIG table."""
    folds = report["fold_results"]
    extra = [v for v in folds[0]["identity"] if v not in CV_VARIANTS]
    variants = [v for v in CV_VARIANTS if v in folds[0]["identity"]] + extra
    label = lambda v: CV_LABELS.get(v, v)
    whose = "dev" if report["targets_of"] == "dev" else "held-out"
    lines = [
        "# Generation evaluation, cross-validated by subject\n",
        f"Command: `{report['command']}`\n",
        f"{report['subjects']} subjects in {len(report['folds'])} folds (targets: each fold's {whose} subjects); "
        f"{report['settings']['repeats']} draws per target; fold models trained without the fold's subjects "
        f"(tokenizer {report['settings']['training']['tokenizer_iterations']} iterations, generator "
        f"{report['settings']['training']['generator_iterations']}); {report['seconds'] / 60:.1f} min in all.\n",
        "## Bars (worst fold)\n",
        "| key | per fold | worst | bar | met |\n|---|---|---|---|---|",
    ]
    for key, (op, bound) in BARS.items():
        values = report["per_fold"][key]
        met = report["bars"][key]
        lines.append(
            f"| `{key}` | {', '.join(_cell(v) for v in values)} | {_cell(report[key])} | {op} {bound:g} | "
            f"{'–' if met is None else 'yes' if met else 'no'} |"
        )
    lines += [
        "",
        "## Per fold\n",
        "Identity: share of targets whose clip the probe gives to the right person (chance 1 / subjects of the "
        "fold). Energy: COM energy fluctuation, std over a clip (J), mean over targets; ratio = full / real. "
        "ZMP in support (%), foot contact velocity (m/s), skate (%), floating (cm).\n",
        "| fold | subjects | targets | "
        + " | ".join(f"identity {label(v)}" for v in variants)
        + " | energy real | energy full | energy w/o guidance | ratio full | ZMP real | ZMP full | "
        "foot contact vel. real / full | skate real / full | floating real / full |",
        "|---" * (4 + len(variants) + 9) + "|",
    ]
    for f in folds:
        c = f["contacts"]
        lines.append(
            f"| {f['fold']} | {len(f['subjects'])} | {f['targets']} | "
            + " | ".join(_cell(f["identity"].get(v)) for v in variants)
            + f" | {_cell(f['energy']['reference'], '.0f')} | {_cell(f['energy']['full'], '.0f')} | "
            f"{_cell(f['energy']['no_guidance'], '.0f')} | {_cell(f['energy_ratio_to_real'])} | "
            f"{_cell(f['zmp_in_support']['reference'], '.1f')} | {_cell(f['zmp_in_support']['full'], '.1f')} | "
            f"{_cell(c['foot_contact_velocity']['reference'])} / {_cell(c['foot_contact_velocity']['full'])} | "
            f"{_cell(c['skate_ratio']['reference'], '.1f')} / {_cell(c['skate_ratio']['full'], '.1f')} | "
            f"{_cell(c['floating']['reference'])} / {_cell(c['floating']['full'])} |"
        )
    table = report["pooled_table"]
    keys = [k for k in table["full"] if k != "diversity"] + ["diversity"]
    shown = [v for v in variants if v in table]
    lines += [
        "",
        "## PG-BIG Tables 2-3, every fold's targets pooled\n",
        "Mean ± std over the clips of every fold and draw; per-fold means in the JSON (``pooled_table``).\n",
        "| Metric | " + " | ".join(label(v) for v in shown) + " |",
        "|---" * (len(shown) + 1) + "|",
    ]
    for key in keys:
        cells, name = [], key
        for v in shown:
            r = table[v].get(key)
            if r is None or r.get("mean") is None:
                cells.append("–")
                continue
            name = f"{r['label']} ({r['unit']})"
            cells.append(f"{r['mean']:.3g} ± {r['std']:.2g}" if r.get("std") is not None else f"{r['mean']:.3g}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "## Folds\n"]
    for f in folds:
        lines.append(
            f"- fold {f['fold']}: held out {', '.join(f['held_out'])}; dev subjects {', '.join(f['dev_subjects'])}; "
            f"models trained in {_cell(f['seconds']['train'], '.0f')} s, generation and scores "
            f"{f['seconds']['generate_and_score']:.0f} s"
        )
    return "\n".join(lines) + "\n"


def with_changes(config: GuidanceConfig, **changes) -> GuidanceConfig:
    """``config`` with fields changed (a named guidance setting of ``guidance``)."""
    return replace(config, **changes)
