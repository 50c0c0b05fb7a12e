"""Millard 2012 muscle curves: OpenSim's ``Millard2012EquilibriumMuscle`` active force-length, force-velocity and
passive (fibre) force-length curves, batched over frames and muscles (what static optimization needs; the tendon
curve is not implemented).

Millard, Uchida, Seth & Delp 2013, "Flexing computational muscle: modeling and simulation of musculotendon
dynamics", J Biomech Eng 135:021005, Sec. 2.2 and Appendix: each curve is a chain of C2-continuous quintic Bezier
"corner" segments. A corner joins (x0, y0) with slope dydx0 to (x1, y1) with slope dydx1; with (xc, yc) the
intersection of the two tangent lines and the curviness c in [0, 1] rescaled to k = 0.1 + 0.8 c, its control
points are

    P0 = (x0, y0),  P1 = P2 = P0 + k (C - P0),  P3 = P4 = P5 + k (C - P5),  P5 = (x1, y1)

(second derivative zero at both ends). Outside the first and last corner a curve continues linearly with its end
slope. y(x) is evaluated by solving x(u) = x for the Bezier parameter u (safeguarded Newton, the curves are
monotonic in x) and evaluating y(u), as OpenSim's ``SmoothSegmentedFunction`` does.

Curve construction (the knot points and slopes of each corner) follows OpenSim 4's
``SmoothSegmentedFunctionFactory``, from the properties stored with each muscle:

- active force-length (``ActiveForceLengthCurve``): five corners through the steep ascending limb start l_min,
  the transition to the shallow ascending limb l_t (slope s), the plateau at l~ = 1 (a shoulder 0.05 wide), and
  the descending limb end l_max, all with curviness 1; floor ``minimum_value``;
- force-velocity (``ForceVelocityCurve``): four corners through v~ = -1 (force 0), -0.9, 0 (force 1, slope
  ``isometric_slope``), 0.9 and 1 (``max_eccentric_velocity_force_multiplier``), with the concentric and
  eccentric slopes at and near vmax and the two curvinesses;
- passive force-length (``FiberForceLengthCurve``): two corners from strain e0 (force 0) through a foot of
  slope k_low to strain e_iso (force 1, slope k_iso). The file gives only the strains (every muscle of Rajagopal
  2016 and its descendants uses OpenSim's defaults 0 and 0.7); OpenSim then derives k_low, k_iso and the
  curviness from a reference fibre, which for those strains gives k_low = 0.2, k_iso = 1/0.35, curviness 0.75
  (read off OpenSim 4.6). Other strains are refused rather than guessed.

The tests compare every curve with OpenSim's own ``calcValue`` (tests/muscles/test_millard.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from biomotion.errors import ModelError

#: OpenSim 4 defaults of the three curves' properties (absent elements of an .osim take these).
ACTIVE_DEFAULTS = {
    "min_norm_active_fiber_length": 0.4441,
    "transition_norm_fiber_length": 0.73,
    "max_norm_active_fiber_length": 1.8123,
    "shallow_ascending_slope": 0.8616,
    "minimum_value": 0.1,
}
VELOCITY_DEFAULTS = {
    "concentric_slope_at_vmax": 0.0,
    "concentric_slope_near_vmax": 0.25,
    "isometric_slope": 5.0,
    "eccentric_slope_at_vmax": 0.0,
    "eccentric_slope_near_vmax": 0.15,
    "max_eccentric_velocity_force_multiplier": 1.4,
    "concentric_curviness": 0.6,
    "eccentric_curviness": 0.9,
}
PASSIVE_DEFAULTS = {"strain_at_zero_force": 0.0, "strain_at_one_norm_force": 0.7}


def _rescaled(curviness: torch.Tensor) -> torch.Tensor:
    """Curviness in [0, 1] to the control-point fraction 0.1 + 0.8 c (Millard 2013, Appendix)."""
    return 0.1 + 0.8 * curviness


def corner_points(x0, y0, dydx0, x1, y1, dydx1, k) -> tuple[torch.Tensor, torch.Tensor]:
    """Control points ([..., 6] x and y) of the quintic Bezier corner from (x0, y0, dydx0) to (x1, y1, dydx1)
    with rescaled curviness ``k`` (module docstring). Arguments broadcast."""
    x0, y0, dydx0, x1, y1, dydx1, k = torch.broadcast_tensors(
        *(torch.as_tensor(v, dtype=torch.float64) for v in (x0, y0, dydx0, x1, y1, dydx1, k))
    )
    parallel = (dydx0 - dydx1).abs() <= 1.4901161193847656e-08  # sqrt(machine epsilon)
    xc = torch.where(
        parallel, (x0 + x1) / 2, (y1 - y0 - x1 * dydx1 + x0 * dydx0) / torch.where(parallel, 1.0, dydx0 - dydx1)
    )
    yc = (xc - x1) * dydx1 + y1
    xa, ya = x0 + k * (xc - x0), y0 + k * (yc - y0)
    xb, yb = x1 + k * (xc - x1), y1 + k * (yc - y1)
    return torch.stack([x0, xa, xa, xb, xb, x1], -1), torch.stack([y0, ya, ya, yb, yb, y1], -1)


@dataclass(frozen=True)
class SegmentedCurve:
    """Quintic Bezier segments per muscle: control points ``x``, ``y`` [M, S, 6], with linear extension before
    the first and after the last segment by ``slopes`` [M, 2]."""

    x: torch.Tensor
    y: torch.Tensor
    slopes: torch.Tensor

    @staticmethod
    def of_corners(corners: list[tuple[torch.Tensor, torch.Tensor]], start_slope, end_slope) -> SegmentedCurve:
        x = torch.stack([c[0] for c in corners], -2)
        y = torch.stack([c[1] for c in corners], -2)
        slopes = torch.stack(
            torch.broadcast_tensors(
                torch.as_tensor(start_slope, dtype=torch.float64), torch.as_tensor(end_slope, dtype=torch.float64)
            ),
            -1,
        )
        return SegmentedCurve(x, y, slopes)

    def __call__(self, value: torch.Tensor) -> torch.Tensor:
        """y at ``value`` [..., M] (autograd flows through value)."""
        m, s = self.x.shape[:2]
        dtype = value.dtype
        x, y, slopes = self.x.to(dtype), self.y.to(dtype), self.slopes.to(dtype)
        flat = value.reshape(-1, m).T.contiguous()  # [M, N]
        starts = x[:, :, 0].contiguous()  # [M, S]
        segment = (torch.searchsorted(starts, flat.detach(), right=True) - 1).clamp(0, s - 1)
        px = torch.gather(x, 1, segment[..., None].expand(-1, -1, 6))  # [M, N, 6]
        py = torch.gather(y, 1, segment[..., None].expand(-1, -1, 6))
        lo, hi = px[..., 0], px[..., 5]
        inside = (flat >= x[:, :1, 0]) & (flat <= x[:, -1:, 5])
        target = torch.minimum(torch.maximum(flat, lo), hi)
        u = _solve_parameter(px, target.detach())
        # one Newton step outside no_grad carries d u / d x = 1 / x'(u) into autograd
        u = u - (_bezier(px, u) - target) / _bezier_slope(px, u).clamp(min=1e-12)
        curve = _bezier(py, u)
        first_x, first_y = x[:, :1, 0], y[:, :1, 0]
        last_x, last_y = x[:, -1:, 5], y[:, -1:, 5]
        before = first_y + slopes[:, :1] * (flat - first_x)
        after = last_y + slopes[:, 1:] * (flat - last_x)
        result = torch.where(inside, curve, torch.where(flat < first_x, before, after))
        return result.T.reshape(value.shape)


_BINOMIAL = (1.0, 5.0, 10.0, 10.0, 5.0, 1.0)


def _bezier(points: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Quintic Bezier value of ``points`` [..., 6] at ``u`` [...]."""
    v = 1 - u
    return sum(c * points[..., i] * u**i * v ** (5 - i) for i, c in enumerate(_BINOMIAL))


def _bezier_slope(points: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """d/du of `_bezier`: 5 sum_i (P_{i+1} - P_i) B_{i,4}(u)."""
    v = 1 - u
    binomial4 = (1.0, 4.0, 6.0, 4.0, 1.0)
    return 5 * sum(c * (points[..., i + 1] - points[..., i]) * u**i * v ** (4 - i) for i, c in enumerate(binomial4))


def _solve_parameter(points: torch.Tensor, target: torch.Tensor, iterations: int = 40) -> torch.Tensor:
    """u in [0, 1] with x(u) = target, x(u) increasing: Newton steps kept inside a shrinking bracket, bisection
    where a step would leave it."""
    with torch.no_grad():
        lo, hi = torch.zeros_like(target), torch.ones_like(target)
        span = (points[..., 5] - points[..., 0]).clamp(min=1e-300)
        u = ((target - points[..., 0]) / span).clamp(0, 1)
        for _ in range(iterations):
            error = _bezier(points, u) - target
            above = error > 0
            hi = torch.where(above, u, hi)
            lo = torch.where(above, lo, u)
            step = u - error / _bezier_slope(points, u).clamp(min=1e-300)
            u = torch.where((step > lo) & (step < hi), step, (lo + hi) / 2)
        return u


# ---- the three curves ------------------------------------------------------------------------------------------


def active_force_length_curve(p: dict[str, torch.Tensor]) -> SegmentedCurve:
    """OpenSim's ``ActiveForceLengthCurve`` (``createFiberActiveForceLengthCurve``) for parameters [M]."""
    x0, x1, x3 = p["min_norm_active_fiber_length"], p["transition_norm_fiber_length"], p["max_norm_active_fiber_length"]
    ylow, slope = p["minimum_value"], p["shallow_ascending_slope"]
    x2 = torch.ones_like(x0)
    if bool(((x1 <= x0) | (x3 <= x2) | (x1 >= x2)).any()):
        raise ModelError("active force-length curve needs min < transition < 1 < max")
    k = _rescaled(torch.ones_like(x0))
    delta = 0.05 * x2  # half-width of the plateau shoulder
    xs = x2 - delta
    y1 = 1 - slope * (xs - x1)
    dydx01 = 1.25 * y1 / (x1 - x0)
    x01, y01 = x0 + 0.5 * (x1 - x0), 0.5 * y1
    x1s, y1s = x1 + 0.5 * (xs - x1), y1 + 0.5 * (1 - y1)
    x23 = (x2 + delta) + 0.5 * (x3 - (x2 + delta))
    dydx23 = -1 / ((x3 - delta) - (x2 + delta))
    zero, one = torch.zeros_like(x0), torch.ones_like(x0)
    corners = [
        corner_points(x0, ylow, zero, x01, y01, dydx01, k),
        corner_points(x01, y01, dydx01, x1s, y1s, slope, k),
        corner_points(x1s, y1s, slope, x2, one, zero, k),
        corner_points(x2, one, zero, x23, 0.5 * one, dydx23, k),
        corner_points(x23, 0.5 * one, dydx23, x3, ylow, zero, k),
    ]
    return SegmentedCurve.of_corners(corners, zero, zero)


def force_velocity_curve(p: dict[str, torch.Tensor]) -> SegmentedCurve:
    """OpenSim's ``ForceVelocityCurve`` (``createFiberForceVelocityCurve``) for parameters [M]."""
    fmax = p["max_eccentric_velocity_force_multiplier"]
    slope_c, near_c = p["concentric_slope_at_vmax"], p["concentric_slope_near_vmax"]
    slope_e, near_e = p["eccentric_slope_at_vmax"], p["eccentric_slope_near_vmax"]
    iso = p["isometric_slope"]
    kc, ke = _rescaled(p["concentric_curviness"]), _rescaled(p["eccentric_curviness"])
    if bool(((fmax <= 1) | (iso <= 1) | (near_c <= slope_c) | (near_e < slope_e)).any()):
        raise ModelError(
            "force-velocity curve parameters out of range (fmax > 1, isometric slope > 1, near-vmax "
            "slopes >= the slopes at vmax)"
        )
    one = torch.ones_like(fmax)
    x_near_c, x_near_e = -0.9 * one, 0.9 * one
    y_near_c = 0.5 * (near_c + slope_c) * (x_near_c + 1)
    y_near_e = fmax + 0.5 * (near_e + slope_e) * (x_near_e - 1)
    corners = [
        corner_points(-one, 0 * one, slope_c, x_near_c, y_near_c, near_c, kc),
        corner_points(x_near_c, y_near_c, near_c, 0 * one, one, iso, kc),
        corner_points(0 * one, one, iso, x_near_e, y_near_e, near_e, ke),
        corner_points(x_near_e, y_near_e, near_e, one, fmax, slope_e, ke),
    ]
    return SegmentedCurve.of_corners(corners, slope_c, slope_e)


def passive_force_length_curve(p: dict[str, torch.Tensor]) -> SegmentedCurve:
    """OpenSim's ``FiberForceLengthCurve`` (``createFiberForceLengthCurve``) for parameters [M], with the
    stiffnesses and curviness OpenSim uses for the default strains (module docstring)."""
    e0, e_iso = p["strain_at_zero_force"], p["strain_at_one_norm_force"]
    if bool(((e0 != 0) | ((e_iso - 0.7).abs() > 1e-12)).any()):
        raise ModelError(
            "passive force-length curve: only OpenSim's default strains (0 at zero force, 0.7 at one "
            "normalised force) are implemented"
        )
    k_iso = torch.full_like(e0, 1 / 0.35)
    k_low = torch.full_like(e0, 0.2)
    k = _rescaled(torch.full_like(e0, 0.75))
    x0, x_iso = 1 + e0, 1 + e_iso
    delta = torch.minimum(0.1 / k_iso, 0.1 * (x_iso - x0))
    x_low = x0 + delta
    y_low = k_low * (x_low - (x0 + 0.5 * delta))
    zero, one = torch.zeros_like(e0), torch.ones_like(e0)
    corners = [
        corner_points(x0, zero, zero, x_low, y_low, k_low, k),
        corner_points(x_low, y_low, k_low, x_iso, one, k_iso, k),
    ]
    return SegmentedCurve.of_corners(corners, zero, k_iso)
