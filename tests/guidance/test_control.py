"""Control specs (`biomotion.guidance.control`): one-line validation errors, the loss on known clips, and a vertical
GRF cap lowering the peak recomputed from the files `biomotion generate` writes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from biomotion.errors import ConfigError
from biomotion.guidance.control import Control
from tests.conftest import REPO

EXAMPLE = REPO / "examples/control/run_grf_cap.yaml"


def write(tmp_path, text: str):
    path = tmp_path / "spec.yaml"
    path.write_text(text)
    return path


def test_the_example_loads():
    control = Control.load(EXAMPLE)
    (target,) = control.targets
    assert (target.quantity, target.kind, target.value, target.window) == ("grf_vertical", "max", 2.2, (0.0, 2.0))
    control.check(2.0)


@pytest.mark.parametrize(
    "targets, message",
    [
        (
            "- {quantity: joint_angle, coordinate: knee_flex_r, kind: max, value: 60}",
            "target 1 (joint_angle): unknown coordinate 'knee_flex_r'",
        ),
        ("- {quantity: grf_vertical, kind: peak, value: 2}", "target 1 (grf_vertical): unknown kind 'peak'"),
        ("- {quantity: muscle_force, kind: max, value: 2}", "target 1 (muscle_force): unknown quantity"),
        (
            "- {quantity: grf_vertical, kind: max, value: 2, window: [1.0, 0.5]}",
            "window [1, 0.5] s must have 0 <= start < end",
        ),
        (
            "- {quantity: com_height, kind: max, value: 0.9, window: [0, 1]}\n"
            "- {quantity: com_height, kind: min, value: 1.0, window: [0.5, 2]}",
            "target 2 (com_height): its lower bound 1 is above target 1's upper bound 0.9",
        ),
        ("- {quantity: com_height, kind: value, value: 0.9}", "kind value needs a non-empty list 'times'"),
        ("- {quantity: com_height, kind: max, value: high}", "target 1 (com_height): value must be a finite number"),
    ],
)
def test_bad_specs_are_one_line_naming_file_and_target(tmp_path, targets, message):
    path = write(tmp_path, "targets:\n" + "\n".join("  " + line for line in targets.splitlines()) + "\n")
    with pytest.raises(ConfigError) as error:
        Control.load(path)
    text = str(error.value)
    assert message in text and str(path) in text and "\n" not in text


def test_a_window_outside_the_clip_is_refused(tmp_path):
    control = Control.load(
        write(tmp_path, "targets:\n  - {quantity: grf_vertical, kind: max, value: 2, window: [0, 3]}\n")
    )
    with pytest.raises(ConfigError, match=r"target 1 \(grf_vertical\): window ends at 3 s, outside the 2 s clip"):
        control.check(2.0)


def test_losses_vanish_inside_bounds_and_grow_outside():
    rate, frames = 30.0, 60
    t = torch.arange(frames) / rate
    com = torch.zeros(1, frames, 3)
    com[0, :, 1] = 0.9 + 0.05 * torch.sin(2 * math.pi * 2.5 * t)  # peak a_y = 0.05 (5 pi)^2 = 12.3 m/s^2: 2.26 BW
    q = torch.zeros(1, frames, 39)
    loose = Control.from_dict({"targets": [{"quantity": "grf_vertical", "kind": "max", "value": 3.0}]})
    tight = Control.from_dict({"targets": [{"quantity": "grf_vertical", "kind": "max", "value": 1.5}]})
    assert loose.loss(q, com, rate).item() == 0.0
    assert tight.loss(q, com, rate).item() > 0.0
    angle = Control.from_dict(
        {"targets": [{"quantity": "joint_angle", "coordinate": "knee_angle_r", "kind": "value", "times": [1.0],
                      "value": 30, "weight": 1}]}
    )  # fmt: skip
    assert angle.loss(q, com, rate).item() == pytest.approx(math.radians(30) ** 2)


def recomputed_peaks(folder) -> tuple[float, float]:
    """Peak vertical GRF (body weights) from the written files: grf.mot (the contact solve) and m (g + a_COM,y)
    from com_zmp.sto, the mass from its potential energy m g y_COM."""
    from biomotion.io.mot import read_storage

    com = read_storage(folder / "com_zmp.sto")
    column = {name: com.data[:, i] for i, name in enumerate(com.labels)}
    mass = float(np.nanmedian(column["potential_energy"] / (9.81 * column["com_y"])))
    grf = read_storage(folder / "grf.mot")
    vertical = sum(grf.data[:, grf.labels.index(f"ground_force_{s}_vy")] for s in "rl")
    return float(np.nanmax(vertical)) / (mass * 9.81), 1.0 + float(np.nanmax(column["com_acc_y"])) / 9.81


def test_a_grf_cap_lowers_the_recomputed_peak(tmp_path, capsys):
    from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, TOKENIZER_FILE
    from tests.conftest import data_path

    if not all((CHECKPOINTS / f).exists() for f in (TOKENIZER_FILE, GENERATOR_FILE)):
        pytest.skip("shipped weights absent")
    from biomotion.cli import main

    args = ["generate", "--action", "run at 3.5 m/s", "--seconds", "2", "--seed", "0", "--no-figures"]
    args += ["--data-root", str(data_path("."))]
    assert main([*args, "--out", str(tmp_path / "free")]) == 0
    assert main([*args, "--control", str(EXAMPLE), "--out", str(tmp_path / "capped")]) == 0
    free_grf, free_com = recomputed_peaks(tmp_path / "free")
    capped_grf, capped_com = recomputed_peaks(tmp_path / "capped")
    cap = Control.load(EXAMPLE).targets[0].value
    assert free_grf > cap  # the cap binds on this seed
    assert capped_grf < free_grf and capped_com < free_com


@pytest.mark.parametrize("extra", [["--no-guidance"], ["--generator", "flexmotion"]])
def test_control_needs_pgbig_guidance(tmp_path, capsys, extra):
    from biomotion.cli import main

    args = ["generate", "--action", "run", "--control", str(EXAMPLE), *extra, "--out", str(tmp_path / "o")]
    assert main(args) == 2
    assert "--control is met through guidance" in capsys.readouterr().err
