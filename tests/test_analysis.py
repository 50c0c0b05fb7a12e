"""`biomotion analyze` end to end on real trials: OpenSim-checked torque peaks and GRF inferred from motion."""

import json

import numpy as np
import pytest

from biomotion.analysis import analyze, summary
from biomotion.body.model import BodyModel
from biomotion.cli import main
from biomotion.io.mot import read_ground_reaction, read_motion, read_storage
from tests.conftest import data_path

SUBJECT4 = "opencap/Subject4/"


@pytest.fixture(scope="module")
def subject4():
    return BodyModel.from_osim(data_path(SUBJECT4 + "Models/optimized_scale_and_markers.osim"))


def test_walking_torques_with_plates_assigned_to_feet(tmp_path, subject4):
    """opencap/SOURCE.md: OpenSim 4.6 ID on walking1 with plate 1 -> right, 2 -> left gives ankle moments peaking
    at -85 N·m (r) and -84 N·m (l). Our automatic plate-to-foot assignment must reproduce that."""
    code = main(["analyze", str(data_path(SUBJECT4 + "IK/walking1_ik.mot")),
                 "--model", str(data_path(SUBJECT4 + "Models/optimized_scale_and_markers.osim")),
                 "--grf", str(data_path(SUBJECT4 + "ID/walking1_grf.mot")), "--out", str(tmp_path)])
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
    """Kinematics-only GRF on a drop jump (flight, box, landing) vs the plates, against m(g + a_COM,y)."""
    motion = read_motion(data_path(SUBJECT4 + "IK/DJ1_ik.mot"))
    plates = read_ground_reaction(data_path(SUBJECT4 + "ID/DJ1_grf.mot"))
    figures = summary(analyze(motion, subject4, plates))
    ours, baseline = figures["inferred_vs_measured_vertical"], figures["com_baseline_vs_measured_vertical"]
    assert ours["r2"] > 0.85 and ours["rmse_bw"] < 0.35            # measured here: R2 0.89, RMSE 0.27 BW
    assert ours["rmse_bw"] < 0.5 * baseline["rmse_bw"]               # baseline: RMSE 0.76 BW (no contact model)


def test_inferred_loads_reproduce_the_root_force(subject4):
    """On a squat (feet always down) the inferred contact explains the pelvis generalized force almost fully."""
    motion = read_motion(data_path(SUBJECT4 + "IK/squats1_ik.mot")).slice(2.0, 4.0)
    result = analyze(motion, subject4)
    weight = result.body_weight
    assert np.abs(result.root_residual[:, 3:]).mean() < 0.02 * weight
    vertical = result.inferred.force[..., 1].sum(1)
    assert 0.7 * weight < vertical.mean() < 1.3 * weight
