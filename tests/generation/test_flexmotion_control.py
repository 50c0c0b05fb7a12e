"""Controlled FlexMotion generation (FlexMotion Sec. 3.3, `biomotion.generation.flexmotion_control`): the shipped
control module brings a seeded clip's vertical force nearer a target, a pelvis path is met on a seeded clip, and
specs FlexMotion cannot take fail in one line."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.errors import ConfigError
from biomotion.generation.pipeline import CHECKPOINTS
from biomotion.guidance.control import Control, body_origins
from tests.conftest import data_path

NEEDED = ("flexmotion.safetensors", "control_net.safetensors", "surrogate.safetensors")


@pytest.fixture(scope="module")
def flex():
    if not all((CHECKPOINTS / f).exists() for f in NEEDED):
        pytest.skip(f"shipped FlexMotion or control weights absent from {CHECKPOINTS}")
    from biomotion.generation.flexmotion import FlexMotionGenerator
    from biomotion.generation.flexmotion_control import load_control_net

    torch.set_num_threads(1)
    generator = FlexMotionGenerator.load(data_path("."), CHECKPOINTS)
    return generator, load_control_net(CHECKPOINTS, generator.model)


def _pelvis(generator, q: torch.Tensor) -> np.ndarray:
    body = generator.refiner.body
    return body_origins(body, q[None].float())[0, :, body.body_index("pelvis")].numpy()


def test_a_vertical_force_target_moves_the_sample_towards_it(flex):
    """The module itself (no coordinate stage): a dense vertical-GRF target taken from another seed's clip brings
    the sampled clip's vertical force nearer to it than the same seed without the module."""
    from biomotion.models.control_net import CONTROL_DIM, CONTROL_SLICES

    generator, net = flex
    target = generator.sample(["run"], [None], seed=11)["forces"][..., 1].sum(-1)  # [1, W] body weights
    values = torch.zeros(1, target.shape[1], CONTROL_DIM)
    mask = torch.zeros(1, target.shape[1], CONTROL_DIM, dtype=torch.bool)
    values[0, :, CONTROL_SLICES["grf"]] = target[0, :, None]
    mask[0, :, CONTROL_SLICES["grf"]] = True
    free = generator.sample(["run"], [None], seed=0)["forces"][..., 1].sum(-1)
    controlled = generator.sample(["run"], [None], seed=0, control=net.bind(values, mask))["forces"][..., 1].sum(-1)
    before, after = (float((x - target).abs().mean()) for x in (free, controlled))
    assert after < 0.8 * before, (before, after)


def test_a_path_target_is_met_on_a_seeded_clip(flex):
    from biomotion.generation.flexmotion_control import generate_controlled
    from biomotion.models.refiner import to_world

    generator, net = flex
    rate = generator.model.config.rate
    # the target: the pelvis path of another seed's walk, turned and shifted (a path FlexMotion can make, but not
    # the one seed 0 makes)
    other = generator.sample(["walk"], [None], seed=11)["q"].float()
    placed = to_world(other, torch.tensor([[0.6, 1.5, -0.4]]))[0]
    pelvis = _pelvis(generator, placed)
    frames = list(range(0, 46, 3))
    path = [[f / rate, *map(float, pelvis[f])] for f in frames]
    spec = Control.from_dict(
        {"targets": [{"quantity": "joint_position", "body": "pelvis", "kind": "path", "path": path, "weight": 1e5}]}
    )
    out = generate_controlled(generator, net, "walk", None, spec, seed=0, frames=60)

    def error(q):
        return float(np.linalg.norm(_pelvis(generator, q)[frames] - np.asarray([p[1:] for p in path]), axis=-1).mean())

    free, final = error(out.uncontrolled), error(out.decoded["q"][0])
    assert final < 0.02 and final < 0.5 * free, (free, final)
    assert out.decoded["q"].shape == (1, 60, 39) and out.rounds == 1


def test_specs_flexmotion_cannot_take_fail_in_one_line(flex, tmp_path):
    from biomotion.generation.flexmotion_control import check_spec, load_control_net

    generator, _ = flex
    muscles = generator.surrogate.names
    com = Control.from_dict({"targets": [{"quantity": "com_height", "kind": "max", "value": 1.0}]}, "spec.yaml")
    late = Control.from_dict({"targets": [{"quantity": "grf_vertical", "kind": "value", "value": 1.0, "times": [3.0]}]})
    muscle = Control.from_dict({"targets": [{"quantity": "muscle_activation", "muscle": "glmed1_R", "kind": "max",
                                             "value": 0.4}]})  # fmt: skip
    for spec, match in ((com, "no COM channel"), (late, "outside the 2.13333 s clip"), (muscle, "unknown muscle")):
        with pytest.raises(ConfigError, match=match) as caught:
            check_spec(spec, 64 / 30, muscles)
        assert "\n" not in str(caught.value)
    with pytest.raises(ConfigError, match="no FlexMotion control weights") as caught:
        load_control_net(tmp_path, generator.model)
    assert "\n" not in str(caught.value)


def test_generate_routes_a_spec_to_flexmotion_and_reports_bad_ones_in_one_line(flex, tmp_path):
    from biomotion.generation.request import generate

    spec = tmp_path / "com.yaml"
    spec.write_text("targets:\n  - {quantity: com_height, kind: min, value: 0.8}\n")
    with pytest.raises(ConfigError, match="com_height.*use --generator pgbig") as caught:
        generate(action="walk", out=tmp_path / "out", data_root=data_path("."), checkpoints=CHECKPOINTS,
                 generator="flexmotion", control=spec)  # fmt: skip
    assert "\n" not in str(caught.value)
    assert not (tmp_path / "out").exists()
