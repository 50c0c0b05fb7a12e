"""`biomotion eval control` (`biomotion.evaluation.control`): target planning, and the whole evaluation on targets of
the held-out subjects (a joint path and a GRF cap; a muscle-activation cap), bounds recomputed by the analysis and
activations by static optimization."""

from __future__ import annotations

import json

import numpy as np
import pytest

from biomotion.evaluation.control import ACTIVATION_MUSCLES, Settings, bars, measurable_bodies, plan, summary
from biomotion.motion import Motion


def clip(names: tuple[str, ...]) -> Motion:
    return Motion(times=np.arange(10) / 30.0, values=np.zeros((10, len(names))), names=names)


def test_plan_takes_paths_of_bodies_the_clip_measures_then_caps():
    from biomotion.body.canonical import CANONICAL_COORDINATES

    legs = clip(tuple(n for n in CANONICAL_COORDINATES if not n.startswith(("arm", "elbow", "pro", "wrist"))))
    full = clip(CANONICAL_COORDINATES)
    assert measurable_bodies(legs) == ["pelvis", "calcn_r"] and measurable_bodies(full)[-1] == "hand_r"
    planned = plan([legs, full], Settings(paths=3, grf_caps=1, torque_caps=1, activation_caps=4))
    assert [p[0] for p in planned] == ["path", "path", "path", "grf", "torque"] + ["activation"] * 4
    assert planned[1] == ("path", 1, "calcn_r") and planned[2] == ("path", 0, "pelvis")
    assert [p[2] for p in planned[5:]] == [*ACTIVATION_MUSCLES, ACTIVATION_MUSCLES[0]]


def test_summary_and_bars():
    records = [
        {"kind": "path", "errors_m": [0.01, 0.03], "uncontrolled_errors_m": [0.2, 0.4]},
        {"kind": "grf", "met": True},
        {"kind": "torque", "met": False},
        {"kind": "activation", "met": True},
        {"kind": "activation", "met": False},
    ]
    figures = summary(records)
    assert figures["control_joint_mean_err_m"] == pytest.approx(0.02)
    assert figures["control_joint_max_err_m"] == pytest.approx(0.03)
    assert figures["control_bounds_met_share"] == 0.5 and figures["control_activation_bounds_met_share"] == 0.5
    assert figures["control_traj_err_share"] == 0.0
    judged = bars(figures)
    assert judged["control_joint_mean_err_m"]["met"] and not judged["control_bounds_met_share"]["met"]
    assert judged["control_fid_ratio"]["met"] is None


def test_eval_control_on_two_held_out_targets(tmp_path):
    from biomotion.evaluation.control import eval_control
    from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, TOKENIZER_FILE
    from tests.conftest import data_path

    root = data_path(".")
    if not all((CHECKPOINTS / f).exists() for f in (TOKENIZER_FILE, GENERATOR_FILE)):
        pytest.skip("shipped weights absent")
    settings = Settings(paths=1, grf_caps=1, torque_caps=0, activation_caps=0, max_seconds=1.0, path_seconds=0.5)
    report = eval_control(root, tmp_path / "c.json", tmp_path / "c.md", settings=settings, fid=False, progress=False)
    assert report["generator"] == "pgbig" and report["targets"] == 2
    path, cap = report["per_target"]
    assert path["kind"] == "path" and cap["kind"] == "grf"
    assert np.mean(path["errors_m"]) < np.mean(path["uncontrolled_errors_m"])
    assert cap["cap"] == pytest.approx(0.9 * cap["uncontrolled_peak"])
    assert cap["controlled_peak"] < cap["uncontrolled_peak"]
    assert json.loads((tmp_path / "c.json").read_text())["control_joint_mean_err_m"] == pytest.approx(
        float(np.mean(path["errors_m"]))
    )
    assert "generator: **pgbig**" in (tmp_path / "c.md").read_text().replace("Generator:", "generator:")


def test_eval_control_both_generators_on_the_same_targets(tmp_path):
    from biomotion.evaluation.control import eval_control
    from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, TOKENIZER_FILE
    from tests.conftest import data_path

    root = data_path(".")
    needed = (TOKENIZER_FILE, GENERATOR_FILE, "flexmotion.safetensors", "control_net.safetensors")
    if not all((CHECKPOINTS / f).exists() for f in needed):
        pytest.skip("shipped weights absent")
    settings = Settings(paths=1, grf_caps=1, torque_caps=0, activation_caps=0, max_seconds=1.0, path_seconds=0.5)
    report = eval_control(
        root, tmp_path / "c.json", tmp_path / "c.md", settings=settings, fid=False, progress=False, generator="both"
    )
    assert report["generator"] == "both" and list(report["columns"]) == ["pgbig", "flexmotion"]
    pgbig, flex = (report["columns"][n]["per_target"] for n in ("pgbig", "flexmotion"))
    assert [(r["kind"], r["clip"], r["seed"]) for r in pgbig] == [(r["kind"], r["clip"], r["seed"]) for r in flex]
    path, cap = flex
    assert np.mean(path["errors_m"]) < 0.02 < np.mean(path["uncontrolled_errors_m"])
    assert len(path["module_errors_m"]) == path["points"]
    assert cap["cap"] == pytest.approx(0.9 * cap["uncontrolled_peak"])
    assert report["control_joint_mean_err_m"] == pytest.approx(float(np.mean(pgbig[0]["errors_m"])))
    text = (tmp_path / "c.md").read_text()
    assert "| PG-BIG guidance | FlexMotion control net |" in text and "Per target, FlexMotion control net" in text


def test_activation_cap_is_measured_by_static_optimization_of_the_generated_kinematics():
    """One activation cap through PG-BIG: the cap is 0.9 x the uncontrolled clip's peak, and both peaks are the
    static-optimization activations `biomotion analyze --muscles rajagopal2016` gives for the returned motions,
    not the generator's surrogate."""
    import torch

    from biomotion.analysis.trial import analyze_trial
    from biomotion.data.clips import build_temporary_cache
    from biomotion.evaluation.control import PGBIGRunner, control_targets
    from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, TOKENIZER_FILE, Generator
    from biomotion.trial import Trial
    from tests.conftest import data_path

    root = data_path(".")
    if not all((CHECKPOINTS / f).exists() for f in (TOKENIZER_FILE, GENERATOR_FILE)):
        pytest.skip("shipped weights absent")
    generator = Generator.load(root, CHECKPOINTS)
    exclude = list(generator.bundle.train_subjects)
    sources = sorted({key.split("/", 1)[0] for key in exclude})
    settings = Settings(paths=0, grf_caps=0, torque_caps=0, activation_caps=1, max_seconds=1.0)
    handle, cache = build_temporary_cache(root, sources=sources, exclude_subjects=exclude)
    with handle:
        records, _, free, controlled = control_targets(PGBIGRunner(generator), cache, settings, progress=False)
    (record,) = records
    muscle = ACTIVATION_MUSCLES[0]
    assert record["kind"] == "activation" and record["muscle"] == muscle
    assert record["cap"] == pytest.approx(0.9 * record["uncontrolled_peak"])
    assert record["met"] == (record["controlled_peak"] <= record["cap"])
    model = generator.body.to(torch.float64)
    for motion, peak in ((free[0], record["uncontrolled_peak"]), (controlled[0], record["controlled_peak"])):
        solution = analyze_trial(Trial(motion=motion), model=model, muscles="rajagopal2016").activations
        expected = float(solution.activations[:, list(solution.muscle_names).index(muscle)].max())
        assert 0.0 < expected <= 1.0 and peak == pytest.approx(expected, abs=1e-9)
    assert not np.allclose(free[0].values, controlled[0].values)  # the cap reached the generator
