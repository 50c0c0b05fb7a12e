"""The shape-conditioned motion c-VAE (`biomotion.models.shape_vae`): shapes, timing, a training step, A → A after
training on a tiny set, the physics term through a real scaled model, and one-line errors for bad inputs.

Truth: a synthetic gait whose stride time is known (sinusoids at 1 / T), and a model trained on it alone, which must
give the gait back when asked for its own body."""

import math

import numpy as np
import pytest
import torch

from biomotion.body.model import BodyModel
from biomotion.body.shape import Shape
from biomotion.errors import BiomotionError, ConfigError
from biomotion.models.shape_vae import (
    FEATURES,
    PHASE_FRAMES,
    YAW,
    ShapeAdapter,
    ShapeVAE,
    ShapeVAEConfig,
    kl_divergence,
    mirror,
    motion_features,
    phase_resample,
    shape_vector,
    stride_time,
)
from biomotion.motion import Motion
from biomotion.training.train_shape_vae import Clip, Subject, stance_velocity_variance, timing_ridge
from tests.conftest import data_path

torch.set_num_threads(1)

AMPLITUDE = {"hip_flexion": 0.5, "knee_angle": 0.6, "ankle_angle": 0.3, "pelvis_tilt": 0.05, "hip_adduction": 0.1}


def _shape(height: float = 1.75, mass: float = 70.0, tibia: float = 0.42) -> Shape:
    lengths = {"tibia_r": tibia, "tibia_l": tibia, "calcn_r": 0.2, "calcn_l": 0.2}
    return Shape(reference="test", scales={"tibia_r": (1.0, 1.0, 1.0)}, mass=mass, height=height, lengths=lengths)


def _gait(stride: float = 0.7, seconds: float = 6.0, rate: float = 100.0, extra: bool = True) -> Motion:
    """A synthetic gait: every feature a sinusoid at 1 / ``stride`` (left half a cycle behind the right), plus a
    pelvis translation column the adapter must pass through."""
    t = np.arange(0.0, seconds, 1.0 / rate)
    names, columns = [], []
    for name in FEATURES:
        base = name.rsplit("_", 1)[0] if name.endswith(("_r", "_l")) else name
        phase = math.pi if name.endswith("_l") else 0.0
        amplitude = AMPLITUDE.get(base, 0.05)
        columns.append(amplitude * np.sin(2 * math.pi * t / stride + phase) + (0.4 if "knee" in name else 0.0))
        names.append(name)
    if extra:
        names.append("pelvis_tx")
        columns.append(0.01 * t)
    return Motion(times=t + 1.0, names=tuple(names), values=np.stack(columns, -1))


def test_forward_shapes_kl_and_save_load(tmp_path):
    model = ShapeVAE(ShapeVAEConfig(window=32, width=32, latent=8, layers=1, heads=2, ff=32))
    x = torch.randn(3, 32, len(FEATURES))
    decoded, log_stride, mu, logvar = model(x, torch.randn(3, 4))
    assert decoded.shape == (3, 32, len(FEATURES)) and log_stride.shape == (3,)
    assert mu.shape == logvar.shape == (3, 8, 8)
    assert float(kl_divergence(torch.zeros(2, 3), torch.zeros(2, 3))) == 0.0
    path = tmp_path / "adapter.safetensors"
    model.save(path, {"subjects": '["fukuchi/RBDS001"]'})
    adapter = ShapeAdapter.load(path)
    assert adapter.subjects == ("fukuchi/RBDS001",)
    again, _, _, _ = adapter.model(x, torch.zeros(3, 4), sample=False)
    model.eval()
    reference, _, _, _ = model(x, torch.zeros(3, 4), sample=False)
    torch.testing.assert_close(again, reference)


def test_stride_time_phase_resample_and_mirror():
    motion = _gait(stride=0.73, rate=150.0)
    values = motion_features(motion)
    assert stride_time(values, motion.rate) == pytest.approx(0.73, abs=0.005)
    phase = phase_resample(values, motion.rate, 0.73)
    assert len(phase) == pytest.approx(6.0 / 0.73 * PHASE_FRAMES, abs=2)
    flipped = mirror(values.astype(np.float32))
    np.testing.assert_allclose(mirror(flipped), values, atol=1e-6)
    right, left = FEATURES.index("knee_angle_r"), FEATURES.index("knee_angle_l")
    np.testing.assert_allclose(flipped[:, right], values[:, left], atol=1e-6)
    assert np.allclose(flipped[:, YAW], -values[:, YAW], atol=1e-6)
    knees = motion_features(motion, knee_flipped=True)
    np.testing.assert_allclose(knees[:, right], -values[:, right])


def test_shape_vector_reads_height_mass_and_lengths():
    vector = shape_vector(_shape(1.8, 80.0, 0.45))
    np.testing.assert_allclose(vector, np.log([1.8, 80.0, 0.45, 0.2]), rtol=1e-6)


def _windows(values: np.ndarray, rate: float, window: int) -> np.ndarray:
    phase = phase_resample(values, rate, stride_time(values, rate))
    chunks = np.stack([phase[s : s + window] for s in range(0, len(phase) - window + 1, 2)]).astype(np.float32)
    chunks[:, :, YAW] -= chunks[:, :, YAW].mean(1, keepdims=True)
    return chunks


def test_training_steps_lower_the_loss_and_a_to_a_keeps_the_motion():
    torch.manual_seed(0)
    motion = _gait()
    shape = _shape()
    values = motion_features(motion)
    model = ShapeVAE(ShapeVAEConfig(window=64, width=32, latent=8, layers=1, heads=2, ff=64, dropout=0.0))
    chunks = _windows(values, motion.rate, 64)
    model.set_normalisation(chunks.reshape(-1, len(FEATURES)), np.stack([shape_vector(shape)] * 2), [math.log(0.7)])
    x = model.standardise(torch.as_tensor(chunks))
    s = model.standardise_shape(shape_vector(shape)).expand(len(x), -1)
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(150):
        decoded, log_stride, mu, logvar = model(x, s)
        loss = (decoded - x).square().mean() + log_stride.square().mean() + 1e-3 * kl_divergence(mu, logvar)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    assert np.mean(losses[-10:]) < 0.2 * losses[0]
    adapter = ShapeAdapter(model)
    same = adapter.adapt(motion, shape, shape)
    assert same.names == motion.names and same.rate == pytest.approx(motion.rate)
    assert same.times[0] == motion.times[0] and abs(same.duration - motion.duration) < 0.02
    n = min(same.n_frames, motion.n_frames)
    error = np.degrees(np.sqrt(np.mean((motion_features(same)[:n] - values[:n]) ** 2)))
    assert error < 3.0  # deg RMS over the 13 angles, against amplitudes of 3 to 34 deg
    np.testing.assert_allclose(same["pelvis_tx"][:n], motion["pelvis_tx"][:n], atol=1e-3)  # passed through
    taller = adapter.adapt(motion, shape, _shape(1.95, 90.0, 0.5))
    assert taller.names == motion.names and np.all(np.isfinite(taller.values))


def test_ridge_timing_lengthens_the_stride_of_a_taller_body():
    """With ``timing: ridge`` the stride time changes by exp(w · (s_B − s_A)): a taller body with a positive height
    weight takes longer strides (at the same belt speed, longer stride length); A → A keeps the timing."""
    model = ShapeVAE(ShapeVAEConfig(window=64, width=32, latent=8, layers=1, heads=2, ff=32, timing="ridge"))
    model.timing_weights.copy_(torch.tensor([0.5, 0.0, 0.0, 0.0]))
    adapter = ShapeAdapter(model)
    motion, short, tall = _gait(stride=0.7), _shape(1.6), _shape(1.9)
    moved = adapter.adapt(motion, short, tall)
    stretch = (1.9 / 1.6) ** 0.5
    assert moved.duration == pytest.approx(motion.duration * stretch, abs=0.02)
    slope = np.polyfit(moved.times, moved["pelvis_tx"], 1)[0]  # passed through, time-warped: 0.01 m/s / stretch
    assert slope == pytest.approx(0.01 / stretch, rel=1e-3)
    same = adapter.adapt(motion, short, short)
    assert np.polyfit(same.times, same["pelvis_tx"], 1)[0] == pytest.approx(0.01, rel=1e-3)


def test_timing_ridge_recovers_a_within_task_law():
    """log T = 0.5 log height + a per-task offset: the ridge with a vanishing penalty finds 0.5 on height (the
    foot length is constant, hence the penalty)."""
    rng = np.random.default_rng(0)
    subjects, clips = [], []
    for k in range(8):
        shape = _shape(float(rng.uniform(1.55, 1.95)), float(rng.uniform(50, 90)), float(rng.uniform(0.38, 0.48)))
        subjects.append(Subject(f"x/{k}", shape_vector(shape), None, None, None))
        for task, offset in (("run/2.5", -0.2), ("run/4.5", -0.5)):
            clips.append(Clip(k, np.zeros((64, len(FEATURES))), offset + 0.5 * math.log(shape.height), task))
    np.testing.assert_allclose(timing_ridge(subjects, clips, 1e-9), [0.5, 0.0, 0.0, 0.0], atol=1e-5)
    assert np.all(timing_ridge(subjects, clips[:1], 0.1) == 0.0)  # one person per task: nothing to compare


def test_bad_inputs_raise_one_line_errors():
    model = ShapeVAE(ShapeVAEConfig(window=32, width=32, latent=8, layers=1, heads=2, ff=32))
    adapter = ShapeAdapter(model)
    shape = _shape()
    cases = [
        lambda: model.encode(torch.zeros(2, 31, len(FEATURES))),
        lambda: model.decode(torch.zeros(2, 8, 8), torch.zeros(2, 3)),
        lambda: ShapeVAEConfig.from_dict({"width": 32, "depth": 3}),
        lambda: ShapeVAEConfig.from_dict({"window": 30}),
        lambda: ShapeVAEConfig.from_dict({"timing": "magic"}),
        lambda: shape_vector(Shape(reference="x", scales={"a": (1, 1, 1)}, mass=60.0)),
        lambda: shape_vector(Shape(reference="x", scales={"a": (1, 1, 1)}, mass=60.0, height=1.7)),
        lambda: adapter.adapt(_gait(seconds=1.0), shape, shape),
        lambda: adapter.adapt(_gait().select(FEATURES[:-1]), shape, shape),
    ]
    for case in cases:
        with pytest.raises(ConfigError) as error:
            case()
        assert "\n" not in str(error.value)
    with pytest.raises(ConfigError, match="positive"):
        _shape(mass=-1.0)
    with pytest.raises(BiomotionError):
        ShapeAdapter.load(data_path("fukuchi-running/participantInfo.csv"))


def test_physics_term_on_a_real_scaled_model():
    """Feet planted and still score 0; a swinging leg whose foot touches down moving scores above 0."""
    model = BodyModel.from_osim(data_path("fukuchi-running/RBDS019/RBDS019_simple.osim"))
    columns = torch.tensor([model.coordinate_names.index(n) for n in FEATURES])
    signs = torch.tensor([-1.0 if n.startswith("knee") else 1.0 for n in FEATURES], dtype=model.dtype)
    subject = Subject("fukuchi/RBDS019", shape_vector(Shape.from_model(model, height=1.7)), model, columns, signs)
    still = torch.zeros(64, len(FEATURES))
    assert float(stance_velocity_variance(subject, still, 0.7, 0.03, 0.01)) == pytest.approx(0.0, abs=1e-9)
    values = motion_features(_gait(stride=0.7, rate=PHASE_FRAMES / 0.7, seconds=2.0))
    moving = torch.as_tensor(values[:64], dtype=torch.float32).requires_grad_()
    term = stance_velocity_variance(subject, moving, 0.7, 0.03, 0.01)
    term.backward()
    assert term.item() > 0.0 and torch.isfinite(moving.grad).all() and moving.grad.abs().sum() > 0
