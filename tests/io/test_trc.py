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
        assert markers.rate in (pytest.approx(60.0, rel=1e-3), pytest.approx(100.0, rel=1e-3)), path  # times rounded to 1 ms


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
    np.testing.assert_allclose([first.get(0), first.get(1), first.get(2)],
                               markers.positions[10, 0] * 1000.0, rtol=1e-12)
    back = read_trc(path)
    np.testing.assert_allclose(back.positions, markers.positions, rtol=1e-12, atol=1e-15)
    assert np.array_equal(np.isnan(back.positions), np.isnan(markers.positions))


def test_errors(tmp_path):
    lines = data_path("opencap/Subject4/MarkerData/DJ1.trc").read_text().splitlines()
    bad_units = lines[:2] + [lines[2].replace("\tm\t", "\tinch\t")] + lines[3:]
    too_many = lines[:8] + [lines[8] + "\t1\t2\t3\t4"] + lines[9:]
    cases = {"units": (bad_units, "unknown units"), "truncated": (lines[:20], "truncated"),
             "width": (too_many, "fields"), "header": (["hello"] * 6, "PathFileType")}
    for name, (content, message) in cases.items():
        path = tmp_path / f"{name}.trc"
        path.write_text("\n".join(content))
        with pytest.raises(DataFormatError, match=message) as info:
            read_trc(path)
        assert str(path) in str(info.value)
    assert ":9:" in str(pytest.raises(DataFormatError, read_trc, tmp_path / "width.trc").value)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=st.integers(1, 15), count=st.integers(1, 4), units=st.sampled_from(["m", "mm", "cm"]),
       seed=st.integers(0, 2**16))
def test_property_round_trip(tmp_path, frames, count, units, seed):
    rng = np.random.default_rng(seed)
    positions = rng.normal(size=(frames, count, 3))
    positions[rng.random(size=(frames, count)) < 0.2] = np.nan
    markers = Markers(times=np.arange(frames) / 50.0, names=tuple(f"M{i}" for i in range(count)),
                      positions=positions)
    back = read_trc(write_trc(tmp_path / "p.trc", markers, units=units, rate=50.0))
    np.testing.assert_allclose(back.positions, positions, rtol=1e-12, atol=1e-15)


def test_short_rows_empty_fields_and_bad_tokens(tmp_path):
    """Rows may leave trailing markers out or fields empty (gaps); such files take the field-by-field path and
    must read the same numbers as full rows, and a bad token is named with its line."""
    source = data_path("opencap/Subject4/MarkerData/DJ1.trc")
    full = read_trc(source)
    lines = source.read_text().splitlines()
    short = lines[:6] + ["\t".join(lines[6].split("\t")[:-3])] + lines[7:]   # frame 1 without its last marker
    empty = lines[:7] + [lines[7].replace("\t" + lines[7].split("\t")[2] + "\t", "\t\t", 1)] + lines[8:]
    for name, content, frame, marker in (("short", short, 0, -1), ("empty", empty, 1, 0)):
        path = tmp_path / f"{name}.trc"
        path.write_text("\n".join(content))
        markers = read_trc(path)
        assert np.isnan(markers.positions[frame, marker, 0])
        expected = full.positions.copy()
        expected[frame, marker, 0 if name == "empty" else slice(None)] = np.nan
        np.testing.assert_array_equal(markers.positions, expected)
    bad = lines[:9] + ["\t".join(lines[9].split("\t")[:2] + ["1.0x"] + lines[9].split("\t")[3:])] + lines[10:]
    path = tmp_path / "bad.trc"
    path.write_text("\n".join(bad))
    with pytest.raises(DataFormatError, match="not a number: '1.0x'") as info:
        read_trc(path)
    assert ":10:" in str(info.value)


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
    lines[5 + 35] = lines[5 + 35].replace(lines[5 + 35].split("\t")[3], "oops")   # a bad token outside the window
    path.write_text("\n".join(lines) + "\n")
    assert read_trc(path, (0.1, 0.25)).n_frames == 16
    with pytest.raises(DataFormatError, match="not a number"):
        read_trc(path)
    with pytest.raises(DataFormatError, match="no frame within time range") as error:
        read_trc(path, (1.0, 2.0))
    assert error.value.field == "time_range"
    lines[5 + 20] = "21\t0.3\t" + "\t".join(lines[5 + 20].split("\t")[2:])             # time goes back: still found
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match="time does not increase"):
        read_trc(path, (0.0, 0.05))
