"""Generation pipeline end to end on tiny untrained networks (shapes, guidance lowers its loss, files written);
the shipped weights are exercised in test_generate_cli.py."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES, COUPLED_COORDINATES
from biomotion.body.kinematics import apply_couplers
from biomotion.body.model import BodyModel
from biomotion.generation.outputs import write_generation
from biomotion.generation.pipeline import Generator
from biomotion.guidance.planting import leg_columns
from biomotion.guidance.refine import GuidanceConfig
from biomotion.io.mot import read_motion
from biomotion.models.actions import ActionRequest, ActionVocabulary
from biomotion.models.bundle import ALL_ACTIONS, GeneratorBundle, GuidanceBounds
from biomotion.models.conditioning import action_size
from biomotion.models.prior import PriorConfig, ProfileActionPrior
from biomotion.models.vqvae import MotionVQVAE, VQVAEConfig
from biomotion.motion import lowpass
from biomotion.muscles.surrogate import MuscleSurrogate, SurrogateConfig
from biomotion.profile import InjuryRecord, Profile
from tests.conftest import data_path

LABELS = [
    {"action": "run", "style": None, "speed": 3.5, "text": "run on a treadmill at 3.5 m/s"},
    {"action": "squat", "style": "normal", "speed": None, "text": "squat"},
]


@pytest.fixture(scope="module")
def generator():
    torch.manual_seed(0)
    body = BodyModel.from_osim(data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim"))
    tokenizer = MotionVQVAE(VQVAEConfig(width=16, code_dim=8, codebook_size=16, depth=1))
    tokenizer.quantiser.initialise(torch.randn(64, 8))
    tokenizer.mean[4] = 0.95  # decoded pelvis height around standing height
    tokenizer.std.fill_(0.05)
    tokenizer.eval()
    vocabulary = ActionVocabulary.from_labels(LABELS)
    prior = ProfileActionPrior(
        PriorConfig(
            codebook_size=16, code_dim=8, action_size=action_size(vocabulary), width=16, layers=1, heads=2, max_tokens=8
        )
    ).eval()
    bounds = {ALL_ACTIONS: GuidanceBounds(tuple([1.0] * 39), (0.5, 4.0), (1.0, 20.0), 1000, tuple([100.0] * 39))}
    surrogate = MuscleSurrogate(["a", "b"], SurrogateConfig(width=8, depth=1)).eval()
    surrogate.high.fill_(0.3)
    return Generator(tokenizer, GeneratorBundle(prior, vocabulary, bounds), body, surrogate)


def test_generate_shapes_and_guidance_lowers_its_loss(generator):
    request = ActionRequest("run", None, 3.5, "run")
    profile = Profile(age=52, sex="M", height=1.76, mass=74.0, injuries=(InjuryRecord("Left knee", "ACL"),))
    config = GuidanceConfig(iterations=12, ramp=1, quantize_at=None, lr=0.05)
    out = generator.generate(request, profile=profile, seconds=1.0, samples=2, seed=3, guidance_config=config)
    assert out.q.shape == out.unguided.shape == (2, 30, 39)
    # physics weights are on from the first iteration (ramp 1): the objective must fall over 12 Adam steps
    assert out.history[-1]["loss"] < out.history[0]["loss"]
    assert out.history[-1]["guidance"] < out.history[0]["guidance"]
    assert not torch.allclose(out.q, out.unguided)
    # foot planting, the last stage, moves the legs only (the knee's coupled _beta follows the knee angle)
    assert out.unplanted.shape == out.q.shape
    legs = leg_columns(CANONICAL_COORDINATES)
    others = [i for i, name in enumerate(CANONICAL_COORDINATES) if i not in legs and name not in COUPLED_COORDINATES]
    torch.testing.assert_close(out.q[..., others], out.unplanted[..., others], rtol=0, atol=0)
    again = generator.generate(request, profile=profile, seconds=1.0, samples=2, seed=3, guidance=False)
    torch.testing.assert_close(again.unguided, out.unguided)  # same seed, same sample
    # every output, planted or not, holds the model's coupler constraints (knee _beta from the knee angle)
    for q in (out.q, out.unplanted, out.unguided):
        torch.testing.assert_close(q, apply_couplers(generator.body, q), rtol=0, atol=0)


def test_the_zmp_term_is_off_by_default_and_when_on_pulls_the_zmp_towards_the_support(generator):
    request = ActionRequest("squat", "normal", None, "squat")
    off = generator.generate(request, seconds=1.0, seed=5, guidance_config=GuidanceConfig(iterations=3, ramp=1))
    assert "zmp" not in off.history[0]
    config = GuidanceConfig(iterations=12, ramp=1, quantize_at=None, lr=0.05, w_zmp=300.0)
    out = generator.generate(request, seconds=1.0, seed=5, guidance_config=config)
    first, last = out.history[0]["zmp"], out.history[-1]["zmp"]
    assert math.isfinite(first) and math.isfinite(last) and torch.isfinite(out.q).all()
    assert first > 0 and last < first


def test_smoothing_low_passes_the_guided_coordinates_before_planting(generator):
    request = ActionRequest("squat", "normal", None, "squat")
    config = GuidanceConfig(iterations=3, ramp=1, planting=None)
    plain = generator.generate(request, seconds=2.0, seed=7, guidance_config=config)
    smooth = generator.generate(
        request, seconds=2.0, seed=7, guidance_config=dataclasses.replace(config, smooth_hz=4.0)
    )
    expected = torch.as_tensor(lowpass(plain.q.numpy(), 30.0, 4.0, axis=1).copy(), dtype=plain.q.dtype)
    ranges = generator.body.ranges.to(plain.q.dtype)
    inside = (expected >= ranges[:, 0]) & (expected <= ranges[:, 1])
    inside[..., [i for i, n in enumerate(CANONICAL_COORDINATES) if n.startswith("pelvis_t")]] = True
    inside[..., [CANONICAL_COORDINATES.index(n) for n in COUPLED_COORDINATES]] = False
    # where the filter stays in range the output is the zero-lag Butterworth of the guided motion (float32), and
    # the coupled knee _beta follows the filtered knee angle
    torch.testing.assert_close(smooth.q, apply_couplers(generator.body, smooth.q), rtol=0, atol=0)
    torch.testing.assert_close(smooth.q[inside], expected[inside], rtol=0, atol=1e-5)
    rotations = [i for i, n in enumerate(CANONICAL_COORDINATES) if not n.startswith("pelvis_t")]
    q = smooth.q[..., rotations]
    assert (q >= ranges[rotations, 0]).all() and (q <= ranges[rotations, 1]).all()
    roughness = lambda x: torch.diff(x, 2, dim=1).abs().mean()  # noqa: E731
    assert roughness(smooth.q) < 0.5 * roughness(plain.q)


def test_requantized_output_decodes_codebook_entries(generator):
    request = ActionRequest("squat", "normal", None, "squat")
    config = GuidanceConfig(iterations=4, ramp=1, quantize_at=2)
    out = generator.generate(request, seconds=0.5, samples=1, guidance_config=config)
    assert out.q.shape == (1, 15, 39) and torch.isfinite(out.q).all()


def test_write_generation_files_open_and_agree(generator, tmp_path):
    request = ActionRequest("run", None, 3.5, "run")
    profile = Profile(height=1.90, mass=90.0)
    out = generator.generate(request, profile=profile, seconds=1.0, samples=1, guidance=False)
    generic = data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")
    files = write_generation(tmp_path, out, generator, profile, generic, figures=False)[tmp_path.name]
    for role in ("motion", "bvh", "grf_inferred", "torques", "com_zmp", "activations", "metrics", "model"):
        assert files[role].exists(), role
    motion = read_motion(files["motion"])
    # pelvis translations are the canonical ones scaled to the person's 1.90 m (generic 1.70 m)
    ty = motion["pelvis_ty"]
    np.testing.assert_allclose(ty, out.q[0, :, 4].double().numpy() * 1.90 / 1.70, atol=2e-5)
    scaled = BodyModel.from_osim(files["model"])
    assert float(scaled.total_mass) == pytest.approx(90.0, rel=1e-6)
    metrics = json.loads(files["metrics"].read_text())
    assert {"penetration", "floating", "jerk", "zmp_in_support"} <= set(metrics["physics"])
    assert metrics["request"]["action"]["action"] == "run"


def test_reference_clips_of_flexion_negative_models_are_flipped(generator):
    from biomotion.body.canonical import CANONICAL_COORDINATES
    from biomotion.errors import BiomotionWarning
    from biomotion.generation.pipeline import reference_motion
    from biomotion.motion import Motion

    t = np.arange(60) / 30.0
    values = np.zeros((60, len(CANONICAL_COORDINATES)))
    knee = CANONICAL_COORDINATES.index("knee_angle_r")
    values[:, knee] = 0.5 + 0.4 * np.sin(2 * np.pi * t)  # flexion positive, canonical
    canonical = Motion(times=t, values=values, names=CANONICAL_COORDINATES)
    flipped = canonical.with_values(np.where(np.arange(values.shape[1]) == knee, -values, values))
    q_canonical, _ = reference_motion(canonical, generator.body, None)
    with pytest.warns(BiomotionWarning, match="flexion-negative"):
        q_flipped, _ = reference_motion(flipped, generator.body, None)
    torch.testing.assert_close(q_flipped[:, knee], q_canonical[:, knee])


def test_reference_clips_centre_the_sample_on_the_persons_posture(generator):
    from biomotion.motion import Motion

    knee = CANONICAL_COORDINATES.index("knee_angle_r")
    population = np.full(39, np.nan)
    population[knee] = 0.6
    with_posture = GuidanceBounds(
        tuple([1.0] * 39), (0.5, 4.0), (1.0, 20.0), 1000, tuple([100.0] * 39), tuple(population), tuple([0.0] * 39), 3.5
    )
    bounds = {ALL_ACTIONS: with_posture, "run": with_posture}
    bundle = GeneratorBundle(generator.bundle.prior, generator.bundle.vocabulary, bounds)
    personal = Generator(generator.tokenizer, bundle, generator.body, generator.surrogate)
    t = np.arange(60) / 30.0
    values = np.zeros((60, 39))
    values[:, knee] = 0.75 + 0.2 * np.sin(2 * np.pi * t)  # the person runs 0.15 rad more bent than everyone
    reference = Motion(times=t, values=values, names=CANONICAL_COORDINATES)
    request = ActionRequest("run", None, 3.5, "run")
    common = {
        "references": [reference],
        "reference_actions": ["run"],
        "reference_speeds": [3.5],
        "seconds": 1.0,
        "seed": 3,
        "guidance": False,
    }
    out = personal.generate(request, **common)
    assert float(out.unguided[0, :, knee].mean()) == pytest.approx(0.75, abs=1e-4)
    assert float(out.posture[knee]) == pytest.approx(0.15, abs=1e-6)
    plain = personal.generate(request, **common, posture=False)
    assert plain.posture is None
    assert abs(float(plain.unguided[0, :, knee].mean()) - 0.75) > 1e-2
