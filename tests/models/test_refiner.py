"""The PhysPT refiner: window frame, shapes and units of its outputs, the contact model, persistence, the noise it is
trained on, the consistency of its physics losses, and (with the shipped weights) that it smooths a real clip."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES, COUPLED_COORDINATES
from biomotion.data.noise import NoiseLevels, corrupt
from biomotion.errors import ModelError
from biomotion.models.refiner import (
    EDGES,
    PhysPT,
    Refiner,
    RefinerConfig,
    refinement_scores,
    to_local,
    to_world,
    window_frame,
)

TINY = RefinerConfig(d_model=16, heads=2, encoder_layers=1, decoder_layers=1, feedforward=32, window=16)


@pytest.fixture(scope="module")
def body(data_root):
    from biomotion.data.clips import body_model

    return body_model(data_root)


@pytest.fixture(scope="module")
def walk(data_root):
    """A real clip on the canonical skeleton at 30 Hz, placed on the floor: OpenCap Subject4 walking1 (a source
    training leaves out), 2 s."""
    from biomotion.data.placement import place_clip
    from biomotion.data.sources import to_canonical
    from biomotion.io.mot import read_motion
    from tests.conftest import data_path

    motion = read_motion(data_path("opencap/Subject4/IK/walking1_ik.mot"))
    from biomotion.data.clips import body_model

    clip = place_clip(to_canonical(motion).resample(30.0), body_model(data_root), height=1.68, treadmill_speed=None)
    clip = clip.frames(slice(0, 60))
    return torch.from_numpy(np.where(clip.mask[None], clip.values, 0.0)).float(), torch.from_numpy(clip.mask.copy())


def test_window_frame_round_trip():
    q = torch.randn(3, 20, 39)
    q[..., 2] += 2.5  # a heading far from 0
    valid = torch.ones(3, 20, dtype=torch.bool)
    frame = window_frame(q, valid)
    local = to_local(q, frame)
    assert torch.allclose(to_world(local, frame), q, atol=1e-5)
    assert torch.allclose(local[..., [2, 3, 5]].mean(1), torch.zeros(3, 3), atol=1e-5)  # heading and path centred
    # horizontal distances are kept (a turn about the vertical)
    step = lambda x: (x[:, 1:, [3, 5]] - x[:, :-1, [3, 5]]).norm(dim=-1)  # noqa: E731
    assert torch.allclose(step(local), step(q), atol=1e-5)


def test_untrained_refiner_returns_its_input_with_forces_of_the_right_shape(body, walk):
    """The motion head starts at zero: a new refiner changes nothing, so clean input stays clean before training.
    Outputs: coordinates [T, 39] (rad, m), generalized forces [T, 39] (N·m, N), point forces [T, K, 3] (N) inside
    the friction cone and gated, positions [T, K, 3] (m)."""
    q, mask = walk
    refiner = Refiner.new(TINY, body)
    out = refiner.refine(q, mask)  # 60 frames: windows of 16 every 8, overlap-added
    n, k = len(q), len(refiner.feet.names)
    assert out.q.shape == (n, 39) and out.torques.shape == (n, 39)
    assert out.point_forces.shape == (n, k, 3) and out.point_positions.shape == (n, k, 3) and out.gate.shape == (n, k)
    assert torch.allclose(out.q, q, atol=1e-5)
    fy = out.point_forces[..., 1]
    horizontal = out.point_forces[..., [0, 2]].abs()
    assert bool((fy >= 0).all()) and bool((horizontal <= 0.8 * fy[..., None] + 1e-3).all())
    assert bool(((out.gate > 0) & (out.gate < 1)).all())
    # the feet of a placed walk are on the floor y = 0 (cm-level), in metres
    assert -0.05 < float(out.point_positions[..., 1].min()) < 0.05
    # a clip shorter than a window is one window of its own length
    assert refiner.refine(q[:10], mask).q.shape == (10, 39)


def test_save_and_load_keep_weights_config_and_metadata(body, tmp_path):
    refiner = Refiner.new(TINY, body)
    torch.nn.init.normal_(refiner.net.motion_head.weight, std=0.01)
    refiner.metadata = {"train_subjects": ["a/1"], "lowpass_cutoff_hz": 5.0}
    path = tmp_path / "refiner.safetensors"
    refiner.save(path)
    loaded = Refiner.load(path, body)
    assert loaded.config == TINY and loaded.metadata == refiner.metadata
    q, mask = torch.randn(1, 16, 39) * 0.1, torch.ones(1, 39, dtype=torch.bool)
    valid = torch.ones(1, 16, dtype=torch.bool)
    assert torch.equal(loaded.net(q, mask, valid).q, refiner.net.eval()(q, mask, valid).q)
    other = tmp_path / "other.safetensors"
    from safetensors.torch import save_file

    save_file({"x": torch.zeros(1)}, str(other), metadata={"format": "something-else"})
    with pytest.raises(ModelError, match="not refiner weights"):
        Refiner.load(other, body)
    with pytest.raises(ModelError, match="no refiner weights"):
        Refiner.load(tmp_path / "missing.safetensors", body)


def test_network_shapes_without_body():
    net = PhysPT(TINY, n_points=10)
    q = torch.randn(2, 16, 39)
    mask = torch.ones(2, 39, dtype=torch.bool)
    valid = torch.ones(2, 16, dtype=torch.bool)
    valid[1, 12:] = False  # a padded window
    out = net(q, mask, valid)
    assert out.q.shape == (2, 16, 39) and out.torques.shape == (2, 16, 39) and out.edges.shape == (2, 16, 10, EDGES)
    assert bool((out.edges >= 0).all()) and bool(torch.isfinite(out.q).all())


def test_noise_is_seeded_and_spares_absent_and_coupled_coordinates():
    q = torch.zeros(4, 50, 39)
    mask = torch.ones(4, 39, dtype=torch.bool)
    mask[:, 25:] = False  # no arms
    every = NoiseLevels(probability=1.0)
    a = corrupt(q, mask, 30.0, every, torch.Generator().manual_seed(3))
    b = corrupt(q, mask, 30.0, every, torch.Generator().manual_seed(3))
    assert torch.equal(a, b)
    assert bool((a[..., 25:] == 0).all())
    coupled = [CANONICAL_COORDINATES.index(n) for n in COUPLED_COORDINATES]
    assert bool((a[..., coupled] == 0).all())
    assert float(a[..., :25].abs().max()) > 0
    assert torch.equal(corrupt(q, mask, 30.0, NoiseLevels(probability=0.0)), q)


def test_physics_losses_vanish_on_the_clean_clip(body, walk):
    """Eq. 8 on the clean clip with its own QP targets is zero (the targets and the loss share the finite
    differences and the contact points), as are the reconstruction terms: the losses measure the refinement, not
    a modelling mismatch. L_force and L_contact are those of an untrained head and a real clip: finite."""
    from biomotion.training.train_refiner import Batch, LossWeights, qp_targets, step_losses

    q, mask = walk
    refiner = Refiner.new(TINY, body)
    targets = qp_targets(refiner, q, mask, 30.0)
    window = slice(8, 24)
    batch = Batch(
        q[None, window],
        mask[None],
        torch.ones(1, 16, dtype=torch.bool),
        targets["forces"][None, window],
        targets["torques"][None, window],
        targets["rest"][None],
    )
    _, terms = step_losses(refiner, batch, batch.q, LossWeights(), 8, torch.Generator().manual_seed(0))
    terms = {k: v.detach() for k, v in terms.items()}
    assert float(terms["q"]) < 1e-10 and float(terms["joints"]) < 1e-10 and float(terms["acceleration"]) < 1e-3
    assert float(terms["euler"]) < 2e-3  # body weights, float32
    assert all(bool(torch.isfinite(v)) for v in terms.values())
    noisy = corrupt(batch.q, batch.mask, 30.0, NoiseLevels(probability=1.0), torch.Generator().manual_seed(0))
    loss, terms = step_losses(refiner, batch, noisy, LossWeights(), 8, torch.Generator().manual_seed(0))
    assert float(terms["euler"]) > 0.05 and float(terms["q"]) > 1e-4
    loss.backward()
    assert refiner.net.motion_head.weight.grad is not None


def test_shipped_refiner_reduces_acceleration_error_on_a_real_clip(body, walk):
    """On a clip of a subject and source it never saw (OpenCap), corrupted like markerless capture, the shipped
    refiner's output is closer to the clean clip in acceleration (ACCL) than its input."""
    from biomotion.generation.refinement import default_refiner_path

    path = default_refiner_path()
    if not path.exists():
        pytest.skip("no shipped refiner weights")
    refiner = Refiner.load(path, body)
    q, mask = walk
    noisy = corrupt(q[None], mask[None], 30.0, NoiseLevels(probability=1.0), torch.Generator().manual_seed(1))[0]
    before = refinement_scores(refiner, q, noisy, mask)
    after = refinement_scores(refiner, q, refiner.refine(noisy, mask).q, mask)
    assert after["accl"] < 0.6 * before["accl"]
    assert after["mje"] < 1.05 * before["mje"]
