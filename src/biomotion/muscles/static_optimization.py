"""Static optimization, batched over frames: muscle activations that reproduce inverse-dynamics torques.

Per frame (Crowninshield & Brand 1981, J Biomech 14:793; Anderson & Pandy 2001, J Biomech Eng 123:381; OpenSim's
``StaticOptimization``):

    minimise   sum_m a_m^p + sum_c x_c^p                       (p = 2: squared, p = 3: cubed activations)
    subject to sum_m r_cm(q) F_m(q, qdot) a_m + R_c x_c = tau_c  for every balanced coordinate c
               a_min <= a_m <= a_max,   -x_max <= x_c <= x_max

with F_m the muscle force at full activation (force-length-velocity and pennation of the model's muscle type,
rigid tendon, `biomotion.muscles.properties.max_active_force`) and x_c the control of a reserve actuator of optimal
force R_c on coordinate c. As in OpenSim, passive fibre forces are not part of the balance (OpenSim overrides each
muscle's whole force with a F_m), and reserves are penalised like muscles.

The per-frame problem is convex with a separable objective, so it is solved in the dual (Lagrange multipliers
lambda, one per balanced coordinate; Bertsekas 1999, "Nonlinear Programming", 6.1): for given lambda the minimiser
of each actuator's term is w_i = clip(sign(s_i) (|s_i|/p)^(1/(p-1)), lo_i, hi_i) with s = B^T lambda, and the
concave dual is maximised by a semismooth Newton method with a backtracking line search (Qi & Sun 1993,
Math Program 58:353), started from the multipliers of the same problem without bounds (closed form). All frames
are solved together: one batched [T, C, C] linear solve per iteration over the frames still iterating. A frame
leaves the batch once balanced, or once its imbalance stops falling (the bounded actuators cannot balance it: a
filter's end effect, a missing reserve), so one such frame does not keep the whole trial iterating to
``max_iterations``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from biomotion.errors import ModelError
from biomotion.muscles.geometry import MusclePaths
from biomotion.muscles.properties import MuscleParameters, max_active_force

STALL_ITERATIONS = 6  # a frame whose torque imbalance has not dropped by STALL_GAIN in this many iterations
STALL_GAIN = 0.01  # stops: the bounded actuators cannot balance it (it is reported as not converged)
MAX_HALVINGS = 10  # a frame whose step is not accepted down to 2^-MAX_HALVINGS keeps its iterate, more damped


@dataclass(frozen=True)
class StaticOptimizationResult:
    """Per-frame solution. ``residual`` = achieved - requested torque; ``converged`` frames meet the tolerance
    (a frame that cannot be balanced within the bounds does not converge and keeps its last iterate)."""

    activations: torch.Tensor  # [T, M]
    muscle_forces: torch.Tensor  # [T, M] N along the tendon
    reserve_controls: torch.Tensor  # [T, C]
    reserve_torques: torch.Tensor  # [T, C] N·m or N
    residual: torch.Tensor  # [T, C]
    converged: torch.Tensor  # [T] bool
    iterations: int
    coordinate_names: tuple[str, ...] = ()
    muscle_names: tuple[str, ...] = ()

    def reserve_usage(self) -> dict[str, dict[str, float]]:
        """Per coordinate: RMS and max |reserve torque| and the fraction of frames it is above 1 N·m (or N)."""
        usage = {}
        for j, name in enumerate(self.coordinate_names or range(self.reserve_torques.shape[-1])):
            column = self.reserve_torques[:, j].abs()
            usage[str(name)] = {
                "rms": float(column.pow(2).mean().sqrt()),
                "max": float(column.max()),
                "frames_over_1": float((column > 1).double().mean()),
            }
        return usage


def _actuator_response(
    s: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor, exponent: float, max_slope: float = 1e8
) -> tuple[torch.Tensor, torch.Tensor]:
    """argmin_{lower <= w <= upper} |w|^p - s w and its derivative with respect to s."""
    if exponent == 2:
        free = s / 2
        slope = torch.full_like(s, 0.5)
    else:
        k = 1 / (exponent - 1)
        magnitude = (s.abs() / exponent).clamp(min=1e-300)
        free = torch.sign(s) * magnitude**k
        slope = (k / exponent * magnitude ** (k - 1)).clamp(max=max_slope)
    inside = (free > lower) & (free < upper)
    return torch.minimum(torch.maximum(free, lower), upper), torch.where(inside, slope, torch.zeros_like(slope))


def _apply(b: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Batched B w: [T, C, N] x [T, N] -> [T, C] (a multiply-sum beats batched mat-vec products on CPU)."""
    return (b * w[:, None, :]).sum(-1)


def _apply_transposed(b: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """Batched B^T lambda: [T, C, N] x [T, C] -> [T, N] (here the batched product beats a multiply-sum)."""
    return torch.bmm(lam[:, None, :], b)[:, 0]


def _dual_value(
    lam: torch.Tensor, w: torch.Tensor, s: torch.Tensor, tau: torch.Tensor, exponent: float
) -> torch.Tensor:
    return (lam * tau).sum(-1) + (w.abs() ** exponent - s * w).sum(-1)


def _unbounded_start(b: torch.Tensor, torques: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Multipliers of the problem without bounds and with squared costs, lambda = 2 (B B^T)^-1 tau: exact when no
    bound is active, and a start whose active set is near the solution's otherwise (lambda = 0 puts every muscle on
    its lower bound, where the dual Hessian sees only the reserves)."""
    c = b.shape[1]
    gram = b @ b.transpose(-1, -2) / 2 + 1e-9 * (scale**2)[:, None, None] * torch.eye(c, dtype=b.dtype)
    return torch.linalg.solve(gram, torques)


def _dual_newton(
    b: torch.Tensor,
    torques: torch.Tensor,
    lam: torch.Tensor,
    scale: torch.Tensor,
    lower: torch.Tensor,
    upper: torch.Tensor,
    exponent: float,
    tolerance: float,
    max_iterations: int,
) -> tuple[torch.Tensor, int]:
    """Semismooth Newton ascent on the dual from ``lam`` [T, C]; the final multipliers and the iterations run.

    The frames still iterating are kept gathered (``*_l``); a frame leaves when balanced, or when its imbalance has
    not dropped by STALL_GAIN in STALL_ITERATIONS iterations (the bounds cannot balance it). Each accepted line
    search point carries its residual and dual value into the next iteration."""
    t, c = torques.shape
    dtype = torques.dtype
    eye = torch.eye(c, dtype=dtype)
    out = lam.clone()
    live = torch.arange(t)
    b_l, tau_l, lam_l, scale_l = b, torques, lam.clone(), scale
    s_l = _apply_transposed(b_l, lam_l)
    w_l, slope_l = _actuator_response(s_l, lower, upper, exponent)
    gradient = tau_l - _apply(b_l, w_l)  # dual ascent direction: the torque imbalance
    value = _dual_value(lam_l, w_l, s_l, tau_l, exponent)
    damping = torch.full((t,), 1e-3, dtype=dtype)
    best = torch.full((t,), torch.inf, dtype=dtype)
    best_lam = lam_l.clone()  # the multipliers at each frame's best imbalance: a stalled frame's answer
    since_best = torch.zeros(t, dtype=torch.long)
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 - the count is reported
        imbalance = gradient.abs().amax(-1)
        improved = imbalance < (1 - STALL_GAIN) * best
        best = torch.where(improved, imbalance, best)
        best_lam = torch.where(improved[:, None], lam_l, best_lam)
        since_best = torch.where(improved, 0, since_best + 1)
        keep = (imbalance > tolerance) & (since_best < STALL_ITERATIONS)
        if not bool(keep.all()):
            balanced = imbalance <= tolerance
            out[live[~keep]] = torch.where(balanced[:, None], lam_l, best_lam)[~keep]
            if not bool(keep.any()):
                break
            live = live[keep]
            state = (b_l, tau_l, lam_l, s_l, w_l, slope_l, gradient, value, imbalance, scale_l, damping, best, best_lam)
            b_l, tau_l, lam_l, s_l, w_l, slope_l, gradient, value, imbalance, scale_l, damping, best, best_lam = (
                x[keep] for x in state
            )
            since_best = since_best[keep]
        n = len(live)
        # Levenberg-Marquardt damping keeps the step bounded where clipped actuators make B D B^T singular
        mu = damping * scale_l * imbalance + 1e-12 * scale_l**2
        hessian = (b_l * slope_l[:, None, :]) @ b_l.transpose(-1, -2) + mu[:, None, None] * eye
        step = torch.linalg.solve(hessian, gradient)
        slope_along = (gradient * step).sum(-1)
        alpha = torch.ones(n, dtype=dtype)
        accepted = torch.zeros(n, dtype=torch.bool)
        # backtracking on the concave dual; frames accept independently, and only the ones still looking for a
        # step are evaluated again (one stubborn frame does not cost the whole batch its halvings)
        rows = torch.arange(n)
        pending = (b_l, tau_l, lam_l, step, value, slope_along, imbalance)
        chosen: list[torch.Tensor] | None = None  # the accepted points, when frames accept at different steps
        for _ in range(MAX_HALVINGS + 1):
            b_p, tau_p, lam_p, step_p, value_p, along_p, imbalance_p = pending
            a = alpha[rows]
            trial = lam_p + a[:, None] * step_p
            s_trial = _apply_transposed(b_p, trial)
            w_trial, slope_trial = _actuator_response(s_trial, lower, upper, exponent)
            value_trial = _dual_value(trial, w_trial, s_trial, tau_p, exponent)
            gradient_trial = tau_p - _apply(b_p, w_trial)
            gain = value_trial >= value_p + 1e-4 * a * along_p
            # near the optimum the dual gain drowns in rounding; then a clear drop of the imbalance also counts
            take = gain | (gradient_trial.abs().amax(-1) <= 0.5 * imbalance_p)
            point = (trial, s_trial, w_trial, slope_trial, gradient_trial, value_trial)
            if chosen is None and bool(take.all()):  # every frame took its first step: nothing to scatter
                lam_l, s_l, w_l, slope_l, gradient, value = point
                accepted[:] = True
                break
            if chosen is None:
                chosen = [x.clone() for x in (lam_l, s_l, w_l, slope_l, gradient, value)]
            taken = rows[take]
            for target, value_t in zip(chosen, point):
                target[taken] = value_t[take]
            accepted[taken] = True
            if bool(take.all()):
                break
            rows = rows[~take]
            alpha[rows] = alpha[rows] / 2
            pending = tuple(x[~take] for x in pending)
        if chosen is not None:
            lam_l, s_l, w_l, slope_l, gradient, value = chosen
        full = accepted & (alpha == 1)
        damping = torch.where(accepted, torch.where(full, damping / 3, damping), damping * 10).clamp(1e-9, 1e6)
    out[live] = lam_l
    return out, iterations


def solve_static_optimization(
    moment_arms: torch.Tensor,
    max_forces: torch.Tensor,
    torques: torch.Tensor,
    reserve_optimal_force: torch.Tensor,
    *,
    exponent: float = 2.0,
    activation_bounds: tuple[torch.Tensor | float, torch.Tensor | float] = (0.01, 1.0),
    reserve_bound: float = 1.0,
    tolerance: float = 1e-8,
    max_iterations: int = 100,
) -> StaticOptimizationResult:
    """Solve the static-optimization problem of every frame at once.

    moment_arms [T, M, C] (m), max_forces [T, M] (N, force at full activation), torques [T, C] (N·m or N),
    reserve_optimal_force [C] (0 = no reserve on that coordinate); ``tolerance`` is on the torque balance in
    N·m. Every coordinate needs at least one actuator (a muscle or a reserve).
    """
    if exponent <= 1:
        raise ModelError(f"static optimization needs an exponent > 1, got {exponent}")
    t, m, c = moment_arms.shape
    if max_forces.shape != (t, m) or torques.shape != (t, c) or reserve_optimal_force.shape != (c,):
        raise ModelError(
            f"static optimization: shapes moment_arms {tuple(moment_arms.shape)}, max_forces "
            f"{tuple(max_forces.shape)}, torques {tuple(torques.shape)}, reserves "
            f"{tuple(reserve_optimal_force.shape)} do not agree"
        )
    dtype = torques.dtype
    muscle_columns = moment_arms.transpose(-1, -2) * max_forces[:, None, :]  # [T, C, M]
    reserve_columns = torch.diag_embed(reserve_optimal_force.to(dtype)).expand(t, c, c)
    b = torch.cat([muscle_columns, reserve_columns], -1)  # [T, C, M + C]
    if bool(((b.abs().amax(-1)) == 0).any()):
        raise ModelError("static optimization: a coordinate has neither a muscle nor a reserve acting on it")
    lo_a, hi_a = (torch.as_tensor(v, dtype=dtype).expand(m) for v in activation_bounds)
    lower = torch.cat([lo_a, torch.full((c,), -reserve_bound, dtype=dtype)])
    upper = torch.cat([hi_a, torch.full((c,), reserve_bound, dtype=dtype)])
    scale = b.abs().amax((-1, -2))  # [T] N·m
    lam, iterations = _dual_newton(
        b, torques, _unbounded_start(b, torques, scale), scale, lower, upper, exponent, tolerance, max_iterations
    )
    w, _ = _actuator_response(_apply_transposed(b, lam), lower, upper, exponent)
    residual = _apply(b, w) - torques
    activations, controls = w[:, :m], w[:, m:]
    return StaticOptimizationResult(
        activations,
        activations * max_forces,
        controls,
        controls * reserve_optimal_force.to(dtype),
        residual,
        residual.abs().amax(-1) <= tolerance * 10,
        iterations,
    )


def optimize_activations(
    paths: MusclePaths,
    muscles: MuscleParameters,
    q: torch.Tensor,
    qdot: torch.Tensor,
    torques: torch.Tensor,
    coordinates: tuple[str, ...] | list[str],
    reserves: dict[str, float] | float = 0.0,
    *,
    exponent: float = 2.0,
    reserve_bound: float = 1.0,
    tolerance: float = 1e-8,
    max_iterations: int = 100,
) -> StaticOptimizationResult:
    """Activations of ``paths``' muscles that balance ``torques`` [T, len(coordinates)] on ``coordinates``.

    q, qdot [T, n_q] in the order of ``paths.coordinate_names`` (rad, rad/s, m, m/s); ``reserves``: optimal
    force per coordinate name (a dict; missing names get none) or one value for all; reserve controls are bounded
    by ``reserve_bound``. Muscle forces per unit activation come from `max_active_force`.
    """
    if q.shape != qdot.shape or q.shape[:-1] != torques.shape[:-1] or torques.shape[-1] != len(coordinates):
        raise ModelError(
            f"static optimization: q {tuple(q.shape)}, qdot {tuple(qdot.shape)}, torques "
            f"{tuple(torques.shape)} for {len(coordinates)} coordinates do not agree"
        )
    muscles = muscles.select(paths.muscle_names)
    lengths, arms = paths.lengths_and_moment_arms(q)
    speeds = -(arms @ qdot[..., None])[..., 0]
    forces = max_active_force(muscles, lengths, speeds)
    columns = paths.select(coordinates)
    if isinstance(reserves, dict):
        unknown = set(reserves) - set(coordinates)
        if unknown:
            raise ModelError(f"reserves for coordinates that are not balanced: {sorted(unknown)}")
        optimal = torch.tensor([float(reserves.get(n, 0.0)) for n in coordinates], dtype=q.dtype)
    else:
        optimal = torch.full((len(coordinates),), float(reserves), dtype=q.dtype)
    result = solve_static_optimization(
        arms[..., columns],
        forces,
        torques,
        optimal,
        exponent=exponent,
        activation_bounds=(muscles.min_control.to(q.dtype), muscles.max_control.to(q.dtype)),
        reserve_bound=reserve_bound,
        tolerance=tolerance,
        max_iterations=max_iterations,
    )
    return StaticOptimizationResult(
        result.activations,
        result.muscle_forces,
        result.reserve_controls,
        result.reserve_torques,
        result.residual,
        result.converged,
        result.iterations,
        tuple(coordinates),
        paths.muscle_names,
    )
