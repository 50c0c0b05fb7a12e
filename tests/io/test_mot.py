"""OpenSim .mot/.sto reader and writer on the real files, round trips through OpenSim's own readers, and errors."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from biomotion.errors import BiomotionWarning, DataFormatError
from biomotion.io.mot import (
    read_ground_reaction,
    read_motion,
    read_storage,
    write_ground_reaction,
    write_motion,
    write_storage,
)
from tests.conftest import DATA_ROOT, data_path


def all_storage_files():
    return sorted(list(DATA_ROOT.glob("**/*.mot")) + list(DATA_ROOT.glob("**/*.sto")))


def test_every_storage_file_in_the_data_reads(data_root):
    files = all_storage_files()
    assert len(files) >= 200
    for path in files:
        table = read_storage(path)
        assert table.data.shape == (len(table.times), len(table.labels)), path
        assert len(table.times) > 0 and np.all(np.diff(table.times) > 0), path


def test_v3_header_in_degrees_is_converted_to_radians():
    path = data_path("fukuchi-running/ik/T35/RBDS001_T35_ik_simple.mot")
    motion = read_motion(path)
    assert motion.n_frames == 1057 and motion.rate == pytest.approx(150.0)
    assert motion.times[0] == pytest.approx(11.467, abs=1e-3)
    raw = read_storage(path)
    knee = raw.labels.index("knee_angle_r")
    assert motion["knee_angle_r"] == pytest.approx(np.deg2rad(raw.data[:, knee]))
    # translations are never converted
    assert motion["pelvis_tx"] == pytest.approx(raw.data[:, raw.labels.index("pelvis_tx")])
    # knee flexion is negative in the Fukuchi simple model, up to ~ -120 deg at 3.5 m/s swing
    assert -2.2 < motion["knee_angle_r"].min() < -1.4


def test_radians_header_and_simm_header():
    opencap = read_motion(data_path("opencap/Subject4/IK/walking1_ik.mot"))
    assert 0.5 < opencap["knee_angle_r"].max() < 1.5  # inDegrees=no: walking knee flexion ~60 deg, in rad
    hamner = read_motion(data_path("Hamner2013/subject01/Run_5.mot"))  # SIMM header, no inDegrees: degrees
    assert hamner.n_frames == 393 and hamner.rate == pytest.approx(100.0)
    assert -2.3 < hamner["knee_angle_r"].min() < -1.5


def test_a_header_that_lies_is_reported():
    path = data_path("opensim-models/Pipelines/Gait2392_Simbody/subject01_walk1_RRA_Kinematics_q.sto")
    with pytest.warns(BiomotionWarning, match="looks like degrees"):
        read_motion(path)
    fixed = read_motion(path, angles="degrees")
    assert -1.3 < fixed["knee_angle_r"].min() < -0.9  # gait2392 knee flexion is negative, ~70 deg


def test_ground_reaction_namings():
    expectations = {
        "opencap/Subject4/ID/walking1_grf.mot": ("ground_force_1", "ground_force_2"),
        "opensim-models/Pipelines/Rajagopal/ExpData/grf_walk.mot": ("ground_force_r", "ground_force_l"),
        "opensim-models/Pipelines/Gait2392_Simbody/subject01_walk1_grf.mot": ("ground_force", "1_ground_force"),
        "Hamner2013/subject01/Run_5_grf.mot": ("R_ground_force", "L_ground_force"),
    }
    for relative, names in expectations.items():
        grf = read_ground_reaction(data_path(relative))
        assert grf.names == names, relative
        assert 600 < np.nanmax(grf.force[:, :, 1]) < 2500, relative
    gait = read_ground_reaction(data_path("opensim-models/Pipelines/Gait2392_Simbody/subject01_walk1_grf.mot"))
    assert gait.force[:, :, 1].max(axis=0) == pytest.approx([805, 811], abs=10)  # SOURCE.md: vy peaks ~805/811 N
    assert np.abs(gait.moment).max() > 0  # torque columns found via the ground_torque naming


def test_written_motion_reads_back_identically_in_opensim(tmp_path):
    osim = pytest.importorskip("opensim")
    motion = read_motion(data_path("opencap/Subject4/IK/DJ1_ik.mot"))
    for suffix, degrees in ((".mot", True), (".sto", False)):
        path = write_motion(tmp_path / f"dj1{suffix}", motion, in_degrees=degrees)
        table = osim.TimeSeriesTable(str(path))
        assert list(table.getColumnLabels()) == list(motion.names)
        times = np.array(table.getIndependentColumn())
        data = table.getMatrix().to_numpy()
        assert np.array_equal(times, motion.times)
        expected = motion.values.copy()
        if degrees:
            expected[:, motion.rotational()] = np.rad2deg(expected[:, motion.rotational()])
        assert np.array_equal(data, expected)
        storage = osim.Storage(str(path))
        assert storage.isInDegrees() == degrees
        back = read_motion(path)
        np.testing.assert_allclose(back.values, motion.values, rtol=0, atol=1e-12)


def test_ground_reaction_round_trip_and_opensim_external_loads(tmp_path):
    osim = pytest.importorskip("opensim")
    grf = read_ground_reaction(data_path("opencap/Subject4/ID/walking1_grf.mot"))
    path = write_ground_reaction(tmp_path / "grf.mot", grf)
    back = read_ground_reaction(path)
    assert back.names == grf.names
    np.testing.assert_array_equal(back.force, grf.force)
    np.testing.assert_array_equal(back.moment, grf.moment)
    table = osim.TimeSeriesTable(str(path))
    assert table.getNumRows() == grf.n_frames and table.getNumColumns() == 9 * grf.n_channels


def test_errors_name_file_and_line(tmp_path):
    source = data_path("opencap/Subject4/IK/walking1_ik.mot").read_text().splitlines()
    end = source.index("endheader")
    cases = {
        "truncated": source[: end + 10],  # fewer rows than nRows
        "columns": source[: end + 5] + [source[end + 5] + "\t1.0"] + source[end + 6 :],
        "nan_time": source[: end + 5] + ["nan\t" + source[end + 5].split("\t", 1)[1]] + source[end + 6 :],
        "no_endheader": [line for line in source if line != "endheader"],
        "text": source[: end + 5] + [source[end + 5].replace("\t", "\tabc", 1)] + source[end + 6 :],
        "empty": [],
    }
    messages = {
        "truncated": "truncated",
        "columns": "column labels",
        "nan_time": "NaN",
        "no_endheader": "endheader",
        "text": "not a number",
        "empty": "empty",
    }
    for name, lines in cases.items():
        path = tmp_path / f"{name}.mot"
        path.write_text("\n".join(lines))
        with pytest.raises(DataFormatError, match=messages[name]) as info:
            read_storage(path)
        assert str(path) in str(info.value)
        if name in ("columns", "text", "nan_time"):
            assert f":{end + 6}:" in str(info.value)  # 1-based line number of the bad row


labels = st.lists(st.from_regex(r"[a-z][a-z0-9_]{0,10}", fullmatch=True), min_size=1, max_size=6, unique=True)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(names=labels, frames=st.integers(1, 30), seed=st.integers(0, 2**16))
def test_property_write_read_is_identity(tmp_path, names, frames, seed):
    names = [n for n in names if n != "time"] or ["q"]
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(1e-3, 0.1, size=frames))
    values = rng.normal(scale=100.0, size=(frames, len(names)))
    path = write_storage(tmp_path / "x.sto", names, times, values)
    table = read_storage(path)
    assert table.labels == tuple(names)
    assert np.array_equal(table.times, times) and np.array_equal(table.data, values)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 10_000), seed=st.integers(0, 2**16))
def test_property_corrupted_files_raise_only_data_format_errors(tmp_path, cut, seed):
    rng = np.random.default_rng(seed)
    times = np.arange(20) / 10.0
    path = write_storage(tmp_path / "x.mot", ["a", "b"], times, rng.normal(size=(20, 2)))
    text = path.read_text()
    mode = seed % 3
    if mode == 0:
        corrupted = text[: cut % len(text)]
    elif mode == 1:
        lines = text.splitlines()
        row = 7 + cut % 20
        lines[row] = "\t".join(lines[row].split("\t")[:-1])
        corrupted = "\n".join(lines)
    else:
        corrupted = text.replace("\t", "\tx", 1 + cut % 5)
    path.write_text(corrupted)
    try:
        table = read_storage(path)
    except DataFormatError:
        return
    # a cut exactly at a line end can leave a shorter but complete-looking file only if nRows still matches
    assert table.data.shape[1] == 2 and len(table.times) == 20


def _with_cell(source, end, row, column, token):
    """The lines of ``source`` with data row ``row`` (0-based) holding ``token`` in column ``column``."""
    lines = list(source)
    cells = lines[end + 2 + row].split("\t")
    cells[column] = token
    lines[end + 2 + row] = "\t".join(cells)
    return lines


def test_nan_and_inf_are_refused_naming_file_line_and_column(tmp_path):
    """A NaN coordinate would reach the filters and the dynamics; a NaN force would read as no load. Both are
    refused with the file, line and column, unless the caller asks for gaps; inf is refused always."""
    source = data_path("opencap/Subject4/IK/walking1_ik.mot").read_text().splitlines()
    end = source.index("endheader")
    labels = source[end + 1].split("\t")
    path = tmp_path / "nan.mot"
    path.write_text("\n".join(_with_cell(source, end, 3, 5, "nan")))
    with pytest.raises(DataFormatError, match="NaN") as info:
        read_motion(path)
    assert str(info.value).startswith(f"{path}:{end + 6}: field '{labels[5]}': ")
    assert (info.value.line, info.value.field) == (end + 6, labels[5])
    gaps = read_motion(path, allow_gaps=True)
    assert np.isnan(gaps.values[3, 4]) and np.isfinite(np.delete(gaps.values, 4, axis=1)).all()
    assert np.isnan(read_storage(path).data[3, 4])  # the raw table keeps NaN by default
    with pytest.raises(DataFormatError, match="NaN"):
        read_storage(path, allow_gaps=False)
    others = [name for name in labels[1:] if name != labels[5]]
    assert read_motion(path, columns=others).n_frames == gaps.n_frames  # only the columns read are checked
    path.write_text("\n".join(_with_cell(source, end, 7, 2, "-inf")))
    for read in (read_motion, read_storage, lambda p: read_motion(p, allow_gaps=True)):
        with pytest.raises(DataFormatError, match="not a finite number") as info:
            read(path)
        assert f"{path}:{end + 10}: field '{labels[2]}'" in str(info.value)


def test_nan_force_is_refused_in_a_ground_reaction_file(tmp_path):
    source = data_path("opencap/Subject4/ID/walking1_grf.mot").read_text().splitlines()
    end = next(i for i, line in enumerate(source) if line.strip().lower() == "endheader")
    labels = source[end + 1].split("\t")
    column = labels.index("ground_force_1_vy")
    path = tmp_path / "grf.mot"
    path.write_text("\n".join(_with_cell(source, end, 0, column, "NaN")))
    with pytest.raises(DataFormatError, match="NaN") as info:
        read_ground_reaction(path)
    assert str(info.value).startswith(f"{path}:{end + 3}: field 'ground_force_1_vy': ")
    assert np.isnan(read_ground_reaction(path, allow_gaps=True).force[0, 0, 1])


def test_rows_of_the_wrong_width_empty_files_and_directories(tmp_path):
    source = data_path("opencap/Subject4/IK/walking1_ik.mot").read_text().splitlines()
    end = source.index("endheader")
    width = len(source[end + 1].split("\t"))
    short = source[: end + 4] + ["\t".join(source[end + 4].split("\t")[:-1])] + source[end + 5 :]
    path = tmp_path / "short.mot"
    path.write_text("\n".join(short))
    with pytest.raises(DataFormatError, match=f"{width - 1} values but {width} column labels") as info:
        read_motion(path)
    assert str(info.value).startswith(f"{path}:{end + 5}: ")
    for bad, message in ((tmp_path, "is a directory"), (tmp_path / "absent.mot", "no such file")):
        with pytest.raises(DataFormatError, match=message) as info:
            read_motion(bad)
        assert str(info.value).startswith(f"{bad}: ")
