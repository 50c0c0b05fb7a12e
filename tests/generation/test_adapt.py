"""`biomotion adapt` / `bm.adapt` (HUMOS shape adapter as a user command) on real Fukuchi runners.

Truth: the runners' own scaled models and IK (``fukuchi-running``), their heights from ``participantInfo.csv``; the
shipped adapter keeps A's stride time exactly for A -> A (its time warp is the change from A's shape to the
target's, zero for the same shape), and predicts a longer stride for a taller body
(docs/results/eval_shape.md); a treadmill run's stance feet move at minus the belt speed (the speed the Fukuchi
trial's name gives), and planting them on that belt removes most of the adapted run's foot skate as
`biomotion.evaluation.shape_physics.clip_physics` scores it: the adapted run skates no more than A's angles copied
onto B, nor than B's own run (HUMOS "skate", issue 48)."""

import json

import numpy as np
import pytest
import torch

import biomotion as bm
from biomotion.body.model import BodyModel
from biomotion.cli import main
from biomotion.evaluation.shape import ANGLES, gait_timing
from biomotion.io.mot import read_motion
from tests.conftest import REPO, data_path

torch.set_num_threads(1)

HEIGHTS = {"RBDS04": 1.68, "RBDS012": 1.786}  # m, participantInfo.csv
ADAPTER = REPO / "checkpoints" / "shape_adapter.safetensors"
#: hip/knee/ankle angles of A -> A against A, RMS: the adapter re-decodes them (3.5 deg measured) and foot planting
#: moves the legs so the re-decoded stance feet rest on the belt (3.9 deg measured with it)
A_TO_A_RMS_DEG = 5.0
BELT = 3.5  # m/s, the T35 trials


def _runner(name: str):
    return data_path(f"fukuchi-running/{name}/{name}_simple.osim")


@pytest.fixture(scope="module")
def source_motion():
    if not ADAPTER.is_file():
        pytest.skip("no shipped shape adapter weights (checkpoints/shape_adapter.safetensors)")
    return read_motion(data_path("fukuchi-running/ik/T35/RBDS04_T35_ik_simple.mot"))


def test_adapt_onto_a_taller_runner_end_to_end(tmp_path, source_motion, capsys):
    """RBDS04 (1.68 m) -> RBDS012 (1.79 m) through the CLI: every output, a readable .mot on the target's model,
    a longer stride at the same belt speed, the feet on the source's floor."""
    out = tmp_path / "adapted"
    motion_file = data_path("fukuchi-running/ik/T35/RBDS04_T35_ik_simple.mot")
    args = ["adapt", str(motion_file), "--from", str(_runner("RBDS04")), "--to", str(_runner("RBDS012"))]
    args += ["--from-height", "1.68", "--to-height", "1.786", "--out", str(out)]
    assert main(args) == 0
    assert "stride" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == [
        "model.osim",
        "motion.bvh",
        "motion.mot",
        "record.json",
        "viewer.html",
    ]
    model = BodyModel.from_osim(out / "model.osim")
    adapted = read_motion(out / "motion.mot")
    assert adapted.names == model.coordinate_names and np.isfinite(adapted.values).all()
    assert adapted.rate == pytest.approx(source_motion.rate, rel=1e-6)
    source = gait_timing(BodyModel.from_osim(_runner("RBDS04")), source_motion, 3.5)
    ours = gait_timing(model, adapted, 3.5)
    assert ours["stride_length_m"] > 1.02 * source["stride_length_m"]  # taller runner, longer stride
    record = json.loads((out / "record.json").read_text())
    assert record["target_shape"]["height"] == pytest.approx(1.786)
    assert record["source_shape"]["mass"] == pytest.approx(57.05, abs=0.01)
    assert len(record["adapter"]["sha256"]) == 64 and record["versions"]["biomotion"] == bm.__version__
    assert record["stride_time_s"]["adapted"] > record["stride_time_s"]["source"]
    assert 0.0 < record["floor_shift_m"] < 0.15  # longer legs: the pelvis goes up to keep the feet on the floor
    assert record["feet_planted"] is True and record["inputs"]["planting"] is True
    assert record["ground_velocity_m_s"]["x"] == pytest.approx(-BELT, abs=0.15)
    assert "motion.mot" in record["files"] and record["command"].startswith("biomotion ")


def test_a_to_a_leaves_the_motion_nearly_unchanged(source_motion):
    """The same runner as source and target: stride time kept (within 0.5 %, as measured again in the output),
    duration within 2 frames, angles within `A_TO_A_RMS_DEG`, pelvis height within 1 cm."""
    body = bm.read_body(_runner("RBDS04"), height=HEIGHTS["RBDS04"])
    same = bm.adapt(source_motion, body, body)
    assert same.stride_time_s["adapted"] == pytest.approx(same.stride_time_s["source"], rel=5e-3)
    assert same.filled == () and same.knee_negative == {"source": True, "target": True}
    n = min(same.motion.n_frames, source_motion.n_frames)
    assert abs(same.motion.n_frames - source_motion.n_frames) <= 2
    ours, theirs = same.motion.select(list(ANGLES)).values[:n], source_motion.select(list(ANGLES)).values[:n]
    rms = float(np.degrees(np.sqrt(np.mean((ours - theirs) ** 2))))
    assert rms < A_TO_A_RMS_DEG
    assert abs(same.floor_shift_m) < 0.01


def test_a_shape_file_builds_the_target_from_its_generic_model(tmp_path, source_motion):
    """A shape file of measures: the target model is its generic model scaled by the ANSUR II lines; a taller
    body gets a longer stride than a shorter one."""
    generic = data_path("fukuchi-running/generic-models/Denton2023_LowerLimb_Fukuchi2017.osim")
    strides = {}
    for height, mass in ((1.55, 50.0), (1.95, 90.0)):
        shape_file = tmp_path / f"body_{height}.yaml"
        shape_file.write_text(f"height: {height}\nmass: {mass}\ngeneric_height: 1.70\n")
        done = bm.adapt(source_motion, _runner("RBDS04"), shape_file, source_height=HEIGHTS["RBDS04"], generic=generic)
        assert done.target.model.name == "Denton2023_LowerLimb_Fukuchi2017"
        assert done.target.shape.height == pytest.approx(height) and done.target.shape.mass == pytest.approx(mass)
        assert done.filled == ("mtp_angle_r", "mtp_angle_l")  # the IK has no toe joint
        strides[height] = done.stride_time_s["adapted"]
    assert strides[1.95] > strides[1.55]


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("negative.yaml", "reference: R\nscales: {pelvis: [1, 1, 1]}\nmass: 70\nlengths: {tibia_r: -0.4}\n", "lengths"),
        ("missing.json", '{"reference": "R", "scales": {"pelvis": [1, 1, 1]}, "mass": 70, "height": 1.7}', "missing"),
        ("bad_mass.yaml", "height: 1.8\nmass: -3\ngeneric_height: 1.7\n", "mass"),
        ("unknown.yaml", "height: 1.8\nmass: 70\nwingspan: 2\n", "unknown keys"),
        ("body.txt", "height: 1.8\n", "must be a scaled OpenSim model"),
        ("absent.osim", None, "not a file"),
    ],
)
def test_bad_targets_exit_2_with_one_error_line(tmp_path, source_motion, capsys, name, text, message):
    target = tmp_path / name
    if text is not None:
        target.write_text(text)
    generic = data_path("fukuchi-running/generic-models/Denton2023_LowerLimb_Fukuchi2017.osim")
    motion_file = data_path("fukuchi-running/ik/T35/RBDS04_T35_ik_simple.mot")
    args = ["adapt", str(motion_file), "--from", str(_runner("RBDS04")), "--from-height", "1.68", "--to", str(target)]
    code = main([*args, "--generic", str(generic), "--out", str(tmp_path / "out"), "--no-viewer", "--no-planting"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("error: ") and str(target) in err[0] and message in err[0]
    assert not (tmp_path / "out").exists()


def test_a_lower_limb_model_without_a_height_is_named(tmp_path, source_motion, capsys):
    motion_file = data_path("fukuchi-running/ik/T35/RBDS04_T35_ik_simple.mot")
    args = ["adapt", str(motion_file), "--from", str(_runner("RBDS04")), "--to", str(_runner("RBDS012"))]
    assert main([*args, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--from-height" in err[0]


def test_the_ground_speed_of_a_treadmill_run_is_minus_the_belt_speed(source_motion):
    """RBDS04 at 3.5 m/s on their own model: the stance feet move backwards at the belt speed (x), not sideways."""
    from biomotion.generation.adapt import _on_model, ground_velocity

    body = bm.read_body(_runner("RBDS04"), height=HEIGHTS["RBDS04"])
    vx, vz = ground_velocity(body.model, _on_model(source_motion, body.model)[0])
    assert vx == pytest.approx(-BELT, abs=0.15)  # -3.57 measured: 2 % off the nominal belt speed
    assert abs(vz) < 0.1


def test_planting_on_the_belt_removes_most_foot_skate(source_motion):
    """RBDS04 -> RBDS012: with planting the adapted run skates on under half as many frame pairs and its stance
    feet float lower than without (50 % -> 0 %, 32 -> 11 mm measured), scored as `biomotion eval shape` does
    (overground at the belt speed); the pelvis translations are the same, so the output is still a treadmill
    run, and only leg angles change."""
    from biomotion.evaluation.shape_physics import clip_physics

    source = bm.read_body(_runner("RBDS04"), height=HEIGHTS["RBDS04"])
    target = bm.read_body(_runner("RBDS012"), height=HEIGHTS["RBDS012"])
    free = bm.adapt(source_motion, source, target, planting=False)
    planted = bm.adapt(source_motion, source, target)
    assert planted.planted and not free.planted
    assert planted.ground_velocity_m_s == free.ground_velocity_m_s
    ours, theirs = clip_physics(target.model, planted.motion, BELT), clip_physics(target.model, free.motion, BELT)
    assert ours["skate"] < 0.5 * theirs["skate"]
    assert ours["float"] < 0.5 * theirs["float"]
    changed = np.abs(planted.motion.values - free.motion.values).max(0) > 0
    names = {n for n, c in zip(planted.motion.names, changed) if c}
    assert names and all(n.startswith(("hip_", "knee_", "ankle_")) for n in names)


def test_the_adapted_run_skates_no_more_than_the_copy_or_the_real_run(source_motion):
    """RBDS04 -> RBDS012 at 3.5 m/s, both held out of the adapter's training: scored as `biomotion eval shape` scores
    a pair (`clip_physics` on B's model, overground at the belt speed), the adapted run skates on no more frame
    pairs than A's angles copied onto B (21.5 % measured) and than B's own run (4.8 %; the adapted 0 %), and its
    stance feet float no higher than B's own (10.8 against 15.8 mm). Before the stance-phase planting of
    `biomotion.generation.adapt.stance_targets` the adapted run skated on 23.2 %."""
    from biomotion.evaluation.shape_physics import clip_physics

    source = bm.read_body(_runner("RBDS04"), height=HEIGHTS["RBDS04"])
    target = bm.read_body(_runner("RBDS012"), height=HEIGHTS["RBDS012"])
    real = read_motion(data_path("fukuchi-running/ik/T35/RBDS012_T35_ik_simple.mot"))
    adapted = bm.adapt(source_motion, source, target)
    ours = clip_physics(target.model, adapted.motion, BELT)
    copy = clip_physics(target.model, source_motion, BELT)
    theirs = clip_physics(target.model, real, BELT)
    assert ours["skate"] <= copy["skate"]
    assert ours["skate"] <= theirs["skate"]
    assert ours["float"] <= theirs["float"]


def test_stance_targets_hold_a_sliding_foot_still_on_the_floor():
    """A right foot moving at 0.5 m/s, 1 cm above the floor for 20 frames (100 Hz), the left foot in the air: the
    targets hold all five right points still (the slip integrated out, about its mean) and on the floor away from
    the phase's edges, fade out over ``ramp`` frames around it, and leave the left foot free."""
    from biomotion.generation.adapt import stance_targets
    from biomotion.guidance.planting import PlantingConfig

    config = PlantingConfig(ramp=3)
    times = np.arange(40) / 100.0
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.05], [0.15, 0.0, 0.0], [0.13, 0.0, 0.05], [0.2, 0.0, 0.02]])
    points = np.zeros((40, 10, 3))
    points[:, :5] = offsets + np.array([0.0, 0.3, 0.0])
    points[:, 5:] = offsets + np.array([0.0, 0.2, 0.3])
    stance = slice(10, 30)
    points[:, :5, 0] += 0.5 * times[:, None]
    points[stance, :5, 1] = 0.01
    target, weight = stance_targets(points, ("r",) * 5 + ("l",) * 5, times, config)
    assert (weight[stance, :5] == 1.0).all() and (weight[:, 5:] == 0.0).all()
    assert weight[9, 0] == pytest.approx(0.75) and weight[6, 0] == 0.0 and weight[32, 0] == pytest.approx(0.25)
    np.testing.assert_allclose(np.diff(target[stance, :5][..., [0, 2]], axis=0), 0.0, atol=1e-9)  # still
    np.testing.assert_allclose(target[stance, :5, 0].mean(0), points[stance, :5, 0].mean(0), atol=1e-9)
    np.testing.assert_allclose(target[14:26, :5, 1], 0.0, atol=1e-12)  # on the floor inside the ramps
    assert (target[stance, :5, 1] >= 0.0).all()
