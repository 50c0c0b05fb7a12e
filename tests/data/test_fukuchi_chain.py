"""The Fukuchi 2017 processing chain (`biomotion.data.fukuchi_chain`): one runner end to end against its shipped
``_ik_simple.mot``, and the chain's small steps on synthetic input."""

from __future__ import annotations

import numpy as np

from biomotion.data.fukuchi_chain import FUKUCHI, as_simple, validate_fukuchi_chain, window
from biomotion.motion import Motion
from tests.conftest import data_path


def test_rbds09_chain_reproduces_the_shipped_ik():
    """RBDS09 (spline-filled gaps in a tracked thigh marker): scaling, placement, welds, IK and conversion give
    the shipped T35 IK on its 953 frames. Measured: worst rotational RMSE 0.54 deg (hip_flexion_r, mostly a
    constant -0.37 deg bias left by the source's under-converged static placement), pelvis translations
    0.0007 m; the bounds leave about 0.15 deg and 0.0003 m of slack."""
    runner = "RBDS09"
    for relative in (f"c3d/{runner}runT35.c3d", f"c3d/{runner}static.c3d", f"ik/T35/{runner}_T35_ik_simple.mot"):
        data_path(f"{FUKUCHI}/{relative}")
    result = validate_fukuchi_chain(data_path(FUKUCHI).parent, [runner])
    detail = result["fukuchi_chain"][runner]
    assert result["skipped"] == []
    assert detail["frames"] == 953
    assert result["fukuchi_ik_rmse_deg"] == detail["rmse_deg"] < 0.7
    assert result["fukuchi_ik_rmse_m"] == detail["rmse_m"] < 0.001
    assert len(detail["coordinate_rmse"]) == 16
    assert detail["marker_rmse_m"] < 0.02


def test_as_simple_drops_knee_betas_and_negates_knee_angles():
    names = ("pelvis_tx", "knee_angle_r", "knee_angle_r_beta", "ankle_angle_r", "knee_angle_l", "knee_angle_l_beta")
    values = np.arange(12, dtype=float).reshape(2, 6) + 1.0
    simple = as_simple(Motion(times=np.array([0.0, 0.01]), names=names, values=values))
    assert simple.names == ("pelvis_tx", "knee_angle_r", "ankle_angle_r", "knee_angle_l")
    np.testing.assert_array_equal(simple.values, values[:, [0, 1, 3, 4]] * np.array([1.0, -1.0, 1.0, -1.0]))


def test_window_takes_the_frames_nearest_the_setup_times():
    """OpenSim's IK tool solves from the frame nearest the start to the frame nearest the end, even when that
    frame lies outside the window (RBDS017 T35: 11.169-18.371 s -> 11.1667-18.3733 s at 150 Hz)."""
    times = np.arange(4500) / 150.0
    start, end = window(times, (11.169, 18.371))
    assert (round(start * 150), round(end * 150)) == (1675, 2756)


def test_runners_lacking_files_are_skipped_and_named(tmp_path):
    result = validate_fukuchi_chain(tmp_path, ["RBDS999"])
    assert result["fukuchi_ik_rmse_deg"] is None and result["fukuchi_chain"] == {}
    assert len(result["skipped"]) == 1 and result["skipped"][0].startswith(f"{FUKUCHI}/RBDS999: no ")
    assert "c3d/RBDS999runT35.c3d" in result["skipped"][0]
