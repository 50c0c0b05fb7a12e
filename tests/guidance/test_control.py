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


def test_control_with_pgbig_needs_guidance(tmp_path, capsys):
    """(FlexMotion takes --control through its control module: tests/generation/test_flexmotion_control.py.)"""
    from biomotion.cli import main

    args = ["generate", "--action", "run", "--control", str(EXAMPLE), "--no-guidance", "--out", str(tmp_path / "o")]
    assert main(args) == 2
    assert "--control is met through guidance" in capsys.readouterr().err


def test_the_new_examples_load():
    squat = Control.load(REPO / "examples/control/squat_knee_cap.yaml")
    assert {(t.quantity, t.coordinate, t.kind, t.value) for t in squat.targets} == {
        ("joint_torque", "knee_angle_r", "min", -0.5),
        ("joint_torque", "knee_angle_l", "min", -0.5),
    }
    (reach,) = Control.load(REPO / "examples/control/reach_hand_path.yaml").targets
    assert (reach.quantity, reach.body, reach.kind, len(reach.points)) == ("joint_position", "hand_r", "path", 5)
    assert reach.times[0] == 0.3 and reach.points[0] == (0.15, 1.0, 0.24)


@pytest.mark.parametrize(
    "targets, message",
    [
        (
            "- {quantity: joint_position, body: hand_R, kind: path, path: [[0, 0, 1, 0]]}",
            "target 1 (joint_position): unknown body 'hand_R' (closest: hand_r",
        ),
        (
            "- {quantity: joint_position, body: calcaneus_r, kind: path, path: [[0, 0, 1, 0]]}",
            "unknown body 'calcaneus_r' (closest: calcn_r",
        ),
        ("- {quantity: joint_position, kind: path, path: [[0, 0, 1, 0]]}", "unknown body None"),
        (
            "- {quantity: joint_position, body: pelvis, kind: max, value: 1}",
            "kind max does not apply to joint_position; choose path or value",
        ),
        (
            "- {quantity: joint_position, body: pelvis, kind: path, path: [[0, 1, 0]]}",
            "path point 1 must be [t, x, y, z]",
        ),
        (
            "- {quantity: joint_position, body: pelvis, kind: value, value: [0, 1], times: [0.5]}",
            "a joint position's value must be [x, y, z]",
        ),
        (
            "- {quantity: joint_torque, coordinate: pelvis_ty, kind: max, value: 1}",
            "target 1 (joint_torque): pelvis_ty has no joint moment",
        ),
        ("- {quantity: joint_torque, coordinate: knee_angle_r, kind: path, path: []}", "kind path does not apply"),
        (
            "- {quantity: joint_torque, coordinate: knee_angle_r, kind: max, value: 1}\n"
            "- {quantity: joint_torque, coordinate: knee_angle_r, kind: min, value: 2}",
            "target 2 (joint_torque knee_angle_r): its lower bound 2 is above target 1's upper bound 1",
        ),
    ],
)
def test_bad_position_and_torque_targets_are_one_line(tmp_path, targets, message):
    path = write(tmp_path, "targets:\n" + "\n".join("  " + line for line in targets.splitlines()) + "\n")
    with pytest.raises(ConfigError) as error:
        Control.load(path)
    text = str(error.value)
    assert message in text and str(path) in text and "\n" not in text


def test_a_path_outside_the_clip_is_refused(tmp_path):
    control = Control.load(
        write(tmp_path, "targets:\n  - {quantity: joint_position, body: pelvis, kind: path, path: [[2.5, 0, 1, 0]]}\n")
    )
    with pytest.raises(ConfigError, match=r"target 1 \(joint_position pelvis\): time ends at 2.5 s"):
        control.check(2.0)


def test_canonical_bodies_are_the_model_bodies():
    from biomotion.body.canonical import CANONICAL_BODIES
    from biomotion.data.clips import body_model
    from tests.conftest import data_path

    assert body_model(data_path(".")).body_names == CANONICAL_BODIES


def shipped_generator():
    from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, TOKENIZER_FILE, Generator
    from tests.conftest import data_path

    root = data_path(".")
    if not all((CHECKPOINTS / f).exists() for f in (TOKENIZER_FILE, GENERATOR_FILE)):
        pytest.skip("shipped weights absent")
    return Generator.load(root, CHECKPOINTS)


def test_a_path_target_is_zero_on_its_own_path_and_lowers_the_distance_on_a_seeded_run():
    from biomotion.guidance.control import body_origins

    generator = shipped_generator()
    body = generator.body.to(torch.float32)
    action = generator.bundle.vocabulary.parse("static")
    free = generator.generate(action, seconds=1.0, seed=0)
    hand = body_origins(body, free.q.float())[0, :, body.body_index("hand_r")]
    frames = [6, 12, 18, 24, 29]
    own = {"quantity": "joint_position", "body": "hand_r", "kind": "path", "weight": 1e5}
    own["path"] = [[f / generator.rate, *hand[f].tolist()] for f in frames]
    assert Control.from_dict({"targets": [own]}).loss(free.q.float(), None, generator.rate, body=body).item() < 1e-6
    # the same hand path raised and brought forward by 10 cm
    moved = dict(own, path=[[t, x + 0.1, y + 0.1, z] for t, x, y, z in own["path"]])
    target = torch.tensor([p[1:] for p in moved["path"]])
    guided = generator.generate(action, seconds=1.0, seed=0, control=Control.from_dict({"targets": [moved]}))
    after = body_origins(body, guided.q.float())[0, frames, body.body_index("hand_r")]
    before, now = (hand[frames] - target).norm(dim=-1), (after - target).norm(dim=-1)
    assert before.mean() == pytest.approx(math.hypot(0.1, 0.1), abs=1e-4)
    assert now.mean() < 0.5 * before.mean()


def test_joint_torque_loss_uses_the_contact_shared_moments():
    from biomotion.guidance.control import joint_moments

    generator = shipped_generator()
    body = generator.body.to(torch.float32)
    q = generator.generate(generator.bundle.vocabulary.parse("squat"), seconds=1.0, seed=0).q.float()
    knee = joint_moments(body, q, generator.rate)[0, :, 9]
    assert torch.isfinite(knee).all() and knee.min() < -0.1  # an extension moment while squatting
    cap = float(knee.min()) + 0.05
    spec = {"quantity": "joint_torque", "coordinate": "knee_angle_r", "kind": "min", "value": cap, "weight": 1}
    loss = Control.from_dict({"targets": [spec]}).loss(q.requires_grad_(True), None, generator.rate, body=body)
    assert loss.item() > 0
    loss.sum().backward()
    assert torch.isfinite(q.grad).all() and q.grad.abs().sum() > 0


MUSCLES = ("glmed1_r", "glmed2_r", "glmed3_r", "glmed1_l")
ABDUCTORS = REPO / "examples/control/gait_abductor_cap.yaml"


def test_the_abductor_example_loads_and_names_surrogate_muscles():
    control = Control.load(ABDUCTORS)
    assert {(t.quantity, t.muscle, t.kind, t.value, t.window) for t in control.targets} == {
        ("muscle_activation", m, "max", 0.4, None) for m in ("glmed1_r", "glmed2_r", "glmed3_r")
    }
    control.check(2.0)
    control.check_muscles(MUSCLES)
    surrogate = REPO / "checkpoints/surrogate.safetensors"
    if surrogate.exists():
        import json

        from safetensors import safe_open

        with safe_open(str(surrogate), "pt") as f:
            control.check_muscles(json.loads(f.metadata()["muscles"]))


@pytest.mark.parametrize(
    "targets, message",
    [
        ("- {quantity: muscle_activation, kind: max, value: 0.4}", "target 1 (muscle_activation): muscle_activation"),
        (
            "- {quantity: muscle_activation, muscle: glmed1_r, kind: max, value: 40}",
            "target 1 (muscle_activation): an activation lies in 0-1, got 40",
        ),
        (
            "- {quantity: muscle_activation, muscle: glmed1_r, kind: path, value: 0.4}",
            "kind path does not apply to muscle_activation",
        ),
        ("- {quantity: com_height, muscle: glmed1_r, kind: max, value: 1}", "a muscle applies to muscle_activation"),
    ],
)
def test_bad_muscle_targets_are_one_line(tmp_path, targets, message):
    path = write(tmp_path, "targets:\n  " + targets + "\n")
    with pytest.raises(ConfigError) as error:
        Control.load(path)
    text = str(error.value)
    assert message in text and str(path) in text and "\n" not in text


def test_an_unknown_muscle_is_refused_with_the_closest_names(tmp_path):
    path = write(tmp_path, "targets:\n  - {quantity: muscle_activation, muscle: glmed_r, kind: max, value: 0.4}\n")
    control = Control.load(path)  # the name is checked once the surrogate's names are known
    with pytest.raises(ConfigError) as error:
        control.check_muscles(MUSCLES)
    text = str(error.value)
    assert f"{path}: target 1 (muscle_activation glmed_r): unknown muscle 'glmed_r' (closest: glmed" in text
    assert "\n" not in text


def test_muscle_targets_without_a_surrogate_are_refused(tmp_path):
    control = Control.load(ABDUCTORS)
    with pytest.raises(ConfigError) as error:
        control.check_muscles(None)
    assert "target 1 (muscle_activation glmed1_r)" in str(error.value) and "\n" not in str(error.value)
    Control.load(EXAMPLE).check_muscles(None)  # no muscle target: nothing to compute


def test_the_pipeline_refuses_muscle_targets_without_a_surrogate():
    from biomotion.generation.pipeline import Generator

    generator = Generator.__new__(Generator)  # only what generate reads before sampling
    generator.surrogate, generator.rate = None, 30.0
    with pytest.raises(ConfigError, match="no surrogate loaded"):
        Generator.generate(generator, None, seconds=2.0, control=Control.load(ABDUCTORS))


def test_muscle_losses_vanish_inside_bounds_and_grow_outside():
    rate, frames = 30.0, 60
    t = torch.arange(frames) / rate
    q, com = torch.zeros(2, frames, 39), torch.zeros(2, frames, 3)
    activations = torch.full((2, frames, len(MUSCLES)), 0.1)
    activations[:, :, 0] = 0.2 + 0.1 * torch.sin(2 * math.pi * t)  # peak 0.3
    activations[1, :, 0] += 0.3  # clip 2 peaks at 0.6
    cap = Control.from_dict({"targets": [{"quantity": "muscle_activation", "muscle": "glmed1_r", "kind": "max",
                                          "value": 0.4}]})  # fmt: skip
    loss = cap.loss(q, com, rate, activations=activations, muscles=MUSCLES)
    assert loss[0].item() == 0.0 and loss[1].item() > 0.0
    higher = activations.clone()
    higher[1, :, 0] += 0.1
    assert cap.loss(q, com, rate, activations=higher, muscles=MUSCLES)[1] > loss[1]
    floor = Control.from_dict({"targets": [{"quantity": "muscle_activation", "muscle": "glmed2_r", "kind": "min",
                                            "value": 0.05}]})  # fmt: skip
    assert floor.loss(q, com, rate, activations=activations, muscles=MUSCLES).abs().max().item() == 0.0
    value = Control.from_dict({"targets": [{"quantity": "muscle_activation", "muscle": "glmed2_r", "kind": "value",
                                            "times": [1.0], "value": 0.3, "weight": 1}]})  # fmt: skip
    got = value.loss(q, com, rate, activations=activations, muscles=MUSCLES)
    assert got.tolist() == pytest.approx([0.04, 0.04])
    with pytest.raises(ValueError, match="need the activations"):
        cap.loss(q, com, rate)
