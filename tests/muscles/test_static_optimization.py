"""Batched static optimization: exact against a reference QP solver, and against OpenSim 4.6's StaticOptimization."""

import numpy as np
import pytest
import torch

from biomotion.errors import ModelError
from biomotion.muscles.static_optimization import solve_static_optimization
from tests.conftest import data_path


def _feasible_problem(frames=20, muscles=30, coordinates=6, seed=0):
    g = torch.Generator().manual_seed(seed)
    arms = 0.04 * torch.randn(frames, muscles, coordinates, generator=g, dtype=torch.float64)
    arms = arms * (torch.rand(frames, muscles, coordinates, generator=g, dtype=torch.float64) < 0.4)
    forces = 200 + 1500 * torch.rand(frames, muscles, generator=g, dtype=torch.float64)
    truth = 0.6 * torch.rand(frames, muscles, generator=g, dtype=torch.float64)
    torques = torch.einsum("tmc,tm->tc", arms, forces * truth)
    return arms, forces, torques, torch.ones(coordinates, dtype=torch.float64)


def test_squared_activations_match_a_reference_qp_solver():
    cvxopt = pytest.importorskip("cvxopt")
    arms, forces, torques, reserves = _feasible_problem()
    result = solve_static_optimization(arms, forces, torques, reserves, exponent=2)
    assert bool(result.converged.all()) and float(result.residual.abs().max()) < 1e-7
    cvxopt.solvers.options.update(show_progress=False, abstol=1e-12, reltol=1e-12, feastol=1e-12)
    t, m, c = arms.shape
    for k in range(t):
        b = torch.cat([arms[k].T * forces[k], torch.diag(reserves)], 1).numpy()
        n = b.shape[1]
        bounds = np.concatenate([np.ones(n), np.r_[-0.01 * np.ones(m), np.ones(c)]])
        solution = cvxopt.solvers.qp(
            cvxopt.matrix(2 * np.eye(n)),
            cvxopt.matrix(np.zeros(n)),
            cvxopt.matrix(np.vstack([np.eye(n), -np.eye(n)])),
            cvxopt.matrix(bounds),
            cvxopt.matrix(b),
            cvxopt.matrix(torques[k].numpy()),
        )
        x = np.array(solution["x"]).ravel()
        np.testing.assert_allclose(result.activations[k].numpy(), x[:m], atol=1e-6)
        np.testing.assert_allclose(result.reserve_controls[k].numpy(), x[m:], atol=1e-6)


def test_cubed_activations_satisfy_the_kkt_conditions():
    arms, forces, torques, reserves = _feasible_problem(seed=1)
    result = solve_static_optimization(arms, forces, torques, reserves, exponent=3)
    assert bool(result.converged.all())
    a = result.activations
    # stationarity: 3 a^2 = (B^T lambda)_m for free muscles, so a^2 / F_m lies in the span of the moment-arm
    # columns; check by least squares that the free muscles' 3 a^2 is reproduced by some lambda
    for k in range(4):
        free = (a[k] > 0.0101) & (a[k] < 0.999)
        columns = (arms[k] * forces[k][:, None])[free]  # [free, C]
        lam = torch.linalg.lstsq(columns, 3 * a[k][free] ** 2).solution
        torch.testing.assert_close(columns @ lam, 3 * a[k][free] ** 2, rtol=0, atol=1e-6)


def test_a_frame_the_bounds_cannot_balance_stops_early_and_leaves_the_others_unchanged():
    arms, forces, torques, reserves = _feasible_problem()
    alone = solve_static_optimization(arms, forces, torques, reserves)
    impossible = torques.clone()
    impossible[7] = 1e6  # far beyond every actuator's reach: no activation in [0.01, 1] balances it
    result = solve_static_optimization(arms, forces, impossible, reserves, max_iterations=100)
    others = torch.arange(len(torques)) != 7
    assert not bool(result.converged[7]) and bool(result.converged[others].all())
    torch.testing.assert_close(result.activations[others], alone.activations[others], rtol=0, atol=1e-12)
    assert result.iterations < 100  # it stalls out instead of running the whole batch to max_iterations


def test_bad_shapes_and_unactuated_coordinates_are_refused():
    arms, forces, torques, reserves = _feasible_problem(frames=2)
    with pytest.raises(ModelError, match="shapes"):
        solve_static_optimization(arms, forces[:, :3], torques, reserves)
    arms[..., 0] = 0
    with pytest.raises(ModelError, match="neither a muscle nor a reserve"):
        solve_static_optimization(arms, forces, torques, reserves * torch.tensor([0.0, 1, 1, 1, 1, 1]))


def test_matches_opensim_static_optimization_on_a_gait_window():
    pytest.importorskip("opensim")
    from biomotion.validation.muscles import (
        gait_static_optimization,
        opensim_gait_static_optimization,
        r_squared,
    )

    root = data_path("opensim-models/Pipelines/Gait2392_Simbody").parents[2]
    reference = opensim_gait_static_optimization(root, 0.9, 1.15)
    result, _ = gait_static_optimization(root, reference)
    assert len(reference.times) == 16 and bool(result.converged.all())
    ours = result.activations.numpy()[:, [result.muscle_names.index(m) for m in reference.muscle_names]]
    error = np.abs(ours - reference.activations)
    varying = reference.activations.std(0) > 0.02
    r2 = r_squared(ours[:, varying], reference.activations[:, varying])
    assert error.max() < 0.05, reference.muscle_names[int(error.max(0).argmax())]
    assert r2.mean() > 0.95


def test_matches_opensim_static_optimization_on_a_rajagopal_walk_window(tmp_path):
    """The Rajagopal comparison (our IK of the walk, Millard 2012 muscles, reserves): OpenSim's optimization states
    are our filtered coordinates, with the patella's coupled speeds equal to the knee's (from a degrees file
    OpenSim 4.6 handed them over in deg/s, 57x, and its solution balanced hip torques 40 N·m off); OpenSim's
    InverseDynamicsTool agrees with our torques; our SO balances them and matches OpenSim's activations. Whole
    walk: `biomotion validate muscles` (docs/results/validate_muscles.md)."""
    pytest.importorskip("opensim")
    from biomotion.validation.muscles import (
        opensim_static_optimization,
        r_squared,
        rajagopal_static_optimization,
        rajagopal_walk_inputs,
        solver_torques,
    )

    root = data_path("opensim-models/Pipelines/Rajagopal/ExpData/motion_capture_walk.trc").parents[4]
    inputs = rajagopal_walk_inputs(root, tmp_path)
    assert len(inputs.balanced) == 10 and inputs.time_range == (0.0, 2.37)
    reference = opensim_static_optimization(
        inputs.model, inputs.coordinates, inputs.external_loads, inputs.force_set, 1.0, 1.1
    )
    assert len(reference.times) == 11 and len(reference.muscle_names) == 80
    assert {f"reserve_{c}" for c in inputs.balanced} <= set(reference.actuator_controls)
    knee, patella = (reference.coordinate_names.index(c) for c in ("knee_angle_r", "knee_angle_r_beta"))
    np.testing.assert_allclose(reference.qdot[:, patella], reference.qdot[:, knee], atol=1e-9)
    torques, state_error = solver_torques(inputs, reference)
    assert state_error < 1e-4  # measured 2e-8 rad
    balanced = [reference.coordinate_names.index(c) for c in inputs.balanced]
    # OpenSim's InverseDynamicsTool on the same file: measured max 0.89 N·m (its own spline derivatives)
    assert np.abs(torques[:, balanced] - reference.torques[:, balanced]).max() < 2.0
    result, seconds = rajagopal_static_optimization(inputs, reference)
    assert bool(result.converged.all()) and seconds < reference.seconds
    achieved = (result.residual + torch.from_numpy(torques[:, balanced])).numpy()
    np.testing.assert_allclose(achieved, torques[:, balanced], atol=1e-4)
    ours = result.activations.numpy()[:, [result.muscle_names.index(m) for m in reference.muscle_names]]
    error = np.abs(ours - reference.activations)
    varying = reference.activations.std(0) > 0.02
    # measured: max 0.0096 (recfem_r), R² 0.998 over the 28 muscles that vary in this window
    assert error.max() < 0.03, reference.muscle_names[int(error.max(0).argmax())]
    assert r_squared(ours[:, varying], reference.activations[:, varying]).mean() > 0.95


def test_validate_muscles_names_what_it_skips(tmp_path):
    from biomotion.validation.muscles import validate_muscles

    report = validate_muscles(tmp_path, surrogate=None)
    assert "so_r2_vs_opensim" not in report and "moment_arm_rmse_m" not in report
    assert any("gait2392" in s for s in report["skipped"])
    assert any("Rajagopal walk" in s for s in report["skipped"])
    assert any("EMG check" in s for s in report["skipped"])


def test_the_oracles_emg_score_uses_the_emg_checks_own_rule():
    """`_emg_same_inputs` scores OpenSim's activations by the EMG check's rule: activations equal to the EMG
    envelopes agree on every frame, and the same activations half a stride (0.55 s) late do not."""
    from biomotion.validation import emg
    from biomotion.validation.muscles import OpenSimStaticOptimization, _emg_same_inputs

    path = data_path(emg.EMG_FILE)
    root = path.parents[len(emg.EMG_FILE.split("/")) - 1]
    times = np.linspace(0.0, 2.37, 238)
    envelopes = emg.emg_envelopes(emg.read_anc(path), times)
    names = tuple(m for muscles in emg.EMG_MUSCLES.values() for m in muscles)
    activations = np.stack([envelopes[c] for c, muscles in emg.EMG_MUSCLES.items() for _ in muscles], axis=1)
    reference = OpenSimStaticOptimization(
        times, names, activations, (), np.zeros((238, 0)), np.zeros((238, 0)), np.zeros((238, 0)), 0.0
    )
    figures = _emg_same_inputs(root, reference, np.roll(activations, 55, axis=0), names)
    assert figures["emg_onoff_agreement_opensim_so"] == 1.0
    assert figures["emg_onoff_agreement_same_inputs_ours"] < 0.8
    assert set(figures["emg_per_muscle_opensim_so"]) == set(emg.EMG_MUSCLES)
