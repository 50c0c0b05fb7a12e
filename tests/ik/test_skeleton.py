"""Joint-position retargeting (PG-BIG A.5): a skeleton's joint centres onto the Rajagopal model.

Truth comes from two places: the model itself (joint centres of known coordinates on a model scaled by known
factors must give those coordinates and factors back) and OpenSim (the written .osim and .mot, loaded by OpenSim,
put the joints where the BVH has them)."""

import json

import numpy as np
import pytest
import torch

from biomotion.body.kinematics import joint_centers
from biomotion.body.model import BodyModel
from biomotion.body.scaling.bodies import scale_model
from biomotion.cli import main
from biomotion.errors import ConfigError
from biomotion.ik.skeleton import BANDAI_NAMCO, JointMap, face_forward, joint_positions, retarget_skeleton
from biomotion.io.bvh import read_bvh
from biomotion.io.mot import read_motion
from biomotion.motion import Markers
from biomotion.validation.bvh import foot_skate
from tests.conftest import data_path

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
WALK = "bandai-namco/dataset-2/dataset-2_walk_normal_016.bvh.gz"
CENTRES = (
    "hip_r",
    "hip_l",
    "walker_knee_r",
    "walker_knee_l",
    "ankle_r",
    "ankle_l",
    "back",
    "acromial_r",
    "acromial_l",
    "elbow_r",
    "elbow_l",
    "radius_hand_r",
    "radius_hand_l",
)


@pytest.fixture(scope="module")
def generic():
    return BodyModel.from_osim(data_path(RAJAGOPAL))


def _known_motion(model: BodyModel, frames: int = 60) -> np.ndarray:
    """A smooth walking-like motion inside every range: q [T, n]."""
    t = np.linspace(0, 2 * np.pi, frames)[:, None]
    q = np.tile(model.defaults.numpy(), (frames, 1))
    amplitude = {
        "hip_flexion_r": 0.5,
        "hip_flexion_l": -0.5,
        "knee_angle_r": 0.6,
        "knee_angle_l": 0.6,
        "ankle_angle_r": 0.2,
        "ankle_angle_l": -0.2,
        "lumbar_extension": 0.1,
        "arm_flex_r": -0.4,
        "arm_flex_l": 0.4,
        "elbow_flex_r": 0.4,
        "elbow_flex_l": 0.4,
        "pelvis_rotation": 0.1,
    }
    for name, a in amplitude.items():
        c = model.coordinate_index(name)
        middle = 0.7 if name.startswith(("knee", "elbow")) else 0.0
        q[:, c] = middle + a * np.sin(t[:, 0] + (np.pi if name.endswith("_l") else 0.0))
    q[:, model.coordinate_index("pelvis_tx")] = np.linspace(0, 2.0, frames)
    q[:, model.coordinate_index("pelvis_ty")] = 0.95
    for coupler in model.couplers:
        q[:, coupler.dependent] = q[:, coupler.independent]
    return q


def test_recovers_known_coordinates_and_segment_scales(generic):
    factors = {
        "femur_r": (1.1,) * 3,
        "femur_l": (1.1,) * 3,
        "patella_r": (1.1,) * 3,
        "patella_l": (1.1,) * 3,
        "tibia_r": (0.9,) * 3,
        "tibia_l": (0.9,) * 3,
        "humerus_r": (1.05,) * 3,
        "humerus_l": (1.05,) * 3,
    }
    person = scale_model(generic, factors)
    q = _known_motion(person)
    with torch.no_grad():
        centres = joint_centers(person, torch.as_tensor(q)).numpy()
    names = [n for n in person.joint_names if n in CENTRES]
    source = Markers(
        times=np.arange(len(q)) / 30.0,
        names=tuple(names),
        positions=centres[:, [person.joint_names.index(n) for n in names]],
    )
    result = retarget_skeleton(source, generic, JointMap({n: n for n in names}), cutoff_hz=100.0)
    for body, expected in factors.items():  # the walker knee's centre slides with flexion: hip-knee is not fixed
        assert result.factors[body] == pytest.approx(expected, rel=0.01), body
    assert result.mean_error < 1e-3  # m
    for name in ("hip_flexion_r", "knee_angle_r", "hip_flexion_l", "knee_angle_l", "arm_flex_r", "elbow_flex_l"):
        c = person.coordinate_index(name)
        # 1.5 deg: forearm pronation moves the wrist centre too, so elbow flexion trades a little with it
        assert np.degrees(np.abs(result.motion.values[:, c] - q[:, c])).max() < 1.5, name


def test_bandai_walk(generic):
    source = joint_positions(read_bvh(data_path(WALK)))
    result = retarget_skeleton(source, generic)
    assert result.joint_names == tuple(BANDAI_NAMCO.centres) + tuple(BANDAI_NAMCO.toes)
    assert result.mean_error < 0.01 and result.max_error < 0.04  # measured 0.48 cm and 1.9 cm
    model, values = result.model, result.motion.values
    clamped = model.clamped.numpy()
    lower, upper = model.ranges[:, 0].numpy(), model.ranges[:, 1].numpy()
    assert np.all((values[:, clamped] >= lower[clamped] - 1e-9) & (values[:, clamped] <= upper[clamped] + 1e-9))
    # foot sliding as in the capture: 0.536 vs 0.510 here (the model's toe rides on a rigid one-axis foot); the
    # bar is pooled over every clip, `biomotion validate ik`
    skate_result, skate_source = (
        foot_skate(result.feet_result, source.rate),
        foot_skate(result.feet_source, source.rate),
    )
    assert 0 < skate_result <= skate_source + 0.05
    knee = np.degrees(result.motion["knee_angle_r"])
    assert 50 < knee.max() < 80 and knee.min() < 15  # a walk: swing flexion, near-straight stance


def test_opensim_loads_the_outputs_and_puts_the_joints_there(tmp_path, generic):
    osim = pytest.importorskip("opensim")
    model_path = data_path(RAJAGOPAL)
    code = main(["retarget", str(data_path(WALK)), "--model", str(model_path), "--out", str(tmp_path), "--quiet"])
    assert code == 0
    name = "dataset-2_walk_normal_016"
    model = osim.Model(str(tmp_path / f"{name}.osim"))
    state = model.initSystem()
    motion = read_motion(tmp_path / f"{name}.mot")
    source = face_forward(joint_positions(read_bvh(data_path(WALK))).select(BANDAI_NAMCO.source_joints()), BANDAI_NAMCO)
    shift = retarget_skeleton(joint_positions(read_bvh(data_path(WALK))), generic).floor_shift
    for frame in range(0, motion.n_frames, 40):
        for c, coordinate in enumerate(motion.names):
            model.getCoordinateSet().get(coordinate).setValue(state, float(motion.values[frame, c]), False)
        model.realizePosition(state)
        for body, joint in (("tibia_r", "LowerLeg_R"), ("talus_l", "Foot_L"), ("humerus_r", "UpperArm_R")):
            where = model.getBodySet().get(body).getPositionInGround(state).to_numpy()
            expected = source[joint][frame] - np.array([0.0, shift, 0.0])
            assert np.linalg.norm(where - expected) < 0.03, (frame, body)  # joint-centre errors here: <= 1.9 cm


def test_errors_name_what_is_wrong(tmp_path, generic):
    source = Markers(times=np.arange(3) / 30.0, names=("a", "b"), positions=np.zeros((3, 2, 3)))
    with pytest.raises(ConfigError, match="no built-in joint map"):
        retarget_skeleton(source, generic)
    with pytest.raises(ConfigError, match="does not have"):
        retarget_skeleton(source, generic, JointMap({"hip_r": "a", "hip_l": "b", "elbow_x": "a"}))
    with pytest.raises(ConfigError, match="both hips"):
        retarget_skeleton(source, generic, JointMap({"back": "a"}))
    bad = tmp_path / "map.json"
    bad.write_text(json.dumps({"hip_r": "a"}))
    with pytest.raises(Exception, match="centres"):
        JointMap.from_file(bad)
