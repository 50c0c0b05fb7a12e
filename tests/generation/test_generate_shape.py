"""`biomotion generate --shape` / `bm.generate(shape=...)`: PG-BIG clips moved onto a body by the HUMOS shape adapter.

Truth: the body's segment lengths are the shape file's (ANSUR II segment lines, `Shape.from_measures`), whose
femur/tibia ratio is not the canonical model's, which uniform scaling keeps; the shipped adapter predicts a longer
stride for a taller, heavier body (docs/results/eval_shape.md), and the generated run keeps its pelvis speed, so the
same seed gives a longer stride on a tall body than on a short one."""

from __future__ import annotations

import hashlib
import json

import pytest
import torch

import biomotion as bm
from biomotion.body.model import BodyModel
from biomotion.body.shape import segment_lengths
from biomotion.cli import main
from biomotion.data.clips import MODEL_FILE
from biomotion.evaluation.shape import gait_timing
from biomotion.generation.adapt import ADAPTER_FILE, read_body
from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, SURROGATE_FILE, TOKENIZER_FILE
from biomotion.generation.request import shape_notes
from biomotion.io.mot import read_motion, read_storage
from biomotion.profile import Profile
from tests.conftest import REPO, data_path

torch.set_num_threads(1)

SPEED = 3.5  # m/s, the asked run
ARGS = ["--action", f"run at {SPEED} m/s", "--seconds", "3", "--seed", "3", "--no-figures", "--threads", "1"]


@pytest.fixture(scope="module")
def shipped():
    needed = (TOKENIZER_FILE, GENERATOR_FILE, SURROGATE_FILE, ADAPTER_FILE)
    missing = [f for f in needed if not (CHECKPOINTS / f).exists()]
    if missing:
        pytest.skip(f"shipped weights absent: {missing} not in {CHECKPOINTS}")
    return data_path(".")


def _shape(folder, name: str, height: float, mass: float, sex: str):
    path = folder / f"{name}.yaml"
    path.write_text(f"height: {height}\nmass: {mass}\nsex: {sex}\n")
    return path


def _ratio(lengths: dict) -> float:
    return lengths["femur_r"] / lengths["tibia_r"]


def test_generate_on_a_tall_and_a_short_body(shipped, tmp_path, capsys):
    """Tall through the CLI (a shape file), short through Python (a Body): each model.osim has its Shape's
    segment lengths, not the canonical proportions; the tall body's stride is longer; the files are on that model."""
    tall = _shape(tmp_path, "tall", 1.95, 100.0, "male")
    out = tmp_path / "tall_out"
    code = main(
        [
            "generate",
            "--profile",
            str(REPO / "examples/runner_52_acl.yaml"),
            *ARGS,
            "--shape",
            str(tall),
            "--out",
            str(out),
            "--data-root",
            str(shipped),
        ]
    )
    printed = capsys.readouterr()
    assert code == 0, printed.err
    # the profile says 1.76 m, 74 kg: the body wins, and the user is told so once
    assert "note: --shape" in printed.out and "tall.yaml sets the body" in printed.out
    body = read_body(tall, data_root=shipped)
    model = BodyModel.from_osim(out / "model.osim")
    lengths = segment_lengths(model)
    for name in ("femur_r", "tibia_r", "pelvis", "torso"):
        assert lengths[name] == pytest.approx(body.shape.lengths[name], rel=1e-3), name
    canonical = segment_lengths(BodyModel.from_osim(shipped / MODEL_FILE))
    assert abs(_ratio(lengths) / _ratio(canonical) - 1.0) > 0.01  # not the canonical model scaled uniformly
    motion = read_motion(out / "motion.mot")
    assert motion.names == model.coordinate_names
    assert read_storage(out / "activations.sto").data.shape[0] == motion.n_frames
    assert motion.n_frames == round(3.0 * motion.rate)  # the asked length, though the adapter re-times the clip
    assert read_storage(out / "torques.sto").data.shape[0] == motion.n_frames
    metrics = json.loads((out / "metrics.json").read_text())
    record = metrics["shape"]
    assert record["input"] == str(tall) and metrics["request"]["shape"] == str(tall)
    assert record["shape"]["height"] == pytest.approx(1.95) and record["shape"]["mass"] == pytest.approx(100.0)
    assert record["adapter"]["sha256"] == hashlib.sha256((CHECKPOINTS / ADAPTER_FILE).read_bytes()).hexdigest()
    assert record["stride_time_s"]["adapted"] > record["stride_time_s"]["source"]
    assert any("sets the body" in note for note in metrics["request"]["notes"])

    short = read_body(_shape(tmp_path, "short", 1.55, 50.0, "female"), data_root=shipped)
    result = bm.generate(
        action=f"run at {SPEED} m/s",
        out=tmp_path / "short_out",
        data_root=shipped,
        profile_file=REPO / "examples/runner_52_acl.yaml",  # the same generated clip as the tall one's
        seconds=3.0,
        seed=3,
        figures=False,
        threads=1,
        shape=short,
    )
    assert any("(height 1.76 m against the body's 1.55" in n for n in result["notes"])
    short_model = BodyModel.from_osim(tmp_path / "short_out" / "model.osim")
    short_motion = read_motion(tmp_path / "short_out" / "motion.mot")
    assert short_motion.n_frames == round(3.0 * short_motion.rate)
    assert segment_lengths(short_model)["tibia_r"] == pytest.approx(short.shape.lengths["tibia_r"], rel=1e-3)
    tall_stride = gait_timing(model, motion, SPEED)["stride_length_m"]
    short_stride = gait_timing(short_model, short_motion, SPEED)["stride_length_m"]
    assert tall_stride > 1.1 * short_stride


def test_a_body_that_agrees_with_the_profile_needs_no_note(shipped):
    body = read_body(shipped / MODEL_FILE, data_root=shipped)  # 1.70 m, 75.3 kg
    assert shape_notes(Profile(height=1.70, mass=75.3), body, "x.osim") == []
    assert shape_notes(Profile(), body, "x.osim") == []
    (note,) = shape_notes(Profile(height=1.80), body, "x.osim")
    assert (
        note.startswith("--shape x.osim sets the body, not the profile")
        and "height 1.8 m" in note
        and "mass" not in note
    )


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--shape", "no_such_body.yaml"], "no_such_body.yaml: --shape is not a file"),
        (["--shape", "{bad}"], "bad.yaml: unknown keys ['waist']"),
        (["--shape", "{txt}"], "body.txt: --shape must be a scaled OpenSim model (.osim) or a shape file"),
        (["--shape", "{tall}", "--generator", "flexmotion"], "--generator flexmotion takes no --shape"),
        (["--shape", "{tall}", "--seconds", "2"], "--seconds 2: --shape moves a gait onto the body"),
        (["--shape-height", "1.8"], "--shape-height and --adapter go with --shape"),
    ],
)
def test_bad_shape_input_is_one_clear_line(shipped, tmp_path, capsys, extra, message):
    files = {
        "bad": tmp_path / "bad.yaml",
        "txt": tmp_path / "body.txt",
        "tall": _shape(tmp_path, "tall", 1.95, 100.0, "male"),
    }
    files["bad"].write_text("height: 1.8\nwaist: 0.9\n")
    files["txt"].write_text("height: 1.8\n")
    extra = [a.format(**{k: str(v) for k, v in files.items()}) for a in extra]
    code = main(["generate", "--action", "run", *extra, "--out", str(tmp_path / "o"), "--data-root", str(shipped)])
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()  # nothing half-written
