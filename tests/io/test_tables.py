"""Subject tables: Fukuchi participantInfo.csv, the Motus Subject Log schema (built here), simple tables."""

import pytest

from biomotion.errors import DataFormatError
from biomotion.io.tables import read_subject_table
from biomotion.profile import InjuryRecord
from tests.conftest import data_path


def test_fukuchi_participant_info():
    profiles = read_subject_table(data_path("fukuchi-running/participantInfo.csv"))
    runner = profiles["RBDS001"]
    # participantInfo.csv row 'RBDS001static.c3d': 22 y, 181 cm, 62 kg, M, right dominant, competitive, 4 months
    assert (runner.age, runner.height, runner.mass, runner.sex) == (22, 1.81, 62, "M")
    assert runner.dominance == "R" and runner.level == "competitive" and runner.sport == "running"
    assert runner.experience_years == pytest.approx(4 / 12)
    assert runner.injuries == (InjuryRecord("Right knee", "Bony edema in the femoral condyles", "3/15/2015"),)
    assert profiles["RBDS019"].sex == "F"  # the only woman (SOURCE.md)
    folders = {p.name for p in data_path("fukuchi-running").iterdir() if p.name.startswith("RBDS")}
    assert folders <= set(profiles)


def test_simple_tables():
    schreiber = read_subject_table(data_path("SchreiberMoissenet2019/subjects.csv"))
    assert len(schreiber) == 18
    assert all(1.5 < p.height < 1.95 and 45 < p.mass < 95 for p in schreiber.values())
    hamner = read_subject_table(data_path("Hamner2013/subjects.csv"))
    assert hamner["subject01"].mass == pytest.approx(72.84) and hamner["subject01"].age is None


def test_motus_subject_log_schema_xlsx(tmp_path):
    openpyxl = pytest.importorskip("openpyxl")
    book = openpyxl.Workbook()
    sheet = book.active
    sheet.append(
        [
            "Subject ID",
            "Age",
            "Gender",
            "Height (cm)",
            "Mass (kg)",
            "Level",
            "Sport",
            "Injury 1",
            "Injury 2",
            "Injury 3",
            "Injury 4",
            "Injury 5",
        ]
    )
    sheet.append(
        [1424, 17, "F", 165.5, 58.2, "Varsity", "Soccer", "ACL tear left knee", "Ankle sprain", None, None, None]
    )
    sheet.append([38, 24, "Male", 182, 80, "Professional", "Hockey", None, None, None, None, None])
    path = tmp_path / "Subject Log.xlsx"
    book.save(path)
    profiles = read_subject_table(path)
    athlete = profiles["1424"]
    assert athlete.height == pytest.approx(1.655) and athlete.sex == "F" and athlete.sport == "soccer"
    assert [i.location for i in athlete.injuries] == ["ACL tear left knee", "Ankle sprain"]
    assert profiles["38"].sex == "M" and profiles["38"].injuries == ()


def test_bad_tables(tmp_path):
    unknown = tmp_path / "u.csv"
    unknown.write_text("a,b\n1,2\n")
    with pytest.raises(DataFormatError, match="unknown subject-table schema"):
        read_subject_table(unknown)
    bad = tmp_path / "bad.csv"
    bad.write_text("subject_id,sex,age_years,height_m,mass_kg\ns1,M,30,1.8,seventy\n")
    with pytest.raises(DataFormatError, match="mass_kg") as info:
        read_subject_table(bad)
    assert ":2:" in str(info.value)
    implausible = tmp_path / "cm.csv"
    implausible.write_text("subject_id,sex,age_years,height_m,mass_kg\ns1,M,30,180,70\n")
    with pytest.raises(DataFormatError, match="height"):
        read_subject_table(implausible)


def test_ansur_and_schreiber_source_tables():
    """anthropometry/SOURCE.md: 4082 men and 1986 women; mean stature 1756 / 1629 mm, mass 85.5 / 67.8 kg."""
    import numpy as np

    for name, count, stature, mass in (("MALE", 4082, 1.756, 85.5), ("FEMALE", 1986, 1.629, 67.8)):
        profiles = read_subject_table(data_path(f"anthropometry/ANSUR_II_{name}_Public.csv"))
        assert len(profiles) == count
        assert np.mean([p.height for p in profiles.values()]) == pytest.approx(stature, abs=0.002)
        assert np.mean([p.mass for p in profiles.values()]) == pytest.approx(mass, abs=0.1)
        assert "trochanterionheight" in next(iter(profiles.values())).extra
    source = read_subject_table(data_path("SchreiberMoissenet2019/anthropometrics_source.csv"))
    assert len(source) == 50 and source["2014001"].height == pytest.approx(1.66)
    assert {p.sex for p in source.values()} == {"M", "F"}  # 'W' in the source means a woman


def test_rows_of_another_width_missing_files_and_directories_are_refused(tmp_path):
    """A cell left out of a row would move every later value under the wrong column: refused, naming the line
    (blank lines counted, as an editor counts them)."""
    table = tmp_path / "people.csv"
    table.write_text("subject_id,sex,age_years,height_m,mass_kg\ns1,F,52,1.68,61\n\ns2,M,1.80,75\n")
    with pytest.raises(DataFormatError, match="4 cells but 5 column names") as info:
        read_subject_table(table)
    assert str(info.value).startswith(f"{table}:4: ")
    for bad, message in ((tmp_path, "is a directory"), (tmp_path / "absent.csv", "no such file")):
        with pytest.raises(DataFormatError, match=message) as info:
            read_subject_table(bad)
        assert str(info.value).startswith(f"{bad}: ")
    empty = tmp_path / "empty.csv"
    empty.write_text("\n")
    with pytest.raises(DataFormatError, match="empty table"):
        read_subject_table(empty)
    from biomotion.io.formats import describe

    table.write_text("subject_id,sex,age_years,height_m,mass_kg\ns1,F,52,1.68,61\ns2,M,1.80,75\n")
    with pytest.raises(DataFormatError, match="4 cells but 5 column names") as info:
        describe(table)  # still recognised as a subject table, and the row named
    assert str(info.value).startswith(f"{table}:3: ")
