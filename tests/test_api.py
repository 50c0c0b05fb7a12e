"""The top-level API: `import biomotion as bm` lists its public names, loads them lazily, and runs the lab chain
in memory (`bm.analyze_trial`)."""

import subprocess
import sys

import numpy as np
import pytest

import biomotion as bm
from tests.conftest import data_path

SUBJECT4 = "opencap/Subject4"


def test_every_public_name_resolves_and_dir_lists_them():
    assert sorted(dir(bm)) == sorted(bm.__all__)
    for name in bm.__all__:
        assert getattr(bm, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        bm.nothing_here  # noqa: B018 - the access itself is the test


def test_import_is_light():
    """`import biomotion` (and the CLI's argument parsing) must not load torch or scipy: argument errors answer
    at once."""
    code = "import sys, biomotion, biomotion.cli; print(sorted(m for m in ('torch', 'scipy') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_top_level_names_work_on_real_files():
    motion = bm.read(data_path(f"{SUBJECT4}/IK/DJ1_ik.mot"))
    assert isinstance(motion, bm.Motion) and motion.n_frames == 269
    model = bm.BodyModel.from_osim(data_path(f"{SUBJECT4}/Models/optimized_scale_and_markers.osim"))
    assert model.total_mass == pytest.approx(62.6)


def test_analyze_trial_from_markers_matches_the_labs_ik_and_writes_nothing(tmp_path, monkeypatch):
    """Markers + plates → IK → ID in memory. The joint angles come out within 2° RMS of the lab's own OpenSim IK
    of the same trial (walking1_ik.mot, same model and setup), and the analysis of our angles gives the same
    vertical ground force (measured plates, assigned to the feet) as the analysis of the lab's angles."""
    monkeypatch.chdir(tmp_path)
    setup = bm.read_ik_setup(data_path(f"{SUBJECT4}/IK/walking1_ik_setup.xml"))
    trial = bm.read_trial(data_path(f"{SUBJECT4}/MarkerData/walking1.trc"), setup.time_range)
    model = bm.BodyModel.from_osim(data_path(f"{SUBJECT4}/Models/optimized_scale_and_markers.osim"))
    forces = bm.read(data_path(f"{SUBJECT4}/ID/walking1_grf.mot"))
    ours = bm.analyze_trial(trial, model=model, forces=forces, setup=setup)
    assert list(tmp_path.iterdir()) == []
    lab = bm.read(data_path(f"{SUBJECT4}/IK/walking1_ik.mot"))
    names = [
        n
        for n in model.coordinate_names
        if n in lab.names and not n.startswith("pelvis_t") and not bool(model.locked[model.coordinate_index(n)])
    ]
    ik = ours.fit.motion
    frames = np.searchsorted(lab.times, ik.times).clip(0, lab.n_frames - 1)
    rms = np.sqrt(np.mean((ik.select(names).values - lab.select(names).values[frames]) ** 2, axis=0))
    assert np.degrees(np.median(rms)) < 2.0
    reference = bm.analyze_trial(bm.Trial(motion=lab.slice(ik.times[0], ik.times[-1])), model=model, forces=forces)
    fz_ours = ours.ground_reaction.force[..., 1].sum(-1)
    fz_lab = reference.ground_reaction.force[..., 1].sum(-1)
    n = min(len(fz_ours), len(fz_lab))
    assert np.abs(fz_ours[:n] - fz_lab[:n]).max() < 1.0  # N: the same plates on the same frames
    assert ours.torques.shape == (ours.angles.n_frames, model.n_q) and np.isfinite(ours.torques).all()
    assert ours.dynamics.zmp.shape == (ours.angles.n_frames, 3)


def test_analyze_trial_refuses_an_empty_trial():
    model = bm.BodyModel.from_osim(data_path(f"{SUBJECT4}/Models/optimized_scale_and_markers.osim"))
    with pytest.raises(bm.ConfigError, match="neither coordinates nor markers"):
        bm.analyze_trial(bm.Trial(), model=model)


def test_analyze_trial_adds_activations_with_shipped_paths():
    """Static optimization through the same call: gait2392's walk with its shipped path functions."""
    g = "opensim-models/Pipelines/Gait2392_Simbody"
    motion = bm.read(data_path(f"{g}/subject01_walk1_ik.mot")).slice(0.6, 0.9)
    model_file = data_path(f"{g}/OutputReference/subject01_simbody.osim")
    model = bm.BodyModel.from_osim(model_file)
    forces = bm.read(data_path(f"{g}/subject01_walk1_grf.mot"))
    result = bm.analyze_trial(bm.Trial(motion=motion), model=model, forces=forces, muscles="gait2392_subject01")
    activations = result.activations.activations.numpy()
    assert activations.shape[0] == result.angles.n_frames and ((activations >= 0) & (activations <= 1)).all()
