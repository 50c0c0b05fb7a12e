"""Musculotendon path geometry as smooth functions of the coordinates: lengths and moment arms, differentiable.

Each muscle's length is a multivariate polynomial in the coordinates it spans (a total-degree tensor-product
Chebyshev basis), fitted to lengths and moment arms
sampled from OpenSim's path geometry (via points, conditional and moving points, wrapping surfaces) by
`biomotion.training.fit_paths`. This is the approach of OpenSim's ``PolynomialPathFitter`` / ``FunctionBasedPath``
(OpenSim 4.5+, after van den Bogert et al. 2013, "An adaptive polynomial method for muscle path geometry",
J Biomech 46:1455, and Sobinov et al. 2020): the moment arm is ``r_j = -dL/dq_j`` (An et al. 1984, J Biomech
17:113), exact for the fitted function, so forces and torques stay consistent. Evaluating the functions needs only
torch; OpenSim is needed only to build them.

Coordinates are normalised per muscle group as ``x = (q - center) / half_range`` (so the sampled box is
[-1, 1]^k) and expanded in Chebyshev polynomials, which keeps high-degree least-squares fits well conditioned. Outside
the sampled ranges the polynomials extrapolate, so lengths there are unvalidated; `MusclePaths.ranges` gives the
sampled box.

Piecewise paths: where OpenSim's path jumps between configurations (a conditional via point switching on or off,
a wrap cylinder with a quadrant constraint snapping on or flipping sides), the length is discontinuous or kinked
and no single polynomial fits it. Such a muscle gets one polynomial per path configuration ("piece") plus a gate
score polynomial per piece in the same basis (`PathGroup.gates`); at each pose the piece with the highest gate
score applies. Each piece is still an exact length function, so ``r = -dL/dq`` holds everywhere except on the
(measure-zero) piece boundaries, where OpenSim's own path jumps too.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch

from biomotion.errors import DataFormatError, ModelError
from biomotion.io.atomic import atomic_write

FORMAT = "biomotion.muscle_paths/2"
READABLE_FORMATS = ("biomotion.muscle_paths/1", FORMAT)  # /1: no gates


@dataclass(frozen=True)
class PathGroup:
    """Muscles that span the same coordinates with polynomials of the same Chebyshev basis.

    Each column of ``coefficients`` is one polynomial of the muscle ``muscles[column]``. A muscle normally has one
    column; a piecewise muscle has one per piece, and then ``gates`` (same basis) scores the pieces: at a pose the
    column with the highest gate score among that muscle's columns applies (see the module docstring).
    """

    coordinates: torch.Tensor  # [k] long, indices into MusclePaths.coordinate_names
    center: torch.Tensor  # [k]
    half_range: torch.Tensor  # [k]
    exponents: torch.Tensor  # [n_terms, k] long: Chebyshev degree of each coordinate in each term
    coefficients: torch.Tensor  # [n_terms, m] length (m) per basis term
    muscles: torch.Tensor  # [m] long, indices into MusclePaths.muscle_names
    gates: torch.Tensor | None = None  # [n_terms, m] gate score per basis term (None: one column per muscle)

    def to(self, dtype: torch.dtype) -> PathGroup:
        return PathGroup(
            self.coordinates,
            self.center.to(dtype),
            self.half_range.to(dtype),
            self.exponents,
            self.coefficients.to(dtype),
            self.muscles,
            None if self.gates is None else self.gates.to(dtype),
        )

    def active(self, values: torch.Tensor) -> torch.Tensor | None:
        """[..., m] 1.0 where a column applies at basis ``values`` [..., n_terms], 0.0 elsewhere (None: all apply).
        Among a muscle's columns the highest gate score wins; ties go to the first column."""
        if self.gates is None:
            return None
        scores = values @ self.gates.to(values)  # [..., m]
        m, device = len(self.muscles), values.device
        muscles = self.muscles.to(device)
        rivals = (muscles[:, None] == muscles[None, :]) & ~torch.eye(m, dtype=torch.bool, device=device)
        order = torch.arange(m, device=device)
        earlier = order[:, None] > order[None, :]  # [j, i]: i before j
        mine, theirs = scores[..., :, None], scores[..., None, :]
        loses = rivals & ((theirs > mine) | ((theirs == mine) & earlier))  # [..., j, i]
        return (~loses.any(-1)).to(values.dtype)


def chebyshev(x: torch.Tensor, degree: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Chebyshev polynomials T_0..T_degree at ``x`` and their derivatives, each [..., degree + 1]
    (T_{n+1} = 2x T_n - T_{n-1}; T_n' = n U_{n-1} with U_{n+1} = 2x U_n - U_{n-1})."""
    t = [torch.ones_like(x), x]
    u = [torch.ones_like(x), 2 * x]
    for _ in range(degree - 1):  # loop over polynomial degree, vectorised over everything else
        t.append(2 * x * t[-1] - t[-2])
        u.append(2 * x * u[-1] - u[-2])
    values = torch.stack(t[: degree + 1], -1)
    derivatives = torch.stack([torch.zeros_like(x)] + [n * u[n - 1] for n in range(1, degree + 1)], -1)
    return values, derivatives


def basis_terms(x: torch.Tensor, exponents: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """`basis` with the derivatives laid out [..., k, n_terms] (the layout evaluation wants)."""
    k = x.shape[-1]
    degree = max(int(exponents.max()) if exponents.numel() else 0, 1)
    values, slopes = chebyshev(x, degree)  # [..., k, d+1]
    exponents = exponents.to(x.device)
    factors = [values[..., j, :].index_select(-1, exponents[:, j]) for j in range(k)]  # k x [..., n_terms]
    factor_slopes = [slopes[..., j, :].index_select(-1, exponents[:, j]) for j in range(k)]
    # products of all factors but one, from prefix and suffix products (k <= a handful of coordinates)
    prefix = [torch.ones_like(factors[0])]
    for j in range(k - 1):
        prefix.append(prefix[-1] * factors[j])
    suffix = [torch.ones_like(factors[0])]
    for j in range(k - 1, 0, -1):
        suffix.append(suffix[-1] * factors[j])
    suffix = suffix[::-1]
    derivatives = torch.stack([factor_slopes[j] * prefix[j] * suffix[j] for j in range(k)], -2)
    return prefix[-1] * factors[-1], derivatives


def basis(x: torch.Tensor, exponents: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Tensor-product Chebyshev basis ``prod_j T_{e_j}(x_j)`` [..., n_terms] and its derivatives
    [..., n_terms, k] at normalised coordinates ``x`` [..., k]."""
    values, derivatives = basis_terms(x, exponents)
    return values, derivatives.transpose(-1, -2)


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
    ranges: torch.Tensor  # [n_q, 2] the box the fit was sampled in (NaN where no muscle spans)
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
        return MusclePaths(
            self.model,
            self.muscle_names,
            self.coordinate_names,
            tuple(g.to(dtype) for g in self.groups),
            self.ranges.to(dtype),
            self.info,
        )

    def spanned(self) -> torch.Tensor:
        """[M, n_q] bool: which coordinates each muscle's path function depends on."""
        mask = torch.zeros(self.n_muscles, self.n_q, dtype=torch.bool)
        for g in self.groups:
            mask[g.muscles[:, None], g.coordinates[None, :]] = True
        return mask

    def _scatter_indices(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Where each group's columns land: muscle indices [C] and flat (muscle, coordinate) indices [sum m*k]."""
        cached = self.__dict__.get("_scatter")
        if cached is None:
            muscles = torch.cat([g.muscles for g in self.groups])
            flat = torch.cat(
                [(g.muscles[:, None] * self.n_q + g.coordinates[None, :]).reshape(-1) for g in self.groups]
            )
            cached = self.__dict__["_scatter"] = (muscles, flat)
        return cached

    def lengths_and_moment_arms(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Musculotendon lengths [..., M] and moment arms ``-dL/dq`` [..., M, n_q] at coordinates ``q``."""
        self._check(q)
        batch = q.shape[:-1]
        length_parts, arm_parts = [], []
        for g in self.groups:
            half = g.half_range.to(q)
            x = (q[..., g.coordinates.to(q.device)] - g.center.to(q)) / half
            values, derivatives = basis_terms(x, g.exponents)  # [..., t], [..., k, t]
            coefficients = g.coefficients.to(q)
            column_lengths = values @ coefficients  # [..., m]
            block = -(derivatives @ coefficients).transpose(-1, -2) / half  # [..., m, k]
            active = g.active(values)
            if active is not None:
                column_lengths = column_lengths * active
                block = block * active[..., None]
            length_parts.append(column_lengths)
            arm_parts.append(block.reshape(*batch, -1))
        muscles, flat = (index.to(q.device) for index in self._scatter_indices())
        lengths = q.new_zeros(*batch, self.n_muscles).index_add(-1, muscles, torch.cat(length_parts, -1))
        arms = q.new_zeros(*batch, self.n_muscles * self.n_q).index_add(-1, flat, torch.cat(arm_parts, -1))
        return lengths, arms.reshape(*batch, self.n_muscles, self.n_q)

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
            tensors.update(
                {
                    f"group{i}.coordinates": g.coordinates,
                    f"group{i}.center": g.center.double(),
                    f"group{i}.half_range": g.half_range.double(),
                    f"group{i}.exponents": g.exponents,
                    f"group{i}.coefficients": g.coefficients.double().contiguous(),
                    f"group{i}.muscles": g.muscles,
                }
            )
            if g.gates is not None:
                tensors[f"group{i}.gates"] = g.gates.double().contiguous()
        metadata = {
            "format": FORMAT,
            "model": self.model,
            "muscles": json.dumps(list(self.muscle_names)),
            "coordinates": json.dumps(list(self.coordinate_names)),
            "groups": str(len(self.groups)),
            "info": json.dumps(self.info),
        }
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
        if meta.get("format") not in READABLE_FORMATS:
            raise DataFormatError(path, f"not a muscle-path file (format {meta.get('format')!r})", field="format")
        try:
            groups = tuple(
                PathGroup(
                    *(
                        tensors[f"group{i}.{name}"]
                        for name in ("coordinates", "center", "half_range", "exponents", "coefficients", "muscles")
                    ),
                    gates=tensors.get(f"group{i}.gates"),
                )
                for i in range(int(meta["groups"]))
            )
            return cls(
                meta["model"],
                tuple(json.loads(meta["muscles"])),
                tuple(json.loads(meta["coordinates"])),
                groups,
                tensors["ranges"],
                json.loads(meta["info"]),
            ).to(dtype)
        except KeyError as exc:
            raise DataFormatError(path, f"missing entry {exc.args[0]!r}", field=str(exc.args[0])) from exc


PATHS_DIR = Path(__file__).resolve().parent / "paths"


def balanced_coordinates(paths: MusclePaths, model) -> tuple[str, ...]:
    """The coordinates static optimization balances with these paths on ``model`` (a `BodyModel` with the same
    coordinates): unlocked, independent (no coupler drives them) and spanned by some muscle."""
    spanned = paths.spanned().any(0)
    dependent = {c.dependent for c in model.couplers}
    return tuple(
        name
        for j, name in enumerate(model.coordinate_names)
        if bool(spanned[j]) and not bool(model.locked[j]) and j not in dependent
    )


def shipped_paths(name: str, dtype: torch.dtype = torch.float64) -> MusclePaths:
    """Path functions shipped with biomotion: ``"rajagopal2016"`` or ``"gait2392_subject01"``."""
    path = PATHS_DIR / f"{name}.safetensors"
    if not path.exists():
        available = sorted(p.stem for p in PATHS_DIR.glob("*.safetensors"))
        raise ModelError(f"no shipped muscle paths named {name!r}; available: {available}")
    return MusclePaths.load(path, dtype)
