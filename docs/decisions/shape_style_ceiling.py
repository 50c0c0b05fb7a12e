"""How much of a runner's joint-angle pattern body shape predicts, and whether a linear shape-to-style correction
reaches the `shape_dtw_gain_vs_copy` bar of issue 48 (docs/decisions/shape-style-ceiling.md).

Per Fukuchi runner and speed: the mean gait cycle (the ten hip/knee/ankle angles of `biomotion.evaluation.shape`,
cycles between right-foot strikes found by `gait_timing`'s rule on the runner's own model, 101 points). A ridge
regression from Shape features to that curve (speed as an unpenalised fixed effect; penalty chosen by
leave-one-runner-out among the fitting runners only). Then A's motion moved onto B as

- copy: A's angles as they are (the baseline of `biomotion eval shape`);
- linear shape correction: A's angles + f(shape_B) - f(shape_A), read at each frame's phase in A's stride;
- oracle (upper bound, uses B's real data): A's angles + B's own mean curve - A's own mean curve;

scored with `biomotion.evaluation.shape.compare` (DTW, stride, cadence on B's model) on the held-out pairs of
`biomotion eval shape` (model fitted on the cache's 17 training runners) and on all 23 runners with each pair
scored by a model fitted without both of its runners.

    python docs/decisions/shape_style_ceiling.py --data-root ../shared/data --cache ~/.cache/biomotion/dataset
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from biomotion.body.model import BodyModel
from biomotion.body.shape import Shape
from biomotion.data.registry import DatasetCache
from biomotion.evaluation.shape import (
    ANGLES,
    CONTACT_FRACTION,
    MIN_STRIDE_S,
    SPEEDS,
    Runner,
    compare,
    gait_timing,
    load_runners,
    right_foot_height,
    runner_pairs,
)
from biomotion.motion import Motion

POINTS = 101  # samples per gait cycle, strike to strike
CYCLE_TOLERANCE = 0.25  # cycles whose duration is off the median stride by more (a missed strike) are not averaged
PENALTIES = (0.01, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 1e3, 1e4, math.inf)  # inf: no shape effect (the copy)
FINITE = PENALTIES[:-1]
FORCED = 1.0  # fixed a priori, not selected: the shape effect at near full strength, whatever LORO says
FEATURES = ("log height", "log mass", "log femur/height", "log tibia/height", "log foot/height")
BAR = 0.15
OUT = Path("docs/results/dev_shape_style")
COMMAND = "python docs/decisions/shape_style_ceiling.py --data-root ../shared/data --cache ~/.cache/biomotion/dataset"

Curves = dict[tuple[str, str], np.ndarray]  # (runner, speed) -> [POINTS, 10] mean cycle, deg


# ---- per runner: shape features, strikes, mean cycle -----------------------------------------------------------


def shape_features(shape: Shape) -> np.ndarray:
    """[5] log height, log mass and log segment-length-to-height ratios (femur, tibia, calcaneus; mean of sides)."""
    height = float(shape.height or 0.0)
    ratios = [
        np.mean([shape.lengths[f"{body}_{side}"] for side in "rl"]) / height for body in ("femur", "tibia", "calcn")
    ]
    return np.log([height, shape.mass, *ratios])


def strike_times(model: BodyModel, motion: Motion, speed: float) -> np.ndarray:
    """Right-foot strike times (s): `gait_timing`'s rule with its constants (it returns only their count; checked)."""
    height = right_foot_height(model, motion)
    low, high = np.percentile(height, [5.0, 95.0])
    down = height < low + CONTACT_FRACTION * (high - low)
    strikes: list[float] = []
    for t in motion.times[np.flatnonzero(down[1:] & ~down[:-1]) + 1]:
        if not strikes or t - strikes[-1] >= MIN_STRIDE_S:
            strikes.append(float(t))
    if len(strikes) != gait_timing(model, motion, speed)["strikes"]:
        raise RuntimeError("strike_times disagrees with biomotion.evaluation.shape.gait_timing")
    return np.asarray(strikes)


def mean_cycle(motion: Motion, strikes: np.ndarray) -> np.ndarray:
    """[POINTS, 10] mean of the strike-to-strike cycles of the ten angles (deg), each resampled to POINTS."""
    stride = float(np.median(np.diff(strikes)))
    grid = np.linspace(0.0, 1.0, POINTS)
    angles = np.degrees(motion.select(list(ANGLES)).values)
    cycles = [
        np.stack([np.interp(start + grid * (stop - start), motion.times, angles[:, k]) for k in range(len(ANGLES))], 1)
        for start, stop in zip(strikes[:-1], strikes[1:])
        if abs(stop - start - stride) <= CYCLE_TOLERANCE * stride
    ]
    return np.mean(cycles, axis=0)


def frame_phase(times: np.ndarray, strikes: np.ndarray) -> np.ndarray:
    """[T] gait phase in [0, 1) of each frame: within a stride between strikes, and by the median stride outside."""
    stride = float(np.median(np.diff(strikes)))
    index = np.searchsorted(strikes, times, side="right") - 1
    phase = ((times - strikes[0]) / stride) % 1.0  # before the first strike
    inside = (index >= 0) & (index < len(strikes) - 1)
    k = index[inside]
    phase[inside] = (times[inside] - strikes[k]) / (strikes[k + 1] - strikes[k])
    after = index >= len(strikes) - 1
    phase[after] = ((times[after] - strikes[-1]) / stride) % 1.0
    return phase


def corrected(motion: Motion, phase: np.ndarray, delta: np.ndarray) -> Motion:
    """``motion`` with ``delta`` [POINTS, 10] (deg) added to the ten angles at each frame's ``phase``."""
    grid = np.linspace(0.0, 1.0, POINTS)
    values = motion.values.copy()
    for k, name in enumerate(ANGLES):
        values[:, motion.index(name)] += np.radians(np.interp(phase, grid, delta[:, k]))
    return motion.with_values(values)


# ---- ridge: Shape features (+ speed) -> mean cycle -------------------------------------------------------------


class Ridge:
    """Mean cycle = per-speed mean + W · standardised (features − per-speed mean): speed an unpenalised fixed
    effect, shape features ridge-penalised (``penalty`` = inf: W = 0)."""

    def __init__(self, keys: Sequence[tuple[str, str]], x: dict[str, np.ndarray], y: Curves, penalty: float):
        self.penalty = penalty
        speeds = sorted({s for _, s in keys})
        self.x_mean = {s: np.mean([x[r] for r, t in keys if t == s], 0) for s in speeds}
        self.y_mean = {s: np.mean([y[(r, t)] for r, t in keys if t == s], 0) for s in speeds}
        xc = np.stack([x[r] - self.x_mean[s] for r, s in keys])
        yc = np.stack([(y[(r, s)] - self.y_mean[s]).ravel() for r, s in keys])
        self.scale = xc.std(0) + 1e-12
        xs = xc / self.scale
        self.weights = np.zeros((xs.shape[1], yc.shape[1]))
        if math.isfinite(penalty):
            self.weights = np.linalg.solve(xs.T @ xs + penalty * np.eye(xs.shape[1]), xs.T @ yc)

    def curve(self, features: np.ndarray, speed: str) -> np.ndarray:
        return self.y_mean[speed] + (((features - self.x_mean[speed]) / self.scale) @ self.weights).reshape(POINTS, -1)

    def delta(self, source: np.ndarray, target: np.ndarray) -> np.ndarray:
        """f(target) − f(source) at one speed, [POINTS, 10] deg (the speed terms cancel)."""
        return (((target - source) / self.scale) @ self.weights).reshape(POINTS, -1)


def loro_mse(keys: list[tuple[str, str]], x: dict[str, np.ndarray], y: Curves, penalty: float) -> float:
    """Mean squared error (deg²) of each runner's mean cycles predicted by a ridge fitted without that runner."""
    errors = []
    for runner in sorted({r for r, _ in keys}):
        model = Ridge([k for k in keys if k[0] != runner], x, y, penalty)
        errors += [np.mean((model.curve(x[r], s) - y[(r, s)]) ** 2) for r, s in keys if r == runner]
    return float(np.mean(errors))


def fit(
    runners: Sequence[str], x: dict[str, np.ndarray], y: Curves, penalties: Sequence[float] = PENALTIES
) -> tuple[Ridge, dict[float, float]]:
    """The ridge on ``runners`` alone, its penalty (of ``penalties``) chosen by leave-one-runner-out among them; and
    each penalty's LORO error."""
    keys = sorted(k for k in y if k[0] in set(runners))
    scores = {p: loro_mse(keys, x, y, p) for p in penalties}
    return Ridge(keys, x, y, min(scores, key=scores.__getitem__)), scores


# ---- scoring ---------------------------------------------------------------------------------------------------

Method = Callable[[Runner, Runner, str], np.ndarray]  # (A, B, speed) -> delta [POINTS, 10] deg


def score(
    pairs: list[tuple[str, str, str]],
    by_name: dict[str, Runner],
    methods: dict[str, Method],
    phases: dict[tuple[str, str], np.ndarray],
) -> list[dict]:
    """Per pair (speed, A, B): `compare` of the copy and of each method's corrected motion against B's real motion."""
    real: dict[tuple[str, str], dict] = {}
    rows = []
    for n, (speed, a, b) in enumerate(pairs):
        runner_a, runner_b = by_name[a], by_name[b]
        target = runner_b.motions[speed]
        if (b, speed) not in real:
            real[(b, speed)] = gait_timing(runner_b.model, target, SPEEDS[speed])
        source = runner_a.motions[speed]
        row = {"speed": speed, "a": a, "b": b}
        row["copy"] = compare(source, target, runner_b.model, SPEEDS[speed], real[(b, speed)])
        for name, method in methods.items():
            moved = corrected(source, phases[(a, speed)], method(runner_a, runner_b, speed))
            row[name] = compare(moved, target, runner_b.model, SPEEDS[speed], real[(b, speed)])
        rows.append(row)
        print(f"\r{n + 1}/{len(pairs)} pairs", end="", file=sys.stderr)
    print(file=sys.stderr)
    return rows


def summary(rows: list[dict], method: str) -> dict:
    def pick(key: str) -> list[float]:
        return [r[method][key] for r in rows if r[method][key] is not None]

    copy = float(np.mean([r["copy"]["dtw_deg"] for r in rows]))
    dtw = float(np.mean(pick("dtw_deg")))
    return {
        "pairs": len(rows),
        "dtw_deg": dtw,
        "dtw_deg_median": float(statistics.median(pick("dtw_deg"))),
        "gain_vs_copy": 1.0 - dtw / copy,
        "stride_rel_err": float(np.mean(pick("stride_rel_err"))),
        "cadence_rel_err": float(np.mean(pick("cadence_rel_err"))),
    }


def pairs_of(names: Sequence[str], by_name: dict[str, Runner]) -> list[tuple[str, str, str]]:
    """`biomotion eval shape`'s pairs among ``names``: per speed, each runner with the next 3 by name, cyclically."""
    jobs = []
    for speed in SPEEDS:
        here = [n for n in names if speed in by_name[n].motions]
        jobs += [(speed, a, b) for a, b in runner_pairs(here)]
    return jobs


def table(results: dict[str, list[dict]], methods: Sequence[tuple[str, str]]) -> list[str]:
    """Markdown rows: per scope, speed and method, the `summary` figures."""
    lines = [
        "| pairs | speed | method | n | DTW mean (deg) | DTW median (deg) | gain vs copy | stride rel. err. "
        "| cadence rel. err. |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for scope, rows in results.items():
        for speed in (*SPEEDS, "all"):
            chosen = [r for r in rows if speed in ("all", r["speed"])]
            for key, label in methods:
                s = summary(chosen, key)
                lines.append(
                    f"| {scope} | {speed} | {label} | {s['pairs']} | {s['dtw_deg']:.2f} | {s['dtw_deg_median']:.2f} | "
                    f"{s['gain_vs_copy']:+.3f} | {s['stride_rel_err']:.3f} | {s['cadence_rel_err']:.3f} |"
                )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, required=True)
    parser.add_argument("--cache", type=Path, required=True, help="dataset cache: its train split names the runners")
    args = parser.parse_args()
    torch.set_num_threads(1)

    runners, skipped = load_runners(args.data_root)
    by_name = {r.name: r for r in runners}
    cache = DatasetCache(args.cache.expanduser())
    train = sorted({cache.records[i]["subject"] for i in cache.indices(split="train", source="fukuchi")})
    scored = sorted(set(by_name) - set(train))
    x = {r.name: shape_features(r.shape) for r in runners}
    strikes = {(r.name, s): strike_times(r.model, m, SPEEDS[s]) for r in runners for s, m in r.motions.items()}
    y = {k: mean_cycle(by_name[k[0]].motions[k[1]], t) for k, t in strikes.items()}
    phases = {k: frame_phase(by_name[k[0]].motions[k[1]].times, t) for k, t in strikes.items()}

    # how much of the mean cycle shape predicts: LORO over the training runners, and nested LORO over all 23
    model, penalty_scores = fit(train, x, y)
    explained_train = 1.0 - min(penalty_scores.values()) / penalty_scores[math.inf]
    keys = sorted(k for k in y if k[0] in set(train))
    full = Ridge(keys, x, y, PENALTIES[0])
    explained_in_sample = 1.0 - sum(np.mean((full.curve(x[r], s) - y[(r, s)]) ** 2) for r, s in keys) / sum(
        np.mean((full.y_mean[s] - y[(r, s)]) ** 2) for r, s in keys
    )
    feature_sets = {}  # sensitivity: smaller feature sets, LORO among the training runners
    for label, columns in (
        ("all five", slice(None)),
        ("log height", slice(0, 1)),
        ("log height, log mass", slice(0, 2)),
    ):
        scores = fit(train, {n: v[columns] for n, v in x.items()}, y)[1]
        best = min(FINITE, key=scores.__getitem__)
        feature_sets[label] = {"best_finite_penalty": best, "explained": 1.0 - scores[best] / scores[math.inf]}
    nested = []
    for runner in sorted(by_name):
        inner, _ = fit([n for n in by_name if n != runner], x, y)
        nested += [
            (
                np.mean((inner.curve(x[runner], s) - y[(runner, s)]) ** 2),
                np.mean((inner.y_mean[s] - y[(runner, s)]) ** 2),
            )
            for s in by_name[runner].motions
        ]
    explained_all = 1.0 - float(np.mean([e for e, _ in nested])) / float(np.mean([b for _, b in nested]))

    def oracle(a: Runner, b: Runner, speed: str) -> np.ndarray:
        return y[(b.name, speed)] - y[(a.name, speed)]

    def offset(a: Runner, b: Runner, speed: str) -> np.ndarray:  # the oracle's cycle mean per angle, a constant
        return np.broadcast_to(oracle(a, b, speed).mean(0), (POINTS, len(ANGLES)))

    forced, _ = fit(train, x, y, (FORCED,))
    held = score(
        pairs_of(scored, by_name),
        by_name,
        {
            "linear": lambda a, b, _: model.delta(x[a.name], x[b.name]),
            "forced": lambda a, b, _: forced.delta(x[a.name], x[b.name]),
            "oracle": oracle,
            "offset": offset,
        },
        phases,
    )

    fits: dict[tuple[frozenset[str], bool], Ridge] = {}

    def without_pair(finite: bool) -> Method:
        def method(a: Runner, b: Runner, speed: str) -> np.ndarray:
            key = (frozenset((a.name, b.name)), finite)
            if key not in fits:
                others = [n for n in by_name if n not in key[0]]
                fits[key] = fit(others, x, y, (FORCED,) if finite else PENALTIES)[0]
            return fits[key].delta(x[a.name], x[b.name])

        return method

    everyone = score(
        pairs_of(sorted(by_name), by_name),
        by_name,
        {"linear": without_pair(False), "forced": without_pair(True), "oracle": oracle, "offset": offset},
        phases,
    )
    folds = {}
    for b in sorted(by_name):
        rows = [r for r in everyone if r["b"] == b]
        folds[b] = {
            "pairs": len(rows),
            "linear": summary(rows, "linear")["gain_vs_copy"],
            "forced": summary(rows, "forced")["gain_vs_copy"],
            "oracle": summary(rows, "oracle")["gain_vs_copy"],
        }
    worst = min(folds, key=lambda b: folds[b]["linear"])

    methods = (
        ("copy", "copy A's angles (baseline)"),
        ("linear", "linear shape correction"),
        ("forced", f"linear, fixed penalty {FORCED:g} (forced shape effect, not selected)"),
        ("oracle", "oracle: B's own mean − A's own mean (upper bound, uses B's data)"),
        ("offset", "oracle, constant offset per angle only (uses B's data)"),
    )
    results = {
        f"held-out (fit on {len(train)} training runners)": held,
        f"all {len(by_name)} (fit without A and B)": everyone,
    }
    report = {
        "question": "how much of B's mean joint-angle cycle body shape predicts; does a linear shape correction "
        f"reach shape_dtw_gain_vs_copy >= {BAR}",
        "features": list(FEATURES),
        "training_runners": train,
        "scored_runners": scored,
        "penalty_chosen": model.penalty,
        "penalty_loro_mse_deg2": {str(p): v for p, v in penalty_scores.items()},
        "curve_variance_explained_by_shape_loro_train": explained_train,
        "curve_variance_explained_by_shape_nested_loro_all": explained_all,
        "penalty_forced": forced.penalty,
        "penalties_chosen_all_23": sorted(str(f.penalty) for (_, finite), f in fits.items() if not finite),
        "feature_sets_loro_train": feature_sets,
        "curve_variance_explained_in_sample_train": explained_in_sample,
        "summary": {scope: {m: summary(rows, m) for m, _ in methods} for scope, rows in results.items()},
        "per_speed": {
            scope: {s: {m: summary([r for r in rows if r["speed"] == s], m) for m, _ in methods} for s in SPEEDS}
            for scope, rows in results.items()
        },
        "folds_by_target_runner": folds,
        "worst_fold": {"runner": worst, **folds[worst]},
        "pair_rows": results,
        "skipped": skipped,
        "command": COMMAND,
    }
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.with_suffix(".json").write_text(json.dumps(report, indent=1) + "\n")
    lines = [
        "# Shape-only style correction: how far a linear shape-to-angle-cycle map gets (issue 48)",
        "",
        f"`{COMMAND}` (docs/decisions/shape-style-ceiling.md). Pairs and scoring of `biomotion eval shape` "
        "(`compare`: DTW of the ten hip/knee/ankle angles at 50 Hz, stride and cadence on B's model).",
        "",
        f"Shape features: {', '.join(FEATURES)}; speed an unpenalised fixed effect. Ridge fitted on the cache's "
        f"training runners ({', '.join(train)}), penalty {model.penalty:g} by leave-one-runner-out among them; "
        f"scored runners: {', '.join(scored)}.",
        "",
        "Between-runner variance of the mean cycle (about the speed mean) that shape predicts, leave-one-runner-out: "
        f"{explained_train:.3f} within the {len(train)} training runners (at the penalty that minimises it), "
        f"{explained_all:.3f} over all {len(by_name)} (nested: penalty chosen without the held runner). "
        "LORO mean squared error of the training runners' mean cycles (deg²) by penalty: "
        + ", ".join(f"{p:g}: {v:.1f}" for p, v in penalty_scores.items())
        + " (inf: the speed mean, no shape effect).",
        "",
        "Sensitivity, LORO among the training runners at the best finite penalty (negative: worse than the speed "
        "mean): "
        + "; ".join(
            f"{k} {v['explained']:+.3f} (penalty {v['best_finite_penalty']:g})" for k, v in feature_sets.items()
        )
        + f". In-sample (fitted and scored on the {len(train)} training runners, penalty {PENALTIES[0]:g}): "
        f"{explained_in_sample:+.3f}, an optimistic ceiling for these features. The forced rows use penalty "
        f"{FORCED:g} fixed a priori: the shape effect at near full strength, to show what it does when not shrunk "
        "away.",
        "",
        *table(results, methods),
        "",
        f"All {len(by_name)}, per target runner B (each a fold of about 9 pairs): worst linear gain "
        f"{folds[worst]['linear']:+.3f} "
        f"({worst}), median {statistics.median(f['linear'] for f in folds.values()):+.3f}, best "
        f"{max(f['linear'] for f in folds.values()):+.3f}; forced linear from "
        f"{min(f['forced'] for f in folds.values()):+.3f} to {max(f['forced'] for f in folds.values()):+.3f}; "
        "oracle from "
        f"{min(f['oracle'] for f in folds.values()):+.3f} to {max(f['oracle'] for f in folds.values()):+.3f}.",
        "",
        "| B | pairs | linear gain | forced linear gain | oracle gain |",
        "|---|---|---|---|---|",
        *(
            f"| {b} | {f['pairs']} | {f['linear']:+.3f} | {f['forced']:+.3f} | {f['oracle']:+.3f} |"
            for b, f in folds.items()
        ),
        "",
        "Skipped:",
        "",
        *(f"- {line}" for line in skipped),
    ]
    OUT.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"-> {OUT}.md, .json", file=sys.stderr)


if __name__ == "__main__":
    main()
