"""Muscle parameters from .osim files and the Thelen 2003 curves against OpenSim 4.6."""

import numpy as np
import pytest
import torch

from biomotion.errors import DataFormatError
from biomotion.muscles.properties import (
    max_active_force,
    passive_force,
    read_muscles,
    thelen_active_force_length,
    thelen_force_velocity,
)
from tests.conftest import data_path

GAIT_MODEL = "opensim-models/Pipelines/Gait2392_Simbody/OutputReference/subject01_simbody.osim"
RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"


def test_gait2392_parameters_from_xml():
    muscles = read_muscles(data_path(GAIT_MODEL))
    assert muscles.n_muscles == 92 and muscles.kind == "Thelen2003Muscle"
    i = muscles.names.index("glut_med1_r")
    assert muscles.max_isometric_force[i] == 819
    assert muscles.optimal_fiber_length[i] == pytest.approx(0.0535)
    assert muscles.tendon_slack_length[i] == pytest.approx(0.078)
    assert muscles.pennation_at_optimal[i] == pytest.approx(0.13962634)
    assert muscles.thelen["KshapeActive"][i] == 0.5 and muscles.thelen["Af"][i] == pytest.approx(0.3)
    assert torch.all(muscles.min_control == 0.01)  # OpenSim 4.6 reports 0.01 for every muscle of this model


def test_rajagopal_millard_curve_parameters_from_xml():
    muscles = read_muscles(data_path(RAJAGOPAL))
    assert muscles.n_muscles == 80 and muscles.kind == "Millard2012EquilibriumMuscle"
    i = muscles.names.index("addbrev_r")
    assert muscles.millard["min_norm_active_fiber_length"][i] == 0.25
    assert muscles.millard["max_norm_active_fiber_length"][i] == pytest.approx(1.9)
    assert muscles.millard["eccentric_slope_near_vmax"][i] == pytest.approx(0.15)
    assert muscles.millard["concentric_curviness"][i] == 0.6  # absent in the file: OpenSim's default


def test_millard_passive_force_is_zero_below_optimal_and_grows():
    muscles = read_muscles(data_path(RAJAGOPAL))
    i = muscles.names.index("vaslat_r")
    slack, optimal = float(muscles.tendon_slack_length[i]), float(muscles.optimal_fiber_length[i])
    lengths = torch.full((3, 80), 0.3, dtype=torch.float64)
    lengths[:, i] = torch.tensor([slack + 0.9 * optimal, slack + 1.3 * optimal, slack + 1.6 * optimal])
    force = passive_force(muscles, lengths)[:, i]
    assert float(force[0]) == 0.0 and 0 < float(force[1]) < float(force[2])


def test_malformed_number_names_the_line(tmp_path):
    bad = tmp_path / "bad.osim"
    bad.write_text(
        '<OpenSimDocument><Model><ForceSet><objects>\n<Thelen2003Muscle name="m">\n'
        "<max_isometric_force>lots</max_isometric_force>\n</Thelen2003Muscle>"
        "</objects></ForceSet></Model></OpenSimDocument>"
    )
    with pytest.raises(DataFormatError, match=r"bad.osim:\d+"):
        read_muscles(bad)


def test_thelen_curves_are_continuous_and_anchored():
    af, flen, thr = (torch.tensor(v, dtype=torch.float64) for v in (0.3, 1.8, 0.95))
    v = torch.linspace(-1.5, 1.5, 30001, dtype=torch.float64)
    fv = thelen_force_velocity(v, af, flen, thr)
    assert float(thelen_force_velocity(torch.zeros(1, dtype=torch.float64), af, flen, thr)) == pytest.approx(1.0)
    assert float(thelen_force_velocity(-torch.ones(1, dtype=torch.float64), af, flen, thr)) == pytest.approx(0.0)
    assert torch.all(fv.diff() > 0)  # monotone
    assert float(fv.diff().abs().max()) < 1e-3  # no jumps at v = -1, 0 or the extrapolation point
    assert float(thelen_active_force_length(torch.ones(1), torch.tensor(0.5))) == 1.0


def _opensim_forces(path, opensim, pose, poses: int):
    """(lengths, speeds, OpenSim's force per unit activation) [poses, M] of every muscle, ``pose(coordinates,
    state, rng)`` setting each random pose."""
    opensim.Logger.setLevelString("error")
    model = opensim.Model(str(path))
    state = model.initSystem()
    coordinates = model.getCoordinateSet()
    rng = np.random.default_rng(0)
    lengths, speeds, reference = [], [], []
    for _ in range(poses):
        pose(coordinates, state, rng)
        model.assemble(state)
        model.realizeVelocity(state)
        ms = [model.getMuscles().get(i) for i in range(model.getMuscles().getSize())]
        lengths.append([m.getLength(state) for m in ms])
        speeds.append([m.getLengtheningSpeed(state) for m in ms])
        reference.append([m.calcInextensibleTendonActiveFiberForce(state, 1.0) for m in ms])
    return (torch.tensor(lengths, dtype=torch.float64), torch.tensor(speeds, dtype=torch.float64), np.array(reference))


def test_max_active_force_matches_opensim():
    opensim = pytest.importorskip("opensim")
    path = data_path(GAIT_MODEL)

    def pose(coordinates, state, rng):
        for name, low, high in [
            ("hip_flexion_r", -0.3, 1.2),
            ("knee_angle_r", -1.5, 0.0),
            ("ankle_angle_r", -0.5, 0.4),
            ("hip_adduction_l", -0.3, 0.2),
            ("lumbar_extension", -0.3, 0.3),
        ]:
            coordinates.get(name).setValue(state, rng.uniform(low, high), False)
            coordinates.get(name).setSpeedValue(state, rng.uniform(-6, 6))

    lengths, speeds, reference = _opensim_forces(path, opensim, pose, 5)
    errors = np.abs(max_active_force(read_muscles(path), lengths, speeds).numpy() - reference) / reference
    assert np.max(errors) < 1e-5  # measured 1.1e-6 (OpenSim's iterative fv inversion)


def test_rajagopal_force_per_activation_matches_opensim():
    """Millard 2012 muscles: OpenSim 4.6 returns the fibre force without the cos(pennation) projection."""
    opensim = pytest.importorskip("opensim")
    path = data_path(RAJAGOPAL)

    def pose(coordinates, state, rng):
        for i in range(coordinates.getSize()):
            c = coordinates.get(i)
            if c.getLocked(state) or c.getMotionType() != 1:  # rotational, free
                continue
            c.setValue(state, rng.uniform(c.getRangeMin(), c.getRangeMax()), False)
            c.setSpeedValue(state, rng.normal(0, 3))

    lengths, speeds, reference = _opensim_forces(path, opensim, pose, 6)
    ours = max_active_force(read_muscles(path), lengths, speeds).numpy()
    relative = np.abs(ours - reference) / np.maximum(np.abs(reference), 1.0)
    assert relative.max() < 5e-3  # measured 3.5e-3 (eccentric fibres; 1e-6 when isometric)
