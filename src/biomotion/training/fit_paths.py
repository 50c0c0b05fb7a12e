"""Build step: fit polynomial path functions to OpenSim's muscle geometry and write them as .safetensors.

    biomotion train paths --model MODEL.osim --out FILE.safetensors [--samples N] [--seed S]
                          [--range COORD=LO:HI ...]

The shipped files were made with the defaults (``--samples 6000 --seed 0``) from the data root ``../shared/data``;
Rajagopal2016 in its own coordinate ranges, gait2392 (whose model ranges are far wider than a person moves) in
Rajagopal2016's ranges, rounded to 4 decimals::

    OMP_NUM_THREADS=1 biomotion train paths \
        --model ../shared/data/opensim-models/Models/Rajagopal/Rajagopal2016.osim \
        --out src/biomotion/muscles/paths/rajagopal2016.safetensors
    OMP_NUM_THREADS=1 biomotion train paths \
        --model ../shared/data/opensim-models/Pipelines/Gait2392_Simbody/OutputReference/subject01_simbody.osim \
        --out src/biomotion/muscles/paths/gait2392_subject01.safetensors \
        --range hip_flexion_r=-0.5236:2.0944 --range hip_adduction_r=-0.8727:0.5236 \
        --range hip_rotation_r=-0.6981:0.6981 --range ankle_angle_r=-0.6981:0.5236 \
        --range subtalar_angle_r=-0.3491:0.3491 --range mtp_angle_r=-0.5236:0.5236 \
        --range hip_flexion_l=-0.5236:2.0944 --range hip_adduction_l=-0.8727:0.5236 \
        --range hip_rotation_l=-0.6981:0.6981 --range ankle_angle_l=-0.6981:0.5236 \
        --range subtalar_angle_l=-0.3491:0.3491 --range mtp_angle_l=-0.5236:0.5236 \
        --range lumbar_extension=-0.5236:0.5236 --range lumbar_bending=-0.5236:0.5236 \
        --range lumbar_rotation=-0.5236:0.5236

The two fits took 8 and 5 minutes run side by side on a shared 2-core machine (``info["fit_seconds"]`` in
each file); ``info`` also records the samples, seed, ranges and each muscle's held-out result. Validation
(`biomotion.validation.muscles.moment_arm_errors`) draws fresh poses from another seed.

OpenSim (the ``validate`` extra) is the oracle here and only here: it samples musculotendon lengths
(``GeometryPath.getLength``) and moment arms (``GeometryPath.computeMomentArm``) at random poses drawn uniformly
in the box of coordinate ranges (the model's ranges unless ``--range`` narrows them), 25% of them held out.
Coupled coordinates follow their coupler function and locked coordinates are unlocked, so each muscle's length is
a function of the independent coordinates it spans (found from central differences of the length at probe poses).
As in OpenSim's ``PolynomialPathFitter``, the targets are OpenSim's own moment arms, not differences of its
lengths: where two wrap cylinders act in series (Rajagopal's gastrocnemii over the femoral condyles)
``computeMomentArm`` -- the moment arm OpenSim's muscle forces act with -- differs from ``-dL/dq`` of OpenSim's
length by up to ~2 cm, and the joint least-squares fit then trades ~1 mm of length for the moment arms.

Each muscle gets the total-degree Chebyshev polynomial (see `biomotion.muscles.geometry`) fitted to lengths and
moment arms jointly by least squares; the degree minimises the held-out moment-arm RMSE (worst coordinate).
Where that stays above ``PIECEWISE_ABOVE`` and OpenSim's path takes several configurations (which via points are
active; which wrap objects touch the path, between which points and on which side), the path may jump between
configurations (a conditional via point switching, a quadrant-limited wrap cylinder snapping on or flipping side),
which no single polynomial can follow. Such a muscle is then also fitted piecewise: the boundaries between
configurations are located by bisection between neighbouring samples of different configuration (with extra
samples around them, more still around rarely seen configurations, and EXTRA_TRAIN more poses of that muscle
alone, half of them Chebyshev-distributed towards the faces of the box), each configuration gets its own polynomial,
and a multinomial logistic gate (polynomial scores in the same basis) picks the configuration at each pose. The
piecewise model is kept where its error on a larger held-out set (EXTRA_HELD_OUT more uniform poses), gate
predictions included, beats the single polynomial's. Its residual error comes from poses within a few thousandths
of the normalised range of a jump, where the gate can pick the wrong side: on Rajagopal's glmax1 about 1 pose in
1000 then errs by 1-4 cm, so while the RMSE over thousands of poses is ~1 mm, a 200-pose RMSE can exceed 2 mm.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.errors import ConfigError
from biomotion.muscles.geometry import MusclePaths, PathGroup, basis
from biomotion.muscles.opensim_paths import OpenSimPaths

SPAN_TOLERANCE = 1e-5  # m: a coordinate is spanned if its length derivative exceeds this at some probe pose
MAX_TERMS = 500  # most basis terms of one polynomial (total degree 12 in 3 coordinates, 8 in 4)
MAX_DEGREE = 14
PIECEWISE_ABOVE = 1e-3  # m: held-out moment-arm RMSE above which a multi-configuration muscle is fitted piecewise
NEIGHBOURS = 8  # boundary search: pairs of k-nearest training samples whose configurations differ
BISECTION_STEPS = 10  # boundary brackets 2^-10 of the neighbour distance wide
BALL_SAMPLES = 1  # extra samples around each differing pair
RARE_BELOW = 400  # configurations seen fewer times (train + boundary samples) get extra samples around them
RARE_BALL = 8  # ... this many per sample, within RARE_RADIUS (normalised coordinates)
RARE_RADIUS = 0.15
MIN_PIECE = 20  # configurations seen fewer times get no piece of their own
GATE_DEGREES = (4, 6, 8)
OTHER_WEIGHT = 1e-3  # weight of other configurations' samples in a piece's fit (tames its extrapolation)
EXTRA_TRAIN = 8000  # piecewise candidates: extra training poses of the muscle alone
EXTRA_HELD_OUT = 4000  # ... and extra held-out poses


def exponent_table(k: int, degree: int) -> np.ndarray:
    """[n_terms, k] per-coordinate degrees of all basis terms of total degree <= ``degree`` in ``k`` variables,
    ordered by total degree (so the table of a lower degree is a prefix of this one)."""

    def compositions(k: int, budget: int):
        if k == 0:
            yield ()
            return
        for e in range(budget + 1):
            for rest in compositions(k - 1, budget - e):
                yield (e, *rest)

    rows = sorted(compositions(k, degree), key=lambda e: (sum(e), tuple(-v for v in e)))
    return np.array(rows, dtype=np.int64).reshape(-1, k)


def _design(x: np.ndarray, exponents: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    values, derivatives = basis(torch.from_numpy(x), torch.from_numpy(exponents))
    return values.numpy(), -(derivatives.numpy() / half)  # moment-arm rows: -dM/dq


def _max_degree(k: int, rows: int) -> int:
    """Highest total degree within MAX_TERMS and with at least 4 fitted values per coefficient."""
    degree = 0
    while degree < MAX_DEGREE and len(exponent_table(k, degree + 1)) <= min(MAX_TERMS, rows / 4):
        degree += 1
    return degree


class _JointFit:
    """Weighted least squares of lengths and moment arms for every degree up to ``degree`` from one Gram matrix
    (the total-degree tables are nested, so each degree's system is a leading block)."""

    def __init__(
        self,
        x: np.ndarray,
        lengths: np.ndarray,
        arms: np.ndarray,
        half: np.ndarray,
        degree: int,
        weights: np.ndarray | None = None,
    ) -> None:
        self.k, self.degree, self.half = x.shape[1], degree, half
        self.exponents = exponent_table(self.k, degree)
        values, rows = _design(x, self.exponents, half)
        w = np.ones(len(x)) if weights is None else weights
        rows = rows.transpose(0, 2, 1).reshape(-1, len(self.exponents))  # [N * k, t]
        w_rows = np.repeat(w, self.k)
        self.gram = (values * w[:, None]).T @ values + (rows * w_rows[:, None]).T @ rows
        self.rhs = (values * w[:, None]).T @ lengths + (rows * w_rows[:, None]).T @ arms.reshape(-1)

    def coefficients(self, degree: int) -> np.ndarray:
        n = len(exponent_table(self.k, degree))
        gram = self.gram[:n, :n]
        ridge = 1e-13 * np.trace(gram) / n
        return np.linalg.solve(gram + ridge * np.eye(n), self.rhs[:n])


def _errors(arms: np.ndarray, reference: np.ndarray) -> np.ndarray:
    return np.sqrt(((arms - reference) ** 2).mean(0))


def fit_muscle(
    x: np.ndarray,
    lengths: np.ndarray,
    arms: np.ndarray,
    x_test: np.ndarray,
    lengths_test: np.ndarray,
    arms_test: np.ndarray,
    half: np.ndarray,
    weights: np.ndarray | None = None,
    test_mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Best polynomial (exponents, coefficients, report) for one muscle: x [N, k] normalised coordinates,
    lengths [N], arms [N, k]; the degree minimises the held-out moment-arm RMSE (worst coordinate) over the
    held-out samples (those in ``test_mask`` when given)."""
    k = x.shape[1]
    top = _max_degree(k, len(x) * (1 + k) if weights is None else int((weights > 0.5).sum()) * (1 + k))
    fit = _JointFit(x, lengths, arms, half, top, weights)
    if test_mask is not None:
        x_test, lengths_test, arms_test = x_test[test_mask], lengths_test[test_mask], arms_test[test_mask]
    test_values, test_rows = _design(x_test, fit.exponents, half)
    best = None
    for degree in range(1, top + 1):
        coefficients = fit.coefficients(degree)
        n = len(coefficients)
        if len(x_test):
            arm_error = _errors(np.einsum("ntk,t->nk", test_rows[:, :n], coefficients), arms_test).max()
            length_error = np.sqrt(((test_values[:, :n] @ coefficients - lengths_test) ** 2).mean())
        else:  # no held-out sample of this piece: take the highest degree the samples support
            arm_error = length_error = 0.0
        if best is None or arm_error <= best[2]["moment_arm_rmse_m"]:
            best = (
                fit.exponents[:n],
                coefficients,
                {"degree": degree, "moment_arm_rmse_m": float(arm_error), "length_rmse_m": float(length_error)},
            )
    return best


def fit_gate(x: np.ndarray, labels: np.ndarray, n_classes: int, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Multinomial logistic regression on the Chebyshev basis of total degree ``degree``: (exponents, weights
    [n_terms, n_classes]); the predicted class is the argmax of the basis values times the weights."""
    exponents = exponent_table(x.shape[1], degree)
    features = basis(torch.from_numpy(x), torch.from_numpy(exponents))[0]
    weights = torch.zeros(len(exponents), n_classes, dtype=torch.float64, requires_grad=True)
    target = torch.from_numpy(labels)
    optimizer = torch.optim.LBFGS(
        [weights],
        max_iter=200,
        history_size=50,
        line_search_fn="strong_wolfe",
        tolerance_grad=1e-10,
        tolerance_change=1e-14,
    )

    def closure():
        optimizer.zero_grad()
        loss = torch.nn.functional.cross_entropy(features @ weights, target) + 1e-6 * (weights**2).sum()
        loss.backward()
        return loss

    for _ in range(5):
        optimizer.step(closure)
    return exponents, weights.detach().numpy()


def _gate_predict(x: np.ndarray, exponents: np.ndarray, weights: np.ndarray) -> np.ndarray:
    return (basis(torch.from_numpy(x), torch.from_numpy(exponents))[0].numpy() @ weights).argmax(1)


def _bisect(oracle: OpenSimPaths, m: int, a: np.ndarray, b: np.ndarray, ca: str) -> tuple[np.ndarray, np.ndarray]:
    """Bracket [a, b] (poses, ``a`` in configuration ``ca``, ``b`` not) narrowed BISECTION_STEPS times."""
    for _ in range(BISECTION_STEPS):
        middle = (a + b) / 2
        oracle._set(middle)
        if oracle.configuration(m) == ca:
            a = middle
        else:
            b = middle
    return a, b


def _boundary_samples(
    oracle: OpenSimPaths,
    m: int,
    span: list[int],
    q: np.ndarray,
    x: np.ndarray,
    configurations: list[str],
    center: np.ndarray,
    half: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Extra samples of muscle ``m`` at the boundaries between its configurations: for each pair of
    neighbouring samples in different configurations, the two ends of the bisected bracket and BALL_SAMPLES
    random poses around the pair. Configurations seen fewer than RARE_BELOW times (small regions, often in a
    corner of the box) then get RARE_BALL samples around each of their samples and a second round of
    bisection. Returns poses, lengths, moment arms and configurations."""
    from scipy.spatial import cKDTree

    def ball(pose: np.ndarray, middle: np.ndarray, radius: float) -> np.ndarray:
        direction = rng.normal(size=len(span))
        out = pose.copy()
        out[span] = center + half * np.clip(
            middle + radius * rng.uniform() ** (1 / len(span)) * direction / np.linalg.norm(direction), -1, 1
        )
        return out

    def differing_pairs(xs: np.ndarray, found: list[str], keep) -> list[tuple[int, int]]:
        _, neighbours = cKDTree(xs).query(xs, k=min(NEIGHBOURS + 1, len(xs)))
        return sorted(
            {
                (min(i, j), max(i, j))
                for i in range(len(xs))
                for j in neighbours[i, 1:]
                if found[i] != found[j] and keep(i, j)
            }
        )

    def refine(qs: np.ndarray, xs: np.ndarray, found: list[str], pairs: list[tuple[int, int]]) -> np.ndarray:
        poses = []
        for i, j in pairs:
            b = qs[i].copy()
            b[span] = qs[j, span]
            poses += list(_bisect(oracle, m, qs[i].copy(), b, found[i]))
            poses += [ball(qs[i], (xs[i] + xs[j]) / 2, np.linalg.norm(xs[i] - xs[j]) / 2) for _ in range(BALL_SAMPLES)]
        return np.array(poses).reshape(-1, qs.shape[1])

    poses = refine(q, x, configurations, differing_pairs(x, configurations, lambda i, j: True))
    lengths, arms, found = oracle.muscle_samples(poses, m, span)
    names, counts = np.unique(list(configurations) + found, return_counts=True)
    rare = {str(n) for n, c in zip(names, counts) if c < RARE_BELOW}
    if rare:
        q_all = np.concatenate([q, poses])
        found_all = list(configurations) + found
        seeds = [i for i, c in enumerate(found_all) if c in rare]
        x_all = (q_all[:, span] - center) / half
        extra = np.array([ball(q_all[i], x_all[i], RARE_RADIUS) for i in seeds for _ in range(RARE_BALL)])
        extra_lengths, extra_arms, extra_found = oracle.muscle_samples(extra, m, span)
        q_all = np.concatenate([q_all, extra])
        found_all += extra_found
        x_all = (q_all[:, span] - center) / half
        second = refine(
            q_all,
            x_all,
            found_all,
            differing_pairs(x_all, found_all, lambda i, j: found_all[i] in rare or found_all[j] in rare),
        )
        second_lengths, second_arms, second_found = oracle.muscle_samples(second, m, span)
        poses = np.concatenate([poses, extra, second])
        lengths = np.concatenate([lengths, extra_lengths, second_lengths])
        arms = np.concatenate([arms, extra_arms, second_arms])
        found += extra_found + second_found
    return poses, lengths, arms, found


def fit_piecewise(
    oracle: OpenSimPaths,
    m: int,
    span: list[int],
    q: np.ndarray,
    x: np.ndarray,
    lengths: np.ndarray,
    arms: np.ndarray,
    configurations: list[str],
    x_test: np.ndarray,
    lengths_test: np.ndarray,
    arms_test: np.ndarray,
    configurations_test: list[str],
    center: np.ndarray,
    half: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict] | None:
    """Piecewise fit of muscle ``m`` (see the module docstring): (exponents, coefficients [n_terms, pieces],
    gate weights [n_terms, pieces], report), or None if fewer than two configurations are common enough."""
    extra_q, extra_lengths, extra_arms, extra_configurations = _boundary_samples(
        oracle, m, span, q, x, configurations, center, half, rng
    )
    x_all = np.concatenate([x, (extra_q[:, span] - center) / half])
    lengths_all = np.concatenate([lengths, extra_lengths])
    arms_all = np.concatenate([arms, extra_arms])
    found = list(configurations) + list(extra_configurations)
    names, counts = np.unique(found, return_counts=True)
    pieces = [str(n) for n, c in zip(names, counts) if c >= MIN_PIECE]
    if len(pieces) < 2:
        return None
    index = {n: i for i, n in enumerate(pieces)}
    label = np.array([index.get(c, -1) for c in found])
    label_test = np.array([index.get(c, -1) for c in configurations_test])

    fits = []
    for p in range(len(pieces)):
        weights = np.where(label == p, 1.0, OTHER_WEIGHT)
        fits.append(
            fit_muscle(
                x_all, lengths_all, arms_all, x_test, lengths_test, arms_test, half, weights, test_mask=label_test == p
            )
        )
    designs = [_design(x_test, e, half) for e, _, _ in fits]
    piece_lengths = np.stack([v @ c for (v, _), (_, c, _) in zip(designs, fits)])  # [P, N]
    piece_arms = np.stack([np.einsum("ntk,t->nk", r, c) for (_, r), (_, c, _) in zip(designs, fits)])  # [P, N, k]

    best = None
    known = label >= 0
    for degree in GATE_DEGREES:
        if len(exponent_table(len(span), degree)) > MAX_TERMS:
            break
        gate_exponents, gate = fit_gate(x_all[known], label[known], len(pieces), degree)
        chosen = _gate_predict(x_test, gate_exponents, gate)
        error = _errors(piece_arms[chosen, np.arange(len(x_test))], arms_test).max()
        if best is None or error < best[0]:
            length_error = np.sqrt(((piece_lengths[chosen, np.arange(len(x_test))] - lengths_test) ** 2).mean())
            best = (error, degree, gate_exponents, gate, float((chosen != label_test).mean()), float(length_error))
    error, gate_degree, gate_exponents, gate, wrong, length_error = best

    degree = max(gate_degree, *(r["degree"] for _, _, r in fits))
    exponents = exponent_table(len(span), degree)
    coefficients = np.zeros((len(exponents), len(pieces)))
    gates = np.zeros((len(exponents), len(pieces)))
    for p, (_, c, _) in enumerate(fits):
        coefficients[: len(c), p] = c
    gates[: len(gate_exponents)] = gate
    report = {
        "degree": degree,
        "moment_arm_rmse_m": float(error),
        "length_rmse_m": length_error,
        "pieces": pieces,
        "piece_degrees": [r["degree"] for _, _, r in fits],
        "gate_degree": gate_degree,
        "held_out_gate_errors": wrong,
        "boundary_samples": len(extra_q),
    }
    return exponents, coefficients, gates, report


def _muscle_poses(
    oracle: OpenSimPaths,
    m: int,
    span: list[int],
    base: np.ndarray,
    n: int,
    center: np.ndarray,
    half: np.ndarray,
    rng: np.random.Generator,
    arcsine: int = 0,
) -> tuple[np.ndarray, ...]:
    """``n`` poses of muscle ``m``'s coordinates (uniform, the first ``arcsine`` of them arcsine-distributed,
    i.e. Chebyshev-like and dense near the faces of the box) with its lengths, moment arms and configurations."""
    x = rng.uniform(-1, 1, size=(n, len(span)))
    x[:arcsine] = np.sin(np.pi / 2 * x[:arcsine])
    poses = np.tile(base, (n, 1))
    poses[:, span] = center + half * x
    return (poses, *oracle.muscle_samples(poses, m, span))


def fit_one_muscle(
    oracle: OpenSimPaths,
    m: int,
    span: list[int],
    q: np.ndarray,
    lengths: np.ndarray,
    arms: np.ndarray,
    configurations: list[str],
    samples: int,
    box: np.ndarray,
    rng: np.random.Generator,
    log=print,
) -> tuple[tuple, dict]:
    """Fit muscle ``m`` from poses ``q`` [N, n_q] (the first ``samples`` for training, the rest held out) with its
    lengths [N], moment arms [N, k] about ``span`` and configurations [N]; ``box`` [k, 2] is the sampled range of
    ``span``. Returns ((exponents, coefficients [t, c], gates [t, c] or None), report)."""
    center = box.mean(1)
    half = (box[:, 1] - box[:, 0]) / 2
    x = (q[:, span] - center) / half
    train, test = slice(0, samples), slice(samples, None)
    exponents, coefficients, rep = fit_muscle(
        x[train], lengths[train], arms[train], x[test], lengths[test], arms[test], half
    )
    fitted = (exponents, coefficients[:, None], None)
    if rep["moment_arm_rmse_m"] > PIECEWISE_ABOVE and len(set(configurations[train])) > 1:
        # more poses of this muscle alone: for training (half of them denser near the faces of the box) and
        # for a larger held-out set, on which the single polynomial and the piecewise fit are compared
        more_q, more_lengths, more_arms, more_configurations = _muscle_poses(
            oracle, m, span, q[0], EXTRA_TRAIN, center, half, rng, arcsine=EXTRA_TRAIN // 2
        )
        test_q, test_lengths, test_arms, test_configurations = _muscle_poses(
            oracle, m, span, q[0], EXTRA_HELD_OUT, center, half, rng
        )
        x_test = np.concatenate([x[test], (test_q[:, span] - center) / half])
        lengths_test = np.concatenate([lengths[test], test_lengths])
        arms_test = np.concatenate([arms[test], test_arms])
        single = _errors(np.einsum("ntk,t->nk", _design(x_test, exponents, half)[1], coefficients), arms_test).max()
        piecewise = fit_piecewise(
            oracle,
            m,
            span,
            np.concatenate([q[train], more_q]),
            np.concatenate([x[train], (more_q[:, span] - center) / half]),
            np.concatenate([lengths[train], more_lengths]),
            np.concatenate([arms[train], more_arms]),
            configurations[train] + more_configurations,
            x_test,
            lengths_test,
            arms_test,
            configurations[test] + test_configurations,
            center,
            half,
            rng,
        )
        if piecewise is not None:
            log(
                f"  {oracle.muscle_names[m]}: single polynomial {single * 1e3:.2f} mm, "
                f"{len(piecewise[3]['pieces'])} pieces {piecewise[3]['moment_arm_rmse_m'] * 1e3:.2f} mm"
            )
            if piecewise[3]["moment_arm_rmse_m"] < single:
                exponents, coefficients, gates, rep = (
                    piecewise[0],
                    piecewise[1],
                    piecewise[2],
                    {**piecewise[3], "single_polynomial_moment_arm_rmse_m": float(single), "held_out": len(x_test)},
                )
                fitted = (exponents, coefficients, gates)
    return fitted, rep


def fit_paths(
    model_path: str | Path,
    samples: int = 6000,
    seed: int = 0,
    ranges: dict[str, tuple[float, float]] | None = None,
    log=print,
) -> MusclePaths:
    """Sample OpenSim's geometry of ``model_path`` and fit one polynomial per muscle (see module docstring)."""
    started = time.perf_counter()
    oracle = OpenSimPaths(model_path)
    rng = np.random.default_rng(seed)
    box = oracle.ranges.copy()
    for name, (low, high) in (ranges or {}).items():
        if name not in oracle.coordinate_names:
            raise ConfigError(f"--range: {model_path} has no coordinate {name!r}")
        box[oracle.coordinate_names.index(name)] = (low, high)
    candidates = [i for i in range(len(oracle.coordinates)) if i not in oracle.dependent]
    probe = oracle.sample_poses(box, 24, rng)
    probe_arms = np.abs(oracle.difference_moment_arms(probe, candidates)).max(0)  # [M, C]
    spans = [[candidates[j] for j in np.flatnonzero(row > SPAN_TOLERANCE)] for row in probe_arms]
    for m, span in enumerate(spans):
        if not span:
            raise ConfigError(f"{model_path}: muscle {oracle.muscle_names[m]!r} spans no coordinate")
    used = sorted({c for s in spans for c in s})
    sampled = np.full_like(box, np.nan)
    sampled[used] = box[used]

    n_test = samples // 4
    q = oracle.sample_poses(sampled, samples + n_test, rng)
    lengths = oracle.lengths(q)
    pairs = [(m, c) for m, span in enumerate(spans) for c in span]
    flat = oracle.moment_arms(q, pairs)
    configurations = oracle.configurations(q)
    log(f"sampled {len(q)} poses ({time.perf_counter() - started:.0f} s)")

    by_span = defaultdict(list)  # coordinates -> [(muscle, exponents, coefficients [t, c], gates [t, c] or None)]
    report = {}
    start = 0
    for m, span in enumerate(tqdm(spans, desc="fitting muscles", unit="muscle", leave=False)):
        arms = flat[:, start : start + len(span)]
        start += len(span)
        fitted, rep = fit_one_muscle(
            oracle, m, span, q, lengths[:, m], arms, [c[m] for c in configurations], samples, box[span], rng, log
        )
        by_span[tuple(span)].append((m, *fitted))
        report[oracle.muscle_names[m]] = {"coordinates": [oracle.coordinate_names[c] for c in span], **rep}

    groups = []
    for span, members in by_span.items():  # one group per span: nested bases, padded to the highest degree
        exponents = max((e for _, e, _, _ in members), key=len)
        center = box[list(span)].mean(1)
        half = (box[list(span), 1] - box[list(span), 0]) / 2
        coefficients, gates, muscles = [], [], []
        for m, e, c, g in members:
            padded = np.zeros((len(exponents), c.shape[1]))
            padded[: len(e)] = c
            coefficients.append(padded)
            padded = np.zeros((len(exponents), c.shape[1]))
            if g is not None:
                padded[: len(g)] = g
            gates.append(padded)
            muscles += [m] * c.shape[1]
        gated = any(g is not None for _, _, _, g in members)
        groups.append(
            PathGroup(
                torch.tensor(span),
                torch.from_numpy(center),
                torch.from_numpy(half),
                torch.from_numpy(exponents),
                torch.from_numpy(np.concatenate(coefficients, 1)),
                torch.tensor(muscles),
                torch.from_numpy(np.concatenate(gates, 1)) if gated else None,
            )
        )
    worst = max(report.values(), key=lambda r: r["moment_arm_rmse_m"])
    info = {
        "source": Path(model_path).name,
        "source_sha256": hashlib.sha256(Path(model_path).read_bytes()).hexdigest(),
        "opensim": oracle.opensim.__version__,
        "samples": samples,
        "held_out": n_test,
        "seed": seed,
        "moment_arm_target": "GeometryPath.computeMomentArm",
        "ranges": {oracle.coordinate_names[c]: list(box[c]) for c in used},
        "fit_seconds": round(time.perf_counter() - started),
        "muscles": report,
        "worst_held_out_moment_arm_rmse_m": worst["moment_arm_rmse_m"],
    }
    return MusclePaths(
        oracle.model.getName(),
        oracle.muscle_names,
        oracle.coordinate_names,
        tuple(groups),
        torch.from_numpy(sampled),
        info,
    )


def parse_range(text: str) -> tuple[str, tuple[float, float]]:
    try:
        name, bounds = text.split("=")
        low, high = (float(v) for v in bounds.split(":"))
    except ValueError as exc:
        raise ConfigError(f"--range expects COORD=LO:HI in rad or m, got {text!r}") from exc
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise ConfigError(f"--range {text!r}: need finite LO < HI")
    return name, (low, high)
