"""HUMOS physics and dynamic stability of `biomotion eval shape` (`biomotion.evaluation.shape_physics`,
`biomotion.evaluation.shape.physics_summary`).

Truth: a synthetic foot of four corners whose ZMP is placed inside or outside it, with flight frames (HUMOS
Sec. 3.4: not counted stable); ratios and gaps worked by hand; a real Fukuchi runner on their own model, whose
treadmill stance foot moves with the belt until the clip is made overground."""

import numpy as np
import pytest
import torch

from biomotion.body.model import BodyModel
from biomotion.evaluation.shape import eval_shape, physics_summary
from biomotion.evaluation.shape_physics import clip_physics, dynamic_stability
from biomotion.io.mot import read_motion
from biomotion.metrics.stability import share_inside_support
from tests.conftest import data_path
from tests.evaluation.test_eval_shape import RUNNERS, _view

torch.set_num_threads(1)

RATE = 30.0
SQUARE = torch.tensor([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.2, 0.0, 0.1], [0.0, 0.0, 0.1]], dtype=torch.float64)


def _foot(frames: int, flight: range, sliding: range = range(0)) -> torch.Tensor:
    """[T, 4, 3] a planted square foot; lifted 0.3 m in ``flight``, sliding at 2 m/s (on the ground) in
    ``sliding``."""
    points = SQUARE.expand(frames, 4, 3).clone()
    for t in flight:
        points[t, :, 1] = 0.3
    for t in sliding:
        points[t, :, 0] += 2.0 * t / RATE
    return points


def test_dynamic_stability_counts_flight_as_unstable():
    """10 frames: ZMP at the foot's centre in frames 0-2, 0.5 m away in 3-5, flight in 6-9 (ZMP NaN in 6-7, at the
    centre in 8-9: no support there either). Stable: 3 of 10 (HUMOS), against 3 of 6 supported frames for the
    share that leaves flight out."""
    points = _foot(10, range(6, 10))
    centre = torch.tensor([0.1, 0.0, 0.05], dtype=torch.float64)
    zmp = centre.expand(10, 3).clone()
    zmp[3:6, 0] += 0.5
    zmp[6:8] = float("nan")
    assert float(dynamic_stability(zmp, points, RATE)) == pytest.approx(0.3)
    assert float(share_inside_support(zmp, points)) == pytest.approx(0.5)
    # the boundary counts as inside; a valid mask removes frames from the denominator
    edge = zmp.clone()
    edge[3:6] = SQUARE[1]
    assert float(dynamic_stability(edge, points, RATE)) == pytest.approx(0.6)
    valid = torch.ones(10, dtype=torch.bool)
    valid[6:] = False
    assert float(dynamic_stability(zmp, points, RATE, valid)) == pytest.approx(0.5)


def test_a_sliding_foot_is_no_base_of_support():
    """Low but fast points are not in contact (HUMOS: slow and low): a foot sliding at 2 m/s supports nothing."""
    points, planted = _foot(12, range(0), sliding=range(12)), _foot(12, range(0))
    zmp = points.mean(1)  # always under the sliding foot
    assert float(dynamic_stability(zmp, points, RATE)) == 0.0
    centre = planted.mean(1)
    assert float(dynamic_stability(centre, planted, RATE)) == 1.0
    batch = torch.stack([points, planted])
    assert dynamic_stability(torch.stack([zmp, centre]), batch, RATE).tolist() == [0.0, 1.0]


def test_physics_summary_by_hand():
    method = {"penetrate": 0.002, "float": 0.01, "skate": 0.2, "dyn_stability": 0.1}
    real = {"penetrate": 0.001, "float": 0.02, "skate": 0.1, "dyn_stability": 0.3}
    other = {"penetrate": 0.003, "float": 0.03, "skate": 0.2, "dyn_stability": 0.3}
    summary = physics_summary([(method, real), (other, real), (None, real)])
    assert summary["pairs"] == 2
    assert summary["ratio_to_real"] == pytest.approx({"penetrate": 2.5, "float": 1.0, "skate": 2.0})
    assert summary["worst_ratio_to_real"] == pytest.approx(2.5)
    assert summary["dyn_stability_gap_points"] == pytest.approx(10.0)  # 30 % real, 20 % method
    zero = dict.fromkeys(method, 0.0)
    assert physics_summary([(zero, zero)])["worst_ratio_to_real"] == 1.0  # as plausible as the real motion
    assert physics_summary([(method, zero)])["worst_ratio_to_real"] is None  # undefined, not infinite
    assert physics_summary([])["dyn_stability_gap_points"] is None


def test_clip_physics_of_a_real_treadmill_run():
    """A runner on their own model: the feet meet the floor within a millimetre on average, and the stance foot
    only rests once the belt speed is added (on the treadmill it moves with the belt, and skates)."""
    model = BodyModel.from_osim(data_path("fukuchi-running/RBDS019/RBDS019_simple.osim"))
    motion = read_motion(data_path("fukuchi-running/ik/T35/RBDS019_T35_ik_simple.mot"))
    overground = clip_physics(model, motion, 3.5)
    on_belt = clip_physics(model, motion, None)
    assert all(np.isfinite(v) for v in overground.values())
    assert 0.0 <= overground["penetrate"] < 0.001 and 0.0 <= overground["float"] < 0.05
    assert overground["skate"] < 0.25 < on_belt["skate"]
    assert 0.0 <= overground["dyn_stability"] <= 1.0


def test_eval_shape_reports_physics_and_stability(tmp_path):
    """The identity adapter scores exactly as the copy; without an adapter the bars are not measured."""
    root = _view(tmp_path, RUNNERS[:2])
    report = eval_shape(root, adapt=lambda motion, a, b: motion, speeds=("T35",), progress=False)
    assert report["shape_physics_worst_ratio_to_real"] == pytest.approx(
        report["shape_copy_physics_worst_ratio_to_real"]
    )
    assert report["shape_dyn_stability_gap_points"] == pytest.approx(report["shape_copy_dyn_stability_gap_points"])
    assert report["bars"]["shape_physics_worst_ratio_to_real"] == (report["shape_physics_worst_ratio_to_real"] <= 1.0)
    assert set(report["physics"]["adapted"]["method"]) == {"penetrate", "float", "skate", "dyn_stability"}
    row = report["pair_rows"][0]
    assert row["physics"] == row["adapted"]["physics"] and row["physics_real"] is not None
    copy_only = eval_shape(root, speeds=("T35",), progress=False)
    assert copy_only["shape_physics_worst_ratio_to_real"] is None
    assert "adapter" in copy_only["not_measured"]["shape_dyn_stability_gap_points"]
    assert copy_only["shape_copy_physics_worst_ratio_to_real"] is not None
