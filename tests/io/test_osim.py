"""The .osim and ScaleSet parser on the real models (no OpenSim needed) and on broken copies of them."""

from __future__ import annotations

import pytest

from biomotion.errors import DataFormatError, ModelError
from biomotion.io import osim
from tests.conftest import data_path

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
RUNNER = "fukuchi-running/RBDS001/RBDS001_simple.osim"
MODEL_GLOBS = (
    "opensim-models/**/*.osim",
    "fukuchi-running/**/*.osim",
    "opencap/**/*.osim",
    "Hamner2013/**/*.osim",
    "SchreiberMoissenet2019/**/*.osim",
)


def test_every_model_in_the_data_parses(data_root) -> None:
    paths = sorted({p for pattern in MODEL_GLOBS for p in data_root.glob(pattern)})
    assert len(paths) >= 10
    for path in paths:
        spec = osim.read_osim(path)
        frames = {osim.GROUND} | {b.path for b in spec.bodies} | {f.path for f in spec.frames}
        assert len(spec.joints) == len(spec.bodies), path  # one joint per body: a tree
        assert all(j.parent_frame in frames and j.child_frame in frames for j in spec.joints), path
        assert all(m.frame in frames for m in spec.markers), path
        assert {c.name for c in spec.coordinates} == {c for j in spec.joints for c in j.coordinates}
        assert all(len(j.transform) == 6 for j in spec.joints)
        assert spec.gravity == (0.0, -9.80665, 0.0)


def test_rajagopal_spec() -> None:
    spec = osim.read_osim(data_path(RAJAGOPAL))
    assert spec.name == "Rajagopal2016" and spec.version == 40000
    assert (len(spec.bodies), len(spec.joints), len(spec.coordinates), len(spec.markers)) == (22, 22, 39, 66)
    assert spec.body("pelvis").mass == pytest.approx(11.777, abs=1e-3)
    knee = next(j for j in spec.joints if j.name == "walker_knee_r")
    assert knee.type == "CustomJoint" and knee.coordinates == ("knee_angle_r",)
    assert isinstance(knee.transform[1].function, osim.SimmSpline) and len(knee.transform[1].function.x) == 13
    assert knee.parent_frame == "/jointset/walker_knee_r/femur_r_offset"
    frame = next(f for f in spec.frames if f.path == knee.parent_frame)
    assert frame.parent == "/bodyset/femur_r" and frame.orientation == (-1.64157, 1.44618, 1.5708)
    wrist = next(j for j in spec.joints if j.name == "radius_hand_r")
    assert wrist.type == "UniversalJoint" and [t.coordinates for t in wrist.transform[:2]] == [
        ("wrist_flex_r",),
        ("wrist_dev_r",),
    ]
    coordinate = next(c for c in spec.coordinates if c.name == "knee_angle_r_beta")
    assert (coordinate.motion_type, coordinate.clamped, coordinate.range) == ("coupled", False, (-99999.9, 99999.9))
    assert spec.couplers[0].dependent == "knee_angle_r_beta" and spec.couplers[0].independent == ("knee_angle_r",)
    assert spec.markers[0] == osim.MarkerSpec("RACR", "/bodyset/torso", (-0.003, 0.425, 0.13), False)
    assert [m.mesh_file for m in spec.body("pelvis").meshes] == ["r_pelvis.vtp", "l_pelvis.vtp", "sacrum.vtp"]


def test_runner_spec_has_pin_knees_and_welds() -> None:
    spec = osim.read_osim(data_path(RUNNER))
    types = {j.name: j.type for j in spec.joints}
    assert types["knee_r"] == "PinJoint" and types["mtp_r"] == "WeldJoint"
    assert len(spec.coordinates) == 16 and sum(b.mass for b in spec.bodies) == pytest.approx(62.0)
    knee = next(c for c in spec.coordinates if c.name == "knee_angle_r")
    assert knee.range[1] == 0.0 and knee.range[0] == pytest.approx(-2.0943951023931948)


def test_scale_set() -> None:
    scales = osim.read_scale_set(data_path("fukuchi-running/RBDS001/RBDS001_scaleSet_simple.xml"))
    by_name = {s.segment: s.scales for s in scales}
    assert by_name["pelvis"] == (1.0292, 0.966928, 0.889063) and by_name["ground"] == (1.0, 1.0, 1.0)
    assert all(s.apply for s in scales)


@pytest.fixture
def runner_text() -> str:
    return data_path(RUNNER).read_text()


def _write(tmp_path, text: str):
    path = tmp_path / "broken.osim"
    path.write_text(text)
    return path


def test_unsupported_joint_names_file_and_line(tmp_path, runner_text: str) -> None:
    text = runner_text.replace('<PinJoint name="knee_r">', '<EllipsoidJoint name="knee_r">', 1).replace(
        "</PinJoint>", "</EllipsoidJoint>", 1
    )
    line = text[: text.index("<EllipsoidJoint")].count("\n") + 1
    with pytest.raises(ModelError, match=rf"broken.osim:{line}: <EllipsoidJoint name='knee_r'>.*not supported"):
        osim.read_osim(_write(tmp_path, text))


def test_malformed_inputs(tmp_path, runner_text: str) -> None:
    with pytest.raises(DataFormatError, match="not well-formed") as error:
        osim.read_osim(_write(tmp_path, runner_text[:5000]))
    assert error.value.line is not None
    bad_mass = runner_text.replace("<mass>", "<mass>heavy", 1)
    with pytest.raises(DataFormatError, match="mass") as error:
        osim.read_osim(_write(tmp_path, bad_mass))
    assert error.value.field == "mass" and error.value.line > 1
    with pytest.raises(ModelError, match="format version 30000"):
        osim.read_osim(_write(tmp_path, runner_text.replace('Version="40600"', 'Version="30000"', 1)))
    missing = runner_text.replace(
        "<socket_child_frame>tibia_r_offset</socket_child_frame>",
        "<socket_child_frame>shin_offset</socket_child_frame>",
        1,
    )
    with pytest.raises(ModelError, match="'shin_offset' not found"):
        osim.read_osim(_write(tmp_path, missing))
    with pytest.raises(DataFormatError, match="not an OpenSim document"):
        osim.read_osim(_write(tmp_path, "<Model/>"))
    with pytest.raises(DataFormatError, match="no <ScaleSet>"):
        osim.read_scale_set(_write(tmp_path, runner_text))
