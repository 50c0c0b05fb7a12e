"""Studies as values: the three folder layouts, TOML configs, plate overrides and marker maps."""

import numpy as np
import pytest

from biomotion.analysis.study import (
    FUKUCHI_LOCKED,
    closest_names,
    detect_layout,
    load_study,
    parse_marker_map,
    parse_plates,
    plate_bodies,
)
from biomotion.errors import ConfigError
from biomotion.io.c3d_writer import write_c3d
from biomotion.motion import Markers
from tests.conftest import data_path


def test_fukuchi_layout_finds_every_runner_trial_setup_and_mass():
    study = load_study(data_path("fukuchi-running"))
    assert study.layout == "fukuchi" and len(study.subjects) == 23 and study.n_trials == 69
    runner = next(s for s in study.subjects if s.name == "RBDS001")
    assert runner.static.name == "RBDS001static.c3d"
    assert runner.model.name == "Denton2023_LowerLimb_Fukuchi2017.osim"  # the model its scale setup names
    assert runner.scale_setup.name == "RBDS001_scaleSetup_simple.xml"
    assert (runner.mass, runner.height) == (62.0, 1.81)  # participantInfo.csv
    assert {t.name: t.setup.name for t in runner.trials} == {
        "runT25": "RBDS001_T25_ikSetup.xml",
        "runT35": "RBDS001_T35_ikSetup.xml",
        "runT45": "RBDS001_T45_ikSetup.xml",
    }
    # RBDS010's trials are not RBDS01's (mixed zero padding): no subject owns another's files
    names = {(s.name, t.name) for s in study.subjects for t in s.trials}
    assert all(not t[0].isdigit() for _, t in names)
    # the source's processing chain: 10 Hz marker low-pass, mtp and subtalar welded
    assert study.settings.marker_filter_hz == 10.0 and study.settings.locked == FUKUCHI_LOCKED


def test_opencap_layout_pairs_markers_forces_and_setups():
    study = load_study(data_path("opencap"))
    assert study.layout == "opencap"
    (subject,) = study.subjects
    assert subject.static.name == "static1.trc" and len(subject.trials) == 23
    assert subject.scale_setup.name == "rescaling_setup.xml" and subject.mass == pytest.approx(62.6)
    walk = next(t for t in subject.trials if t.name == "walking1")
    assert walk.forces.name == "walking1_grf.mot" and walk.setup.name == "walking1_ik_setup.xml"


def _motus_folder(root, openpyxl):
    """The Motus layout of movement-screen-183/SOURCE.md, built from its schema: two athletes, C3D trials."""
    book = openpyxl.Workbook()
    sheet = book.active
    sheet.append(
        ["Subject ID", "Age", "Gender", "Height (cm)", "Mass (kg)", "Level", "Sport"]
        + [f"Injury {i}" for i in range(1, 6)]
    )
    sheet.append([1424, 17, "F", 165.5, 58.2, "Varsity", "Soccer", None, None, None, None, None])
    sheet.append([38, 21, "M", 180.0, 77.0, "Varsity", "Hockey", None, None, None, None, None])
    info = root / "Participants Info" / "Participants Info"  # some zips unpack one folder deeper
    info.mkdir(parents=True)
    book.save(info / "Subject Log.xlsx")
    markers = Markers(times=np.arange(5) / 120.0, names=("LHEE", "RHEE"), positions=np.ones((5, 2, 3)))
    for ppid, trials in (("1424", ("Calib1", "DJ1", "HDL1")), ("38", ("Calib1", "scorpion2"))):
        folder = root / "Kinematic_Data" / ppid / "Generated_C3D_files"
        folder.mkdir(parents=True)
        for trial in trials:
            write_c3d(folder / f"{trial}.c3d", markers)
    return root


def test_motus_layout_from_its_documented_schema(tmp_path):
    openpyxl = pytest.importorskip("openpyxl")
    root = _motus_folder(tmp_path / "motus", openpyxl)
    assert detect_layout(root) == "motus"
    with pytest.raises(ConfigError, match="holds no model"):
        load_study(root)
    model = data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")
    study = load_study(root, model=model)
    assert [s.name for s in study.subjects] == ["38", "1424"]
    athlete = study.subjects[1]
    assert athlete.static.name == "Calib1.c3d" and [t.name for t in athlete.trials] == ["DJ1", "HDL1"]
    assert (athlete.mass, athlete.height) == (58.2, pytest.approx(1.655))


def test_config_names_everything_and_refuses_unknown_keys(tmp_path):
    gait = data_path("opensim-models/Pipelines/Gait2392_Simbody")
    config = tmp_path / "study.toml"
    config.write_text(
        f"""
[study]
name = "walks"
forces = "measured"
plates = {{ 1 = "right", 2 = "left", 3 = "none" }}
marker_map = {{ "RASI" = "R.ASIS" }}

[[subject]]
name = "s01"
model = "{gait}/OutputReference/subject01_simbody.osim"
[[subject.trial]]
markers = "{gait}/subject01_walk1.trc"
forces = "{gait}/subject01_walk1_grf.mot"
time_range = [0.5, 1.5]
plates = "1=left"
"""
    )
    study = load_study(config)
    assert study.layout == "config" and study.name == "walks"
    (trial,) = study.subjects[0].trials
    assert trial.name == "subject01_walk1" and trial.time_range == (0.5, 1.5)
    assert trial.plates == (("1", "calcn_l"),)
    assert study.settings.plates == (("1", "calcn_r"), ("2", "calcn_l"), ("3", None))
    assert study.settings.marker_map == (("RASI", "R.ASIS"),)
    config.write_text(config.read_text().replace('forces = "measured"', 'froces = "measured"'))
    with pytest.raises(ConfigError, match="did you mean 'forces'"):
        load_study(config)


def test_plate_override_matches_numbers_and_names():
    plates = parse_plates("1=right, 2=left,3=none")
    assert plates == (("1", "calcn_r"), ("2", "calcn_l"), ("3", None))
    names = ("ground_force_1", "ground_force_2", "ground_force_3")
    assert plate_bodies(names, plates) == {
        "ground_force_1": "calcn_r",
        "ground_force_2": "calcn_l",
        "ground_force_3": None,
    }
    assert plate_bodies(("1",), parse_plates({1: "toes_r"})) == {"1": "toes_r"}
    with pytest.raises(ConfigError, match="trial's plates are"):
        plate_bodies(("1", "2"), parse_plates("4=right"))
    with pytest.raises(ConfigError, match="CHANNEL=SIDE"):
        parse_plates("1:right")


def test_marker_maps_and_closest_names(tmp_path):
    assert parse_marker_map("RASI=R.ASIS, LASI=L.ASIS") == (("RASI", "R.ASIS"), ("LASI", "L.ASIS"))
    table = tmp_path / "map.csv"
    table.write_text("data,model\nRASI,R.ASIS\n# a comment\nLASI,L.ASIS\n")
    assert parse_marker_map(table) == (("RASI", "R.ASIS"), ("LASI", "L.ASIS"))
    hints = closest_names(["RASIS", "L_ASIS", "XYZ"], ["R.ASIS", "L.ASIS", "R.PSIS"])
    assert hints["RASIS"][0] == "R.ASIS" and hints["L_ASIS"][0] == "L.ASIS" and hints["XYZ"] == []
