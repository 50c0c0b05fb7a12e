"""TRC reader and writer: every real TRC, units, gaps, OpenSim reading our output, corrupted files."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from biomotion.errors import DataFormatError
from biomotion.io.trc import read_trc, write_trc
from biomotion.motion import Markers
from tests.conftest import DATA_ROOT, data_path


def test_every_trc_in_the_data_reads_in_metres(data_root):
    files = sorted(DATA_ROOT.glob("**/*.trc"))
    assert len(files) >= 30
    for path in files:
        markers = read_trc(path)
        heights = markers.positions[..., 1]
        assert np.nanmax(heights) < 2.2 and np.nanmin(heights) > -0.2, path  # y up, metres
        assert markers.rate in (pytest.approx(60.0, rel=1e-3), pytest.approx(100.0, rel=1e-3)), (
            path
        )  # times rounded to 1 ms


def test_mm_file_and_trailing_tab_rows():
    markers = read_trc(data_path("opensim-models/Pipelines/Gait2392_Simbody/subject01_walk1.trc"))
    assert markers.n_frames == 151 and len(markers.names) == 41 and markers.rate == pytest.approx(60.0)
    assert np.isfinite(markers.positions).all()
    walk = read_trc(data_path("opensim-models/Pipelines/Rajagopal/ExpData/motion_capture_walk.trc"))
    asis = walk["R.ASIS"][:, 0]
    assert asis[0] == pytest.approx(-0.567, abs=2e-3) and asis[-1] == pytest.approx(2.407, abs=2e-3)


def test_gaps_are_nan():
    markers = read_trc(data_path("opencap/Subject4/MarkerData/walking1.trc"))
    missing = markers.occluded().mean()
    assert 0.005 < missing < 0.05  # SOURCE.md: walking trials ~2 % NaN samples


def test_opensim_reads_what_we_write(tmp_path):
    osim = pytest.importorskip("opensim")
    markers = read_trc(data_path("opencap/Subject4/MarkerData/walking1.trc"))
    path = write_trc(tmp_path / "walk.trc", markers, units="mm")
    table = osim.TimeSeriesTableVec3(str(path))
    assert list(table.getColumnLabels()) == list(markers.names)
    assert table.getNumRows() == markers.n_frames
    row = table.getRowAtIndex(10)
    first = row[0]
    np.testing.assert_allclose(
        [first.get(0), first.get(1), first.get(2)], markers.positions[10, 0] * 1000.0, rtol=1e-12
    )
    back = read_trc(path)
    np.testing.assert_allclose(back.positions, markers.positions, rtol=1e-12, atol=1e-15)
    assert np.array_equal(np.isnan(back.positions), np.isnan(markers.positions))


def test_errors(tmp_path):
    lines = data_path("opencap/Subject4/MarkerData/DJ1.trc").read_text().splitlines()
    bad_units = lines[:2] + [lines[2].replace("\tm\t", "\tinch\t")] + lines[3:]
    too_many = lines[:8] + [lines[8] + "\t1\t2\t3\t4"] + lines[9:]
    cases = {
        "units": (bad_units, "unknown units"),
        "truncated": (lines[:20], "truncated"),
        "width": (too_many, "fields"),
        "header": (["hello"] * 6, "PathFileType"),
    }
    for name, (content, message) in cases.items():
        path = tmp_path / f"{name}.trc"
        path.write_text("\n".join(content))
        with pytest.raises(DataFormatError, match=message) as info:
            read_trc(path)
        assert str(path) in str(info.value)
    assert ":9:" in str(pytest.raises(DataFormatError, read_trc, tmp_path / "width.trc").value)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    frames=st.integers(1, 15),
    count=st.integers(1, 4),
    units=st.sampled_from(["m", "mm", "cm"]),
    seed=st.integers(0, 2**16),
)
def test_property_round_trip(tmp_path, frames, count, units, seed):
    rng = np.random.default_rng(seed)
    positions = rng.normal(size=(frames, count, 3))
    positions[rng.random(size=(frames, count)) < 0.2] = np.nan
    markers = Markers(times=np.arange(frames) / 50.0, names=tuple(f"M{i}" for i in range(count)), positions=positions)
    back = read_trc(write_trc(tmp_path / "p.trc", markers, units=units, rate=50.0))
    np.testing.assert_allclose(back.positions, positions, rtol=1e-12, atol=1e-15)


def test_empty_fields_read_as_gaps_and_bad_tokens_name_their_line(tmp_path):
    """Empty fields (gaps) take the field-by-field path and must read the same numbers as full rows, trailing
    empty fields beyond the markers are ignored, and a bad token is named with its line."""
    source = data_path("opencap/Subject4/MarkerData/DJ1.trc")
    full = read_trc(source)
    lines = source.read_text().splitlines()
    empty = lines[:7] + [lines[7].replace("\t" + lines[7].split("\t")[2] + "\t", "\t\t", 1)] + lines[8:]
    blank_last = lines[:6] + ["\t".join(lines[6].split("\t")[:-3] + ["", "", "", ""])] + lines[7:]
    for name, content, frame, marker in (("empty", empty, 1, 0), ("blank_last", blank_last, 0, -1)):
        path = tmp_path / f"{name}.trc"
        path.write_text("\n".join(content))
        markers = read_trc(path)
        expected = full.positions.copy()
        expected[frame, marker, 0 if name == "empty" else slice(None)] = np.nan
        np.testing.assert_array_equal(markers.positions, expected)
    bad = lines[:9] + ["\t".join(lines[9].split("\t")[:2] + ["1.0x"] + lines[9].split("\t")[3:])] + lines[10:]
    path = tmp_path / "bad.trc"
    path.write_text("\n".join(bad))
    with pytest.raises(DataFormatError, match="not a number: '1.0x'") as info:
        read_trc(path)
    assert ":10:" in str(info.value)


@pytest.mark.parametrize("cut", ["first", "middle", "last_marker"])
def test_a_short_row_is_refused_not_shifted(tmp_path, cut):
    """A row with a value left out (not left empty) would put every later value under the wrong marker: refused,
    naming the file, the line and the expected and found field counts."""
    source = data_path("opencap/Subject4/MarkerData/DJ1.trc")
    lines = source.read_text().splitlines()
    fields = lines[8].split("\t")
    width = len(fields)
    if cut == "first":
        del fields[2]
    elif cut == "middle":
        del fields[width // 2]
    else:
        fields = fields[:-3]  # a whole trailing marker left out, tabs and all
    path = tmp_path / "short.trc"
    path.write_text("\n".join(lines[:8] + ["\t".join(fields)] + lines[9:]))
    with pytest.raises(DataFormatError, match=f"{len(fields)} fields, expected {width}") as info:
        read_trc(path)
    assert str(info.value).startswith(f"{path}:9: ") and "wrong columns" in str(info.value)
    assert info.value.line == 9


def test_infinite_values_empty_files_and_directories_are_refused(tmp_path):
    source = data_path("opencap/Subject4/MarkerData/DJ1.trc")
    lines = source.read_text().splitlines()
    names = [n for n in lines[3].split("\t")[2:] if n.strip()]
    fields = lines[10].split("\t")
    fields[2 + 3 + 1] = "inf"  # second marker, Y
    path = tmp_path / "inf.trc"
    path.write_text("\n".join(lines[:10] + ["\t".join(fields)] + lines[11:]))
    with pytest.raises(DataFormatError, match="infinite value") as info:
        read_trc(path)
    assert info.value.line == 11 and info.value.field == f"{names[1]}.Y"
    assert str(info.value).startswith(f"{path}:11: field '{names[1]}.Y': ")
    empty = tmp_path / "empty.trc"
    empty.write_text("")
    with pytest.raises(DataFormatError, match="empty file") as info:
        read_trc(empty)
    assert str(empty) in str(info.value)
    with pytest.raises(DataFormatError, match="is a directory") as info:
        read_trc(tmp_path)
    assert str(tmp_path) in str(info.value)
    with pytest.raises(DataFormatError, match="no such file"):
        read_trc(tmp_path / "missing.trc")


def test_time_range_parses_only_the_window(tmp_path):
    """A window read equals the whole file sliced the same way (OpenSim's inclusive ``time_range``), whatever the
    rows outside it hold; a window with no frame names the field."""
    rng = np.random.default_rng(3)
    times = np.arange(40) / 100.0
    markers = Markers(times=times, names=("a", "b"), positions=rng.normal(size=(40, 2, 3)))
    path = write_trc(tmp_path / "w.trc", markers)
    window = read_trc(path, (0.1, 0.25))
    whole = read_trc(path).slice(0.1, 0.25)
    assert window.n_frames == 16 and np.array_equal(window.times, whole.times)
    np.testing.assert_array_equal(window.positions, whole.positions)
    lines = path.read_text().splitlines()
    lines[5 + 35] = lines[5 + 35].replace(lines[5 + 35].split("\t")[3], "oops")  # a bad token outside the window
    path.write_text("\n".join(lines) + "\n")
    assert read_trc(path, (0.1, 0.25)).n_frames == 16
    with pytest.raises(DataFormatError, match="not a number"):
        read_trc(path)
    with pytest.raises(DataFormatError, match="no frame within time range") as error:
        read_trc(path, (1.0, 2.0))
    assert error.value.field == "time_range"
    lines[5 + 20] = "21\t0.3\t" + "\t".join(lines[5 + 20].split("\t")[2:])  # time goes back: still found
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match="time does not increase"):
        read_trc(path, (0.0, 0.05))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=st.integers(1, 8), count=st.integers(1, 4), row=st.integers(0, 10**6), column=st.integers(0, 10**6))
def test_property_a_deleted_field_never_reads_silently(tmp_path, frames, count, row, column):
    """Deleting any one field of any data row (gap or not) is refused: it can never read as a shifted frame."""
    rng = np.random.default_rng(frames * 31 + count)
    positions = rng.normal(size=(frames, count, 3))
    positions[rng.random(size=(frames, count)) < 0.3] = np.nan
    markers = Markers(times=np.arange(frames) / 50.0, names=tuple(f"M{i}" for i in range(count)), positions=positions)
    lines = write_trc(tmp_path / "p.trc", markers, rate=50.0).read_text().splitlines()
    line = 6 + row % frames
    fields = lines[line].split("\t")
    del fields[column % len(fields)]
    lines[line] = "\t".join(fields)
    (tmp_path / "p.trc").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError) as info:
        read_trc(tmp_path / "p.trc")
    assert info.value.line == line + 1


def test_a_row_that_lost_a_value_is_refused_even_with_a_trailing_tab(tmp_path):
    """subject01_walk1.trc ends every row with a tab: a row that lost a value still holds 2 + 3 x markers fields,
    its last one empty, which read as a gap would shift every later value into the wrong marker (bad-input corpus
    case trc-row-missing-value). A whole marker left empty stays a gap."""
    lines = data_path("opensim-models/Pipelines/Gait2392_Simbody/subject01_walk1.trc").read_text().splitlines()
    fields = lines[16].split("\t")
    assert fields[-1] == ""  # the trailing tab
    lost = tmp_path / "lost.trc"
    lost.write_text("\n".join(lines[:16] + ["\t".join(fields[:7] + fields[8:])] + lines[17:]) + "\n")
    with pytest.raises(DataFormatError, match=r"lost\.trc:17: 125 fields where the other rows have 126"):
        read_trc(lost)
    gap = tmp_path / "gap.trc"
    gap.write_text("\n".join(lines[:16] + ["\t".join(fields[:5] + ["", "", ""] + fields[8:])] + lines[17:]) + "\n")
    assert np.isnan(read_trc(gap).positions[10, 1]).all()


def test_a_data_rate_far_from_the_time_column_is_refused(tmp_path):
    """DataRate is checked against the Time column: 2 % apart is a real file's rounding (subject01_walk1.trc: 60 Hz,
    steps of 0.017 s), a header saying 200 Hz for 60 Hz rows belongs to another file."""
    source = data_path("opensim-models/Pipelines/Gait2392_Simbody/subject01_walk1.trc")
    assert read_trc(source).n_frames == 151
    lines = source.read_text().splitlines()
    lines[2] = lines[2].replace("60.00", "200.00", 1)
    path = tmp_path / "clock.trc"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=r"clock\.trc:3: field 'DataRate': DataRate says 200 Hz"):
        read_trc(path)
    with pytest.raises(DataFormatError, match="DataRate says 200 Hz"):
        read_trc(path, time_range=(0.5, 1.0))
