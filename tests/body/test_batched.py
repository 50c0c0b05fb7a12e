"""The joint-vectorised paths against the per-joint formulas: `FunctionStack` against each function's own
derivatives, the tree's subspaces and velocity terms against `motion_subspace` and `joint_velocity`, batch
shapes, the per-model cache, and `torch_threads`."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from tests.body.oracle import random_poses
from tests.conftest import data_path

from biomotion.body.dynamics import _tree_motion, inverse_dynamics, joint_velocity, mass_matrix
from biomotion.body.functions import FunctionStack
from biomotion.body.kinematics import (KinematicTree, forward_kinematics, joint_terms, motion_subspace,
                                       to_frames_first, to_frames_last, torch_threads)
from biomotion.body.model import BodyModel

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"       # splines, a knee of three rotations
OPENCAP = "opencap/Subject4/Models/optimized_scale_and_markers.osim"   # polynomials, multipliers, welds


@pytest.mark.parametrize("relative", [RAJAGOPAL, OPENCAP])
def test_function_stack_matches_each_function(relative: str) -> None:
    model = BodyModel.from_osim(data_path(relative))
    axes = [axis for joint in model.joints for axis in joint.axes]
    stack = FunctionStack([a.function for a in axes], [a.scale for a in axes])
    line = torch.linspace(-2.5, 2.5, 41, dtype=torch.float64)                    # inside and past the knots
    q = line[:, None].expand(-1, model.n_q)                                      # every coordinate at x
    x = torch.stack([line if a.coordinate is not None else torch.zeros_like(line) for a in axes])
    batched = stack.derivatives(x)
    assert {type(a.function).__name__ for a in axes} >= {"Linear", "Constant", "PiecewiseCubic"} or \
        {type(a.function).__name__ for a in axes} >= {"Linear", "Multiplier", "Polynomial"}
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
    rotations, positions = (to_frames_first(x, q.shape[:-1]) for x in (motion.poses.rotations,
                                                                        motion.poses.positions))
    origin = to_frames_first(motion.origin, q.shape[:-1])
    subspace = to_frames_first(motion.subspace, q.shape[:-1])            # [T, n_q, 6]
    velocity, bias = (to_frames_first(x, q.shape[:-1]) for x in (motion.joint_velocity, motion.joint_bias))

    def to_body(vector: torch.Tensor, b: int) -> torch.Tensor:   # [T, 6] about O in ground -> body frame at origin
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
