"""Build step: fit polynomial path functions to OpenSim's muscle geometry and write them as .safetensors.

    python -m biomotion.muscles.fit_paths --model MODEL.osim --out FILE.safetensors [--samples N] [--seed S]
                                          [--range COORD=LO:HI ...]

OpenSim (the ``validate`` extra) is the oracle here and only here: it samples musculotendon lengths at random
poses drawn uniformly in the box of coordinate ranges (the model's ranges unless ``--range`` narrows them), with
moment arms from central differences of those lengths. Coupled coordinates follow their coupler function and
locked coordinates are unlocked, so each muscle's length is a function of the independent coordinates it spans.
Each muscle then gets the total-degree polynomial (Chebyshev basis) (see `biomotion.muscles.geometry`) that fits lengths and moment
arms jointly by least squares; the degree is chosen per muscle by held-out moment-arm error, as in OpenSim's
``PolynomialPathFitter`` (which also fits lengths and moment arms jointly, up to a maximum order).
"""

from __future__ import annotations

import argparse
import math
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

from biomotion.errors import ConfigError
from biomotion.muscles.geometry import MusclePaths, PathGroup, basis

FD_STEP = 1e-5        # rad (or m): central-difference step for moment arms
SPAN_TOLERANCE = 1e-5  # m: a coordinate is spanned if its moment arm exceeds this at some probe pose
MAX_TERMS = 500


class OpenSimPaths:
    """Musculotendon lengths and moment arms of an .osim model from OpenSim (the oracle; needs ``opensim``)."""

    def __init__(self, model_path: str | Path) -> None:
        import opensim

        opensim.Logger.setLevelString("error")
        self.opensim = opensim
        self.model = opensim.Model(str(model_path))
        coordinate_set = self.model.getCoordinateSet()
        self.coordinates = [coordinate_set.get(i) for i in range(coordinate_set.getSize())]
        for c in self.coordinates:
            c.set_locked(False)
        self.state = self.model.initSystem()
        self.coordinate_names = tuple(c.getName() for c in self.coordinates)
        muscles = self.model.getMuscles()
        self.muscles = [muscles.get(i) for i in range(muscles.getSize())]
        self.muscle_names = tuple(m.getName() for m in self.muscles)
        self.paths = [m.getGeometryPath() for m in self.muscles]
        self.couplers = []   # (dependent index, independent index, function, scale)
        constraints = self.model.getConstraintSet()
        index = {n: i for i, n in enumerate(self.coordinate_names)}
        for i in range(constraints.getSize()):
            coupler = opensim.CoordinateCouplerConstraint.safeDownCast(constraints.get(i))
            if coupler is not None and coupler.get_isEnforced():
                self.couplers.append((index[coupler.getDependentCoordinateName()],
                                      index[coupler.getIndependentCoordinateNames().get(0)],
                                      coupler.getFunction(), float(coupler.getPropertyByName("scale_factor").toString())))
        self.dependent = {d for d, _, _, _ in self.couplers}
        self.ranges = np.array([[c.getRangeMin(), c.getRangeMax()] for c in self.coordinates])
        self.defaults = np.array([c.getDefaultValue() for c in self.coordinates])

    def _set(self, q: np.ndarray) -> None:
        q = q.copy()
        for dependent, independent, function, scale in self.couplers:
            q[dependent] = scale * function.calcValue(self.opensim.Vector(1, float(q[independent])))
        for c, value in zip(self.coordinates, q):
            c.setValue(self.state, float(value), False)
        self.model.realizePosition(self.state)

    def lengths(self, q: np.ndarray) -> np.ndarray:
        """[N, M] lengths at poses ``q`` [N, n_q] (dependent coordinates are overwritten by their couplers)."""
        out = np.empty((len(q), len(self.paths)))
        for n, pose in enumerate(q):
            self._set(pose)
            out[n] = [p.getLength(self.state) for p in self.paths]
        return out

    def difference_moment_arms(self, q: np.ndarray, columns: list[int]) -> np.ndarray:
        """[N, M, len(columns)] moment arms -dL/dq by central differences (total derivative through couplers)."""
        out = np.empty((len(q), len(self.paths), len(columns)))
        for j, column in enumerate(columns):
            step = np.zeros(q.shape[1])
            step[column] = FD_STEP
            out[:, :, j] = -(self.lengths(q + step) - self.lengths(q - step)) / (2 * FD_STEP)
        return out

    def moment_arms(self, q: np.ndarray, pairs: list[tuple[int, int]]) -> np.ndarray:
        """[N, len(pairs)] OpenSim's own moment arms (``GeometryPath.computeMomentArm``) for (muscle, coordinate)."""
        out = np.empty((len(q), len(pairs)))
        for n, pose in enumerate(q):
            self._set(pose)
            out[n] = [self.paths[m].computeMomentArm(self.state, self.coordinates[c]) for m, c in pairs]
        return out

    def sample_poses(self, ranges: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
        """[n, n_q] poses uniform in ``ranges`` where finite, default values elsewhere."""
        q = np.tile(self.defaults, (n, 1))
        free = np.isfinite(ranges).all(1)
        q[:, free] = rng.uniform(ranges[free, 0], ranges[free, 1], size=(n, int(free.sum())))
        return q


def exponent_table(k: int, degree: int) -> np.ndarray:
    """[n_terms, k] per-coordinate degrees of all basis terms of total degree <= ``degree`` in ``k`` variables."""
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
    return values.numpy(), -(derivatives.numpy() / half)   # moment-arm rows: -dM/dq


def fit_muscle(x: np.ndarray, lengths: np.ndarray, arms: np.ndarray, x_test: np.ndarray, lengths_test: np.ndarray,
               arms_test: np.ndarray, half: np.ndarray, max_degree: int = 14) -> tuple[np.ndarray, np.ndarray, dict]:
    """Best polynomial (exponents, coefficients, report) for one muscle: x [N, k] normalised coordinates,
    lengths [N], arms [N, k]; the degree minimises the held-out moment-arm RMSE (worst coordinate)."""
    k = x.shape[1]
    best = None
    for degree in range(1, max_degree + 1):
        exponents = exponent_table(k, degree)
        if len(exponents) > MAX_TERMS or len(exponents) * 4 > len(x) * (1 + k):
            break
        values, rows = _design(x, exponents, half)
        a = np.concatenate([values, rows.transpose(0, 2, 1).reshape(-1, len(exponents))])
        b = np.concatenate([lengths, arms.reshape(-1)])
        coefficients = np.linalg.lstsq(a, b, rcond=None)[0]
        test_values, test_rows = _design(x_test, exponents, half)
        arm_error = np.sqrt(((np.einsum("ntk,t->nk", test_rows, coefficients) - arms_test) ** 2).mean(0)).max()
        length_error = np.sqrt(((test_values @ coefficients - lengths_test) ** 2).mean())
        if best is None or arm_error < best[2]["moment_arm_rmse_m"]:
            best = (exponents, coefficients, {"degree": degree, "moment_arm_rmse_m": float(arm_error),
                                              "length_rmse_m": float(length_error)})
    return best


def fit_paths(model_path: str | Path, samples: int = 3000, seed: int = 0,
              ranges: dict[str, tuple[float, float]] | None = None) -> MusclePaths:
    """Sample OpenSim's geometry of ``model_path`` and fit one polynomial per muscle (see module docstring)."""
    oracle = OpenSimPaths(model_path)
    rng = np.random.default_rng(seed)
    box = oracle.ranges.copy()
    for name, (low, high) in (ranges or {}).items():
        if name not in oracle.coordinate_names:
            raise ConfigError(f"--range: {model_path} has no coordinate {name!r}")
        box[oracle.coordinate_names.index(name)] = (low, high)
    candidates = [i for i in range(len(oracle.coordinates)) if i not in oracle.dependent]
    probe = oracle.sample_poses(box, 24, rng)
    probe_arms = np.abs(oracle.difference_moment_arms(probe, candidates)).max(0)   # [M, C]
    spans = [tuple(candidates[j] for j in np.flatnonzero(row > SPAN_TOLERANCE)) for row in probe_arms]
    used = sorted({c for s in spans for c in s})
    sampled = np.full_like(box, np.nan)
    sampled[used] = box[used]

    n_test = samples // 4
    q = oracle.sample_poses(sampled, samples + n_test, rng)
    lengths = oracle.lengths(q)
    arms = oracle.difference_moment_arms(q, used)
    column = {c: j for j, c in enumerate(used)}

    fits = defaultdict(list)   # (coordinates, degree) -> [(muscle, coefficients)]
    exponents_of, report = {}, {}
    for m, span in enumerate(spans):
        if not span:
            raise ConfigError(f"{model_path}: muscle {oracle.muscle_names[m]!r} spans no coordinate")
        center = box[list(span)].mean(1)
        half = (box[list(span), 1] - box[list(span), 0]) / 2
        x = (q[:, list(span)] - center) / half
        cols = [column[c] for c in span]
        exponents, coefficients, rep = fit_muscle(x[:samples], lengths[:samples, m], arms[:samples, m][:, cols],
                                                  x[samples:], lengths[samples:, m], arms[samples:, m][:, cols],
                                                  half)
        fits[(span, rep["degree"])].append((m, coefficients))
        exponents_of[(span, rep["degree"])] = (exponents, center, half)
        report[oracle.muscle_names[m]] = {"coordinates": [oracle.coordinate_names[c] for c in span], **rep}

    groups = []
    for key, members in fits.items():
        exponents, center, half = exponents_of[key]
        groups.append(PathGroup(torch.tensor(key[0]), torch.from_numpy(center), torch.from_numpy(half),
                                torch.from_numpy(exponents), torch.from_numpy(np.stack([c for _, c in members], 1)),
                                torch.tensor([m for m, _ in members])))
    worst = max(report.values(), key=lambda r: r["moment_arm_rmse_m"])
    info = {"source": Path(model_path).name, "opensim": oracle.opensim.__version__, "samples": samples,
            "held_out": n_test, "seed": seed, "fd_step": FD_STEP, "muscles": report,
            "worst_held_out_moment_arm_rmse_m": worst["moment_arm_rmse_m"]}
    return MusclePaths(oracle.model.getName(), oracle.muscle_names, oracle.coordinate_names, tuple(groups),
                       torch.from_numpy(sampled), info)


def _parse_range(text: str) -> tuple[str, tuple[float, float]]:
    try:
        name, bounds = text.split("=")
        low, high = (float(v) for v in bounds.split(":"))
    except ValueError as exc:
        raise ConfigError(f"--range expects COORD=LO:HI in rad or m, got {text!r}") from exc
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise ConfigError(f"--range {text!r}: need finite LO < HI")
    return name, (low, high)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m biomotion.muscles.fit_paths", description=__doc__.split("\n")[0])
    parser.add_argument("--model", required=True, help=".osim model")
    parser.add_argument("--out", required=True, help="output .safetensors")
    parser.add_argument("--samples", type=int, default=3000, help="training poses (plus 25%% held out)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--range", action="append", default=[], metavar="COORD=LO:HI",
                        help="sample COORD in [LO, HI] (rad or m) instead of its model range")
    args = parser.parse_args(argv)
    paths = fit_paths(args.model, args.samples, args.seed, dict(_parse_range(r) for r in args.range))
    paths.save(args.out)
    info = paths.info
    print(f"{paths.n_muscles} muscles, {len(paths.groups)} groups; worst held-out moment-arm RMSE "
          f"{info['worst_held_out_moment_arm_rmse_m'] * 1000:.3f} mm -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
