"""Motion CSV reader: round trip, and every refusal names the file, line and column."""

import numpy as np
import pytest

from biomotion.errors import DataFormatError
from biomotion.io.csvfile import read_motion_csv, write_motion_csv
from biomotion.motion import Motion


def _written(tmp_path):
    rng = np.random.default_rng(0)
    motion = Motion(times=np.arange(5) / 100.0, names=("hip_flexion_r", "knee_angle_r"), values=rng.normal(size=(5, 2)))
    path = write_motion_csv(tmp_path / "m.csv", motion)
    return motion, path, path.read_text().splitlines()


def test_round_trip(tmp_path):
    motion, path, _ = _written(tmp_path)
    back = read_motion_csv(path)
    assert back.names == motion.names and np.array_equal(back.values, motion.values)


@pytest.mark.parametrize(
    "cell, message",
    [
        ("", "cell is empty"),
        ("nan", "'nan', not a finite number"),
        ("inf", "'inf', not a finite number"),
        ("1.2.3", "not a number"),
    ],
)
def test_bad_cells_name_line_and_column(tmp_path, cell, message):
    _, path, lines = _written(tmp_path)
    cells = lines[3].split(",")
    cells[2] = cell
    lines[3] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=message) as info:
        read_motion_csv(path)
    assert str(info.value).startswith(f"{path}:4: field 'knee_angle_r': ")
    if cell in ("", "nan"):
        assert np.isnan(read_motion_csv(path, allow_gaps=True).values[2, 1])
    else:
        with pytest.raises(DataFormatError):
            read_motion_csv(path, allow_gaps=True)


def test_short_rows_empty_files_and_directories(tmp_path):
    _, path, lines = _written(tmp_path)
    lines[2] = lines[2].rsplit(",", 1)[0]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match="2 cells but 3 columns") as info:
        read_motion_csv(path)
    assert str(info.value).startswith(f"{path}:3: ")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    for bad, message in ((empty, "empty file"), (tmp_path, "is a directory"), (tmp_path / "absent.csv", "no such")):
        with pytest.raises(DataFormatError, match=message) as info:
            read_motion_csv(bad)
        assert str(bad) in str(info.value)
