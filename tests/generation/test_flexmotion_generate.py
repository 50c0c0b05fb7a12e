"""`biomotion generate --generator flexmotion` end to end with a small untrained FlexMotion (the pipeline, not the
shipped weights' quality): every file, a seeded request is deterministic, bad prompts and profiles are one-line
errors."""

from __future__ import annotations

import json

import pytest
import torch

from biomotion.cli import main
from biomotion.generation.pipeline import CHECKPOINTS, SURROGATE_FILE
from biomotion.io.mot import read_motion, read_storage
from biomotion.models.flexmotion import FlexMotion, FlexMotionConfig
from tests.conftest import data_path

FILES = ("motion.mot", "torques_generated.sto", "grf_generated.mot", "activations_generated.sto", "metrics.json")


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    if not (CHECKPOINTS / SURROGATE_FILE).exists():
        pytest.skip(f"shipped surrogate absent from {CHECKPOINTS}")
    data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")
    folder = tmp_path_factory.mktemp("flexmotion_checkpoints")
    (folder / SURROGATE_FILE).symlink_to((CHECKPOINTS / SURROGATE_FILE).resolve())
    torch.manual_seed(0)
    model = FlexMotion(FlexMotionConfig(width=32, denoiser_width=64, denoiser_blocks=1, sample_steps=3))
    for p in model.denoiser.out.parameters():
        torch.nn.init.normal_(p, std=0.05)
    model.save(folder / "flexmotion.safetensors")
    return folder


def _generate(checkpoints, out, *extra):
    return main(
        ["generate", "--generator", "flexmotion", "--checkpoints", str(checkpoints), "--out", str(out),
         "--data-root", str(data_path(".")), "--seed", "5", *extra]
    )  # fmt: skip


def test_flexmotion_generate_writes_files_and_is_deterministic(checkpoints, tmp_path, capsys):
    for name in ("a", "b"):
        code = _generate(checkpoints, tmp_path / name, "--action", "walk at 1.2 m/s", "--seconds", "1")
        assert code == 0, capsys.readouterr().err
    for name in FILES:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert read_motion(tmp_path / "a" / "motion.mot").n_frames == 30
    assert read_storage(tmp_path / "a" / "grf_generated.mot").data.shape == (30, 6)
    metrics = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert set(metrics["consistency"]) >= {"torque_rel_rmse", "grf_rmse_bw", "activation_rmse_vs_surrogate"}


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (("--action", "   "), "non-empty action text"),
        (("--action", "walk", "--refine"), "takes no --reference, --refine or --smooth"),
        (("--action", "walk", "--profile", "PROFILE"), "height"),
    ],
)
def test_flexmotion_generate_bad_input_is_one_line(checkpoints, tmp_path, capsys, extra, message):
    profile = tmp_path / "p.yaml"
    profile.write_text("height: -1.7\nmass: 70\n")
    extra = tuple(str(profile) if e == "PROFILE" else e for e in extra)
    code = _generate(checkpoints, tmp_path / "out", *extra)
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and "\n" not in err and "Traceback" not in err
