"""Motion, Markers and GroundReaction: construction checks, resampling, filtering, slicing, selection."""

import numpy as np
import pytest

from biomotion.errors import DataFormatError
from biomotion.motion import GroundReaction, Markers, Motion, lowpass


def sine_motion(rate=100.0, seconds=2.0, freq=1.0):
    t = np.arange(int(rate * seconds) + 1) / rate
    values = np.stack([np.sin(2 * np.pi * freq * t), 0.9 + 0.01 * t], axis=1)
    return Motion(times=t, names=("knee_angle_r", "pelvis_ty"), values=values)


def test_resample_keeps_a_slow_signal_and_hits_the_new_rate():
    motion = sine_motion()
    down = motion.resample(30.0)
    assert down.rate == pytest.approx(30.0)
    assert down.times[0] == pytest.approx(0.0) and down.times[-1] == pytest.approx(2.0)
    expected = np.sin(2 * np.pi * down.times)
    # a 1 Hz sine passes a 12 Hz anti-alias filter untouched (within 1e-3 rad away from the padded ends)
    assert np.max(np.abs(down["knee_angle_r"][3:-3] - expected[3:-3])) < 1e-3


def test_resample_removes_content_above_the_new_nyquist():
    t = np.arange(1001) / 1000.0
    noisy = np.sin(2 * np.pi * 2 * t) + 0.5 * np.sin(2 * np.pi * 140 * t)  # 140 Hz would alias at 30 Hz
    motion = Motion(times=t, names=("hip_flexion_r",), values=noisy[:, None])
    down = motion.resample(30.0)
    residual = down["hip_flexion_r"] - np.sin(2 * np.pi * 2 * down.times)
    assert np.max(np.abs(residual[3:-3])) < 0.02


def test_lowpass_keeps_nan_gaps():
    t = np.arange(200) / 100.0
    x = np.sin(2 * np.pi * t)
    x[50:60] = np.nan
    y = lowpass(x, 100.0, 6.0)
    assert np.isnan(y[50:60]).all() and np.isfinite(y[:50]).all() and np.isfinite(y[60:]).all()
    assert np.max(np.abs(y[5:45] - x[5:45])) < 0.01


def test_slice_select_and_mask():
    motion = sine_motion()
    part = motion.slice(0.5, 1.0)
    assert part.times[0] == pytest.approx(0.5) and part.times[-1] == pytest.approx(1.0) and part.n_frames == 51
    chosen = motion.select(["pelvis_ty", "lumbar_extension"])
    assert chosen.names == ("pelvis_ty", "lumbar_extension")
    assert chosen.mask.tolist() == [True, False]
    assert np.all(chosen["lumbar_extension"] == 0.0)
    assert motion.rotational().tolist() == [True, False]


def test_constructor_rejects_bad_shapes_and_clocks():
    with pytest.raises(DataFormatError, match="does not match"):
        Motion(times=np.arange(3.0), names=("a", "b"), values=np.zeros((3, 3)))
    with pytest.raises(DataFormatError, match="does not increase"):
        Motion(times=np.array([0.0, 0.1, 0.1]), names=("a",), values=np.zeros((3, 1)))
    with pytest.raises(DataFormatError, match="no frames"):
        Motion(times=np.zeros(0), names=("a",), values=np.zeros((0, 1)))


def test_markers_and_forces_resample_and_select():
    t = np.arange(11) / 10.0
    positions = np.random.default_rng(0).normal(size=(11, 2, 3))
    positions[4, 1] = np.nan
    markers = Markers(times=t, names=("A", "B"), positions=positions)
    assert markers.occluded()[4].tolist() == [False, True]
    assert np.isnan(markers.select(["C"]).positions).all()
    up = markers.resample(20.0)
    assert up.n_frames == 21 and np.isnan(up["B"][8]).all() and np.isfinite(up["A"]).all()
    force = np.zeros((11, 2, 3))
    force[:, 0, 1] = 700.0
    grf = GroundReaction(times=t, names=("r", "l"), force=force, cop=np.zeros((11, 2, 3)), moment=np.zeros((11, 2, 3)))
    assert grf.total_force()[:, 1] == pytest.approx(np.full(11, 700.0))
    assert grf.assign(["calcn_r", "calcn_l"]).select(["l"]).bodies == ("calcn_l",)
