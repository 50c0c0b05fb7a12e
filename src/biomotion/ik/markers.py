"""Marker inverse kinematics for every frame at once: batched, bounded Levenberg-Marquardt in torch (float64).

The objective per frame is OpenSim's (Delp et al. 2007, IEEE TBME 54:1940; Seth et al. 2018, PLoS Comput Biol
14:e1006223), as Simbody's Assembler evaluates it (``Markers::calcGoal`` and ``QValue::calcGoal``):

    E(q) = sum_i w_i |x_i(q) - m_i|^2 / (2 sum_i w_i)  +  sum_j w_j (q_j - v_j)^2

over the tracked markers i visible in the frame (NaN samples drop out, and so does their weight) and the
coordinate tasks j. As in OpenSim, locked coordinates stay at their default value, coordinates driven by a
CoordinateCouplerConstraint follow their coupler exactly (OpenSim's default ``constraint_weight`` of infinity; a
finite weight, which makes OpenSim treat the coupler as a soft goal, is not modelled), and only clamped
coordinates are held within their range. The unknowns z are the remaining (free) coordinates. Iterations stop on
``tolerance`` (relative change of the objective), not on OpenSim's ``accuracy`` setting.

Solver: Levenberg-Marquardt (Levenberg 1944; Marquardt 1963), every frame an independent problem in one batch
([T, n] tensors; per-frame damping and acceptance), with a projected active set for the bounds (Bertsekas 1982,
SIAM J Control Optim 20:221). Derivatives are analytic: each coordinate moves its joint's axes, whose ground twist
(omega, v) gives d x / d q = omega x x + v for every marker distal to the joint (the spatial Jacobian of
Featherstone 2008, "Rigid Body Dynamics Algorithms", ch. 4), times the axis function's slope and the chain rule
through couplers. Poses, markers and twists come from the body module's one kinematics engine
(`biomotion.body.kinematics.KinematicTree`, the one forward kinematics and dynamics use). The Gauss-Newton normal
equations are assembled from 6x6 marker sums accumulated over the subtree each coordinate moves, as the
composite-rigid-body algorithm accumulates inertias (ibid., ch. 6), so the marker Jacobian is never formed: the
cost per frame grows with markers x coordinates + coordinates^2, not markers x coordinates^2.

Warm start, without a loop over frames: a coarse pass solves frames ``coarse_interval`` seconds apart, each from
the root body's pose fitted to its markers (in closed form, a weighted Procrustes fit, where the root joint is
three orthogonal rotations and three translations; else a multi-start over the root joint alone), then re-solves
each from its neighbours' solutions and keeps the best; the fine pass starts every frame from the cubic-spline
interpolation of the coarse solutions; frames left with a clearly higher cost than a neighbour, or off the line
between their neighbours, are re-solved from the neighbours' solutions (OpenSim's frame-to-frame propagation, done in
parallel). Unclamped angles are finally unwrapped in time, so a trajectory never jumps by 2 pi.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.interpolate
import torch

from biomotion.body.kinematics import KinematicTree
from biomotion.body.model import BodyModel
from biomotion.body.spatial import cross_frames_last as _cross
from biomotion.errors import DataFormatError, ModelError
from biomotion.io.setup import CoordinateTask
from biomotion.motion import Markers, Motion

_F64 = torch.float64
_ROOT_ITERATIONS = 5  # iterations of the root-joint multi-start: a start, not a solution (enough to rank starts)
_COARSE_ITERATIONS = 30  # coarse pass and neighbour re-solves: starts for the fine pass, not solutions
_COARSE_TOLERANCE = 1e-6
_NEIGHBOUR_ITERATIONS = 10  # coarse frames re-solved from their neighbours: enough to see a better basin
_STEP_TOLERANCE = 1e-6  # rad or m: an accepted step this small ends a frame's iterations


# --- kinematics with analytic Jacobians, on the body module's engine ----------------------------------------------


def _value_and_slope(function, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """f(x) and f'(x) of one of the model's functions (analytic where the function offers it, else by
    forward-mode autograd)."""
    if hasattr(function, "derivatives"):
        value, slope, _ = function.derivatives(x)
        return value, slope
    return torch.func.jvp(function, (x,), (torch.ones_like(x),))


class _Kinematics:
    """Marker positions, coordinate twists and Gauss-Newton normal equations of a `BodyModel`, for chosen markers
    and free coordinates.

    The forward kinematics is the body module's one engine, `KinematicTree` (poses, body-fixed points, each
    coordinate's ground twist; body-indexed, joint b being the joint whose child is body b). What is IK's own: the
    free coordinates z and the chain rule through couplers (`coordinates`, `dq_dz`), the normal equations
    accumulated per coordinate without forming the marker Jacobian, and the structure the warm start reads
    (periodic and whole-turn coordinates, ball joints). ``joints`` restricts the tree to a subtree closed under
    parents (the root joint alone for the multi-start); the markers must sit on bodies that subtree moves.
    """

    def __init__(
        self, model: BodyModel, markers: Sequence[int], free: Sequence[int], joints: Sequence[int] | None = None
    ) -> None:
        self.n_q = model.n_q
        free = list(free)
        self.free = torch.as_tensor(free, dtype=torch.long)
        self.n_z = len(free)
        self.defaults = model.defaults.to(_F64)
        self.couplers = list(model.couplers)
        if joints is None:
            tree = KinematicTree.of(model, _F64)
        else:
            tree = KinematicTree(model, _F64, bodies=[model.joints[j].child for j in joints])
        self.tree = tree
        # twist columns: the free coordinates, then the coupled ones (chain rule to z afterwards)
        self.dependents = [c.dependent for c in self.couplers if c.dependent not in free]
        self.columns = torch.tensor(free + self.dependents, dtype=torch.long)
        self.n_columns = len(self.columns)
        # [c, d] of the Hessian's products (`normal_equations`): 1 where c's joint is above d's (the product is
        # H_cd, and H_dc by symmetry), 1/2 where they share a joint (both orders are H_cd: their mean), else 0
        mask = tree.ancestor_joint.to(_F64) + 0.5 * tree.same_joint.to(_F64)
        self.hessian_mask = mask[self.columns][:, self.columns]

        # markers: their tree body (-1 on ground) and which columns move them, [C, M]
        self.markers = torch.as_tensor(list(markers), dtype=torch.long)
        self.marker_body = tree.tree_bodies(model.marker_bodies[self.markers])
        self.marker_offsets = model.marker_offsets[self.markers].to(_F64)
        moved = tree.moves[self.marker_body.clamp(min=0)][:, self.columns] & (self.marker_body >= 0)[:, None]
        self.marker_columns = moved.T.to(_F64)

        # free coordinates that only turn rotation axes with unit slope: a 2 pi change gives the same pose
        affine, slope, intercept = tree.affine_axes()
        rotation = torch.zeros(len(tree.argument), dtype=torch.bool)
        rotation[tree.rotation] = True
        unit_turn = rotation & affine & ((slope.abs() - 1.0).abs() < 1e-12)
        independent = {c.independent for c in self.couplers}
        turning = torch.tensor(
            [
                c not in independent and bool((tree.argument == c).any()) and bool(unit_turn[tree.argument == c].all())
                for c in free
            ],
            dtype=torch.bool,
        )
        clamped = model.clamped[free]
        self.periodic = turning & ~clamped
        # clamped to a whole turn ([-pi, pi] and the like): every pose is in range, so the limit is only where the
        # circle is cut; solving across it (and wrapping back after) keeps a frame off a limit it could go round
        span = (model.ranges[free, 1] - model.ranges[free, 0]).to(_F64)
        self.full_turn = turning & clamped & (span >= 2 * math.pi - 1e-6)
        self.ball_joints = self._ball_joints(model, free, affine, slope, intercept)
        self.task_base = torch.zeros(self.n_q, self.n_z, dtype=_F64)
        self.task_base[self.free, torch.arange(self.n_z)] = 1.0

    def _ball_joints(
        self, model: BodyModel, free: Sequence[int], affine: torch.Tensor, slope: torch.Tensor, intercept: torch.Tensor
    ) -> list[tuple[tuple[int, int, int], float, float]]:
        """Joints that turn by three rotations about mutually orthogonal axes, each the amount s q + c (s = +-1) of
        its own free coordinate, and that translate independently of them (shoulders, usually): their pose has a
        second set of angles, (a + pi, pi - b, c + pi) in the rotation amounts (Tait-Bryan). Per joint the three
        z columns, and the middle axis's slope and intercept; ``affine``, ``slope``, ``intercept`` are the tree's
        `KinematicTree.affine_axes`."""
        column = {c: k for k, c in enumerate(free)}
        tree_body = {b: k for k, b in enumerate(self.tree.bodies.tolist())}
        found = []
        for j in model.joint_order:
            joint = model.joints[j]
            if joint.child not in tree_body:
                continue
            numbers = (self.tree.axis_body == tree_body[joint.child]).nonzero().flatten().tolist()  # in axis order
            rotations = [(a, n) for a, n in zip(joint.axes, numbers) if a.rotation]
            if len(rotations) != 3 or any(
                not bool(affine[n]) or a.coordinate not in column or abs(abs(float(slope[n])) - 1.0) > 1e-12
                for a, n in rotations
            ):
                continue
            coordinates = [a.coordinate for a, _ in rotations]
            directions = torch.stack([a.axis.to(_F64) for a, _ in rotations])
            moved = any(a.coordinate in coordinates for a in joint.axes if not a.rotation)
            if (
                len(set(coordinates)) < 3
                or moved
                or not torch.allclose(directions @ directions.T, torch.eye(3, dtype=_F64), atol=1e-9)
            ):
                continue
            middle = rotations[1][1]
            found.append((tuple(column[c] for c in coordinates), float(slope[middle]), float(intercept[middle])))
        return found

    @classmethod
    def of(
        cls, model: BodyModel, markers: Sequence[int], free: Sequence[int], joints: Sequence[int] | None = None
    ) -> _Kinematics:
        """`_Kinematics` of these markers and free coordinates, cached on the (immutable) model: a batch solves
        many trials on one model, and building the structure costs as much as a few evaluations."""
        key = (tuple(int(m) for m in markers), tuple(int(c) for c in free), None if joints is None else tuple(joints))
        cache = model.__dict__.get("_ik_kinematics")
        if cache is None:
            cache = {}
            object.__setattr__(model, "_ik_kinematics", cache)  # frozen dataclass: a cache, not a field
        if key not in cache:
            cache[key] = cls(model, markers, free, joints)
        return cache[key]

    # coordinates ------------------------------------------------------------------------------------------------
    def coordinates(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Full q [T, n_q] from free z [T, n_z], and d(coupled coordinates)/dz [T, n_dependents, n_z]."""
        q = self.defaults.expand(z.shape[0], self.n_q).clone()
        q[:, self.free] = z
        coupled = z.new_zeros(z.shape[0], len(self.dependents), self.n_z)
        for coupler in self.couplers:
            value, slope = _value_and_slope(coupler.function, q[:, coupler.independent])
            q[:, coupler.dependent] = coupler.scale_factor * value
            if coupler.dependent not in self.dependents:
                continue
            row = self.dependents.index(coupler.dependent)
            if coupler.independent in self.dependents:
                upstream = coupled[:, self.dependents.index(coupler.independent)]
            else:
                upstream = self.task_base[coupler.independent].expand(z.shape[0], -1)
            coupled[:, row] = coupler.scale_factor * slope[:, None] * upstream
        return q, coupled

    def task_free(self, columns: torch.Tensor) -> torch.Tensor | None:
        """The z index of each coordinate in ``columns`` when all of them are free (not coupled), else None."""
        position = {c: k for k, c in enumerate(self.free.tolist())}
        found = [position.get(c) for c in columns.tolist()]
        return None if None in found else torch.tensor(found, dtype=torch.long)

    def dq_dz(self, coupled: torch.Tensor) -> torch.Tensor:
        """[T, n_q, n_z] dq/dz: ones for the free coordinates, the couplers' chain rule for the coupled ones."""
        out = self.task_base.expand(coupled.shape[0], -1, -1)
        if self.dependents:
            out = out.clone()
            out[:, self.dependents] = coupled
        return out

    # forward kinematics -----------------------------------------------------------------------------------------
    def evaluate(self, z: torch.Tensor, twists: bool = True) -> _Pose:
        """Markers in ground and, with ``twists``, every column's ground twist at free coordinates z [T, n_z]: the
        tree's pass (`KinematicTree.axis_values` -> `joint_frames` -> `poses` -> `points`, and `ground_axes` ->
        `twists`), frames last as the tree gives them (the normal equations work in that layout)."""
        q, coupled = self.coordinates(z)
        tree = self.tree
        values, slopes = tree.axis_values(q.T, order=1)
        frames = tree.joint_frames(values)
        poses = tree.poses(frames)
        x = tree.points(poses, self.marker_body, self.marker_offsets)  # [M, 3, T]
        if not twists:
            return _Pose(x, q, coupled, None, None)
        # omega x p + v is the velocity of a point p per unit rate of the column's coordinate
        omega, velocity = tree.twists(tree.ground_axes(poses, frames), slopes)  # [n_q, 3, T]
        return _Pose(x, q, coupled, omega[self.columns], velocity[self.columns])

    def normal_equations(
        self, pose: _Pose, weights: torch.Tensor, residuals: torch.Tensor, column_weights: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Gauss-Newton H = J^T W J [T, C, C] and g = J^T W r [T, C] over the columns, without forming J, from the
        marker ``weights`` [M, T] (zero where occluded), ``residuals`` [M, 3, T] and ``column_weights`` [C, T], the
        weight of the markers each column moves (constant over iterations, so the caller keeps it).

        A marker x on body b has d x / d column c = omega_c x x + v_c when c's joint is an ancestor of b (else 0).
        Summing over markers, each body contributes twist^T G_b twist with the 6x6 G_b = sum_i w_i A_i^T A_i,
        A_i = [-[x_i]x | I]; and the bodies below a joint add up (the composite inertia trick of Featherstone's
        CRBA, "Rigid Body Dynamics Algorithms" ch. 6), so H_cd = twist_c^T G~_j twist_d with j the deeper of the
        two columns' joints when one is the other's ancestor, 0 otherwise. G~ of each column's joint is one matrix
        product of the per-marker sums [M, 15, T] (w x, the six products of w x x^T, w x x r, w r) with the tree's
        [column, marker] "moves" mask, frames last so that it is a single GEMM over every frame (batched small
        products loop over frames on the CPU); the sums are written in place, one operation each, since at a few
        hundred frames the count of tensor operations, not arithmetic, sets the time.
        """
        x, r = pose.x_last, residuals  # [M, 3, T]
        w = weights[:, None, :]  # [M, 1, T]
        count, _, frames = x.shape
        sums = x.new_empty(count, 15, frames)
        wx = torch.mul(w, x, out=sums[:, 0:3])
        torch.mul(wx, x, out=sums[:, 3:6])  # xx, yy, zz
        torch.mul(wx[:, 0:1], x[:, 1:3], out=sums[:, 6:8])  # xy, xz
        torch.mul(wx[:, 1], x[:, 2], out=sums[:, 8])  # yz
        for k, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):  # w x x r
            torch.mul(wx[:, a], r[:, b], out=sums[:, 9 + k]).sub_(wx[:, b] * r[:, a])
        torch.mul(w, r, out=sums[:, 12:15])
        at = (self.marker_columns @ sums.view(count, 15 * frames)).view(-1, 15, frames)  # [C, 15, T]
        s1, xr, rr = at[:, 0:3], at[:, 9:12], at[:, 12:15]
        xx, yy, zz, xy, xz, yz = at[:, 3:9].unbind(1)
        omega, velocity = pose.omega, pose.velocity  # [C, 3, T]
        o0, o1, o2 = omega.unbind(1)
        # [|x|^2 I - x x^T] omega, summed: the rotational block of G~ applied to omega
        k_omega = torch.stack(
            [
                (yy + zz) * o0 - xy * o1 - xz * o2,
                (xx + zz) * o1 - xy * o0 - yz * o2,
                (xx + yy) * o2 - xz * o0 - yz * o1,
            ],
            1,
        )
        top = k_omega + _cross(s1, velocity)
        bottom = _cross(omega, s1) + column_weights[:, None] * velocity
        twist, moment = torch.cat([omega, velocity], 1), torch.cat([top, bottom], 1)  # [C, 6, T]
        columns = twist.shape[0]
        # [c, d]: twist_c . G~_d twist_d, valid where c's joint is d's or above it (`hessian_mask`)
        if columns <= 8 or frames >= 256:  # few columns or many frames: six products along contiguous frames
            products = twist[:, None, 0] * moment[None, :, 0]  # [C, C, T]
            for k in range(1, 6):
                products.addcmul_(twist[:, None, k], moment[None, :, k])
            kept = products.mul_(self.hessian_mask[..., None])
            hessian = (kept + kept.transpose(0, 1)).permute(2, 0, 1).contiguous()
        else:  # contiguous operands (strided ones make bmm loop per frame)
            products = torch.bmm(twist.permute(2, 0, 1).contiguous(), moment.permute(2, 1, 0).contiguous())
            kept = products.mul_(self.hessian_mask)
            hessian = kept + kept.transpose(1, 2)
        gradient = ((omega * xr).sum(1) + (velocity * rr).sum(1)).T
        return hessian, gradient


@dataclass(frozen=True)
class _Pose:
    x_last: torch.Tensor  # [M, 3, T] markers in ground, frames last
    q: torch.Tensor  # [T, n_q]
    coupled: torch.Tensor  # [T, n_dependents, n_z] d(coupled coordinates)/dz
    omega: torch.Tensor | None  # [C, 3, T] angular part of each column's ground twist
    velocity: torch.Tensor | None  # [C, 3, T] linear part (velocity of the point at the ground origin)

    @property
    def x(self) -> torch.Tensor:
        """[T, M, 3] markers in ground (a view)."""
        return self.x_last.permute(2, 0, 1)


# --- the least-squares problem ----------------------------------------------------------------------------------


@dataclass
class _Problem:
    """One batch of frames: observations, weights, coordinate tasks and bounds of the free coordinates.

    Markers are stored frames last, the layout the kinematics gives them in, so that residuals and sums over
    markers are operations along contiguous frames."""

    kinematics: _Kinematics
    observed: torch.Tensor  # [M, 3, T], zeros where occluded
    weights: torch.Tensor  # [M, T], zero where occluded
    task_columns: torch.Tensor  # [K] coordinate index of each task
    task_weights: torch.Tensor  # [K]
    task_targets: torch.Tensor  # [T, K]
    lower: torch.Tensor  # [n_z]
    upper: torch.Tensor  # [n_z]

    def __post_init__(self) -> None:
        # constant over the iterations: each frame's marker weight, the weight of the markers each column moves,
        # and where the coordinate tasks sit in z (None when one is on a coupled coordinate)
        self.total_weight = self.weights.sum(0).clamp(min=1e-300)  # [T]
        self.column_weights = self.kinematics.marker_columns @ self.weights  # [C, T]
        self.task_free = self.kinematics.task_free(self.task_columns) if len(self.task_columns) else None

    def frames(self, index: torch.Tensor) -> _Problem:
        return _Problem(
            self.kinematics,
            self.observed[..., index],
            self.weights[:, index],
            self.task_columns,
            self.task_weights,
            self.task_targets[index],
            self.lower,
            self.upper,
        )

    def repeat(self, count: int) -> _Problem:
        """The same frames ``count`` times over (for multi-starts), start-major."""
        return self.frames(torch.arange(self.observed.shape[-1]).repeat(count))

    def evaluate(
        self, z: torch.Tensor, derivatives: bool = True
    ) -> tuple[_Pose, torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """(pose, S [T], H [T, n_z, n_z], g [T, n_z]) at z: S = W E is OpenSim's objective E times the frame's
        marker weight W, i.e. half the weighted squared marker residuals plus W sum_j w_j (q_j - v_j)^2; H and g
        are its Gauss-Newton Hessian and gradient (None without ``derivatives``)."""
        kin = self.kinematics
        pose = kin.evaluate(z, derivatives)
        residuals = pose.x_last - self.observed  # [M, 3, T]; an occluded marker's weight is 0, so it drops out
        task_error = pose.q[:, self.task_columns] - self.task_targets
        task_scale = 2.0 * self.total_weight[:, None] * self.task_weights  # [T, K]
        cost = 0.5 * (self.weights * (residuals * residuals).sum(1)).sum(0) + 0.5 * (
            task_scale * task_error * task_error
        ).sum(-1)
        if not derivatives:
            return pose, cost, None, None
        h, g = kin.normal_equations(pose, self.weights, residuals, self.column_weights)
        n_z = kin.n_z
        hessian, gradient = h[:, :n_z, :n_z], g[:, :n_z]
        if kin.dependents:  # chain rule through the couplers: columns = [free | coupled]
            f = pose.coupled  # [T, D, n_z]
            f_t = f.transpose(1, 2).contiguous()  # contiguous operands: strided ones make bmm loop per frame
            cross = h[:, :n_z, n_z:].contiguous() @ f
            hessian = hessian + cross + cross.transpose(1, 2) + f_t @ (h[:, n_z:, n_z:].contiguous() @ f)
            gradient = gradient + (f_t @ g[:, n_z:, None])[..., 0]
        if len(self.task_columns):
            tasks = self.task_free
            if tasks is not None:  # tasks on free coordinates: rows of dq/dz are unit vectors, add on the diagonal
                # in place: hessian is h (made for this call) or a sum made above
                hessian.diagonal(dim1=1, dim2=2).index_add_(1, tasks, task_scale)
                gradient = gradient.index_add(1, tasks, task_scale * task_error)
            else:
                rows = kin.dq_dz(pose.coupled)[:, self.task_columns]  # [T, K, n_z]
                rows_t = rows.transpose(1, 2).contiguous()
                hessian = hessian + rows_t @ (task_scale[..., None] * rows)
                gradient = gradient + (rows_t @ (task_scale * task_error)[..., None])[..., 0]
        return pose, cost, hessian, gradient


def _levenberg_marquardt(
    problem: _Problem, z: torch.Tensor, max_iterations: int, tolerance: float, damping: float = 1e-3
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """Minimise every frame's objective from ``z`` [T, n_z] within the bounds.

    Returns (z, objective [T] (OpenSim's), converged [T], iterations). A frame is converged when the Gauss-Newton
    model predicts, or a step makes, a change of its cost below ``tolerance`` times the cost (plus 1e-15 of the
    marker weight), when an accepted step moves no coordinate by more than 1e-6 (rad or m), or when no damping
    makes a step descend.
    """
    lower, upper = problem.lower, problem.upper
    z = torch.maximum(torch.minimum(z, upper), lower)
    count, n_z = z.shape
    _, cost, hessian, gradient = problem.evaluate(z)
    scale = problem.total_weight
    lam = torch.full((count,), damping, dtype=_F64)
    done = torch.zeros(count, dtype=torch.bool)
    eye = torch.eye(n_z, dtype=_F64)
    # The frames still iterating are a working set: rows of compact copies (`work` their frame numbers, `live`
    # which still iterate). Finished frames stay in it, frozen, until fewer than half of its rows are live; then it
    # is compacted. Gathering and scattering every array at every iteration cost more than the rows they save.
    work = torch.arange(count)
    sub, z_w, cost_w, h_w, g_w, lam_w, scale_w = problem, z.clone(), cost.clone(), hessian, gradient, lam, scale
    live = torch.ones(count, dtype=torch.bool)
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        remaining = int(live.sum())
        if remaining == 0:
            iterations -= 1
            break
        if remaining < len(work) // 2:
            z[work], cost[work] = z_w, cost_w
            done[work[~live]] = True
            rows = live.nonzero().squeeze(-1)
            work = work[rows]
            sub = problem.frames(work)
            z_w, cost_w, h_w, g_w, lam_w, scale_w, live = (
                t[rows] for t in (z_w, cost_w, h_w, g_w, lam_w, scale_w, live)
            )
        blocked = ((z_w <= lower + 1e-12) & (g_w > 0)) | ((z_w >= upper - 1e-12) & (g_w < 0))
        diagonal = h_w.diagonal(dim1=-2, dim2=-1)
        shift = lam_w[:, None] * (diagonal + 1e-9 * (1.0 + diagonal.amax(-1, keepdim=True)))  # the damping [T, n]
        damped = h_w.clone()
        rhs = g_w
        if bool(blocked.any()):  # coordinates a bound holds: their rows and columns become the identity's
            keep = (~blocked).to(_F64)
            damped.mul_(keep[:, :, None] * keep[:, None, :])
            shift = shift * keep
            damped.diagonal(dim1=-2, dim2=-1).add_(1.0 - keep)
            rhs = g_w * keep
        damped.diagonal(dim1=-2, dim2=-1).add_(shift)
        factor, info = torch.linalg.cholesky_ex(damped)
        if bool((info > 0).any()):  # numerically indefinite: regularise those frames harder
            bad = info > 0
            extra = (1.0 + diagonal[bad].amax(-1))[:, None]
            factor[bad] = torch.linalg.cholesky(damped[bad] + eye * extra[..., None])
            shift[bad] = shift[bad] + extra
        step = -torch.cholesky_solve(rhs[..., None], factor)[..., 0]
        # the Gauss-Newton model's predicted decrease -g.s - s^T H s / 2; the step solves (H + diag(shift)) s = -g
        # on the coordinates it moves (0 on the others), so s^T H s = -g.s - sum(shift s^2), without a product by H
        predicted = 0.5 * ((shift * step * step).sum(-1) - (g_w * step).sum(-1))
        # frames that cannot gain more than the tolerance stop here
        finished = live & (predicted <= 0.5 * tolerance * cost_w) & (lam_w < 0.1)  # not after rejections
        live = live & ~finished
        if not bool(live.any()):
            break
        trial = torch.maximum(torch.minimum(z_w + step, upper), lower)
        _, cost_new, h_new, g_new = sub.evaluate(trial)
        accept = live & (cost_new <= cost_w)
        small = ((cost_w - cost_new).abs() <= tolerance * cost_w + 1e-15 * scale_w) | (
            accept & ((trial - z_w).abs().amax(-1) <= _STEP_TOLERANCE)
        )
        z_w = torch.where(accept[:, None], trial, z_w)
        cost_w = torch.where(accept, cost_new, cost_w)
        h_w = torch.where(accept[:, None, None], h_new, h_w)
        g_w = torch.where(accept[:, None], g_new, g_w)
        stop = live & (small | (lam_w > 1e12))
        lam_w = torch.where(live, torch.where(accept, (lam_w / 3.0).clamp(min=1e-12), lam_w * 8.0), lam_w)
        live = live & ~stop
    z[work], cost[work] = z_w, cost_w
    done[work] = ~live
    return z, cost / scale, done, iterations


# --- warm start ----------------------------------------------------------------------------------------------------


def _root_candidates(model: BodyModel, kin: _Kinematics) -> torch.Tensor:
    """Start values [S, n_root] for the root joint's free coordinates: the defaults, then a quarter or half
    turn of one rotation at a time (within its range if clamped)."""
    start = kin.defaults[kin.free]
    rows = [start]
    for k, c in enumerate(kin.free.tolist()):
        if model.motion_types[c] != "rotational":
            continue
        low, high = (float(v) for v in model.ranges[c]) if bool(model.clamped[c]) else (-math.inf, math.inf)
        for turn in (math.pi / 2, -math.pi / 2, math.pi):
            if low <= float(start[k]) + turn <= high:
                row = start.clone()
                row[k] += turn
                rows.append(row)
    return torch.stack(rows)


def _root_start(
    model: BodyModel, problem: _Problem, marker_index: Sequence[int], count: int, free: Sequence[int]
) -> torch.Tensor:
    """Initial z [T, n_z]: defaults, with the root joint's free coordinates fitted to the markers on the root
    body. In closed form where the root joint allows it (`_fit_root`), else, and in the frames the closed form
    cannot take, by a multi-start over the root joint alone (`_root_multistart`). Defaults alone when the root body
    carries fewer than three tracked markers."""
    z0 = model.defaults.to(_F64)[list(free)].expand(count, len(free)).clone()
    roots = [j for j in model.joint_order if model.joints[j].parent < 0]
    if not roots:
        return z0
    root = max(roots, key=lambda j: sum(int(model.marker_bodies[m]) == model.joints[j].child for m in marker_index))
    body = model.joints[root].child
    on_root = [k for k, m in enumerate(marker_index) if int(model.marker_bodies[m]) == body]
    root_free = [c for c in model.joints[root].coordinates if c in set(free)]
    if len(on_root) < 3 or not root_free:
        return z0
    columns = [list(free).index(c) for c in root_free]
    fitted = _fit_root(model, problem, [marker_index[k] for k in on_root], on_root, root, root_free, columns)
    if fitted is None:
        rest = torch.arange(count)
    else:
        values, fit = fitted
        z0[:, columns] = torch.where(fit[:, None], values, z0[:, columns])
        rest = (~fit).nonzero().squeeze(-1)
    if rest.numel():
        z0[rest[:, None], columns] = _root_multistart(
            model, problem.frames(rest), [marker_index[k] for k in on_root], on_root, root, root_free, columns
        )
    return z0


def _fit_root(
    model: BodyModel,
    problem: _Problem,
    markers: Sequence[int],
    on_root: Sequence[int],
    root: int,
    root_free: Sequence[int],
    columns: Sequence[int],
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """The root joint's coordinates [T, len(root_free)] that place the root body's markers best, in closed form,
    and [T] the frames where that fit is taken; None when the joint is not of the form it needs.

    The root body's pose in ground is the weighted Procrustes fit of its markers' body-fixed offsets to the
    observed positions (Kabsch 1976, Acta Cryst A32:922; weights the markers' IK weights, occluded ones 0): the
    exact minimiser of the markers' part of the objective over rigid poses, for every frame at once (one batched
    3x3 SVD). The joint's coordinates follow when it is six affine axes of its six free coordinates: three rotations
    about mutually orthogonal axes with unit slope (their angles are the Euler angles of the joint rotation in that
    basis; of the two sets, (a + pi, pi - b, c + pi), the one nearest the defaults among those in range) and three
    independent translations (a 3x3 solve). A frame is left to the multi-start when fewer than three of its markers
    are visible, they are collinear, the middle angle is at gimbal lock, or no set of angles is within the bounds.
    """
    joint = model.joints[root]
    tree = KinematicTree.of(model, _F64)
    numbers = (tree.axis_body == int((tree.bodies == joint.child).nonzero())).nonzero().flatten().tolist()
    affine, slope, intercept = tree.affine_axes()
    rotations = [(a, n) for a, n in zip(joint.axes, numbers) if a.rotation]
    translations = [(a, n) for a, n in zip(joint.axes, numbers) if not a.rotation]
    coordinates = [a.coordinate for a, _ in rotations + translations]
    if (
        len(rotations) != 3
        or len(translations) != 3
        or sorted(coordinates, key=str) != sorted(root_free, key=str)
        or any(not bool(affine[n]) for _, n in rotations + translations)
        or any(abs(abs(float(slope[n])) - 1.0) > 1e-12 for _, n in rotations)
    ):
        return None
    units = torch.stack([a.axis.to(_F64) for a, _ in rotations], 1)  # [3, 3] columns u_k
    shifts = torch.stack([a.axis.to(_F64) for a, _ in translations], 1)  # [3, 3] columns b_m
    if not torch.allclose(units.T @ units, torch.eye(3, dtype=_F64), atol=1e-9) or abs(float(torch.det(shifts))) < 1e-9:
        return None
    flip = float(torch.det(units))  # -1: a left-handed basis, made right-handed by reversing u_3 (and its angle)
    basis = units * torch.tensor([1.0, 1.0, flip], dtype=_F64)

    # weighted Procrustes: R_GB, p_GB minimising sum_i w_i |R o_i + p - y_i|^2
    offsets = model.marker_offsets[list(markers)].to(_F64)  # [M, 3] in the body
    observed, weights = problem.observed[list(on_root)], problem.weights[list(on_root)]  # [M, 3, T], [M, T]
    total = weights.sum(0).clamp(min=1e-300)  # [T]
    o_mean = (weights.T @ offsets) / total[:, None]  # [T, 3]
    y_mean = (weights[:, None] * observed).sum(0).T / total[:, None]  # [T, 3]
    o_centred = (offsets[None] - o_mean[:, None]) * weights.T[..., None]  # [T, M, 3], weighted
    y_centred = observed.permute(2, 0, 1) - y_mean[:, None]
    u, s, vh = torch.linalg.svd(o_centred.transpose(1, 2) @ y_centred)  # sum_i w_i o_i y_i^T = U S V^T
    v = vh.transpose(1, 2)
    sign = torch.sign(torch.linalg.det(v @ u.transpose(1, 2)))
    r_gb = (v * torch.stack([torch.ones_like(sign), torch.ones_like(sign), sign], -1)[:, None]) @ u.transpose(1, 2)
    p_gb = y_mean - (r_gb @ o_mean[..., None])[..., 0]
    fit = ((weights > 0).sum(0) >= 3) & (s[:, 1] > 1e-9 * s[:, 0].clamp(min=1e-300))

    # the joint: R_GB = R_PF R_FM R_BM^T, p_GB = p_PF + R_PF (p_FM - R_FM R_BM^T p_BM)
    r_pf, p_pf = joint.parent_rotation.to(_F64), joint.parent_translation.to(_F64)
    r_bm, p_bm = joint.child_rotation.to(_F64), joint.child_translation.to(_F64)
    r_fm = r_pf.T @ r_gb @ r_bm
    p_fm = ((p_gb - p_pf) @ r_pf) + (r_fm @ (r_bm.T @ p_bm))  # [T, 3]
    # Euler angles in the basis: B^T R_FM B = Rx(a) Ry(b) Rz(c)
    m = basis.T @ r_fm @ basis
    a = torch.atan2(-m[:, 1, 2], m[:, 2, 2])
    b = torch.asin(m[:, 0, 2].clamp(-1.0, 1.0))
    c = torch.atan2(-m[:, 0, 1], m[:, 0, 0])
    fit &= m[:, 0, 2].abs() < 1.0 - 1e-9
    angles = [torch.stack([a, b, flip * c], -1), torch.stack([a + math.pi, math.pi - b, flip * (c + math.pi)], -1)]
    amounts = torch.linalg.solve(shifts, p_fm.T).T  # [T, 3] translation amounts

    def coordinate_values(rotation_amounts: torch.Tensor) -> torch.Tensor:
        values = torch.empty(rotation_amounts.shape[0], len(root_free), dtype=_F64)
        for k, (axis, n) in enumerate(rotations):
            values[:, root_free.index(axis.coordinate)] = (rotation_amounts[:, k] - intercept[n]) / slope[n]
        for k, (axis, n) in enumerate(translations):
            values[:, root_free.index(axis.coordinate)] = (amounts[:, k] - intercept[n]) / slope[n]
        return values

    lower, upper = problem.lower[list(columns)], problem.upper[list(columns)]
    defaults = model.defaults.to(_F64)[list(root_free)]
    turning = [root_free.index(axis.coordinate) for axis, _ in rotations]
    reference = defaults.expand(len(total), -1)
    options, distances = [], []
    for option in angles:
        values = _nearest_in_range(coordinate_values(option), turning, lower, upper, reference)
        inside = _in_range(values, list(range(len(root_free))), lower, upper)
        distance = ((values[:, turning] - defaults[turning]) ** 2).sum(-1)
        options.append(values)
        distances.append(torch.where(inside, distance, torch.full_like(distance, math.inf)))
    second = distances[1] < distances[0]
    chosen = torch.where(second[:, None], options[1], options[0])
    fit &= torch.isfinite(torch.minimum(*distances))
    return chosen, fit


def _root_multistart(
    model: BodyModel,
    problem: _Problem,
    markers: Sequence[int],
    on_root: Sequence[int],
    root: int,
    root_free: Sequence[int],
    columns: Sequence[int],
) -> torch.Tensor:
    """The root joint's free coordinates [T, len(root_free)] fitted to the root body's markers from several
    orientations (`_root_candidates`, a few iterations each over the root joint alone, the best kept per frame):
    the start where the closed form (`_fit_root`) does not apply."""
    count = problem.observed.shape[-1]
    kin = _Kinematics.of(model, markers, root_free, joints=[root])
    candidates = _root_candidates(model, kin)
    sub = _Problem(
        kin,
        problem.observed[list(on_root)],
        problem.weights[list(on_root)],
        torch.zeros(0, dtype=torch.long),
        torch.zeros(0, dtype=_F64),
        problem.task_targets.new_zeros(count, 0),
        problem.lower[list(columns)],
        problem.upper[list(columns)],
    )
    starts = candidates.repeat_interleave(count, dim=0)
    z, cost, _, _ = _levenberg_marquardt(sub.repeat(len(candidates)), starts, _ROOT_ITERATIONS, 1e-6, damping=1e-2)
    cost = torch.where(torch.isfinite(cost), cost, torch.full_like(cost, math.inf)).reshape(len(candidates), count)
    z = z.reshape(len(candidates), count, -1)
    # equal fits (equivalent Euler angles): prefer the one nearest the defaults, as a start from them would give
    tie = cost <= cost.amin(0) * (1 + 1e-6) + 1e-12
    distance = ((z - kin.defaults[list(root_free)]) ** 2).sum(-1)
    best = torch.where(tie, distance, torch.full_like(distance, math.inf)).argmin(0)
    return z[best, torch.arange(count)]


def _propagate(
    problem: _Problem,
    z: torch.Tensor,
    cost: torch.Tensor,
    max_iterations: int,
    tolerance: float,
    every_frame: bool = False,
    rounds: int = 3,
    ratio: float = 1.5,
    jump: float = 0.1,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Re-solve suspect frames from each neighbour's solution and keep the best: a frame-parallel version of the
    sequential warm start that keeps OpenSim's IK on one branch of the solutions.

    Suspect are frames whose cost exceeds ``ratio`` times a neighbour's or that leave the line between their
    neighbours by more than ``jump`` (rad or m) in some coordinate; repeats while it helps. With ``every_frame``
    (the coarse pass, whose frames are far apart) the first round re-solves all frames, later ones only those
    whose cost stands out.
    """
    count = z.shape[0]
    if count < 2:
        return z, cost
    for round_ in range(rounds):
        if every_frame and round_ == 0:
            suspect = torch.arange(count)
        else:
            neighbour_cost = torch.minimum(torch.cat([cost[:1], cost[:-1]]), torch.cat([cost[1:], cost[-1:]]))
            midpoint = 0.5 * (torch.cat([z[:1], z[:-1]]) + torch.cat([z[1:], z[-1:]]))
            off_line = ((z - midpoint).abs().amax(-1) > jump) & (not every_frame)  # coarse: far apart
            off_line[[0, -1]] = False
            suspect = ((cost > ratio * neighbour_cost + 1e-12) | off_line).nonzero().squeeze(-1)
        if suspect.numel() == 0:
            break
        left, right = (suspect - 1).clamp(min=0), (suspect + 1).clamp(max=count - 1)
        from_left, from_right = suspect[left != suspect], suspect[right != suspect]
        starts = torch.cat([left[left != suspect], right[right != suspect]])
        frames = torch.cat([from_left, from_right])
        z_try, cost_try, _, _ = _levenberg_marquardt(
            problem.frames(frames), z[starts].clone(), max_iterations, tolerance
        )
        improved = False
        for part in (slice(0, len(from_left)), slice(len(from_left), None)):  # each side holds a frame once
            target = frames[part]
            # better by more than the solver's tolerance: a lower cost within it is the same minimum
            better = cost_try[part] < cost[target] * (1 - tolerance)
            z[target[better]] = z_try[part][better]
            cost[target[better]] = cost_try[part][better]
            improved |= bool(better.any())
        if not improved:
            break
    return z, cost


# --- public API ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class IKResult:
    """Marker IK of a trial.

    Attributes:
        motion: every model coordinate (CoordinateSet order, SI units) at the solved frames.
        marker_names: the tracked markers (in the model and the data, weight > 0).
        weights: [M] their weights.
        errors: [T, M] distance between model and experimental marker (m), NaN where occluded.
        cost: [T] OpenSim's IK objective at the solution.
        converged: [T] whether the solver met its tolerance.
        iterations: solver iterations of the final pass.
    """

    motion: Motion
    marker_names: tuple[str, ...]
    weights: np.ndarray
    errors: np.ndarray
    cost: np.ndarray
    converged: np.ndarray
    iterations: int

    def rms(self) -> np.ndarray:
        """[T] marker error RMS per frame over the visible tracked markers (what OpenSim's IK tool logs)."""
        with np.errstate(invalid="ignore"):
            return np.sqrt(np.nanmean(self.errors**2, axis=1))

    def max_error(self) -> np.ndarray:
        """[T] largest marker error per frame."""
        return np.nanmax(self.errors, axis=1)

    @property
    def rmse(self) -> float:
        """Marker RMS error over every visible (frame, marker) sample (m)."""
        return float(np.sqrt(np.nanmean(self.errors**2)))


def within(markers: Markers, time_range: tuple[float, float]) -> Markers:
    """The frames with ``start <= t <= end``; a `DataFormatError` naming the field when there is none."""
    start, end = time_range
    if not np.any((markers.times >= start - 1e-9) & (markers.times <= end + 1e-9)):
        raise DataFormatError(
            None,
            f"no marker frame within time range {start}-{end} s (the markers span "
            f"{markers.times[0]}-{markers.times[-1]} s)",
            field="time_range",
        )
    return markers.slice(start, end)


def tracked_markers(
    model: BodyModel, markers: Markers, weights: Mapping[str, float] | None
) -> tuple[list[int], list[int], np.ndarray]:
    """(model marker indices, data marker indices, weights) of the markers IK tracks: in the model and in the
    data with a positive weight; ``weights=None`` tracks every such marker with weight 1."""
    data = {name: i for i, name in enumerate(markers.names)}
    model_index, data_index, w = [], [], []
    for m, name in enumerate(model.marker_names):
        weight = 1.0 if weights is None else float(weights.get(name, 0.0))
        if name in data and weight > 0:
            model_index.append(m)
            data_index.append(data[name])
            w.append(weight)
    return model_index, data_index, np.asarray(w, dtype=float)


#: The factor by which the markers' spread may differ from the model's before a length unit is taken to be wrong:
#: people differ from their (generic or scaled) model by far less, a unit mistake is 10x (mm/cm), 100x or 1000x.
UNIT_FACTOR = 3.0


def check_marker_scale(markers: Markers, model: BodyModel, source=None) -> None:
    """Refuse (`DataFormatError` naming ``source``, the file) markers whose spread about their centre differs from
    the model's markers' by more than `UNIT_FACTOR`: a file in millimetres declared in metres puts the subject 1.8 km
    tall, and IK would fit it without a word. Compares the median over frames of the RMS distance of the visible
    tracked markers from their centroid with the same for the model's markers in its default pose."""
    from biomotion.body.kinematics import marker_positions

    model_index, data_index, _ = tracked_markers(model, markers, None)
    if len(model_index) < 3:
        return
    frames = markers.positions[:: max(1, markers.n_frames // 50), data_index]  # [F, K, 3], up to ~50 frames
    spreads = []
    for frame in frames:
        visible = frame[np.isfinite(frame).all(axis=-1)]
        if len(visible) >= 3:
            spreads.append(np.sqrt(np.mean(np.sum((visible - visible.mean(axis=0)) ** 2, axis=-1))))
    if not spreads:
        return
    with torch.no_grad():
        points = marker_positions(model, model.defaults[None])[0, model_index].detach().cpu().numpy()
    expected = float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=-1))))
    found = float(np.median(spreads))
    if expected > 0 and not 1 / UNIT_FACTOR <= found / expected <= UNIT_FACTOR:
        raise DataFormatError(
            source,
            f"the markers spread {found:.3g} m about their centre, the model's {expected:.3g} m ({found / expected:.3g}"
            " times): a length unit is wrong (millimetres declared as metres?)",
            field="Units",
        )


def _task_targets(
    model: BodyModel, tasks: Sequence[CoordinateTask], times: np.ndarray, coordinate_data: Motion | None
) -> tuple[list[int], list[float], np.ndarray]:
    columns, weights, targets = [], [], []
    for task in tasks:
        if task.weight <= 0:
            continue
        c = model.coordinate_index(task.name)
        if task.value_type == "default_value":
            target = np.full(times.shape, float(model.defaults[c]))
        elif task.value_type == "manual_value":
            target = np.full(times.shape, task.value)
        else:
            if coordinate_data is None or task.name not in coordinate_data.names:
                raise DataFormatError(
                    None,
                    f"coordinate task {task.name!r} takes its value from a coordinates "
                    f"file, but no coordinate data with that column was given",
                    field=task.name,
                )
            target = np.interp(times, coordinate_data.times, coordinate_data[task.name])
        columns.append(c)
        weights.append(task.weight)
        targets.append(target)
    stacked = np.stack(targets, axis=1) if targets else np.zeros((times.size, 0))
    return columns, weights, stacked


def free_coordinates(model: BodyModel) -> list[int]:
    """Coordinates IK solves for: neither locked nor driven by a coupler."""
    dependent = {c.dependent for c in model.couplers}
    return [c for c in range(model.n_q) if not bool(model.locked[c]) and c not in dependent]


@dataclass(frozen=True)
class _Setup:
    model: BodyModel
    markers: Markers
    problem: _Problem
    free: list[int]
    model_index: list[int]
    weights: np.ndarray
    positions: torch.Tensor  # [T, M, 3] with NaN


def _setup(
    model: BodyModel,
    markers: Markers,
    weights: Mapping[str, float] | None,
    coordinate_tasks: Sequence[CoordinateTask],
    coordinate_data: Motion | None,
    time_range: tuple[float, float] | None,
) -> _Setup:
    model = model if model.dtype == _F64 else model.to(_F64)  # the same object keeps its cached kinematic tree
    if time_range is not None:
        markers = within(markers, time_range)
    model_index, data_index, w = tracked_markers(model, markers, weights)
    if not model_index:
        raise DataFormatError(
            None, "no marker is both in the model and tracked in the data (check names and weights)", field="markers"
        )
    free = free_coordinates(model)
    if not free:
        raise ModelError(f"model {model.name!r} has no free coordinate to solve for")
    positions = torch.as_tensor(markers.positions[:, data_index], dtype=_F64)
    visible = torch.isfinite(positions).all(-1)
    observed = torch.where(visible[..., None], positions, torch.zeros_like(positions))
    columns, task_w, targets = _task_targets(model, coordinate_tasks, markers.times, coordinate_data)
    kinematics = _Kinematics.of(model, model_index, free)
    clamped = model.clamped[free] & ~kinematics.full_turn
    infinite = torch.full((len(free),), math.inf, dtype=_F64)
    lower = torch.where(clamped, model.ranges[free, 0].to(_F64), -infinite)
    upper = torch.where(clamped, model.ranges[free, 1].to(_F64), infinite)
    problem = _Problem(
        kinematics,
        observed.permute(1, 2, 0).contiguous(),
        (torch.as_tensor(w, dtype=_F64) * visible).T.contiguous(),
        torch.tensor(columns, dtype=torch.long),
        torch.tensor(task_w, dtype=_F64),
        torch.as_tensor(targets, dtype=_F64),
        lower,
        upper,
    )
    return _Setup(model, markers, problem, free, model_index, w, positions)


def _result(setup: _Setup, z: torch.Tensor, converged: torch.Tensor, iterations: int) -> IKResult:
    pose, cost, _, _ = setup.problem.evaluate(z, derivatives=False)
    difference = pose.x_last - setup.positions.permute(1, 2, 0)  # [M, 3, T]
    # not torch.linalg.vector_norm, which takes 30x longer over these three-element rows
    errors = (difference * difference).sum(1).sqrt().T.contiguous().numpy()
    motion = Motion(times=setup.markers.times, names=setup.model.coordinate_names, values=pose.q.numpy())
    return IKResult(
        motion,
        tuple(setup.model.marker_names[m] for m in setup.model_index),
        setup.weights,
        errors,
        (cost / setup.problem.total_weight).numpy(),
        converged.numpy(),
        iterations,
    )


def solve_ik(
    model: BodyModel,
    markers: Markers,
    *,
    weights: Mapping[str, float] | None = None,
    coordinate_tasks: Sequence[CoordinateTask] = (),
    coordinate_data: Motion | None = None,
    time_range: tuple[float, float] | None = None,
    tolerance: float = 1e-8,
    max_iterations: int = 100,
    coarse_interval: float = 0.1,
    initial: Motion | None = None,
) -> IKResult:
    """Marker IK of every frame of ``markers`` (within ``time_range``) on ``model``.

    Args:
        weights: marker name -> weight (an IK setup's `IKSetup.marker_weights`); markers not named are not
            tracked. None tracks every model marker present in the data with weight 1.
        coordinate_tasks: coordinate tasks (`IKSetup.coordinate_tasks`); ``from_file`` ones read
            ``coordinate_data``.
        time_range: (start, end) seconds, inclusive, as OpenSim's ``time_range``; default all frames.
        tolerance: relative change of a frame's objective at which its iterations stop.
        coarse_interval: spacing (s) of the coarse warm-start pass.
        initial: a starting motion (any coordinate names; missing ones start at defaults) instead of the
            warm-start passes.
    """
    setup = _setup(model, markers, weights, coordinate_tasks, coordinate_data, time_range)
    problem, free, count = setup.problem, setup.free, setup.markers.n_frames
    if initial is not None:
        z = _start_from(setup, initial)
    else:
        stride = max(1, int(round(coarse_interval * setup.markers.rate))) if count > 1 else 1
        coarse = torch.unique(torch.cat([torch.arange(0, count, stride), torch.tensor([count - 1])]))
        sub = problem.frames(coarse)
        z_coarse = _root_start(setup.model, sub, setup.model_index, len(coarse), free)
        z_coarse, cost_coarse, _, _ = _levenberg_marquardt(
            sub, z_coarse, _COARSE_ITERATIONS, _COARSE_TOLERANCE, damping=1e-2
        )
        z_coarse, _ = _propagate(sub, z_coarse, cost_coarse, _NEIGHBOUR_ITERATIONS, _COARSE_TOLERANCE, every_frame=True)
        z = _interpolate(coarse, z_coarse, count)
    z, cost, converged, iterations = _levenberg_marquardt(problem, z, max_iterations, tolerance)
    z, _ = _propagate(problem, z, cost, min(max_iterations, _COARSE_ITERATIONS), tolerance)
    if initial is None:  # a given start already chose its branches
        z = _continuous_branches(problem, z, setup.model.defaults[free].to(_F64), setup.model.ranges[free, 0])
    z = _unwrap(z, problem.kinematics.periodic, setup.model.defaults[free])
    return _result(
        setup, _into_turn(z, problem.kinematics.full_turn, setup.model.ranges[free, 0]), converged, iterations
    )


def _continuous_branches(
    problem: _Problem, z: torch.Tensor, defaults: torch.Tensor, turn_start: torch.Tensor
) -> torch.Tensor:
    """Pick, for every ball joint (`_Kinematics._ball_joints`), the set of angles that keeps its trajectory
    continuous: the two sets give the same pose and objective, so frames solved apart can land on either, and a
    limb then flips between them (OpenSim's sequential warm start stays on one). The first angle is made
    continuous modulo pi (numpy's unwrap with period pi), frames it moves by an odd number of half turns take the
    other set, and the whole trajectory then takes the set whose middle angle is nearer the default pose (the
    anatomical one). A frame keeps its angles where the other set is out of range or changes the objective.
    Last, `_switch_at_cuts` moves to the other set where a whole-turn angle crosses its range's cut."""
    kin = problem.kinematics
    if not kin.ball_joints or z.shape[0] == 0:
        return z
    cost = None  # the objective at z, evaluated once a joint's two sets can differ in it
    for joint in kin.ball_joints:
        (a, b, _), _, _ = joint
        if cost is None and _sets_can_differ(problem, joint):
            _, cost, _, _ = problem.evaluate(z, derivatives=False)
        alternative, valid = _other_set(problem, z, cost, joint)
        first = z[:, a].numpy()
        turns = np.round((np.unwrap(first, period=math.pi) - first) / math.pi).astype(int)
        switch = torch.as_tensor(turns % 2 == 1)
        taken = [chosen & valid for chosen in (switch, ~switch)]
        distance = [float((torch.where(t[:, None], alternative, z)[:, b] - defaults[b]).abs().mean()) for t in taken]
        took = taken[int(distance[1] < distance[0])]
        chosen = torch.where(took[:, None], alternative, z)
        other = torch.where((valid & ~took)[:, None], alternative, z)  # the set not taken, where usable
        cut = [k for k in joint[0] if bool(kin.full_turn[k])]
        z = _switch_at_cuts(chosen, other, cut, turn_start) if cut else chosen
    return z


def _sets_can_differ(problem: _Problem, joint: tuple[tuple[int, int, int], float, float]) -> bool:
    """Whether a ball joint's two sets of angles can differ in the objective: they give one pose, so the same
    marker objective, and only coordinate tasks and couplers on the joint's coordinates can tell them apart."""
    kin = problem.kinematics
    coordinates = {int(kin.free[k]) for k in joint[0]}
    seen = {int(c) for c in problem.task_columns} | {c.independent for c in kin.couplers}
    return bool(coordinates & seen)


def _other_set(
    problem: _Problem, z: torch.Tensor, cost: torch.Tensor | None, joint: tuple[tuple[int, int, int], float, float]
) -> tuple[torch.Tensor, torch.Tensor]:
    """A ball joint's second set of angles (a + pi, pi - b, c + pi in the rotation amounts) for every frame of
    ``z``, each angle the in-range representative nearest ``z``'s, and [T] whether it is usable: in range and
    with the same objective as ``cost`` (the pose's; needed only where `_sets_can_differ`)."""
    (a, b, c), slope, intercept = joint
    columns = [a, b, c]
    alternative = z.clone()
    alternative[:, a] = z[:, a] + math.pi
    alternative[:, c] = z[:, c] + math.pi
    alternative[:, b] = (math.pi - 2 * intercept) / slope - z[:, b]
    alternative = _nearest_in_range(alternative, columns, problem.lower, problem.upper, z)
    valid = _in_range(alternative, columns, problem.lower, problem.upper)
    inside = valid.nonzero().squeeze(-1)
    if inside.numel() and _sets_can_differ(problem, joint):  # only in range is it worth asking
        _, alt_cost, _, _ = problem.frames(inside).evaluate(alternative[inside], derivatives=False)
        valid[inside] = (alt_cost - cost[inside]).abs() <= 1e-9 * cost[inside].abs() + 1e-12
    return alternative, valid


def _switch_at_cuts(z: torch.Tensor, other: torch.Tensor, cut: Sequence[int], turn_start: torch.Tensor) -> torch.Tensor:
    """Follow ``z`` until one of a ball joint's whole-turn angles (``cut``, clamped to [lower, lower + 2 pi],
    solved across the limit) crosses its range's cut, then follow ``other`` (the joint's second set of angles)
    until it crosses one, and so on. OpenSim cannot cross a clamped limit: its sequential solve sits at the
    limit until it falls into the other set, where it stays. On OpenCap Subject4's asymmetric drop jumps, where a
    shoulder passes overhead, what is left after this rule are the frames where OpenSim sits at the limit
    (docs/decisions/batched-lm-ik.md)."""
    options = (z, other)
    low = turn_start[list(cut)].to(z.dtype)
    # solved without the limit, the angles may sit whole turns away: a crossing is a half-turn step once wrapped
    crossing = [
        (torch.remainder(option[:, cut] - low, 2 * math.pi).diff(dim=0).abs() > math.pi).any(-1) for option in options
    ]
    out, start, current = z.clone(), 0, 0
    while start < z.shape[0]:  # one pass per crossing, not per frame
        later = crossing[current][start:].nonzero()
        end = start + int(later[0]) + 1 if later.numel() else z.shape[0]
        out[start:end] = options[current][start:end]
        start, current = end, 1 - current
    return out


def _in_range(values: torch.Tensor, columns: Sequence[int], lower: torch.Tensor, upper: torch.Tensor) -> torch.Tensor:
    part = values[:, columns]
    return ((part >= lower[columns] - 1e-12) & (part <= upper[columns] + 1e-12)).all(-1)


def _nearest_in_range(
    values: torch.Tensor, columns: Sequence[int], lower: torch.Tensor, upper: torch.Tensor, reference: torch.Tensor
) -> torch.Tensor:
    """Each of ``columns`` shifted by whole turns to the representative nearest ``reference`` that is in range
    (nearest overall where none is)."""
    out = values.clone()
    for k in columns:
        shifts = torch.arange(-2, 3, dtype=_F64) * 2 * math.pi
        options = values[:, k, None] + shifts  # [T, 5]
        inside = (options >= lower[k] - 1e-12) & (options <= upper[k] + 1e-12)
        distance = (options - reference[:, k, None]).abs() + (~inside) * 1e6
        out[:, k] = options.gather(1, distance.argmin(1, keepdim=True))[:, 0]
    return out


def _unwrap(z: torch.Tensor, periodic: torch.Tensor, defaults: torch.Tensor) -> torch.Tensor:
    """Remove 2 pi jumps between frames from the periodic coordinates (same poses), and bring each such
    trajectory's mean within pi of the coordinate's default."""
    if not bool(periodic.any()):
        return z
    columns = periodic.nonzero().squeeze(-1)
    angles = torch.as_tensor(np.unwrap(z[:, columns].numpy(), axis=0), dtype=_F64)
    turns = torch.round((angles.mean(0) - defaults[columns].to(_F64)) / (2 * math.pi))
    z = z.clone()
    z[:, columns] = angles - 2 * math.pi * turns
    return z


def evaluate_ik(
    model: BodyModel,
    markers: Markers,
    motion: Motion,
    *,
    weights: Mapping[str, float] | None = None,
    coordinate_tasks: Sequence[CoordinateTask] = (),
    coordinate_data: Motion | None = None,
    time_range: tuple[float, float] | None = None,
) -> IKResult:
    """The IK objective and marker errors of a given ``motion`` (e.g. another solver's), without solving.

    The motion's free coordinates are interpolated at the marker times; locked coordinates are taken at their
    defaults and coupled ones from their couplers, as `solve_ik` would have them.
    """
    setup = _setup(model, markers, weights, coordinate_tasks, coordinate_data, time_range)
    count = setup.markers.n_frames
    return _result(setup, _start_from(setup, motion), torch.zeros(count, dtype=torch.bool), 0)


def _into_turn(z: torch.Tensor, full_turn: torch.Tensor, lower: torch.Tensor) -> torch.Tensor:
    """Whole-turn-range coordinates (solved without their limits) brought back into [lower, lower + 2 pi)."""
    if not bool(full_turn.any()):
        return z
    columns = full_turn.nonzero().squeeze(-1)
    low = lower[columns].to(_F64)
    z = z.clone()
    z[:, columns] = low + torch.remainder(z[:, columns] - low, 2 * math.pi)
    return z


def _start_from(setup: _Setup, motion: Motion) -> torch.Tensor:
    start = motion.select(setup.model.coordinate_names)
    values = [
        np.interp(setup.markers.times, start.times, start.values[:, c])
        if start.mask[c]
        else np.full(setup.markers.n_frames, float(setup.model.defaults[c]))
        for c in setup.free
    ]
    return torch.as_tensor(np.stack(values, axis=1), dtype=_F64)


def _interpolate(frames: torch.Tensor, values: torch.Tensor, count: int) -> torch.Tensor:
    """Cubic-spline interpolation [count, n] of ``values`` [K, n] known at increasing frame indices ``frames``
    (linear with fewer than four known frames)."""
    if frames.numel() == 1:
        return values.expand(count, -1).clone()
    t = np.arange(count, dtype=float)
    known = frames.numpy().astype(float)
    if frames.numel() < 4:
        out = np.stack([np.interp(t, known, column) for column in values.numpy().T], axis=1)
    else:
        out = scipy.interpolate.CubicSpline(known, values.numpy(), axis=0)(t)
    return torch.as_tensor(out, dtype=_F64)
