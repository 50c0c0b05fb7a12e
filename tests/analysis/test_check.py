"""Plausibility verdicts: the a-priori share rule, and `check` on a real walk and on the same walk with its feet
made to slide."""

import numpy as np
import pytest

from biomotion.analysis.check import FAIL_SHARE, WARN_SHARE, check, marker_fit, share_verdict, worst
from biomotion.body.model import BodyModel
from biomotion.io.mot import read_ground_reaction, read_motion
from tests.conftest import data_path

SUBJECT4 = "opencap/Subject4"


def test_share_rule_fails_on_the_median_frame_and_warns_on_the_95th():
    assert share_verdict(0, 100) == "ok"
    assert share_verdict(round(100 * WARN_SHARE) - 1, 100) == "ok"
    assert share_verdict(round(100 * WARN_SHARE), 100) == "warn"
    assert share_verdict(round(100 * FAIL_SHARE), 100) == "fail"
    assert worst(["ok", "fail", "warn"]) == "fail" and worst([]) == "ok"


def test_marker_fit_uses_opensims_bars():
    errors = np.full((100, 4), 0.01)
    reason, flags = marker_fit(errors, ["a", "b", "c", "d"])
    assert reason.verdict == "ok" and not flags.any()
    errors[:10, 0] = 0.05  # max over 4 cm on 10 % of the frames: warn
    assert marker_fit(errors, ["a", "b", "c", "d"])[0].verdict == "warn"
    errors[:, 1] = np.nan  # an occluded marker is no error
    errors[:60, 0] = 0.05
    reason, flags = marker_fit(errors, ["a", "b", "c", "d"])
    assert reason.verdict == "fail" and flags.sum() == 60
    assert reason.figures["worst_markers"][0]["marker"] == "a"


@pytest.fixture(scope="module")
def walk():
    model = BodyModel.from_osim(data_path(f"{SUBJECT4}/Models/optimized_scale_and_markers.osim"))
    return model, read_motion(data_path(f"{SUBJECT4}/IK/walking1_ik.mot"))


def test_check_passes_the_real_walk(walk):
    model, motion = walk
    verdict = check(motion, model)
    assert verdict.verdict != "fail", verdict.messages()
    forces = read_ground_reaction(data_path(f"{SUBJECT4}/ID/walking1_grf.mot"))
    with_plates = check(motion, model, forces)
    assert with_plates.verdict != "fail" and {r.rule for r in with_plates.reasons} >= {
        "residuals",
        "foot_sliding",
        "ground_penetration",
        "velocity_spikes",
        "joint_limits",
        "zmp_outside_support",
    }


def test_check_fails_the_walk_with_its_feet_sliding(walk):
    """The same clip with the whole body carried forward 1 m/s faster than it steps: every planted foot slides."""
    model, motion = walk
    values = motion.values.copy()
    values[:, motion.index("pelvis_tx")] += 1.0 * (motion.times - motion.times[0])
    verdict = check(motion.with_values(values), model)
    assert verdict.verdict == "fail"
    assert verdict.reasons[0].rule == "foot_sliding" and verdict.reasons[0].verdict == "fail"


def test_check_flags_a_velocity_spike_and_a_joint_beyond_its_range(walk):
    model, motion = walk
    values = motion.values.copy()
    knee = motion.index("knee_angle_r")
    values[60, knee] += 3.0  # a one-frame glitch of 3 rad at 100 Hz: 300 rad/s
    verdict = check(motion.with_values(values), model, cutoff_hz=0)
    rules = {r.rule: r for r in verdict.reasons}
    assert rules["velocity_spikes"].verdict != "ok" and "knee_angle_r" in rules["velocity_spikes"].message
    assert rules["joint_limits"].flagged >= 1
