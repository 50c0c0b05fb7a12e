"""The joint-vectorised paths against the per-joint formulas: `FunctionStack` against each function's own
derivatives, the tree's subspaces and velocity terms against `motion_subspace` and `joint_velocity`, batch
shapes, the per-model cache, and `torch_threads`."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from biomotion.body.dynamics import _tree_motion, inverse_dynamics, joint_velocity, mass_matrix
from biomotion.body.functions import FunctionStack
from biomotion.body.kinematics import (
    KinematicTree,
    forward_kinematics,
    joint_terms,
    motion_subspace,
    to_frames_first,
    to_frames_last,
    torch_threads,
)
from biomotion.body.model import BodyModel
from biomotion.errors import ModelError
from tests.body.oracle import random_poses
from tests.conftest import data_path

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"  # splines, a knee of three rotations
OPENCAP = "opencap/Subject4/Models/optimized_scale_and_markers.osim"  # polynomials, multipliers, welds


@pytest.mark.parametrize("relative", [RAJAGOPAL, OPENCAP])
def test_function_stack_matches_each_function(relative: str) -> None:
    model = BodyModel.from_osim(data_path(relative))
    axes = [axis for joint in model.joints for axis in joint.axes]
    stack = FunctionStack([a.function for a in axes], [a.scale for a in axes])
    line = torch.linspace(-2.5, 2.5, 41, dtype=torch.float64)  # inside and past the knots
    q = line[:, None].expand(-1, model.n_q)  # every coordinate at x
    x = torch.stack([line if a.coordinate is not None else torch.zeros_like(line) for a in axes])
    batched = stack.derivatives(x)
    assert {type(a.function).__name__ for a in axes} >= {"Linear", "Constant", "PiecewiseCubic"} or {
        type(a.function).__name__ for a in axes
    } >= {"Linear", "Multiplier", "Polynomial"}
    for k, axis in enumerate(axes):
        for mine, theirs in zip(batched, axis.derivatives(q)):
            assert torch.allclose(mine[k], theirs, atol=1e-12, rtol=1e-12)


@pytest.mark.parametrize("hdot", ["opensim", "exact"])
def test_tree_terms_match_the_per_joint_formulas(hdot: str) -> None:
    """S, v_J and c_J of the tree (ground orientation, about the root origin) carried into each child body frame
    equal `motion_subspace` and `joint_velocity` joint by joint."""
    model = BodyModel.from_osim(data_path(RAJAGOPAL))
    rng = np.random.default_rng(1)
    q = torch.tensor(random_poses(model, rng, 3))
    qd = torch.tensor(rng.normal(size=q.shape) * 2.0)
    motion = _tree_motion(model, to_frames_last(q, 1), to_frames_last(qd, 1), hdot)
    rotations, positions = (to_frames_first(x, q.shape[:-1]) for x in (motion.poses.rotations, motion.poses.positions))
    origin = to_frames_first(motion.origin, q.shape[:-1])
    subspace = to_frames_first(motion.subspace, q.shape[:-1])  # [T, n_q, 6]
    velocity, bias = (to_frames_first(x, q.shape[:-1]) for x in (motion.joint_velocity, motion.joint_bias))

    def to_body(vector: torch.Tensor, b: int) -> torch.Tensor:  # [T, 6] about O in ground -> body frame at origin
        angular = vector[..., :3]
        linear = vector[..., 3:] + torch.linalg.cross(angular, positions[:, b] - origin)
        rt = rotations[:, b].transpose(-1, -2)
        return torch.cat([(rt @ angular[..., None])[..., 0], (rt @ linear[..., None])[..., 0]], -1)

    for joint in model.joints:
        terms = joint_terms(joint, q)
        v_j, c_j = joint_velocity(joint, q, qd, hdot, terms)
        assert torch.allclose(to_body(velocity[:, joint.child], joint.child), v_j, atol=1e-12, rtol=0)
        assert torch.allclose(to_body(bias[:, joint.child], joint.child), c_j, atol=1e-10, rtol=0)
        s = motion_subspace(joint, q, terms)
        for i, c in enumerate(joint.coordinates):
            assert torch.allclose(to_body(subspace[:, c], joint.child), s[..., i], atol=1e-12, rtol=0)


def test_batch_shapes_and_single_frames() -> None:
    model = BodyModel.from_osim(data_path(OPENCAP))
    rng = np.random.default_rng(2)
    q = torch.tensor(random_poses(model, rng, 6))
    qd, qdd = torch.tensor(rng.normal(size=q.shape)), torch.tensor(rng.normal(size=q.shape))
    flat = inverse_dynamics(model, q, qd, qdd)
    grid = inverse_dynamics(model, q.reshape(2, 3, -1), qd.reshape(2, 3, -1), qdd.reshape(2, 3, -1))
    assert grid.shape == (2, 3, model.n_q) and torch.allclose(grid.reshape(6, -1), flat, atol=1e-12, rtol=0)
    assert torch.allclose(inverse_dynamics(model, q[4], qd[4], qdd[4]), flat[4], atol=1e-12, rtol=0)
    assert mass_matrix(model, q[0]).shape == (model.n_q, model.n_q)
    assert forward_kinematics(model, q[0]).rotations.shape == (model.n_bodies, 3, 3)


def test_tree_is_cached_per_model_and_dtype_but_not_for_trainable_models() -> None:
    model = BodyModel.from_osim(data_path(OPENCAP))
    assert KinematicTree.of(model, torch.float64) is KinematicTree.of(model, torch.float64)
    assert KinematicTree.of(model, torch.float32) is not KinematicTree.of(model, torch.float64)
    masses = model.masses.clone().requires_grad_()
    trainable = dataclasses.replace(model, masses=masses)
    assert KinematicTree.of(trainable, torch.float64) is not KinematicTree.of(trainable, torch.float64)
    q = model.default_q()[None]
    with torch.no_grad():  # a first call without grad must not freeze the masses into a cached tree
        inverse_dynamics(trainable, q, torch.zeros_like(q), torch.zeros_like(q))
    tau = inverse_dynamics(trainable, q, torch.zeros_like(q), torch.zeros_like(q))
    (gradient,) = torch.autograd.grad(tau[0, model.coordinate_index("pelvis_ty")], masses)
    assert torch.allclose(gradient, torch.full_like(gradient, 9.80665), rtol=1e-9)  # weight = g * sum of masses


def test_torch_threads_restores_the_setting() -> None:
    before = torch.get_num_threads()
    with torch_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before


def test_subtree_matches_the_whole_tree_and_must_hold_its_parents() -> None:
    """A tree over a subtree (the root, or the root and a leg) poses those bodies, places their points and gives
    their coordinates' twists as the whole tree does; a subtree without a body's parent is rejected."""
    model = BodyModel.from_osim(data_path(OPENCAP))
    q = to_frames_last(torch.tensor(random_poses(model, np.random.default_rng(3), 4)), 1)
    whole = KinematicTree.of(model, torch.float64)
    root = next(j.child for j in model.joints if j.parent < 0)
    leg = [root] + [
        b
        for b in range(model.n_bodies)
        if model.body_names[b] in ("femur_r", "tibia_r", "talus_r", "calcn_r", "toes_r")
    ]

    def passes(tree: KinematicTree) -> tuple:
        values, slopes, _ = tree.axis_values(q)
        frames = tree.joint_frames(values)
        poses = tree.poses(frames)
        return poses, tree.twists(tree.ground_axes(poses, frames), slopes)

    full_poses, (full_w, full_v) = passes(whole)
    for bodies in ([root], leg):
        tree = KinematicTree(model, torch.float64, bodies=bodies)
        assert tree.bodies.tolist() == sorted(bodies)
        poses, (w, v) = passes(tree)
        assert torch.allclose(poses.rotations, full_poses.rotations[tree.bodies], atol=1e-14)
        assert torch.allclose(poses.positions, full_poses.positions[tree.bodies], atol=1e-14)
        owned = [c for j in model.joints if j.child in bodies for c in j.coordinates]
        assert torch.allclose(w[owned], full_w[owned], atol=1e-14) and torch.allclose(
            v[owned], full_v[owned], atol=1e-14
        )
        others = [c for c in range(model.n_q) if c not in owned]
        assert not w[others].any() and not v[others].any()
        on = model.marker_bodies[torch.isin(model.marker_bodies, torch.tensor(bodies))]
        offsets = torch.zeros(len(on), 3, dtype=torch.float64)
        assert torch.allclose(
            tree.points(poses, tree.tree_bodies(on), offsets), whole.points(full_poses, on, offsets), atol=1e-14
        )
    with pytest.raises(ModelError):
        KinematicTree(model, torch.float64, bodies=leg[2:])
    with pytest.raises(ModelError):
        KinematicTree(model, torch.float64, bodies=[root]).tree_bodies(torch.tensor([leg[1]]))
