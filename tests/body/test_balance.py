"""COM kinematics, ZMP and energy: OpenSim as the oracle for COM velocity and kinetic energy, hand cases for ZMP."""

import numpy as np
import pytest
import torch

from biomotion.body.balance import center_of_mass_motion, mechanical_energy, zero_moment_point
from biomotion.body.kinematics import center_of_mass
from biomotion.body.model import BodyModel
from tests.conftest import data_path

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"


@pytest.fixture(scope="module")
def model():
    return BodyModel.from_osim(data_path(RAJAGOPAL))


def random_state(model, n, seed=0):
    g = torch.Generator().manual_seed(seed)
    low, high = model.ranges[:, 0].clamp(-1.0, 1.0), model.ranges[:, 1].clamp(-1.0, 1.0)
    q = low + (high - low) * torch.rand(n, model.n_q, generator=g, dtype=torch.float64)
    qd = torch.randn(n, model.n_q, generator=g, dtype=torch.float64)
    qdd = torch.randn(n, model.n_q, generator=g, dtype=torch.float64)
    return q, qd, qdd


def test_com_velocity_and_kinetic_energy_match_opensim(model):
    osim = pytest.importorskip("opensim")
    q, qd, qdd = random_state(model, 3)
    com = center_of_mass_motion(model, q, qd, qdd)
    kinetic, _ = mechanical_energy(model, q, qd)
    omodel = osim.Model(str(data_path(RAJAGOPAL)))
    state = omodel.initSystem()
    coordinates = omodel.getCoordinateSet()
    names = [coordinates.get(i).getName() for i in range(coordinates.getSize())]
    assert tuple(names) == model.coordinate_names
    for k in range(3):
        for i, name in enumerate(names):
            coordinate = coordinates.get(name)
            coordinate.setLocked(state, False)
            coordinate.setValue(state, float(q[k, i]), False)
            coordinate.setSpeedValue(state, float(qd[k, i]))
        omodel.realizeVelocity(state)
        velocity = omodel.calcMassCenterVelocity(state)
        position = omodel.calcMassCenterPosition(state)
        np.testing.assert_allclose(com.position[k].numpy(), [position.get(j) for j in range(3)], atol=1e-9)
        np.testing.assert_allclose(com.velocity[k].numpy(), [velocity.get(j) for j in range(3)], atol=1e-9)
        expected = omodel.getMatterSubsystem().calcKineticEnergy(state)
        assert float(kinetic[k]) == pytest.approx(expected, rel=1e-9)


def test_accelerations_are_time_derivatives_of_velocities(model):
    """Central difference of COM velocity along a smooth path q(t) matches the analytic acceleration."""
    t = torch.linspace(0, 1, 201, dtype=torch.float64)[:, None]
    q0, a, w = random_state(model, 1, seed=3)
    q = q0 + 0.2 * torch.sin(3 * t) * a
    qd = 0.6 * torch.cos(3 * t) * a
    qdd = -1.8 * torch.sin(3 * t) * a
    com = center_of_mass_motion(model, q, qd, qdd)
    dt = float(t[1] - t[0])
    numeric = (com.velocity[2:] - com.velocity[:-2]) / (2 * dt)
    assert torch.max(torch.abs(numeric - com.acceleration[1:-1])) < 1e-3
    positions = center_of_mass(model, q)
    assert torch.max(torch.abs((positions[2:] - positions[:-2]) / (2 * dt) - com.velocity[1:-1])) < 1e-4


def test_zmp_is_com_projection_when_static(model):
    q = model.default_q()[None]
    zero = torch.zeros_like(q)
    zmp = zero_moment_point(model, q, zero, zero)
    com = center_of_mass(model, q)
    assert float(zmp[0, 0]) == pytest.approx(float(com[0, 0]), abs=1e-12)
    assert float(zmp[0, 2]) == pytest.approx(float(com[0, 2]), abs=1e-12)
    assert float(zmp[0, 1]) == 0.0


def test_zmp_shifts_back_under_forward_pelvis_acceleration(model):
    """Whole body translating with acceleration a along x (no rotation): x_zmp = x_com - y_com * a / g."""
    q = model.default_q()[None]
    qd = torch.zeros_like(q)
    qdd = torch.zeros_like(q)
    qdd[0, model.coordinate_index("pelvis_tx")] = 2.0
    zmp = zero_moment_point(model, q, qd, qdd)
    com = center_of_mass(model, q)
    expected = float(com[0, 0]) - float(com[0, 1]) * 2.0 / 9.80665
    assert float(zmp[0, 0]) == pytest.approx(expected, abs=1e-9)


def test_zmp_is_undefined_near_free_fall(model):
    """The whole body accelerating down at a (no rotation) asks m (g - a) of the ground: a ZMP at or above
    `MIN_VERTICAL_LOAD_BW` body weights (the COM's projection here), NaN below it (flight)."""
    q = model.default_q().expand(3, -1).clone()
    qd, qdd = torch.zeros_like(q), torch.zeros_like(q)
    g = 9.80665
    qdd[:, model.coordinate_index("pelvis_ty")] = torch.tensor([-0.79, -0.81, -1.0], dtype=q.dtype) * g
    zmp = zero_moment_point(model, q, qd, qdd)
    com = center_of_mass(model, q)
    assert float(zmp[0, 0]) == pytest.approx(float(com[0, 0]), abs=1e-9)  # 0.21 body weights: loaded
    assert torch.isnan(zmp[1:, [0, 2]]).all()  # 0.19 and 0: in flight
    assert torch.isfinite(zero_moment_point(model, q, qd, qdd, min_load_bw=0.1)[1]).all()


def test_potential_energy_is_weight_times_com_height(model):
    q, qd, _ = random_state(model, 4, seed=5)
    _, potential = mechanical_energy(model, q, qd)
    com = center_of_mass(model, q)
    np.testing.assert_allclose(potential.numpy(), (model.total_mass * 9.80665 * com[:, 1]).numpy(), rtol=1e-12)


def test_sampled_body_motion_and_its_zmp_match_the_exact_ones(model):
    """A smooth motion (every coordinate a 1 Hz sine about an in-range pose) sampled at 300 Hz: central differences
    of the posed bodies give the COM accelerations (within 1 cm/s²) and angular velocities (1e-3 rad/s) of
    `body_motion`, and the ZMP of `loaded_zero_moment_point` on them matches `zero_moment_point` within a millimetre
    away from the ends (one-sided differences there); frames asking the ground for less than 0.2 body weights are
    flagged, and finite."""
    from biomotion.body.balance import body_motion, loaded_zero_moment_point, sampled_body_motion
    from biomotion.body.kinematics import body_coms, forward_kinematics

    rate = 300.0
    t = torch.arange(0, 1.0, 1 / rate, dtype=torch.float64)[:, None]
    g = torch.Generator().manual_seed(3)
    centre = model.defaults + 0.1 * torch.randn(model.n_q, generator=g, dtype=torch.float64)
    amplitude = 0.2 * torch.rand(model.n_q, generator=g, dtype=torch.float64)
    w = 2 * np.pi
    q = centre + amplitude * torch.sin(w * t)
    qd, qdd = amplitude * w * torch.cos(w * t), -amplitude * w**2 * torch.sin(w * t)
    exact = body_motion(model, q, qd, qdd)
    poses = forward_kinematics(model, q)
    sampled = sampled_body_motion(body_coms(model, q, poses), poses.rotations, rate)
    inner = slice(3, -3)
    assert torch.allclose(sampled.com_acceleration[inner], exact.com_acceleration[inner], atol=1e-2)  # m/s²
    assert torch.allclose(sampled.angular_velocity[inner], exact.angular_velocity[inner], atol=1e-3)  # rad/s
    reference = zero_moment_point(model, q, qd, qdd)
    zmp, loaded = loaded_zero_moment_point(model, sampled)
    assert torch.isfinite(zmp).all()
    assert torch.equal(loaded, torch.isfinite(reference[:, 0]))
    both = loaded.clone()
    both[:3] = both[-3:] = False
    assert both.sum() > 100
    assert (zmp[both] - reference[both]).abs().max() < 1e-3
