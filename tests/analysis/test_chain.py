"""`biomotion analyze` end to end on real trials: OpenSim-checked torque peaks and GRF inferred from motion."""

import json

import numpy as np
import pytest
import torch

from biomotion.analysis.chain import (
    analyze,
    model_motion,
    plate_feet,
    plate_frames,
    summary,
    unwrapped,
    zmp_to_plate_cop,
)
from biomotion.body.model import BodyModel
from biomotion.cli import main
from biomotion.errors import ModelError
from biomotion.io.mot import read_ground_reaction, read_motion, read_storage
from biomotion.motion import Motion
from tests.conftest import data_path

SUBJECT4 = "opencap/Subject4/"


@pytest.fixture(scope="module")
def subject4():
    return BodyModel.from_osim(data_path(SUBJECT4 + "Models/optimized_scale_and_markers.osim"))


def test_walking_torques_with_plates_assigned_to_feet(tmp_path, subject4):
    """opencap/SOURCE.md: OpenSim 4.6 ID on walking1 with plate 1 -> right, 2 -> left gives ankle moments peaking
    at -85 N·m (r) and -84 N·m (l). Our automatic plate-to-foot assignment must reproduce that."""
    code = main(
        [
            "analyze",
            str(data_path(SUBJECT4 + "IK/walking1_ik.mot")),
            "--model",
            str(data_path(SUBJECT4 + "Models/optimized_scale_and_markers.osim")),
            "--grf",
            str(data_path(SUBJECT4 + "ID/walking1_grf.mot")),
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    torques = read_storage(tmp_path / "torques.sto")
    right = torques.data[:, torques.labels.index("ankle_angle_r_moment")]
    left = torques.data[:, torques.labels.index("ankle_angle_l_moment")]
    assert right.min() == pytest.approx(-85.0, abs=3.0) and left.min() == pytest.approx(-84.0, abs=3.0)
    figures = json.loads((tmp_path / "summary.json").read_text())
    assert figures["torques_from"] == "measured" and figures["body_mass_kg"] == pytest.approx(62.6)
    for name in ("grf_inferred.mot", "grf_inferred_loads.xml", "com_zmp.sto", "coordinates_filtered.mot"):
        assert (tmp_path / name).stat().st_size > 1000
    grf = read_ground_reaction(tmp_path / "grf_inferred.mot")
    assert grf.names == ("ground_force_r", "ground_force_l")
    osim = pytest.importorskip("opensim")
    for name in ("torques.sto", "com_zmp.sto", "grf_inferred.mot", "coordinates_filtered.mot"):
        assert osim.TimeSeriesTable(str(tmp_path / name)).getNumRows() == figures["frames"]
    loads = osim.ExternalLoads(str(tmp_path / "grf_inferred_loads.xml"), True)
    assert loads.getSize() == 2 and loads.get(0).get_applied_to_body() == "calcn_r"


def test_drop_jump_grf_from_kinematics_beats_the_com_estimate(subject4):
    """Kinematics-only GRF on a drop jump (box, flight, landing) vs the plates, against m(g + a_COM,y). The first
    second, standing on the box, is left out: the box carries the body there and no plate measures it."""
    motion = read_motion(data_path(SUBJECT4 + "IK/DJ1_ik.mot"))
    plates = read_ground_reaction(data_path(SUBJECT4 + "ID/DJ1_grf.mot"))
    result = analyze(motion, subject4, plates)
    keep = plate_frames(result)
    assert result.motion.times[~keep].max() < 1.05 and (~keep).sum() >= 90  # measured: 0-1.01 s, 102 frames
    figures = summary(result)
    ours, baseline = figures["inferred_vs_measured_vertical"], figures["com_baseline_vs_measured_vertical"]
    assert ours["r2"] > 0.88 and ours["rmse_bw"] < 0.30  # measured here: R2 0.91, RMSE 0.27 BW
    assert ours["rmse_bw"] < baseline["rmse_bw"]  # baseline: R2 0.87, RMSE 0.33 BW


def test_angles_wrapped_by_ik_are_unwrapped(subject4):
    """OpenCap's DJAsym1 IK wraps arm_flex_r from 170° to −176° between two frames at landing; taken as motion
    that jump put 3.4 BW of spurious ground force into the inferred GRF (7.7 BW at a 10 Hz cutoff)."""
    times = np.arange(50) / 100.0
    swing = np.deg2rad(150.0 + 60.0 * times)  # passes 180° at t = 0.5 s
    wrapped = np.angle(np.exp(1j * swing))
    names = list(subject4.coordinate_names)
    values = np.tile(subject4.defaults.numpy(), (len(times), 1))
    values[:, names.index("arm_flex_r")] = wrapped
    values[:, names.index("pelvis_ty")] = 0.9 + 2.0 * np.pi * times  # a translation is never unwrapped
    motion = unwrapped(Motion(times=times, names=tuple(names), values=values), subject4)
    assert np.allclose(motion.values[:, names.index("arm_flex_r")], swing)
    assert np.array_equal(
        np.delete(motion.values, names.index("arm_flex_r"), axis=1),
        np.delete(values, names.index("arm_flex_r"), axis=1),
    )
    figures = summary(
        analyze(
            read_motion(data_path(SUBJECT4 + "IK/DJAsym1_ik.mot")),
            subject4,
            read_ground_reaction(data_path(SUBJECT4 + "ID/DJAsym1_grf.mot")),
        )
    )
    assert figures["peak_inferred_vertical_grf_bw"] < 2.6  # measured 2.33 BW (plates: 3.0 BW)
    assert figures["inferred_vs_measured_vertical"]["rmse_bw"] < 0.3  # measured 0.27 BW (0.32 wrapped)


def test_inferred_loads_reproduce_the_root_force(subject4):
    """On a squat (feet always down) the inferred contact explains the pelvis generalized force almost fully."""
    motion = read_motion(data_path(SUBJECT4 + "IK/squats1_ik.mot")).slice(2.0, 4.0)
    result = analyze(motion, subject4)
    weight = result.body_weight
    assert np.abs(result.root_residual[:, 3:]).mean() < 0.02 * weight
    vertical = result.inferred.force[..., 1].sum(1)
    assert 0.7 * weight < vertical.mean() < 1.3 * weight


def test_zmp_from_kinematics_lands_on_the_plates_centre_of_pressure(subject4):
    """On level ground the ZMP is the CoP of the ground reaction (Sardain & Bessonnet 2004): the ZMP from the
    walking1 kinematics alone against the plates' combined CoP. Measured here: 3.4 cm RMS over 116 frames (the
    frames with both feet on plates and at least 0.2 body weights on them); tolerance 4.5 cm."""
    motion = read_motion(data_path(SUBJECT4 + "IK/walking1_ik.mot"))
    result = analyze(motion, subject4, read_ground_reaction(data_path(SUBJECT4 + "ID/walking1_grf.mot")))
    figures = summary(result)["zmp_vs_plate_cop"]
    assert figures["frames"] >= 100
    assert figures["rmse_m"] < 0.045
    no_plates = analyze(motion, subject4)
    with pytest.raises(ModelError, match="measured forces"):
        zmp_to_plate_cop(no_plates)


@pytest.mark.parametrize("trial", ["walking1", "DJ1", "squats1"])
def test_plate_feet_finds_the_foot_on_each_plate(trial, subject4):
    """opencap/SOURCE.md verified by hand (CoP against the calcaneus and toe markers at peak load) that plate 1 is
    the right foot and plate 2 the left in every Subject4 trial; plate 3 is never loaded."""
    model = subject4
    motion = model_motion(read_motion(data_path(SUBJECT4 + f"IK/{trial}_ik.mot")), model)
    forces = read_ground_reaction(data_path(SUBJECT4 + f"ID/{trial}_grf.mot"))
    assert plate_feet(forces, model, torch.tensor(motion.values), motion.times) == {
        "ground_force_1": "calcn_r",
        "ground_force_2": "calcn_l",
    }
