"""`biomotion.analysis.trial.check_coordinates`: coordinates that cannot be analysed on their model are refused,
naming the file, frame and column, before any dynamics is computed."""

import numpy as np
import pytest

from biomotion.analysis.trial import check_coordinates
from biomotion.body.model import BodyModel
from biomotion.errors import DataFormatError
from biomotion.io.mot import read_motion
from biomotion.motion import Motion
from tests.conftest import data_path

GAIT = "opensim-models/Pipelines/Gait2392_Simbody"


@pytest.fixture(scope="module")
def walk():
    model = BodyModel.from_osim(data_path(f"{GAIT}/OutputReference/subject01_simbody.osim"))
    return read_motion(data_path(f"{GAIT}/subject01_walk1_ik.mot")), model


def changed(motion: Motion, name: str, frame: int, value: float) -> Motion:
    values = motion.values.copy()
    values[frame, motion.names.index(name)] = value
    return motion.with_values(values)


def test_a_real_ik_result_passes(walk):
    motion, model = walk
    check_coordinates(motion, model, "walk.mot")


def test_degrees_read_as_radians_are_refused(walk):
    """A header saying inDegrees=no over degrees: the 60-degree knee becomes 60 rad, ten turns beyond the knee's
    range (bad-input corpus case mot-degrees-declared-radians was analysed with a warning only)."""
    motion, model = walk
    as_radians = motion.with_values(np.degrees(motion.values))
    with pytest.raises(
        DataFormatError, match=r"walk\.mot: frame \d+, field '\w+': .* angles in degrees read as radians"
    ):
        check_coordinates(as_radians, model, "walk.mot")


def test_a_corrupted_number_is_refused(walk):
    motion, model = walk
    with pytest.raises(DataFormatError, match=r"frame 40, field 'pelvis_tx': 1e\+09 is not a plausible coordinate"):
        check_coordinates(changed(motion, "pelvis_tx", 40, 1e9), model, "walk.mot")


def test_the_free_joint_turns_freely_and_small_excursions_pass(walk):
    """The pelvis may turn through many turns (a spinning dancer); a joint a little beyond its range passes."""
    motion, model = walk
    check_coordinates(changed(motion, "pelvis_rotation", 10, 40.0), model, "walk.mot")
    knee = model.ranges[model.coordinate_index("knee_angle_r")]
    check_coordinates(changed(motion, "knee_angle_r", 10, float(knee[0]) - 0.3), model, "walk.mot")


def test_columns_of_another_model_are_refused(walk):
    motion, model = walk
    other = Motion(times=motion.times, names=tuple(f"q{k}" for k in range(len(motion.names))), values=motion.values)
    with pytest.raises(DataFormatError, match=r"walk\.mot: none of its 23 columns .* is a coordinate of model"):
        check_coordinates(other, model, "walk.mot")
