"""`biomotion train ground-forces`, `biomotion eval ground-forces` and `biomotion analyze --forces learned` on a data
root of three runners and one OpenCap walk, with a tiny config: the commands run on whoever is in the folder,
score people the weights never saw, and refuse what they cannot take on one line."""

from __future__ import annotations

import hashlib
import json

import pytest

from biomotion.cli import main
from biomotion.io.mot import read_motion, write_motion
from biomotion.models.ground_forces import LearnedGroundReaction
from tests.conftest import data_path

RUNNERS = ("RBDS010", "RBDS03", "RBDS05")
TINY = """
model: {width: 12, dilations: [1, 2, 4]}
data: {speeds: [T35]}
train: {iterations: 40, batch_size: 4, window_s: 1.0, warmup: 5}
"""


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """Links into the shared data: three runners at 3.5 m/s and OpenCap Subject4's walking1; samples cached in the
    session's temporary folder (shared with tests/models/test_ground_forces.py)."""
    base = tmp_path_factory.mktemp("root")
    shared = data_path("fukuchi-running")
    for runner in RUNNERS:
        for relative in (
            f"{runner}/{runner}_simple.osim",
            f"ik/T35/{runner}_T35_ik_simple.mot",
            f"c3d/{runner}runT35.c3d",
        ):
            target = base / "fukuchi-running" / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            target.symlink_to(shared / relative)
    for relative in ("Models/optimized_scale_and_markers.osim", "IK/walking1_ik.mot", "ID/walking1_grf.mot"):
        target = base / "opencap/Subject4" / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        target.symlink_to(data_path(f"opencap/Subject4/{relative}"))
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("XDG_CACHE_HOME", str(tmp_path_factory.getbasetemp() / "ground-forces-cache"))
        yield base


def test_train_then_evaluate_on_people_never_seen(root, tmp_path):
    config = tmp_path / "tiny.yaml"
    config.write_text(TINY)
    weights = tmp_path / "checkpoints" / "ground_forces.safetensors"
    train = ["train", "ground-forces", "--config", str(config), "--data-root", str(root), "--out", str(weights)]
    assert main([*train, "--exclude-subjects", "RBDS05", "--quiet"]) == 0
    card = json.loads(weights.with_suffix(".json").read_text())
    assert card["sha256"] == hashlib.sha256(weights.read_bytes()).hexdigest()
    assert card["data"]["train_subjects"] == ["fukuchi/RBDS010", "fukuchi/RBDS03"]
    assert weights.with_suffix(".md").read_text().startswith("# Learned ground reaction")
    assert LearnedGroundReaction.load(weights).train_subjects == {"fukuchi/RBDS010", "fukuchi/RBDS03"}

    report_path = tmp_path / "eval.json"
    evaluate = ["eval", "ground-forces", "--data-root", str(root), "--folds", "5", "--checkpoints"]
    outputs = ["--json", str(report_path), "--md", str(tmp_path / "e.md"), "--plots", str(tmp_path)]
    assert main([*evaluate, str(weights.parent), *outputs]) == 0
    report = json.loads(report_path.read_text())
    assert report["folds"] == 3 and [r["runners"] for r in report["fold_results"]] == [[r] for r in RUNNERS]
    assert report["config"]["train"]["iterations"] == 40  # the folds are trained as the weights were
    worst = max(r["learned_rmse_bw"] for r in report["fold_results"])
    assert report["grf_learned_vertical_rmse_bw"] == worst and 0.0 < worst < 0.5
    assert report["grf_learned_to_com_baseline"] == max(r["learned_to_baseline"] for r in report["fold_results"])
    assert report["shipped_unseen_runners"]["runners"] == ["RBDS05"]
    assert set(report["opencap"]) == {"walking"} and report["grf_learned_vertical_rmse_bw_opencap"] < 0.15
    assert set(report["bars"]) == {
        "grf_learned_vertical_rmse_bw",
        "grf_learned_to_com_baseline",
        "grf_learned_vertical_rmse_bw_opencap",
    }
    assert "| RBDS05 | 2 |" in (tmp_path / "e.md").read_text()
    assert (tmp_path / "eval_ground_forces_examples.png").is_file()

    model = data_path("fukuchi-running/RBDS05/RBDS05_simple.osim")
    motion = data_path("fukuchi-running/ik/T35/RBDS05_T35_ik_simple.mot")
    out = tmp_path / "analysis"
    analyze = ["analyze", str(motion), "--model", str(model), "--forces", "learned", "--forces-model", str(weights)]
    assert main([*analyze, "--no-figures", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["force_source"] == "learned" and summary["peak_learned_vertical_grf_bw"] > 1.5
    assert (out / "grf_learned.mot").is_file() and (out / "grf_learned_loads.xml").is_file()


def test_analyze_refuses_what_learned_forces_cannot_take(tmp_path, capsys):
    model = data_path("fukuchi-running/RBDS05/RBDS05_simple.osim")
    motion = read_motion(data_path("fukuchi-running/ik/T35/RBDS05_T35_ik_simple.mot"))
    short = write_motion(tmp_path / "short.mot", motion.frames(slice(0, 30)))
    weights = tmp_path / "w.safetensors"
    from biomotion.models.ground_forces import GroundForceNet, GroundForcesConfig

    LearnedGroundReaction(GroundForceNet(GroundForcesConfig(width=8))).save(weights)
    base = ["analyze", str(short), "--model", str(model), "--no-figures", "--out", str(tmp_path / "o")]
    assert main([*base, "--forces", "learned", "--forces-model", str(weights)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "at least 0.5 s" in error
    assert main([*base, "--forces", "measured"]) == 2
    assert "--forces measured needs the plates" in capsys.readouterr().err
    assert main([*base, "--forces", "learned", "--forces-model", str(tmp_path / "none.safetensors")]) == 2
    assert "no learned ground-forces weights" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_validate_dynamics_keeps_the_physics_rows_beside_the_shipped_learned_ones(root, tmp_path):
    from biomotion.models.ground_forces import SHIPPED
    from biomotion.validation.dynamics import check_ground_reaction

    if not SHIPPED.is_file():
        pytest.skip("no shipped learned ground-forces weights")
    small = tmp_path / "root"  # one runner and the walk
    for relative in ("fukuchi-running/RBDS05", "fukuchi-running/c3d/RBDS05runT35.c3d", "opencap"):
        (small / relative).parent.mkdir(parents=True, exist_ok=True)
        (small / relative).symlink_to(root / relative)
    (small / "fukuchi-running/ik/T35").mkdir(parents=True)
    (small / "fukuchi-running/ik/T35/RBDS05_T35_ik_simple.mot").symlink_to(
        root / "fukuchi-running/ik/T35/RBDS05_T35_ik_simple.mot"
    )
    report = check_ground_reaction(small, progress=False)
    rows = {row["trial"]: row for row in report["grf_trials"]}
    assert set(rows) == {"fukuchi/RBDS05/T35", "opencap/Subject4/walking1"}
    for row in rows.values():  # the physics-only figures stay, the learned ones stand beside them
        assert {"rmse_bw", "baseline_rmse_bw", "learned_rmse_bw"} <= set(row)
    assert not rows["fukuchi/RBDS05/T35"]["learned_held_out"]  # the shipped weights were trained on every runner
    assert rows["opencap/Subject4/walking1"]["learned_held_out"]
    held_out = report["grf_learned_shipped_vertical_rmse_bw_held_out"]
    assert held_out == pytest.approx(rows["opencap/Subject4/walking1"]["learned_rmse_bw"])
    assert report["grf_learned_shipped_vertical_rmse_bw_trained_on"] < report["grf_com_baseline_rmse_bw"]
