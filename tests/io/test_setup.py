"""OpenSim IK and Scale setup files: the shipped gait2392, OpenCap and Fukuchi setups, path quirks, bad files."""

from __future__ import annotations

import pytest

from biomotion.errors import DataFormatError
from biomotion.io.setup import CoordinateTask, locate, read_ik_setup, read_scale_setup
from tests.conftest import data_path

GAIT_SETUP = "opensim-models/Pipelines/Gait2392_Simbody/subject01_Setup_IK.xml"


def test_gait2392_ik_setup_weights_tasks_and_time_range():
    setup = read_ik_setup(data_path(GAIT_SETUP))
    assert setup.time_range == (0.5, 2.5)
    assert len(setup.marker_weights) == 31
    assert setup.marker_weights["R.ASIS"] == 10 and setup.marker_weights["Top.Head"] == 0.1
    assert setup.coordinate_tasks == tuple(
        CoordinateTask(n, 1000.0, "default_value", 0.0)
        for n in ("subtalar_angle_r", "mtp_angle_r", "subtalar_angle_l", "mtp_angle_l")
    )
    assert setup.constraint_weight == 20 and setup.accuracy == 1e-5
    assert setup.file("marker_file").name == "subject01_walk1.trc"
    assert setup.file("model_file") is None  # subject01_simbody.osim lives only under OutputReference/


def test_opencap_setup_paths_resolve_despite_mixed_bases():
    setup = read_ik_setup(data_path("opencap/Subject4/IK/walking1_ik_setup.xml"))
    assert setup.time_range is None
    assert setup.file("model_file").name == "optimized_scale_and_markers.osim"  # relative to Subject4/
    assert setup.file("marker_file").name == "walking1.trc"  # relative to IK/
    assert len(setup.marker_weights) == 49 and set(setup.marker_weights.values()) == {1.0}


def test_fukuchi_scale_setup_measurements_and_placer_tasks():
    setup = read_scale_setup(data_path("fukuchi-running/RBDS001/RBDS001_scaleSetup_simple.xml"))
    assert setup.mass == 62 and setup.preserve_mass_distribution and setup.scaling_order == ("measurements",)
    pelvis_h = next(m for m in setup.measurements if m.name == "pelvis_h")
    assert len(pelvis_h.pairs) == 6 and pelvis_h.pairs[0] == ("R.ASIS", "R.GTR")
    assert pelvis_h.bodies == (("pelvis", "Y"),)
    breadth = next(m for m in setup.measurements if m.name == "r_thigh_breadth")
    assert breadth.bodies == (("femur_r", "XZ"),)
    weights = setup.placer_tasks.marker_weights
    assert weights["R.ASIS"] == 10 and weights["R.MT2"] == 2.5
    assert "R.Thigh.Top.Lateral" not in weights  # <apply>false</apply>: not tracked
    assert len(setup.placer_tasks.coordinate_tasks) == 13
    assert setup.placer_time_range == (0.0, 0.993333) and setup.placer_apply and setup.scaler_apply


def test_setup_without_placer_skips_placement():
    setup = read_scale_setup(data_path("opencap/Subject4/Models/rescaling_setup.xml"))
    assert not setup.placer_apply and setup.scaling_order == ("manualScale",)
    assert len(setup.manual_scales) > 10 and setup.manual_scales[0].segment == "pelvis"
    assert setup.file("model_file").name == "unscaled_but_with_optimized_markers.osim"


def test_task_set_in_another_file(tmp_path):
    (tmp_path / "tasks.xml").write_text(
        '<OpenSimDocument Version="40000"><IKTaskSet><objects>'
        '<IKMarkerTask name="A"><weight>3</weight></IKMarkerTask>'
        '<IKCoordinateTask name="knee"><weight>2</weight><value_type>manual_value</value_type><value>0.5</value>'
        "</IKCoordinateTask></objects></IKTaskSet></OpenSimDocument>"
    )
    (tmp_path / "setup.xml").write_text(
        '<OpenSimDocument Version="40000"><InverseKinematicsTool><IKTaskSet file="tasks.xml"/>'
        "<time_range>0 1</time_range></InverseKinematicsTool></OpenSimDocument>"
    )
    setup = read_ik_setup(tmp_path / "setup.xml")
    assert setup.marker_weights == {"A": 3.0}
    assert setup.coordinate_tasks == (CoordinateTask("knee", 2.0, "manual_value", 0.5),)


@pytest.mark.parametrize(
    "body, line, field",
    [
        (
            "<IKTaskSet><objects><IKMarkerTask name='A'>\n<weight>heavy</weight></IKMarkerTask></objects></IKTaskSet>",
            2,
            "weight",
        ),
        (
            "<IKTaskSet><objects>\n<IKMarkerTask name='A'><weight>-1</weight></IKMarkerTask></objects></IKTaskSet>",
            2,
            "weight",
        ),
        ("\n<time_range>2 1</time_range>", 2, "time_range"),
    ],
)
def test_bad_setup_names_line_and_field(tmp_path, body, line, field):
    path = tmp_path / "bad.xml"
    path.write_text(
        f"<OpenSimDocument Version='40000'><InverseKinematicsTool>{body}</InverseKinematicsTool></OpenSimDocument>"
    )
    with pytest.raises(DataFormatError) as error:
        read_ik_setup(path)
    assert error.value.line == line and error.value.field == field and error.value.path == path


def test_not_an_ik_setup(tmp_path):
    path = tmp_path / "scale.xml"
    path.write_text("<OpenSimDocument Version='40000'><ScaleTool/></OpenSimDocument>")
    with pytest.raises(DataFormatError, match="InverseKinematicsTool"):
        read_ik_setup(path)
    path.write_text("<OpenSimDocument><unclosed></OpenSimDocument>")
    with pytest.raises(DataFormatError, match="not well-formed") as error:
        read_ik_setup(path)
    assert error.value.line == 1


def test_locate_windows_separators_and_unassigned(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "m.trc").write_text("x")
    setup = tmp_path / "setup.xml"
    assert locate("sub\\m.trc", setup) == (tmp_path / "sub" / "m.trc").resolve()
    assert locate("Unassigned", setup) is None and locate("missing.trc", setup) is None


@pytest.mark.parametrize(
    "edit, message",
    [
        (("<weight>1</weight>", "<weight>nan</weight>"), "<weight> is NaN"),
        (("<weight>1</weight>", "<weight>inf</weight>"), "weight inf: a weight is a finite number >= 0"),
        (("<time_range> 0.5 2.5</time_range>", "<time_range> 0.5 nan</time_range>"), "<time_range> holds NaN"),
    ],
)
def test_a_nan_or_infinite_setting_is_refused_with_its_line(tmp_path, edit, message):
    """NaN compares false with everything, so a NaN weight passed the negative-weight check and weighed a marker
    by NaN (bad-input corpus case ik-setup-nan-weight)."""
    text = data_path(GAIT_SETUP).read_text()
    assert edit[0] in text
    path = tmp_path / "setup.xml"
    path.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(DataFormatError, match=r"setup\.xml:\d+: ") as info:
        read_ik_setup(path)
    assert message in str(info.value)
