"""C3D writer: files that ezc3d (an independent C3D implementation) and our reader read back exactly, real and
synthetic, including after OpenSim has run in the process."""

import dataclasses

import ezc3d
import numpy as np
import pytest

from biomotion.errors import ConfigError
from biomotion.io.c3d import read_c3d_markers
from biomotion.io.c3d_writer import write_c3d
from biomotion.motion import Markers
from tests.conftest import data_path


def _running_trial() -> Markers:
    files = sorted(data_path("fukuchi-running/c3d").glob("*runT35.c3d"))
    if not files:
        pytest.skip("no Fukuchi *runT35.c3d under fukuchi-running/c3d")
    return read_c3d_markers(files[0])


def test_a_cropped_trial_with_a_gap_reads_back_on_its_clock(tmp_path):
    """A Fukuchi running trial (150 Hz) cropped to start at frame 31, one marker occluded for 11 frames: same labels,
    same times, positions within float32 storage (1e-6 m), the gap as a gap; ezc3d sees the standard's invalid
    points (residual -1) exactly there, and the header's 1-based first and last frame."""
    source = _running_trial()
    cropped = source.slice(source.times[30], source.times[329])
    positions = cropped.positions.copy()
    positions[10:21, 3] = np.nan
    cropped = dataclasses.replace(cropped, positions=positions)
    path = write_c3d(tmp_path / "cropped.c3d", cropped)
    back = read_c3d_markers(path)
    assert back.names == cropped.names and back.n_frames == 300
    np.testing.assert_allclose(back.times, cropped.times, atol=1e-9)
    np.testing.assert_array_equal(np.isnan(back.positions), np.isnan(positions))
    np.testing.assert_allclose(back.positions, positions, atol=1e-6, equal_nan=True)
    raw = ezc3d.c3d(str(path))
    invalid = np.asarray(raw["data"]["meta_points"]["residuals"])[0].T < 0  # [T, M]
    np.testing.assert_array_equal(invalid, np.isnan(positions).any(axis=-1))
    assert (raw["header"]["points"]["first_frame"], raw["header"]["points"]["last_frame"]) == (30, 329)
    assert raw["parameters"]["POINT"]["UNITS"]["value"] == ["mm"]
    assert float(raw["parameters"]["POINT"]["RATE"]["value"][0]) == pytest.approx(150.0)


def test_the_writer_works_after_opensim_has_run(tmp_path):
    """Once an OpenSim function has taken a std::vector<int> (as the body-model oracle tests' spline derivatives
    do), ezc3d's own writer cannot pass integer parameters (both bindings wrap that type in SWIG's shared type
    table; measured with ezc3d 1.7.2 and opensim 4.6); this writer does not go through it."""
    osim = pytest.importorskip("opensim", reason="the clash needs OpenSim's bindings")
    spline = osim.SimmSpline()
    for x, y in ((0.0, 1.0), (1.0, 2.0), (2.0, 0.0)):
        spline.addPoint(x, y)
    spline.calcDerivative(osim.StdVectorInt([0]), osim.Vector(1, 0.5))
    markers = _running_trial().frames(slice(0, 20))
    back = read_c3d_markers(write_c3d(tmp_path / "after_opensim.c3d", markers))
    np.testing.assert_allclose(back.positions, markers.positions, atol=1e-6)


def test_many_markers_and_long_trials_use_the_standards_continuations(tmp_path):
    """300 markers spill into POINT:LABELS2; 40000 frames (past int16) keep their count and last frame."""
    rng = np.random.default_rng(0)
    wide = Markers(
        times=np.arange(3) / 100.0, names=tuple(f"M{i:03d}" for i in range(300)), positions=rng.normal(size=(3, 300, 3))
    )
    back = read_c3d_markers(write_c3d(tmp_path / "wide.c3d", wide))
    assert back.names == wide.names
    np.testing.assert_allclose(back.positions, wide.positions, atol=1e-6)
    long = Markers(times=np.arange(40000) / 1000.0, names=("A",), positions=rng.normal(size=(40000, 1, 3)))
    path = write_c3d(tmp_path / "long.c3d", long)
    back = read_c3d_markers(path)
    assert back.n_frames == 40000 and back.times[-1] == pytest.approx(39.999)
    assert ezc3d.c3d(str(path))["header"]["points"]["last_frame"] == 39999


def test_times_off_the_frame_grid_are_refused_and_nothing_is_written(tmp_path):
    markers = _running_trial().frames(slice(0, 20))
    shifted = dataclasses.replace(markers, times=markers.times + 0.5 / 150.0)
    with pytest.raises(ConfigError, match="not on the 150 Hz grid"):
        write_c3d(tmp_path / "shifted.c3d", shifted)
    assert list(tmp_path.iterdir()) == []


def test_a_trc_with_millisecond_times_keeps_its_whole_rate(tmp_path):
    """gait2392 subject01_static.trc: 60 Hz, its times written to 3 decimals (0.017, 0.033 ...), so its measured
    rate is 60.004 Hz; the C3D records 60 Hz and every time within half a millisecond of the TRC's."""
    from biomotion.io.trc import read_trc

    markers = read_trc(data_path("opensim-models/Pipelines/Gait2392_Simbody/subject01_static.trc"))
    assert markers.rate == pytest.approx(60.004, abs=1e-3)
    raw = ezc3d.c3d(str(write_c3d(tmp_path / "walk.c3d", markers)))
    assert float(raw["parameters"]["POINT"]["RATE"]["value"][0]) == 60.0
    back = read_c3d_markers(tmp_path / "walk.c3d")
    assert np.abs(back.times - markers.times).max() <= 5e-4
    np.testing.assert_allclose(back.positions, markers.positions, atol=1e-6, equal_nan=True)
