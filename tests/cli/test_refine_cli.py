"""`biomotion refine`: files out for a good motion; one line and exit status 2 for a motion it cannot take."""

from __future__ import annotations

import numpy as np
import pytest

from biomotion.cli import main
from biomotion.io.mot import read_motion, write_motion
from biomotion.motion import Motion
from tests.conftest import data_path


@pytest.fixture(scope="module")
def weights(tmp_path_factory, data_root):
    """An untrained small refiner saved as a weights file (the command's --model)."""
    from biomotion.data.clips import body_model
    from biomotion.models.refiner import Refiner, RefinerConfig

    config = RefinerConfig(d_model=16, heads=2, encoder_layers=1, decoder_layers=1, feedforward=32, window=16)
    path = tmp_path_factory.mktemp("refiner") / "tiny.safetensors"
    Refiner.new(config, body_model(data_root)).save(path)
    return path


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    motion = read_motion(data_path("opencap/Subject4/IK/walking1_ik.mot")).slice(0.0, 1.2)
    path = tmp_path_factory.mktemp("motion") / "walk.mot"
    write_motion(path, motion)
    return path


def test_refine_writes_the_files(weights, walk, data_root, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["refine", str(walk), "--model", str(weights), "--out", str(out), "--data-root", str(data_root)]
    assert main([*argv, "--mass", "62.6", "--no-figures"]) == 0
    assert {p.name for p in out.iterdir()} == {"refined.mot", "grf.mot", "grf_loads.xml", "torques.sto"}
    assert read_motion(out / "refined.mot").names == read_motion(walk).names
    assert "refined 121 frames" in capsys.readouterr().out
    assert main(argv) == 2  # the folder exists now: refused, not overwritten
    assert "not empty" in capsys.readouterr().err


def _one_line_error(argv, capsys) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "\n" not in err
    return err


def test_a_motion_the_refiner_cannot_take_is_one_line_and_exit_2(weights, walk, data_root, tmp_path, capsys):
    common = ["--model", str(weights), "--data-root", str(data_root)]
    motion = read_motion(walk)
    # NaN: refused by the reader, with its line and column
    nan = motion.values.copy()
    nan[5, motion.index("knee_angle_r")] = np.nan
    write_motion(tmp_path / "nan.mot", Motion(times=motion.times, names=motion.names, values=nan))
    err = _one_line_error(["refine", str(tmp_path / "nan.mot"), "--out", str(tmp_path / "a"), *common], capsys)
    assert "nan.mot" in err and "knee_angle_r" in err
    # unknown skeleton: no canonical coordinates
    other = Motion(times=motion.times, names=("joint_a", "joint_b"), values=motion.values[:, :2])
    write_motion(tmp_path / "other.mot", other)
    err = _one_line_error(["refine", str(tmp_path / "other.mot"), "--out", str(tmp_path / "b"), *common], capsys)
    assert "unknown skeleton" in err and "pelvis_tx" in err
    # too short
    write_motion(tmp_path / "short.mot", motion.frames(slice(0, 10)))
    err = _one_line_error(["refine", str(tmp_path / "short.mot"), "--out", str(tmp_path / "c"), *common], capsys)
    assert "too short" in err
    # not a coordinates file, and weights that are not a refiner's
    (tmp_path / "clip.bvh").write_text("HIERARCHY\n")
    assert ".mot/.sto" in _one_line_error(["refine", str(tmp_path / "clip.bvh"), "--out", str(tmp_path / "d")], capsys)
    (tmp_path / "bad.safetensors").write_bytes(b"not weights")
    err = _one_line_error(
        ["refine", str(walk), "--out", str(tmp_path / "e"), "--model", str(tmp_path / "bad.safetensors")], capsys
    )
    assert "bad.safetensors" in err
    for name in "abcde":
        assert not (tmp_path / name).exists()


def test_generate_takes_the_refiner_only_with_refine(tmp_path, capsys):
    weights = tmp_path / "w.safetensors"
    weights.write_bytes(b"x")
    argv = ["generate", "--action", "run", "--out", str(tmp_path / "g"), "--refiner", str(weights)]
    assert "give --refine too" in _one_line_error(argv, capsys)
    assert "not a file" in _one_line_error([*argv[:-1], str(tmp_path / "none"), "--refine"], capsys)
