"""`biomotion generate` with the shipped weights on real models: every output, and clear errors on bad input."""

from __future__ import annotations

import json

import pytest
import torch

from biomotion.cli import main
from biomotion.generation.pipeline import (
    CHECKPOINTS,
    GENERATOR_FILE,
    SURROGATE_FILE,
    TOKENIZER_FILE,
)
from biomotion.io.mot import read_motion, read_storage
from tests.conftest import REPO, data_path

OUTPUTS = (
    "motion.mot",
    "model.osim",
    "motion.bvh",
    "grf.mot",
    "grf_loads.xml",
    "torques.sto",
    "activations.sto",
    "com_zmp.sto",
    "metrics.json",
    "viewer.html",
    "joint_angles.png",
    "grf.png",
    "balance.png",
    "activations.png",
)


@pytest.fixture(scope="module")
def shipped():
    missing = [f for f in (TOKENIZER_FILE, GENERATOR_FILE, SURROGATE_FILE) if not (CHECKPOINTS / f).exists()]
    if missing:
        pytest.skip(f"shipped weights absent: {missing} not in {CHECKPOINTS}")
    data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")


def test_generate_writes_every_output(shipped, tmp_path, capsys):
    out = tmp_path / "runner"
    code = main(
        [
            "generate",
            "--profile",
            str(REPO / "examples/runner_52_acl.yaml"),
            "--action",
            "running at 3.5 m/s",
            "--seconds",
            "1.5",
            "--out",
            str(out),
            "--data-root",
            str(data_path(".")),
        ]
    )
    assert code == 0, capsys.readouterr().err
    for name in OUTPUTS:
        assert (out / name).exists(), name
    motion = read_motion(out / "motion.mot")
    assert motion.n_frames == 45 and motion.rate == pytest.approx(30.0)
    assert read_storage(out / "activations.sto").data.shape[0] == 45
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["request"]["action"] == {
        "action": "run",
        "style": None,
        "speed": 3.5,
        "text": metrics["request"]["action"]["text"],
    }
    assert metrics["request"]["bundle"] == "lab" and metrics["request"]["biodata_used"] is True
    # the weighted physics terms (Table 1 + ground) fall from the sample to the guided clip
    assert metrics["guidance_last_iteration"]["guidance"] < metrics["guidance_first_iteration"]["guidance"]
    assert 0.8 <= metrics["tempo"] <= 1.25  # played faster or slower to reach 3.5 m/s (biomotion.guidance.tempo)
    planting = metrics["foot_planting"]
    assert 0 < planting["mean_change_deg"] <= planting["max_change_deg"] < 45
    assert 0 < planting["frames_changed_over_1deg"] <= 1
    printed = capsys.readouterr().out
    assert "generated 1 x 1.5 s of 'run'" in printed and "at 3.5 m/s" in printed
    # "running" is no label's exact name: the user is told what it was taken as, on the console and in the file
    assert len(metrics["request"]["notes"]) == 1 and "taken as 'run on a treadmill'" in metrics["request"]["notes"][0]
    assert f"note: {metrics['request']['notes'][0]}" in printed
    # what made the clip: the inputs, every field of the profile used, the text and the seed, the versions
    request = metrics["request"]
    assert request["inputs"]["profile"].endswith("runner_52_acl.yaml") and request["inputs"]["subject_table"] is None
    assert request["text"] == "running at 3.5 m/s" and request["seed"] == 0
    profile = request["profile"]
    assert (profile["age"], profile["sex"], profile["height"], profile["mass"]) == (52, "M", 1.76, 74.0)
    assert (profile["sport"], profile["level"], profile["experience_years"]) == ("running", "recreational", 15)
    assert profile["injuries"] == [{"location": "Left knee", "diagnosis": "ACL reconstruction", "date": "2015"}]
    assert set(request["versions"]) >= {"biomotion", "torch", "python"} and all(request["versions"].values())


def test_the_same_seed_writes_the_same_motion(shipped, tmp_path, capsys):
    """Two runs of the same request and seed write byte-identical motion.mot."""
    written = []
    for name in ("a", "b"):
        args = ["generate", "--action", "walk", "--seconds", "0.5", "--seed", "7", "--no-figures"]
        assert main([*args, "--out", str(tmp_path / name), "--data-root", str(data_path("."))]) == 0
        written.append((tmp_path / name / "motion.mot").read_bytes())
    assert written[0] == written[1]


@pytest.mark.parametrize(
    "args, message",
    [
        (["--profile", "no_such_profile.yaml"], "no_such_profile.yaml: --profile is not a file"),
        (["--subject-table", "x.csv"], "--subject-table and --subject-id go together"),
        (["--threads", "0"], "argument --threads: 0: must be at least 1"),
        (
            ["--reference", "a.mot", "--reference-action", "run", "--reference-action", "walk"],
            "--reference-action given 2 times for 1 --reference clips",
        ),
        (["--seconds", "0.1"], "argument --seconds: 0.1: must be at least 0.5"),
        (["--smooth", "20"], "--smooth 20 Hz: the cutoff must lie between 0 and 15 Hz"),
        (["--smooth", "6", "--no-guidance"], "--smooth filters the guided motion: it has no effect with --no-guidance"),
    ],
)
def test_generate_bad_input_is_one_clear_line(shipped, tmp_path, capsys, args, message):
    code = main(
        ["generate", *args, "--action", "run", "--out", str(tmp_path / "o"), "--data-root", str(data_path("."))]
    )
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # nothing half-written


def test_a_profile_field_that_is_not_a_number_is_named(shipped, tmp_path, capsys):
    profile = tmp_path / "person.yaml"
    profile.write_text("age: fifty\nmass: 70\n")
    code = main(
        [
            "generate",
            "--profile",
            str(profile),
            "--action",
            "run",
            "--out",
            str(tmp_path / "o"),
            "--data-root",
            str(data_path(".")),
        ]
    )
    assert code == 2
    assert (
        "person.yaml: invalid profile: age must be a number (SI units: m, kg, years), got 'fifty'"
        in capsys.readouterr().err
    )
    assert not (tmp_path / "o").exists()


def test_a_reference_clip_centres_the_motion_on_the_persons_posture(shipped, tmp_path, capsys):
    reference = data_path("fukuchi-running/ik/T25/RBDS001_T25_ik_simple.mot")
    out = tmp_path / "rbds001"
    code = main(
        [
            "generate",
            "--subject-table",
            str(data_path("fukuchi-running/participantInfo.csv")),
            "--subject-id",
            "RBDS001",
            "--reference",
            str(reference),
            "--reference-action",
            "run at 2.5 m/s",
            "--action",
            "run at 4.5 m/s",
            "--seconds",
            "1.5",
            "--no-figures",
            "--out",
            str(out),
            "--data-root",
            str(data_path(".")),
        ]
    )
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    offset = metrics["posture_offset"]  # degrees: the Fukuchi model has legs and pelvis, no trunk or arms
    assert {"pelvis_tilt", "knee_angle_r", "hip_flexion_l"} <= set(offset)
    assert not {"pelvis_rotation", "pelvis_tx", "pelvis_ty", "pelvis_tz", "lumbar_extension"} & set(offset)
    assert all(abs(v) < 30 for v in offset.values())
    assert metrics["request"]["reference_actions"] == ["run at 2.5 m/s"]


def test_tempo_brings_the_sample_to_the_asked_speed_before_any_guidance_step(shipped):
    """With zero guidance iterations and no planting, the guided clip is the sample played at its tempo: its speed
    error is the unguided sample's cut down (to zero unless the tempo hit a bound of its range)."""
    from biomotion.generation.pipeline import Generator
    from biomotion.guidance.refine import GuidanceConfig
    from biomotion.guidance.tempo import WARP_RANGE
    from biomotion.models.foot_contact import mean_horizontal_speed

    generator = Generator.load(data_path("."), CHECKPOINTS)
    action = generator.bundle.vocabulary.parse("run at 3.5 m/s")
    out = generator.generate(
        action, seconds=2.0, samples=4, seed=5, guidance_config=GuidanceConfig(iterations=0, planting=None)
    )
    target = 3.5  # no profile: the canonical size, the request's speed as it is
    before = (mean_horizontal_speed(out.unguided, generator.rate) - target).abs()
    after = (mean_horizontal_speed(out.q, generator.rate) - target).abs()
    bounded = (out.tempo <= WARP_RANGE[0] + 1e-6) | (out.tempo >= WARP_RANGE[1] - 1e-6)
    assert (after[~bounded] < 0.1 * before[~bounded] + 0.05).all(), (before, after, out.tempo)
    assert (after[bounded] < before[bounded]).all(), (before, after, out.tempo)
    assert not torch.equal(out.q, out.unguided)
