"""Control targets measured on written outputs (`biomotion.analysis.control_measures`): bounds, values and paths
judged on series whose answer is known, and each quantity read back from files written with known values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from biomotion.analysis.control_measures import (
    ClipOutputs,
    control_record,
    length_scale,
    measure_control,
    measure_series,
    quantity_series,
    read_outputs,
)
from biomotion.guidance.control import Control
from tests.conftest import data_path

RATE = 30.0
TIMES = np.arange(60) / RATE  # 2 s


def one(spec: dict):
    (target,) = Control.from_dict({"targets": [spec]}, "test").targets
    return target


def bump(peak: float, at: float = 1.0, base: float = 1.0) -> np.ndarray:
    """A series at ``base`` with one smooth bump to ``peak`` at ``at`` s."""
    return base + (peak - base) * np.exp(-(((TIMES - at) / 0.1) ** 2))


def test_a_max_bound_is_judged_on_the_peak_inside_its_window():
    series = bump(2.5, at=1.0)
    over = measure_series(one({"quantity": "grf_vertical", "kind": "max", "value": 2.2}), TIMES, series)
    assert not over.met
    assert over.achieved == pytest.approx(2.5) and over.at == pytest.approx(1.0)
    assert over.margin == pytest.approx(-0.3)
    assert over.window == (0.0, TIMES[-1])
    assert "NOT met (peak 2.5 BW at 1.00 s)" in over.outcome()
    # the same series with the window after the bump: met, its peak the window's own
    late = one({"quantity": "grf_vertical", "kind": "max", "value": 2.2, "window": [1.5, 1.9]})
    inside = measure_series(late, TIMES, series)
    assert inside.met and inside.achieved < 1.01 and 1.5 - 0.5 / RATE <= inside.at <= 1.9 + 0.5 / RATE
    # the cap above the peak: met
    assert measure_series(one({"quantity": "grf_vertical", "kind": "max", "value": 2.6}), TIMES, series).met


def test_a_min_bound_keeps_opensims_sign():
    # a knee extension moment of 0.8 N·m/kg is -0.8: under a cap of 0.5 (min -0.5) it is not met
    target = one({"quantity": "joint_torque", "coordinate": "knee_angle_r", "kind": "min", "value": -0.5})
    moment = -bump(0.8, at=0.5, base=0.0)
    measure = measure_series(target, TIMES, moment)
    assert not measure.met and measure.achieved == pytest.approx(-0.8) and measure.at == pytest.approx(0.5)
    assert measure.unit == "N·m/kg" and measure.name == "knee_angle_r"
    assert measure_series(target, TIMES, 0.5 * moment).met  # -0.4 stays above -0.5


def test_a_joint_angle_value_is_judged_in_degrees_at_the_nearest_frames():
    target = one(
        {"quantity": "joint_angle", "coordinate": "knee_angle_r", "kind": "value", "value": 40, "times": [0.5, 1.0]}
    )
    assert target.value == pytest.approx(math.radians(40))  # the spec holds rad; the measure reports degrees
    degrees = 40.0 + 10.0 * (TIMES > 0.75)  # 40 at 0.5 s, 50 at 1.0 s
    measure = measure_series(target, TIMES, degrees)
    assert measure.value == pytest.approx(40.0) and measure.unit == "deg"
    assert measure.errors.tolist() == pytest.approx([0.0, 10.0]) and not measure.met
    assert measure_series(target, TIMES, np.full(len(TIMES), 41.5)).met  # within 2 degrees at both times


def test_a_path_is_met_when_every_point_lies_within_the_tolerance():
    path = [[0.3, 0.1, 1.0, 0.2], [0.9, 0.4, 1.2, 0.25], [1.5, 0.5, 1.3, 0.25]]
    target = one({"quantity": "joint_position", "body": "hand_r", "kind": "path", "path": path})
    series = np.zeros((len(TIMES), 3))
    for t, *point in path:  # the body passes through every point ...
        series[round(t * RATE)] = point
    measure = measure_series(target, TIMES, series)
    assert measure.met and measure.errors.max() == pytest.approx(0.0)
    series[round(0.9 * RATE), 1] += 0.05  # ... but 5 cm above the middle one
    missed = measure_series(target, TIMES, series)
    assert not missed.met and missed.errors.tolist() == pytest.approx([0.0, 0.05, 0.0])
    record = missed.record()
    assert record["largest_distance_m"] == pytest.approx(0.05) and record["met"] is False
    assert record["target"] == [p[1:] for p in path] and record["body"] == "hand_r"


def test_the_record_says_per_target_what_was_asked_and_achieved():
    control = Control.from_dict(
        {
            "targets": [
                {"quantity": "grf_vertical", "kind": "max", "value": 2.2},
                {"quantity": "muscle_activation", "muscle": "glmed1_r", "kind": "max", "value": 0.4},
            ]
        },
        "spec.yaml",
    )
    grf, activation = bump(2.0), bump(0.6, base=0.1)
    measures = [measure_series(t, TIMES, s, n) for n, (t, s) in enumerate(zip(control.targets, (grf, activation)), 1)]
    free = [measure_series(t, TIMES, s + 0.5, n) for n, (t, s) in enumerate(zip(control.targets, (grf, activation)), 1)]
    record = control_record(control, measures, uncontrolled=free)
    assert record["spec"] == "spec.yaml" and record["targets"] == 2 and record["targets_met"] == 1
    assert record["all_met"] is False
    first, second = record["per_target"]
    assert (first["quantity"], first["kind"], first["target"], first["met"]) == ("grf_vertical", "max", 2.2, True)
    assert first["achieved"] == pytest.approx(2.0) and first["uncontrolled_achieved"] == pytest.approx(2.5)
    assert first["uncontrolled_met"] is False
    assert (second["muscle"], second["met"], second["achieved"]) == ("glmed1_r", False, pytest.approx(0.6))


def test_each_quantity_is_read_from_its_file(tmp_path):
    """Files written with known values on the canonical model: every quantity comes back in its unit, lengths at
    the canonical size."""
    from biomotion.analysis.chain import STANDARD_GRAVITY, torque_labels
    from biomotion.body.model import BodyModel
    from biomotion.io.mot import write_ground_reaction, write_motion, write_storage
    from biomotion.motion import GroundReaction, Motion

    model = BodyModel.from_osim(data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim"))
    n = len(TIMES)
    values = np.tile(model.defaults.numpy(), (n, 1))
    knee = model.coordinate_index("knee_angle_r")
    values[:, knee] = np.deg2rad(30.0)
    values[:, model.coordinate_index("pelvis_ty")] = 1.0 * 1.1  # a person 1.1 times the canonical size
    write_motion(tmp_path / "motion.mot", Motion(times=TIMES, values=values, names=model.coordinate_names))
    weight = float(model.total_mass) * STANDARD_GRAVITY
    force = np.zeros((n, 2, 3))
    force[:, :, 1] = 0.75 * weight  # 1.5 BW in all
    grf = GroundReaction(
        times=TIMES,
        names=("ground_force_r", "ground_force_l"),
        force=force,
        cop=np.zeros_like(force),
        moment=np.zeros_like(force),
    )
    write_ground_reaction(tmp_path / "grf.mot", grf)
    torques = np.zeros((n, len(model.coordinate_names)))
    torques[:, knee] = -2.0 * float(model.total_mass)  # -2 N·m/kg
    write_storage(tmp_path / "torques.sto", torque_labels(model), TIMES, torques)
    write_storage(tmp_path / "activations.sto", ["glmed1_r"], TIMES, np.full((n, 1), 0.3))
    write_storage(tmp_path / "com_zmp.sto", ["com_x", "com_y", "com_z"], TIMES, np.tile([0.0, 1.1, 0.0], (n, 1)))
    scale = length_scale(1.70 * 1.1)
    assert scale == pytest.approx(1 / 1.1)
    outputs = read_outputs(tmp_path, model=model, scale=scale)
    assert isinstance(outputs, ClipOutputs)

    def series(spec: dict) -> np.ndarray:
        return quantity_series(outputs, one(spec))[1]

    assert series({"quantity": "grf_vertical", "kind": "max", "value": 2}) == pytest.approx(np.full(n, 1.5))
    knee_spec = {"quantity": "joint_angle", "coordinate": "knee_angle_r", "kind": "max", "value": 90}
    assert series(knee_spec) == pytest.approx(np.full(n, 30.0))
    pelvis_spec = {"quantity": "joint_angle", "coordinate": "pelvis_ty", "kind": "max", "value": 2}
    assert series(pelvis_spec) == pytest.approx(np.full(n, 1.0))
    torque = {"quantity": "joint_torque", "coordinate": "knee_angle_r", "kind": "min", "value": -1}
    assert series(torque) == pytest.approx(np.full(n, -2.0))
    activation = {"quantity": "muscle_activation", "muscle": "glmed1_r", "kind": "max", "value": 0.5}
    assert series(activation) == pytest.approx(np.full(n, 0.3))
    assert series({"quantity": "com_height", "kind": "max", "value": 2}) == pytest.approx(np.full(n, 1.0))
    pelvis = series({"quantity": "joint_position", "body": "pelvis", "kind": "value", "value": [0, 1, 0], "times": [1]})
    assert pelvis[:, 1] == pytest.approx(np.full(n, 1.0))  # the pelvis origin: pelvis_ty, at the canonical size
    control = Control.from_dict({"targets": [torque, activation]}, "spec.yaml")
    assert [m.met for m in measure_control(control, outputs)] == [False, True]
