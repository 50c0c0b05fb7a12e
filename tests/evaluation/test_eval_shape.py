"""`biomotion eval shape` (HUMOS real pairs, copy baseline): the metrics on known cases and a small real run.

Truth: a motion against itself (DTW 0, no stride or cadence error), a brute-force DTW, the Fukuchi IK windows (each
covers 10 right strides from a right foot strike: SOURCE.md, "Processing chain" step 4), and an adapter whose effect
on timing is known exactly (a time stretch)."""

import json

import numpy as np
import pytest
import torch

from biomotion.body.model import BodyModel
from biomotion.cli import main
from biomotion.errors import ConfigError
from biomotion.evaluation.shape import (
    compare,
    dtw_cost,
    dtw_distance,
    eval_shape,
    gait_timing,
    runner_pairs,
)
from biomotion.io.mot import read_motion
from tests.conftest import data_path

torch.set_num_threads(1)

RUNNERS = ("RBDS002", "RBDS010", "RBDS019")


def _naive_dtw(x: np.ndarray, y: np.ndarray) -> float:
    cost = np.sqrt(((x[:, None] - y[None]) ** 2).mean(-1))
    total = np.full((len(x) + 1, len(y) + 1), np.inf)
    total[0, 0] = 0.0
    for i in range(1, len(x) + 1):
        for j in range(1, len(y) + 1):
            total[i, j] = cost[i - 1, j - 1] + min(total[i - 1, j - 1], total[i - 1, j], total[i, j - 1])
    return float(total[-1, -1])


def test_dtw_against_brute_force_and_known_cases():
    rng = np.random.default_rng(1)
    for n, m in ((1, 1), (5, 9), (23, 17), (40, 40)):
        x, y = rng.normal(size=(n, 3)), rng.normal(size=(m, 3))
        total, steps = dtw_cost(x, y)
        assert total == pytest.approx(_naive_dtw(x, y), rel=1e-12)
        assert max(n, m) <= steps <= n + m - 1
    x = np.sin(np.linspace(0, 6, 80))[:, None] * np.ones((1, 4))
    assert dtw_distance(x, x) == 0.0
    assert dtw_distance(np.zeros((7, 2)), np.full((11, 2), 3.0)) == pytest.approx(3.0, rel=1e-14)
    # the same curve sampled at another rate: warping aligns it (what is left is the sampling)
    slow = np.sin(np.linspace(0, 6, 160))[:, None] * np.ones((1, 4))
    assert dtw_distance(x, slow) < 0.02
    # an offset curve: no better than the diagonal's 0.5 per step, and warping cannot remove the offset
    assert 0.1 < dtw_distance(x, x + 0.5) <= 0.5
    with pytest.raises(ConfigError):
        dtw_distance(np.zeros((3, 2)), np.zeros((3, 3)))


def test_pairs_are_deterministic_and_cyclic():
    assert runner_pairs(["c", "a", "b"], 2) == [("a", "b"), ("a", "c"), ("b", "c"), ("b", "a"), ("c", "a"), ("c", "b")]
    assert runner_pairs(["b", "a"], 5) == [("a", "b"), ("b", "a")]
    assert runner_pairs(["a"], 3) == []


@pytest.fixture(scope="module")
def runner019():
    model = BodyModel.from_osim(data_path("fukuchi-running/RBDS019/RBDS019_simple.osim"))
    return model, read_motion(data_path("fukuchi-running/ik/T35/RBDS019_T35_ik_simple.mot"))


def test_copy_onto_self_is_exact_and_timing_matches_the_ik_window(runner019):
    model, motion = runner019
    scores = compare(motion, motion, model, 3.5)
    assert scores["dtw_deg"] == 0.0
    assert scores["stride_rel_err"] == pytest.approx(0.0, abs=1e-12)
    assert scores["cadence_rel_err"] == pytest.approx(0.0, abs=1e-12)
    timing = gait_timing(model, motion, 3.5)
    window = (motion.times[-1] - motion.times[0]) / 10.0  # 10 right strides per IK file
    assert timing["stride_time_s"] == pytest.approx(window, rel=0.03)
    assert 10 <= timing["strikes"] <= 11
    assert 150.0 < timing["cadence_spm"] < 200.0  # steps/min of trained runners at 3.5 m/s
    assert timing["stride_length_m"] == pytest.approx(3.5 * timing["stride_time_s"], rel=1e-12)


def _view(tmp_path, runners=RUNNERS):
    """A data root of symlinks: the generic model, the subject table, three runners' models and their T35 IK."""
    root = tmp_path / "data"
    base = root / "fukuchi-running"
    (base / "ik" / "T35").mkdir(parents=True)
    for name in ("generic-models", "participantInfo.csv"):
        (base / name).symlink_to(data_path(f"fukuchi-running/{name}"))
    for runner in runners:
        (base / runner).symlink_to(data_path(f"fukuchi-running/{runner}"))
        mot = f"{runner}_T35_ik_simple.mot"
        (base / "ik" / "T35" / mot).symlink_to(data_path(f"fukuchi-running/ik/T35/{mot}"))
    return root


def test_small_real_run_through_the_cli(tmp_path, capsys):
    root = _view(tmp_path)
    out_json, out_md = tmp_path / "shape.json", tmp_path / "shape.md"
    args = ["eval", "shape", "--data-root", str(root), "--json", str(out_json), "--md", str(out_md)]
    code = main([*args, "--adapter", "none"])
    assert code == 0
    report = json.loads(out_json.read_text())
    assert report["pairs"] == 6 and report["subjects"] == 3  # 3 runners x 2 partners (capped), T35 only
    assert {(r["a"], r["b"]) for r in report["pair_rows"]} == {(a, b) for a in RUNNERS for b in RUNNERS if a != b}
    # different people run differently: a few degrees of joint angle apart, strides a few percent apart
    assert 2.0 < report["shape_copy_dtw"] < 20.0
    assert 0.0 < report["shape_copy_stride_rel_err"] < 0.3
    assert 0.0 < report["shape_copy_cadence_rel_err"] < 0.3
    assert report["shape_dtw_gain_vs_copy"] is None and "adapter" in report["not_measured"]["shape_dtw_gain_vs_copy"]
    assert report["shape_stride_rel_err"] is None and report["bars"]["shape_stride_rel_err"] is None
    skipped = "\n".join(report["skipped"])
    assert "SchreiberMoissenet2019: absent" in skipped and "RBDS002 T25: no RBDS002_T25_ik_simple.mot" in skipped
    assert report["shapes"]["RBDS019"]["height_m"] == pytest.approx(1.7, abs=0.15)
    assert str(tmp_path) not in out_json.read_text() + out_md.read_text()
    assert "| copy A's angles onto B (baseline) |" in out_md.read_text()
    assert "6 pairs of 3 runners" in capsys.readouterr().out


def test_adapter_hook_is_scored_beside_the_copy(tmp_path):
    """An adapter that slows A's motion by 10 % changes the cadence it is scored with by exactly 1/1.1; the identity
    adapter scores as the copy (gain 0)."""
    root = _view(tmp_path, RUNNERS[:2])
    seen = []

    def slower(motion, source_shape, target_shape):
        seen.append((source_shape.reference, target_shape.mass))
        start = motion.times[0]
        return type(motion)(times=start + 1.1 * (motion.times - start), names=motion.names, values=motion.values)

    report = eval_shape(root, adapt=slower, speeds=("T35",), progress=False)
    assert report["pairs"] == 2 and len(seen) == 4  # each pair, then each runner's clip onto itself (A -> A)
    assert seen[0][0] == "Denton2023_LowerLimb_Fukuchi2017"
    for row in report["pair_rows"]:
        assert row["adapted"]["cadence_spm"] == pytest.approx(row["cadence_spm"] / 1.1, rel=1e-9)
    assert report["shape_dtw_gain_vs_copy"] is not None and report["bars"]["shape_dtw_gain_vs_copy"] is not None
    same = eval_shape(root, adapt=lambda motion, a, b: motion, speeds=("T35",), progress=False)
    assert same["shape_dtw_gain_vs_copy"] == pytest.approx(0.0, abs=1e-12)
    assert same["shape_adapted_stride_rel_err"] == pytest.approx(same["shape_copy_stride_rel_err"], rel=1e-12)
    with pytest.raises(ConfigError, match="speeds"):
        eval_shape(root, speeds=("T99",), progress=False)


def test_a_learned_adapter_is_scored_on_runners_it_never_saw(tmp_path):
    """`--adapter` weights name their training runners; those are left out before pairing, and the copy baseline
    is scored on the same pairs."""
    from biomotion.models.shape_vae import ShapeVAE, ShapeVAEConfig

    root = _view(tmp_path)
    weights = tmp_path / "adapter.safetensors"
    ShapeVAE(ShapeVAEConfig(width=16, latent=4, layers=1, heads=2, ff=16)).save(
        weights, {"subjects": '["fukuchi/RBDS002", "hamner/subject01"]'}
    )
    out_json = tmp_path / "shape.json"
    args = ["eval", "shape", "--data-root", str(root), "--json", str(out_json), "--adapter", str(weights)]
    assert main(args) == 0
    report = json.loads(out_json.read_text())
    assert {(r["a"], r["b"]) for r in report["pair_rows"]} == {("RBDS010", "RBDS019"), ("RBDS019", "RBDS010")}
    assert report["held_out"]["left_out_training_runners"] == ["RBDS002"]
    assert report["adapter"]["weights"] == "adapter.safetensors"
    assert all("adapted" in r for r in report["pair_rows"]) and report["shape_dtw_gain_vs_copy"] is not None
    assert report["shape_adapted_self_dtw"] is not None  # A -> A: how far the adapter moves a motion that should stay
