"""`bm.refine`: a motion in, the same columns and clock out, with forces and torques in SI; what it refuses."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.errors import BiomotionError, DataFormatError, ModelError
from biomotion.generation.refinement import refine, write_refined
from biomotion.models.refiner import Refiner, RefinerConfig
from biomotion.motion import Motion

TINY = RefinerConfig(d_model=16, heads=2, encoder_layers=1, decoder_layers=1, feedforward=32, window=16)


@pytest.fixture(scope="module")
def refiner(data_root):
    from biomotion.data.clips import body_model

    torch.manual_seed(0)
    model = Refiner.new(TINY, body_model(data_root))
    return model


@pytest.fixture(scope="module")
def walk():
    """OpenCap Subject4 walking1 as recorded: 100 Hz, 33 coordinates (no knee ``_beta``), 1.5 s."""
    from biomotion.io.mot import read_motion
    from tests.conftest import data_path

    return read_motion(data_path("opencap/Subject4/IK/walking1_ik.mot")).slice(0.0, 1.5)


def test_refine_keeps_columns_clock_and_frame(refiner, walk):
    out = refine(walk, refiner, height=1.68, mass=62.6)
    assert out.motion.names == walk.names and np.array_equal(out.motion.times, walk.times)
    assert np.isfinite(out.motion.values).all()
    # an untrained refiner (the identity) gives the motion back where it was recorded: what is left is the 30 Hz
    # round trip (anti-alias low-pass at 12 Hz, cubic splines) and the placement undone
    translation = [walk.index(n) for n in ("pelvis_tx", "pelvis_ty", "pelvis_tz")]
    rotation = [i for i in range(len(walk.names)) if i not in translation]
    assert np.abs(out.motion.values[:, translation] - walk.values[:, translation]).max() < 0.005
    angles = np.degrees(np.abs(out.motion.values[:, rotation] - walk.values[:, rotation]))
    assert angles.max() < 1.5 and np.median(angles) < 0.2
    # forces per foot in N on the input's clock, CoP in the lab frame, torques per canonical coordinate
    grf = out.ground_reaction
    assert grf.names == ("r", "l") and grf.bodies == ("calcn_r", "calcn_l")
    assert grf.force.shape == (walk.n_frames, 2, 3) and out.torques.shape == (walk.n_frames, 39)
    assert (grf.force[..., 1] >= 0).all()
    assert out.torque_labels[3] == "pelvis_tx_force" and out.torque_labels[9] == "knee_angle_r_moment"
    cop_x = grf.cop[..., 0][np.isfinite(grf.cop[..., 0])]
    pelvis_x = walk["pelvis_tx"]
    assert cop_x.size == 0 or (cop_x.min() > pelvis_x.min() - 1.0 and cop_x.max() < pelvis_x.max() + 1.0)


def test_write_refined_gives_opensim_files(refiner, walk, tmp_path):
    from biomotion.io.mot import read_ground_reaction, read_motion, read_storage

    files = write_refined(tmp_path, refine(walk, refiner), figures=True)
    assert set(files) == {"motion", "grf", "grf_loads", "torques", "plot"}
    assert read_motion(files["motion"]).names == walk.names
    assert read_ground_reaction(files["grf"]).force.shape == (walk.n_frames, 2, 3)
    assert "<applied_to_body>calcn_r</applied_to_body>" in files["grf_loads"].read_text()
    assert read_storage(files["torques"]).labels[0] == "pelvis_tilt_moment"
    assert files["plot"].stat().st_size > 10_000


def test_flexion_negative_knees_come_back_with_their_sign(refiner, walk):
    flipped = walk.values.copy()
    for name in ("knee_angle_r", "knee_angle_l"):
        flipped[:, walk.index(name)] *= -1
    with pytest.warns(UserWarning, match="flexion-negative"):
        out = refine(walk.with_values(flipped), refiner)
    assert np.median(out.motion["knee_angle_r"]) < 0


def test_bad_inputs_are_refused_with_one_line_each(refiner, walk):
    nan = walk.values.copy()
    nan[7, walk.index("hip_flexion_r")] = np.nan
    with pytest.raises(DataFormatError, match="NaN") as error:
        refine(walk.with_values(nan), refiner, source="walk.mot")
    assert "frame 7" in str(error.value) and "hip_flexion_r" in str(error.value) and "\n" not in str(error.value)
    bvh_like = Motion(times=walk.times, names=("Hips_x", "Hips_y"), values=walk.values[:, :2])
    with pytest.raises(ModelError, match="unknown skeleton") as error:
        refine(bvh_like, refiner)
    assert "pelvis_tilt" in str(error.value) and "0 of its 2 columns" in str(error.value)
    no_legs = walk.select([n for n in walk.names if not n.startswith("knee_angle")])
    with pytest.raises(ModelError, match="knee_angle_r"):
        refine(no_legs, refiner)
    with pytest.raises(DataFormatError, match="too short"):
        refine(walk.frames(slice(0, 20)), refiner)  # 0.19 s: 7 frames at 30 Hz
    assert isinstance(DataFormatError(None, "x"), BiomotionError)
