"""Musculotendon path geometry as smooth functions of the coordinates: lengths and moment arms, differentiable.

Each muscle's length is a multivariate polynomial in the coordinates it spans (a total-degree tensor-product
Chebyshev basis), fitted to lengths and moment arms
sampled from OpenSim's path geometry (via points, conditional and moving points, wrapping surfaces) by
`biomotion.muscles.fit_paths`. This is the approach of OpenSim's ``PolynomialPathFitter`` / ``FunctionBasedPath``
(OpenSim 4.5+, after van den Bogert et al. 2013, "An adaptive polynomial method for muscle path geometry",
J Biomech 46:1455, and Sobinov et al. 2020): the moment arm is ``r_j = -dL/dq_j`` (An et al. 1984, J Biomech
17:113), exact for the fitted function, so forces and torques stay consistent. Evaluating the functions needs only
torch; OpenSim is needed only to build them.

Coordinates are normalised per muscle group as ``x = (q - center) / half_range`` (so the sampled box is
[-1, 1]^k) and expanded in Chebyshev polynomials, which keeps high-degree least-squares fits well conditioned. Outside the sampled ranges the polynomials extrapolate, so
lengths there are unvalidated; `MusclePaths.ranges` gives the sampled box.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch

from biomotion.errors import DataFormatError, ModelError
from biomotion.io.atomic import atomic_write

FORMAT = "biomotion.muscle_paths/1"


@dataclass(frozen=True)
class PathGroup:
    """Muscles that span the same coordinates with polynomials of the same monomial basis."""
    coordinates: torch.Tensor   # [k] long, indices into MusclePaths.coordinate_names
    center: torch.Tensor        # [k]
    half_range: torch.Tensor    # [k]
    exponents: torch.Tensor     # [n_terms, k] long: Chebyshev degree of each coordinate in each term
    coefficients: torch.Tensor  # [n_terms, m] length (m) per basis term
    muscles: torch.Tensor       # [m] long, indices into MusclePaths.muscle_names

    def to(self, dtype: torch.dtype) -> PathGroup:
        return PathGroup(self.coordinates, self.center.to(dtype), self.half_range.to(dtype), self.exponents,
                         self.coefficients.to(dtype), self.muscles)


def chebyshev(x: torch.Tensor, degree: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Chebyshev polynomials T_0..T_degree at ``x`` and their derivatives, each [..., degree + 1]
    (T_{n+1} = 2x T_n - T_{n-1}; T_n' = n U_{n-1} with U_{n+1} = 2x U_n - U_{n-1})."""
    t = [torch.ones_like(x), x]
    u = [torch.ones_like(x), 2 * x]
    for _ in range(degree - 1):  # loop over polynomial degree, vectorised over everything else
        t.append(2 * x * t[-1] - t[-2])
        u.append(2 * x * u[-1] - u[-2])
    values = torch.stack(t[:degree + 1], -1)
    derivatives = torch.stack([torch.zeros_like(x)] + [n * u[n - 1] for n in range(1, degree + 1)], -1)
    return values, derivatives


def basis(x: torch.Tensor, exponents: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Tensor-product Chebyshev basis ``prod_j T_{e_j}(x_j)`` [..., n_terms] and its derivatives
    [..., n_terms, k] at normalised coordinates ``x`` [..., k]."""
    k = x.shape[-1]
    degree = max(int(exponents.max()) if exponents.numel() else 0, 1)
    values, slopes = chebyshev(x, degree)                              # [..., k, d+1]
    columns = torch.arange(k)
    factors = values[..., columns, exponents]                           # [..., n_terms, k]
    factor_slopes = slopes[..., columns, exponents]
    derivatives = []
    for j in range(k):  # k <= a handful of coordinates; vectorised over frames and terms
        others = torch.cat([factors[..., :j], factors[..., j + 1:]], -1).prod(-1)
        derivatives.append(factor_slopes[..., j] * others)
    return factors.prod(-1), torch.stack(derivatives, -1)


@dataclass(frozen=True)
class MusclePaths:
    """Fitted path functions of one model: ``lengths(q)`` [..., M] (m), ``moment_arms(q)`` [..., M, n_q] (m).

    ``q`` holds all of the model's coordinates in OpenSim CoordinateSet order (``coordinate_names``), in rad or m;
    coordinates that no muscle spans are ignored, and coupled coordinates (e.g. Rajagopal's knee_angle_beta) are
    folded into their independent coordinate, whose moment arm is the total derivative.
    """
    model: str
    muscle_names: tuple[str, ...]
    coordinate_names: tuple[str, ...]
    groups: tuple[PathGroup, ...]
    ranges: torch.Tensor        # [n_q, 2] the box the fit was sampled in (NaN where no muscle spans)
    info: dict

    @property
    def n_muscles(self) -> int:
        return len(self.muscle_names)

    @property
    def n_q(self) -> int:
        return len(self.coordinate_names)

    @property
    def dtype(self) -> torch.dtype:
        return self.ranges.dtype

    def to(self, dtype: torch.dtype) -> MusclePaths:
        return MusclePaths(self.model, self.muscle_names, self.coordinate_names,
                           tuple(g.to(dtype) for g in self.groups), self.ranges.to(dtype), self.info)

    def spanned(self) -> torch.Tensor:
        """[M, n_q] bool: which coordinates each muscle's path function depends on."""
        mask = torch.zeros(self.n_muscles, self.n_q, dtype=torch.bool)
        for g in self.groups:
            mask[g.muscles[:, None], g.coordinates[None, :]] = True
        return mask

    def lengths_and_moment_arms(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Musculotendon lengths [..., M] and moment arms ``-dL/dq`` [..., M, n_q] at coordinates ``q``."""
        self._check(q)
        batch = q.shape[:-1]
        lengths = q.new_zeros(*batch, self.n_muscles)
        arms = q.new_zeros(*batch, self.n_muscles, self.n_q)
        for g in self.groups:
            x = (q[..., g.coordinates] - g.center.to(q.dtype)) / g.half_range.to(q.dtype)
            values, derivatives = basis(x, g.exponents)
            coefficients = g.coefficients.to(q.dtype)
            lengths = lengths.index_copy(-1, g.muscles, values @ coefficients)
            dl_dx = torch.einsum("...tk,tm->...mk", derivatives, coefficients)       # [..., m, k]
            block = -dl_dx / g.half_range.to(q.dtype)
            rows = arms.new_zeros(*batch, len(g.muscles), self.n_q).index_copy(-1, g.coordinates, block)
            arms = arms.index_copy(-2, g.muscles, rows)
        return lengths, arms

    def lengths(self, q: torch.Tensor) -> torch.Tensor:
        return self.lengths_and_moment_arms(q)[0]

    def moment_arms(self, q: torch.Tensor) -> torch.Tensor:
        return self.lengths_and_moment_arms(q)[1]

    def lengthening_speeds(self, q: torch.Tensor, qdot: torch.Tensor) -> torch.Tensor:
        """dL/dt [..., M] = -sum_j r_j qdot_j (m/s)."""
        _, arms = self.lengths_and_moment_arms(q)
        return -(arms @ qdot[..., None])[..., 0]

    def select(self, coordinate_names: tuple[str, ...] | list[str]) -> torch.Tensor:
        """Column indices of ``coordinate_names`` in this model's coordinate order."""
        index = {n: i for i, n in enumerate(self.coordinate_names)}
        missing = [n for n in coordinate_names if n not in index]
        if missing:
            raise ModelError(f"muscle paths of {self.model!r} have no coordinates {missing}")
        return torch.tensor([index[n] for n in coordinate_names])

    def _check(self, q: torch.Tensor) -> None:
        if q.shape[-1] != self.n_q:
            raise ModelError(f"q must have {self.n_q} coordinates (the order of {self.model!r}), got {q.shape[-1]}")

    # ---- persistence -----------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the path functions to a .safetensors file (atomically)."""
        from safetensors.torch import save

        tensors = {"ranges": self.ranges.to(torch.float64).contiguous()}
        for i, g in enumerate(self.groups):
            tensors.update({f"group{i}.coordinates": g.coordinates, f"group{i}.center": g.center.double(),
                            f"group{i}.half_range": g.half_range.double(), f"group{i}.exponents": g.exponents,
                            f"group{i}.coefficients": g.coefficients.double().contiguous(),
                            f"group{i}.muscles": g.muscles})
        metadata = {"format": FORMAT, "model": self.model, "muscles": json.dumps(list(self.muscle_names)),
                    "coordinates": json.dumps(list(self.coordinate_names)), "groups": str(len(self.groups)),
                    "info": json.dumps(self.info)}
        with atomic_write(path, "wb") as handle:
            handle.write(save(tensors, metadata=metadata))

    @classmethod
    def load(cls, path: str | Path, dtype: torch.dtype = torch.float64) -> MusclePaths:
        """Read path functions written by `save` (e.g. the shipped ``biomotion/muscles/paths/*.safetensors``)."""
        from safetensors import SafetensorError, safe_open

        path = Path(path)
        try:
            with safe_open(str(path), framework="pt") as handle:
                meta = handle.metadata() or {}
                tensors = {k: handle.get_tensor(k) for k in handle.keys()}
        except (OSError, ValueError, SafetensorError) as exc:
            raise DataFormatError(path, f"not a readable safetensors file: {exc}") from exc
        if meta.get("format") != FORMAT:
            raise DataFormatError(path, f"not a muscle-path file (format {meta.get('format')!r})", field="format")
        try:
            groups = tuple(PathGroup(*(tensors[f"group{i}.{name}"] for name in
                                       ("coordinates", "center", "half_range", "exponents", "coefficients",
                                        "muscles")))
                           for i in range(int(meta["groups"])))
            return cls(meta["model"], tuple(json.loads(meta["muscles"])), tuple(json.loads(meta["coordinates"])),
                       groups, tensors["ranges"], json.loads(meta["info"])).to(dtype)
        except KeyError as exc:
            raise DataFormatError(path, f"missing entry {exc.args[0]!r}", field=str(exc.args[0])) from exc


PATHS_DIR = Path(__file__).resolve().parent / "paths"


def shipped_paths(name: str, dtype: torch.dtype = torch.float64) -> MusclePaths:
    """Path functions shipped with biomotion: ``"rajagopal2016"`` or ``"gait2392_subject01"``."""
    path = PATHS_DIR / f"{name}.safetensors"
    if not path.exists():
        available = sorted(p.stem for p in PATHS_DIR.glob("*.safetensors"))
        raise ModelError(f"no shipped muscle paths named {name!r}; available: {available}")
    return MusclePaths.load(path, dtype)
