"""The evaluation harness on real data: a few cache clips, OpenSim .mot files and a folder of three BVH clips."""

from __future__ import annotations

import json
import math
import shutil

import pytest

from tests.conftest import data_path

BVH_CLIPS = ("dataset-2_walk_normal_001", "dataset-2_walk_normal_004", "dataset-2_walk_normal_006")
MOT_FILES = ("opencap/Subject4/IK/walking1_ik.mot", "opencap/Subject4/IK/squats1_ik.mot")


@pytest.fixture(scope="module")
def model():
    from biomotion.data.clips import body_model

    data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")
    return body_model(data_path(""))


@pytest.fixture(scope="module")
def cache_set(tmp_path_factory, model):
    """Four Schreiber walking clips from a dataset cache, through the body model."""
    from biomotion.data.clips import cache_clips, coordinate_set
    from biomotion.data.registry import DatasetCache, build_cache

    data_path("SchreiberMoissenet2019")
    out = tmp_path_factory.mktemp("cache")
    build_cache(data_path(""), out, sources=["schreiber"], progress=False)
    cache = DatasetCache(out)
    return coordinate_set(cache_clips(cache, range(4)), model, cache.rate, derivatives=True)


@pytest.fixture(scope="module")
def bvh_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bvh")
    for clip in BVH_CLIPS:
        shutil.copy(data_path(f"bandai-namco/dataset-2/{clip}.bvh.gz"), folder)
    return folder


def _finite(record: dict) -> bool:
    return record["mean"] is not None and math.isfinite(record["mean"])


def test_cache_clips_score_in_sanity_ranges(cache_set, model):
    from biomotion.metrics.registry import summarize_set

    records = summarize_set(cache_set, model, physics=True)
    assert {
        "penetration",
        "floating",
        "skate_ratio",
        "jerk",
        "energy_com",
        "energy_body",
        "zmp_in_support",
        "joint_range",
        "entropy",
        "diversity",
    } <= set(records)
    for key in (
        "penetration",
        "penetration_median",
        "floating",
        "floating_median",
        "jerk",
        "energy_com",
        "energy_body",
        "joint_range",
        "entropy",
        "diversity",
    ):
        assert _finite(records[key]), key
        assert records[key]["count"] == (4 if key != "diversity" else 6)  # 4 clips, 6 pairs
    # walking IK at 30 Hz: contact errors of cm, not m; jerk of joint centres tens to hundreds of m/s^3
    assert 0 <= records["penetration"]["mean"] < 10  # cm
    assert 0 < records["penetration_median"]["mean"] < 3  # cm: real data is never perfect on it
    assert 0 <= records["floating"]["mean"] < 20  # cm
    assert 0 <= records["skate_ratio"]["mean"] <= 100  # %
    assert 20 < records["jerk"]["mean"] < 500  # m/s^3
    assert 1 < records["energy_com"]["mean"] < 50  # J, a walker's energy swings by a few J
    assert records["energy_body"]["mean"] >= records["energy_com"]["mean"] * 0.5
    assert 2 < records["entropy"]["mean"] < math.log(50)  # nat, 50 bins
    assert 0 <= records["zmp_in_support"]["mean"] <= 100


def test_identical_pred_and_ref_have_zero_error(cache_set, model):
    from biomotion.evaluation.harness import evaluate

    result = evaluate(cache_set, cache_set, model)
    assert [a for a, b in result["pairs"]] == list(cache_set.names)
    assert all(a == b for a, b in result["pairs"])
    for key, record in result["paired"].items():
        assert record["count"] == 4, key
        assert record["mean"] == pytest.approx(0.0, abs=1e-6), key


def test_different_clips_have_positive_error(cache_set, model):
    from biomotion.evaluation.harness import evaluate
    from biomotion.metrics.clip_set import ClipSet

    shifted = ClipSet(**{**cache_set.__dict__, "names": ("a", "b", "c", "d")})
    reversed_ref = ClipSet(**{**shifted.__dict__, "points": cache_set.points.flip(0), "valid": cache_set.valid.flip(0)})
    paired = evaluate(shifted, reversed_ref, model)["paired"]
    assert paired["fidelity"]["mean"] > 1.0  # cm: different walkers, DTW-aligned
    assert paired["mje"]["mean"] > 10.0  # mm


def test_eval_command_on_bvh_folder(bvh_folder, tmp_path):
    from biomotion.evaluation.harness import eval_command

    result = eval_command(
        bvh_folder,
        bvh_folder,
        data_path(""),
        tmp_path / "eval.json",
        tmp_path / "eval.md",
        plots_dir=tmp_path / "plots",
    )
    stored = json.loads((tmp_path / "eval.json").read_text())
    assert stored["sets"]["pred"]["clips"] == list(BVH_CLIPS)
    metrics = stored["sets"]["pred"]["metrics"]
    assert "joint_range" not in metrics  # no coordinates in a BVH
    for key in ("penetration", "floating", "skate_ratio", "foot_contact_velocity", "jerk", "energy_com", "entropy"):
        assert _finite(metrics[key]), key
    assert 0 <= metrics["floating"]["mean"] < 2  # cm: soles lowered, foot-locked clips
    assert 50 < metrics["jerk"]["mean"] < 300  # m/s^3 (docs/metrics.md: 112 on 10 walks)
    assert 2.5 < metrics["entropy"]["mean"] < 3.9  # nat (docs/metrics.md: 3.20)
    assert all(r["mean"] == pytest.approx(0.0, abs=1e-6) for r in result["paired"].values())
    table = (tmp_path / "eval.md").read_text()
    assert "| Reference | 3 |" in table and "| Generated | 3 |" in table and "Fidelity (DTW) (cm) ↓" in table
    assert (tmp_path / "plots" / "eval_distributions.png").stat().st_size > 10_000


def test_eval_command_on_mot_files(tmp_path):
    from biomotion.evaluation.harness import eval_command

    files = [data_path(f) for f in MOT_FILES]
    result = eval_command(files, None, data_path(""), tmp_path / "e.json", tmp_path / "e.md")
    metrics = result["sets"]["pred"]["metrics"]
    assert result["sets"]["pred"]["kind"] == "coordinates" and "paired" not in result
    assert metrics["jerk"]["count"] == 2 and _finite(metrics["joint_range"])
    assert 0 <= metrics["joint_range"]["mean"] < 30  # % of entries outside the Rajagopal ranges


def test_unpairable_sets_are_refused(cache_set, model):
    from biomotion.errors import BiomotionError
    from biomotion.evaluation.harness import evaluate
    from biomotion.metrics.registry import _take

    with pytest.raises(BiomotionError, match="cannot pair"):
        evaluate(
            _take(cache_set, [0, 1]),
            _take(cache_set, [2]).__class__(**{**_take(cache_set, [2]).__dict__, "names": ("other",)}),
            model,
        )


def test_eval_without_report_files_prints_the_table_and_writes_nothing(tmp_path, capsys, monkeypatch):
    from biomotion.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["eval", "--pred", str(data_path(MOT_FILES[0])), "--data-root", str(data_path(""))]) == 0
    out = capsys.readouterr().out
    assert "| Generated | 1 |" in out and "Jerk (m/s³) ↓" in out and "wrote" not in out
    assert list(tmp_path.iterdir()) == []


def test_markdown_arrow_comes_from_higher_is_better():
    """The header mark of a column is the metric object's direction (`higher_is_better`), through its record."""
    import torch

    from biomotion.evaluation.harness import markdown_table
    from biomotion.metrics.base import ARROWS
    from biomotion.metrics.registry import DIVERSITY, every_metric, record

    for metric in every_metric("bvh"):
        values = torch.tensor([1.0, 2.0])
        rec = record(metric, values)
        table = markdown_table({"Generated": {metric.name: rec}})
        unit = metric.display_unit or metric.unit
        assert f"| {metric.label} ({unit}) {ARROWS[metric.higher_is_better]} |" in table, metric.name
    assert DIVERSITY.arrow == "→"

    from biomotion.metrics.stability import ZMPInsideSupport

    class LowerIsBetter(ZMPInsideSupport):
        higher_is_better = False

    table = markdown_table(
        {
            "a": {"zmp_in_support": record(ZMPInsideSupport(), torch.tensor([0.9]))},
            "b": {"low": record(LowerIsBetter(), torch.tensor([0.9]))},
        }
    )
    assert "ZMP in support (%) ↑" in table and "ZMP in support (%) ↓" in table
