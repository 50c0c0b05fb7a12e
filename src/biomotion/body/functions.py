"""OpenSim's one-argument functions in torch: batched over any shape, differentiable, float32 or float64.

Each reproduces the OpenSim 4 class of the same name (the functions a CustomJoint's TransformAxis and a
CoordinateCouplerConstraint use), including its behaviour outside the knots:

- `SimmSpline`: the cubic spline of SIMM (Delp & Loan 1995, Comput Biol Med 25:21), whose end conditions match
  the third derivative to divided differences of the end knots (Forsythe, Malcolm & Moler 1977, "Computer
  Methods for Mathematical Computations", routine SPLINE); linear extrapolation with the end slopes.
- `NaturalCubicSpline`: despite its name, OpenSim 4.6 computes it with the same algorithm and end conditions as
  SimmSpline (its values equal SimmSpline's to 1e-15 for 2-9 knots; checked with `opensim`), so it is one here.
- `PiecewiseLinearFunction`, `LinearFunction`, `Constant`, `PolynomialFunction` (highest order first) and
  `MultiplierFunction` (scale times an inner function).

Coefficients are computed once in float64 numpy; evaluation is a gather of the interval's cubic. `FunctionStack`
evaluates many functions (each on its own argument) in a few tensor operations: the kinematics of every transform
axis of a model at once.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np
import torch

from biomotion.errors import ModelError
from biomotion.io import osim

_F64 = torch.float64


class Function(Protocol):
    def __call__(self, x: torch.Tensor) -> torch.Tensor: ...

    def derivatives(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(f, f', f'') at ``x``, each differentiable."""
        ...

    def to(self, dtype: torch.dtype) -> Function: ...


class Constant:
    def __init__(self, value: float) -> None:
        self.value = float(value)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return torch.full_like(x, self.value)

    def derivatives(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self(x), torch.zeros_like(x), torch.zeros_like(x)

    def to(self, dtype: torch.dtype) -> Constant:
        return self


class Linear:
    def __init__(self, slope: float, intercept: float) -> None:
        self.slope, self.intercept = float(slope), float(intercept)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return self.slope * x + self.intercept

    def derivatives(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self(x), torch.full_like(x, self.slope), torch.zeros_like(x)

    def to(self, dtype: torch.dtype) -> Linear:
        return self


class Polynomial:
    def __init__(self, coefficients: tuple[float, ...]) -> None:
        self.coefficients = tuple(float(c) for c in coefficients)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return self.derivatives(x)[0]

    def derivatives(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        f, d1, d2 = torch.zeros_like(x), torch.zeros_like(x), torch.zeros_like(x)
        for c in self.coefficients:  # Horner, highest order first, carrying two derivatives
            d2 = d2 * x + 2.0 * d1
            d1 = d1 * x + f
            f = f * x + c
        return f, d1, d2

    def to(self, dtype: torch.dtype) -> Polynomial:
        return self


class Multiplier:
    def __init__(self, function: Function, scale: float | torch.Tensor) -> None:
        self.function, self.scale = function, scale

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return self.scale * self.function(x)

    def derivatives(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return tuple(self.scale * d for d in self.function.derivatives(x))  # type: ignore[return-value]

    def to(self, dtype: torch.dtype) -> Multiplier:
        scale = self.scale.to(dtype) if isinstance(self.scale, torch.Tensor) else self.scale
        return Multiplier(self.function.to(dtype), scale)


class PiecewiseCubic:
    """y[k] + dx (b[k] + dx (c[k] + dx d[k])) on knot interval k, dx = x - x[k]; linear beyond the ends with
    slopes b[0] and b[-1] (the extrapolation OpenSim's splines use)."""

    def __init__(
        self,
        x: np.ndarray,
        y: np.ndarray,
        b: np.ndarray,
        c: np.ndarray,
        d: np.ndarray,
        dtype: torch.dtype = torch.float64,
    ) -> None:
        self._numpy = (x, y, b, c, d)
        self.x, self.y, self.b, self.c, self.d = (torch.as_tensor(a, dtype=dtype) for a in (x, y, b, c, d))

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return self.derivatives(x)[0]

    def derivatives(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        knots = self.x.to(x.dtype)
        n = knots.shape[0]
        k = (x.unsqueeze(-1) >= knots[1:-1]).sum(-1) if n > 2 else torch.zeros_like(x, dtype=torch.long)
        y, b, c, d = (t.to(x.dtype)[k] for t in (self.y, self.b, self.c, self.d))
        dx = x - knots[k]
        value = y + dx * (b + dx * (c + dx * d))
        slope = b + dx * (2.0 * c + 3.0 * dx * d)
        curvature = 2.0 * c + 6.0 * dx * d
        below, above = x < knots[0], x > knots[-1]
        b0, bn = self.b[0].to(x.dtype), self.b[-1].to(x.dtype)
        value = torch.where(
            below,
            self.y[0].to(x.dtype) + (x - knots[0]) * b0,
            torch.where(above, self.y[-1].to(x.dtype) + (x - knots[-1]) * bn, value),
        )
        slope = torch.where(below, b0, torch.where(above, bn, slope))
        curvature = torch.where(below | above, torch.zeros_like(x), curvature)
        return value, slope, curvature

    def to(self, dtype: torch.dtype) -> PiecewiseCubic:
        return PiecewiseCubic(*self._numpy, dtype=dtype)


def simm_spline_coefficients(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """b, c, d of SIMM's cubic spline (Forsythe, Malcolm & Moler 1977, SPLINE): not-a-knot-like end conditions
    matching third derivatives to divided differences over the first and last four knots."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    n = x.size
    b, c, d = np.zeros(n), np.zeros(n), np.zeros(n)
    if n == 2:
        b[:] = (y[1] - y[0]) / (x[1] - x[0])
        return b, c, d
    nm1, nm2 = n - 1, n - 2
    # tridiagonal system: b diagonal, d off-diagonal, c right-hand side
    d[0] = x[1] - x[0]
    c[1] = (y[1] - y[0]) / d[0]
    for i in range(1, nm1):
        d[i] = x[i + 1] - x[i]
        b[i] = 2.0 * (d[i - 1] + d[i])
        c[i + 1] = (y[i + 1] - y[i]) / d[i]
        c[i] = c[i + 1] - c[i]
    b[0], b[nm1] = -d[0], -d[nm2]
    c[0] = c[nm1] = 0.0
    if n > 3:
        c[0] = c[2] / (x[3] - x[1]) - c[1] / (x[2] - x[0])
        c[nm1] = c[nm2] / (x[nm1] - x[n - 3]) - c[n - 3] / (x[nm2] - x[n - 4])
        c[0] = c[0] * d[0] * d[0] / (x[3] - x[0])
        c[nm1] = -c[nm1] * d[nm2] * d[nm2] / (x[nm1] - x[n - 4])
    for i in range(1, n):  # forward elimination
        t = d[i - 1] / b[i - 1]
        b[i] -= t * d[i - 1]
        c[i] -= t * c[i - 1]
    c[nm1] /= b[nm1]  # back substitution
    for i in range(nm2, -1, -1):
        c[i] = (c[i] - d[i] * c[i + 1]) / b[i]
    b[nm1] = (y[nm1] - y[nm2]) / d[nm2] + d[nm2] * (c[nm2] + 2.0 * c[nm1])
    for i in range(nm1):
        b[i] = (y[i + 1] - y[i]) / d[i] - d[i] * (c[i + 1] + 2.0 * c[i])
        d[i] = (c[i + 1] - c[i]) / d[i]
        c[i] *= 3.0
    c[nm1] *= 3.0
    d[nm1] = d[nm2]
    return b, c, d


class FunctionStack:
    """Functions f_k evaluated together, each scaled by s_k: x [K, ...] -> s_k f_k(x[k]) and its first two
    derivatives, [K, ...] each (row k is function k's argument, any trailing batch shape), differentiable in x
    and in the scales (tensors keep their autograd graph).

    Affine functions (`Constant`, `Linear`, and `Multiplier` of them) are one multiply-add, splines
    (`PiecewiseCubic`, possibly under `Multiplier`) one gather of their interval's cubic with the same rule
    outside the knots, polynomials one Horner pass; any other `Function` is evaluated on its own. The results
    equal the functions' own `derivatives` up to rounding.
    """

    def __init__(
        self,
        functions: Sequence[Function],
        scales: Sequence[float | torch.Tensor] | None = None,
        dtype: torch.dtype = torch.float64,
    ) -> None:
        scales = [1.0] * len(functions) if scales is None else list(scales)
        affine, splines, polynomials, others, factors = [], [], [], [], []
        for k, (function, scale) in enumerate(zip(functions, scales)):
            while isinstance(function, Multiplier):  # fold the multipliers into one scale per function
                scale = scale * function.scale
                function = function.function
            factors.append(scale if isinstance(scale, torch.Tensor) else torch.tensor(float(scale), dtype=_F64))
            if isinstance(function, (Constant, Linear)):
                affine.append(
                    (
                        k,
                        0.0 if isinstance(function, Constant) else function.slope,
                        function.value if isinstance(function, Constant) else function.intercept,
                    )
                )
            elif isinstance(function, PiecewiseCubic):
                splines.append((k, function))
            elif isinstance(function, Polynomial):
                polynomials.append((k, function.coefficients))
            else:
                others.append((k, function))
        self.size = len(functions)
        self.scale = torch.stack([f.to(dtype) for f in factors]) if factors else torch.zeros(0, dtype=dtype)
        self.affine = torch.tensor([k for k, _, _ in affine], dtype=torch.long)
        self.slope = torch.tensor([a for _, a, _ in affine], dtype=dtype)
        self.intercept = torch.tensor([b for _, _, b in affine], dtype=dtype)
        self.splines = torch.tensor([k for k, _ in splines], dtype=torch.long)
        self._spline_table(dtype, [f for _, f in splines])
        self.polynomials = torch.tensor([k for k, _ in polynomials], dtype=torch.long)
        degree = max((len(c) for _, c in polynomials), default=0)
        self.coefficients = torch.tensor(
            [[0.0] * (degree - len(c)) + list(c) for _, c in polynomials], dtype=dtype
        ).reshape(len(polynomials), degree)
        self.others = others
        order = torch.cat(
            [self.affine, self.splines, self.polynomials, torch.tensor([k for k, _ in others], dtype=torch.long)]
        )
        self.order = torch.argsort(order)  # row of function k in the concatenated groups

    def _spline_table(self, dtype: torch.dtype, splines: list[PiecewiseCubic]) -> None:
        width = max((int(f.x.numel()) for f in splines), default=2)
        inner = torch.full((len(splines), max(width - 2, 1)), torch.inf, dtype=dtype)
        table = torch.zeros(5, len(splines), width, dtype=dtype)  # knots, y, b, c, d
        for i, f in enumerate(splines):
            n = int(f.x.numel())
            inner[i, : n - 2] = f.x[1:-1].to(dtype)
            for row, values in enumerate((f.x, f.y, f.b, f.c, f.d)):
                table[row, i, :n] = values.to(dtype)
        self.inner = inner
        self.table = table.flatten(1)
        self.offset = torch.arange(len(splines)) * width
        ends = [
            torch.stack([torch.stack([f.x[i], f.y[i], f.b[i]]) for f in splines], -1).to(dtype)
            if splines
            else torch.zeros(3, 0, dtype=dtype)
            for i in (0, -1)
        ]
        self.first, self.last = ends

    def derivatives(self, x: torch.Tensor, order: int = 2) -> tuple[torch.Tensor, ...]:
        """(s f, s f', s f'') at ``x`` [K, ...], or only the first ``order + 1`` of them: the derivatives not asked
        for are not computed (forward kinematics needs the values, its Jacobians the slopes, dynamics all three)."""
        if x.shape[0] != self.size:
            raise ModelError(f"FunctionStack of {self.size} functions got {x.shape[0]} arguments")
        if order not in (0, 1, 2):
            raise ValueError(f"order must be 0, 1 or 2, not {order}")
        trailing = (1,) * (x.dim() - 1)
        parts: list[tuple[torch.Tensor, ...]] = []
        if len(self.affine):
            u = x[self.affine]
            slope = self.slope.to(x.dtype).reshape(-1, *trailing)
            value = slope * u + self.intercept.to(x.dtype).reshape(-1, *trailing)
            parts.append((value, slope.expand_as(u), torch.zeros_like(u))[: order + 1])
        if len(self.splines):
            parts.append(self._evaluate_splines(x[self.splines], order))
        if len(self.polynomials):
            u = x[self.polynomials]
            f, d1, d2 = torch.zeros_like(u), torch.zeros_like(u), torch.zeros_like(u)
            for c in self.coefficients.to(x.dtype).unbind(-1):  # Horner, as `Polynomial`
                c = c.reshape(-1, *trailing)
                d2 = d2 * u + 2.0 * d1
                d1 = d1 * u + f
                f = f * u + c
            parts.append((f, d1, d2)[: order + 1])
        for k, function in self.others:
            parts.append(tuple(d[None] for d in function.derivatives(x[k])[: order + 1]))
        if not parts:
            zero = x.new_zeros(x.shape)
            return (zero,) * (order + 1)
        scale = self.scale.to(x.dtype).reshape(-1, *trailing)
        return tuple(scale * torch.cat([p[i] for p in parts])[self.order] for i in range(order + 1))

    def _evaluate_splines(self, x: torch.Tensor, order: int) -> tuple[torch.Tensor, ...]:
        trailing = (1,) * (x.dim() - 1)
        inner = self.inner.to(x.dtype).reshape(self.inner.shape[0], *trailing, -1)
        k = (x[..., None] >= inner).sum(-1) + self.offset.reshape(-1, *trailing)
        knot, y, b, c, d = self.table.to(x.dtype)[:, k]
        dx = x - knot
        (x0, y0, b0), (x1, y1, b1) = (e.to(x.dtype).reshape(3, -1, *trailing) for e in (self.first, self.last))
        below, above = x < x0, x > x1
        value = y + dx * (b + dx * (c + dx * d))
        out = [torch.where(below, y0 + (x - x0) * b0, torch.where(above, y1 + (x - x1) * b1, value))]
        if order >= 1:
            slope = b + dx * (2.0 * c + 3.0 * dx * d)
            out.append(torch.where(below, b0, torch.where(above, b1, slope)))
        if order >= 2:
            curvature = 2.0 * c + 6.0 * dx * d
            out.append(torch.where(below | above, torch.zeros_like(x), curvature))
        return tuple(out)


def build_function(spec: osim.FunctionSpec) -> Function:
    """The torch function for a parsed OpenSim function."""
    if isinstance(spec, osim.ConstantFunction):
        return Constant(spec.value)
    if isinstance(spec, osim.LinearFunction):
        return Linear(spec.slope, spec.intercept)
    if isinstance(spec, osim.PolynomialFunction):
        return Polynomial(spec.coefficients)
    if isinstance(spec, osim.MultiplierFunction):
        return Multiplier(build_function(spec.function), spec.scale)
    if isinstance(spec, (osim.SimmSpline, osim.NaturalCubicSpline, osim.PiecewiseLinearFunction)):
        x, y = np.asarray(spec.x, float), np.asarray(spec.y, float)
        if isinstance(spec, (osim.SimmSpline, osim.NaturalCubicSpline)):
            b, c, d = simm_spline_coefficients(x, y)
        else:
            slopes = np.diff(y) / np.diff(x)
            b, c, d = np.append(slopes, slopes[-1]), np.zeros_like(x), np.zeros_like(x)
        return PiecewiseCubic(x, y, b, c, d)
    raise ModelError(f"function {type(spec).__name__} is not supported")
