"""C3D reader: every real C3D, Fukuchi GRF peaks against SOURCE.md and the subject table, ezc3d's own force-platform
extraction as an oracle, force-platform formulas on synthetic plates with a known load, corrupted files."""

import csv
import shutil

import ezc3d
import numpy as np
import pytest

from biomotion.errors import ConfigError, DataFormatError
from biomotion.io.c3d import lab_rotation, plate_frame, read_c3d, read_c3d_forces, read_c3d_markers
from tests.conftest import data_path

G = 9.81
FUKUCHI = "fukuchi-running"
PELVIS = ("L.ASIS", "R.ASIS", "L.PSIS", "R.PSIS")


def _c3d_files(kind: str = "") -> list:
    files = sorted(data_path(f"{FUKUCHI}/c3d").glob(f"*{kind}.c3d"))
    if not files:
        pytest.skip(f"no *{kind}.c3d under {FUKUCHI}/c3d")
    return files


def _masses() -> dict[str, float]:
    """Body mass (kg) per runner from participantInfo.csv, one row per subject (the static.c3d row)."""
    with data_path(f"{FUKUCHI}/participantInfo.csv").open(newline="", encoding="utf-8-sig") as handle:
        return {
            row["FileName"].removesuffix("static.c3d"): float(row["Mass"])
            for row in csv.DictReader(handle)
            if row["FileName"].endswith("static.c3d")
        }


def test_every_fukuchi_c3d_reads_in_metres_at_150_hz():
    files = _c3d_files()
    for path in files:
        trial = read_c3d(path)
        markers, forces = trial.markers, trial.forces
        assert trial.source == path
        assert markers.rate == pytest.approx(150.0) and markers.times[0] == 0.0, path
        assert np.array_equal(markers.times, np.arange(markers.n_frames) / 150.0), path  # OpenSim's k / rate
        running = path.name.endswith(("runT25.c3d", "runT35.c3d", "runT45.c3d"))  # SOURCE.md: 3 speeds
        assert path.name.endswith("static.c3d") or running, path
        assert markers.n_frames == (4500 if running else 150), path
        assert len(markers.names) == (len(set(markers.names))) and all(n == n.strip() for n in markers.names)
        present = ~markers.occluded()
        assert present.mean() > 0.9, path
        assert np.isfinite(markers.positions[present]).all(), path
        assert not (markers.positions[present] == 0).all(axis=-1).any(), path  # zeros are gaps
        heights = np.nanmedian(np.stack([markers[name][:, 1] for name in PELVIS]), axis=1)
        assert np.all((heights > 0.85) & (heights < 1.2)), (path, heights)  # y up, metres (0.89-1.16 m)
        raw = ezc3d.c3d(str(path))["data"]["points"]
        assert np.array_equal(~present, (raw[:3] == 0).all(axis=0).T), path  # exactly the zero samples
        np.testing.assert_allclose(markers.positions[present], np.transpose(raw[:3], (2, 1, 0))[present] / 1000)
        if forces is not None:
            assert forces.names == ("1",) and forces.rate == pytest.approx(300.0), path
            assert forces.n_frames == 2 * markers.n_frames, path


def test_static_trial_without_analog_data_has_no_forces():
    path = data_path(f"{FUKUCHI}/c3d/RBDS001static.c3d")  # SOURCE.md: 4 static trials have no analog channels
    assert read_c3d(path).forces is None
    with pytest.raises(DataFormatError, match="RBDS001static.c3d") as error:
        read_c3d_forces(path)
    assert error.value.field == "ANALOG:USED"


def test_times_are_those_of_the_opensim_processed_ik():
    """The source's IK (.mot) took its times from OpenSim's C3DFileAdapter: they must fall on our 150 Hz clock,
    and the IK pelvis translation must track the pelvis markers at zero lag (a constant offset aside)."""
    markers = read_c3d_markers(data_path(f"{FUKUCHI}/c3d/RBDS001runT35.c3d"))
    ik = np.loadtxt(data_path(f"{FUKUCHI}/ik/T35/RBDS001_T35_ik_simple.mot"), skiprows=13)
    frame = np.rint(ik[:, 0] * 150).astype(int)
    np.testing.assert_allclose(markers.times[frame], ik[:, 0], atol=1e-6)
    centroid = np.nanmean(np.stack([markers[name] for name in PELVIS]), axis=0)
    spread = {lag: (centroid[frame + lag] - ik[:, 4:7]).std(axis=0) for lag in (-2, 0, 2)}
    assert np.all(spread[0][:2] < 0.005)  # measured 1.2 mm (x), 3.3 mm (y)
    assert np.all(spread[0][:2] < spread[-2][:2]) and np.all(spread[0][:2] < spread[2][:2])


def test_rbds001_vertical_grf_peak_is_2_64_body_weights():
    forces = read_c3d_forces(data_path(f"{FUKUCHI}/c3d/RBDS001runT35.c3d"))
    peak = forces.force[:, 0, 1].max()
    assert peak == pytest.approx(1607.0, abs=1.0)  # SOURCE.md: 1607 N
    assert peak / (_masses()["RBDS001"] * G) == pytest.approx(2.64, rel=0.02)  # 62 kg


def test_every_running_trial_peaks_between_2_3_and_3_4_body_weights():
    masses = _masses()
    peaks = {}
    for path in _c3d_files("runT35"):
        runner = path.name.removesuffix("runT35.c3d")
        vertical = read_c3d_forces(path).force[:, 0, 1]
        peaks[runner] = vertical.max() / (masses[runner] * G)
    print("peak vertical GRF (body weights):", {k: round(v, 3) for k, v in peaks.items()})
    assert all(2.3 < value < 3.4 for value in peaks.values()), peaks


def test_cop_lies_on_the_plate_under_load_and_is_nan_below_threshold():
    path = data_path(f"{FUKUCHI}/c3d/RBDS001runT35.c3d")
    forces = read_c3d_forces(path, cop_threshold=20.0)
    corners = np.asarray(ezc3d.c3d(str(path))["parameters"]["FORCE_PLATFORM"]["CORNERS"]["value"])[:, :, 0].T / 1000
    vertical, cop = forces.force[:, 0, 1], forces.cop[:, 0]
    loaded = vertical > 200
    assert loaded.mean() > 0.3  # about 40 % stance at 3.5 m/s
    low, high = corners.min(axis=0), corners.max(axis=0)
    assert np.all((cop[loaded] >= low - 1e-9) & (cop[loaded] <= high + 1e-9))
    assert np.all(cop[loaded, 1] == 0.0)  # on the surface (y = 0)
    assert np.array_equal(np.isnan(cop[:, 0]), np.abs(vertical) < 20.0)
    assert np.array_equal(np.isnan(forces.moment[:, 0, 1]), np.abs(vertical) < 20.0)
    free = forces.moment[loaded, 0]
    assert np.all(free[:, [0, 2]] == 0)  # the free moment is about the vertical
    assert np.median(np.abs(free[:, 1])) < 20  # measured 10 N·m above 1000 N (treadmill CoP jitter makes spikes)


@pytest.mark.parametrize("name", ["RBDS001runT35", "RBDS019runT35", "RBDS002static"])
def test_agrees_with_ezc3d_force_platform_extraction(name):
    path = data_path(f"{FUKUCHI}/c3d/{name}.c3d")
    ours = read_c3d_forces(path)
    plate = ezc3d.c3d(str(path), extract_forceplat_data=True)["data"]["platform"][0]
    assert (plate["unit_force"], plate["unit_moment"], plate["unit_position"]) == ("N", "Nmm", "mm")
    force, cop = ours.force[:, 0], ours.cop[:, 0]
    np.testing.assert_allclose(force, plate["force"].T, atol=1e-9)
    defined = np.isfinite(cop[:, 0])
    np.testing.assert_allclose(cop[defined], plate["center_of_pressure"].T[defined] / 1000, atol=1e-9)
    np.testing.assert_allclose(ours.moment[defined, 0], plate["Tz"].T[defined] / 1000, atol=1e-9)
    centre = plate["corners"].mean(axis=1) / 1000  # ezc3d's moment is about the plate centre
    about_centre = np.cross(cop[defined] - centre, force[defined]) + ours.moment[defined, 0]
    np.testing.assert_allclose(about_centre, plate["moment"].T[defined] / 1000, atol=1e-9)


def test_axes_rotate_markers_and_forces_alike():
    path = data_path(f"{FUKUCHI}/c3d/RBDS001runT35.c3d")
    plain, turned = read_c3d(path), read_c3d(path, axes="x,-z,y")
    rotation = lab_rotation("x,-z,y")
    np.testing.assert_array_equal(rotation, [[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    np.testing.assert_allclose(turned.markers.positions, plain.markers.positions @ rotation.T)
    for name in ("force", "cop", "moment"):
        np.testing.assert_allclose(getattr(turned.forces, name), getattr(plain.forces, name) @ rotation.T)
    np.testing.assert_allclose(lab_rotation(rotation.tolist()), rotation)
    for bad in ("x,y,-z", "x,q,z", "x,y", [[1, 0, 0], [0, 1, 0], [0, 1, 0]]):
        with pytest.raises(ConfigError):
            lab_rotation(bad)


# --- synthetic files: known loads on plates of every supported type ---------------------------------------

RATE, RATIO = 100.0, 10


def _write(path, **kwargs):
    """`_write_c3d` in a fresh interpreter: ezc3d's SWIG overloads for parameter values can resolve wrongly once
    other SWIG-wrapped libraries (opensim) share the process, which made writing fail only in some test orders."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_write_c3d, path, **kwargs).result()


def _write_c3d(path, *, labels, points, analogs=None, units="mm", plates=(), extra=()):
    """A C3D written by ezc3d: points [3, M, T] in ``units``, analogs [C, T * RATIO], plates as parameter dicts."""
    c3d = ezc3d.c3d()
    parameters = c3d["parameters"]
    parameters["POINT"]["RATE"]["value"] = [RATE]
    parameters["POINT"]["LABELS"]["value"] = list(labels)
    parameters["POINT"]["UNITS"]["value"] = [units]
    c3d["data"]["points"] = np.concatenate([points, np.ones((1,) + points.shape[1:])])
    if analogs is not None:
        parameters["ANALOG"]["RATE"]["value"] = [RATE * RATIO]
        parameters["ANALOG"]["LABELS"]["value"] = [f"ch{i}" for i in range(len(analogs))]
        parameters["ANALOG"]["SCALE"]["value"] = np.ones(len(analogs))
        parameters["ANALOG"]["OFFSET"]["value"] = np.zeros(len(analogs), dtype=int)
        c3d["data"]["analogs"] = analogs[None]
    if plates:
        group = parameters["FORCE_PLATFORM"]
        group["USED"]["value"] = np.array([len(plates)])
        group["TYPE"]["value"] = np.array([plate["type"] for plate in plates])
        width = max(len(plate["channel"]) for plate in plates)
        group["CHANNEL"]["value"] = np.array([np.pad(p["channel"], (0, width - len(p["channel"]))) for p in plates]).T
        group["CORNERS"]["value"] = np.stack([np.asarray(p["corners"], float).T for p in plates], axis=2)
        group["ORIGIN"]["value"] = np.stack([np.asarray(p["origin"], float) for p in plates], axis=1)
        group["CAL_MATRIX"]["value"] = np.stack([p.get("cal", np.eye(6)) for p in plates], axis=2)
    for group, name, value in extra:
        if isinstance(value[0], str):
            parameters[group][name] = {"type": -1, "description": "", "is_locked": False, "value": list(value)}
        else:
            c3d.add_parameter(group, name, np.asarray(value, dtype=float))
    c3d.write(str(path))
    return path


def _plate_corners(centre):
    """Corners (mm, lab, y up) of a 600 x 400 mm plate: plate x = lab X, plate y = lab Z, plate z = down."""
    quadrants = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * [300.0, 200.0]
    return np.column_stack([quadrants[:, 0], np.zeros(4), quadrants[:, 1]]) + centre


def _known_load(samples, rng):
    """Force (plate frame, N), CoP (plate frame, m, on the surface) and free moment Tz (N·m) per sample."""
    force = np.column_stack(
        [rng.uniform(-150, 150, samples), rng.uniform(-150, 150, samples), rng.uniform(-900, -300, samples)]
    )  # z down: a load pressing on the plate
    cop = np.column_stack([rng.uniform(-0.25, 0.25, samples), rng.uniform(-0.15, 0.15, samples), np.zeros(samples)])
    return force, cop, rng.uniform(-5, 5, samples)


def test_plate_types_1_to_4_recover_a_known_load(tmp_path):
    """Channels synthesised from a known force applied at a known CoP with a known free moment (plate statics),
    per plate type; the reader must give that force, CoP and free moment back, in the lab frame, and agree with
    ezc3d's extraction of the same file."""
    rng = np.random.default_rng(7)
    frames = 20
    samples = frames * RATIO
    force, cop, torque = _known_load(samples, rng)
    force[:15, 2] = -5.0  # below the 20 N CoP threshold
    channels, plates, centres = (
        [],
        [],
        [np.array(c) for c in ([1000.0, 0, 500], [0, 0, 0], [-800, 0, 300], [2000, 0, -600])],
    )
    mm = 1000.0
    # TYPE 1: Fx Fy Fz CoPx CoPy Tz (mm, N·mm)
    channels.append(np.column_stack([force, cop[:, :2] * mm, torque * mm]))
    plates.append({"type": 1, "origin": [0, 0, 0], "corners": _plate_corners(centres[0])})
    # TYPE 2: moments about a transducer origin 40 mm below the surface centre; ORIGIN stored with the old AMTI
    # positive z, which the reader (like ezc3d and Visual3D) must negate
    origin = np.array([3.0, -2.0, -40.0]) / mm  # vector from the transducer origin to the surface centre, m
    arm = cop + origin  # load point relative to the transducer origin
    moment = np.cross(arm, force) + np.column_stack([np.zeros((samples, 2)), torque])
    channels.append(np.column_stack([force, moment * mm]))
    plates.append({"type": 2, "origin": -origin * mm, "corners": _plate_corners(centres[1])})
    # TYPE 3 (Kistler): sensors at (±a, ±b), 50 mm below the surface; vertical loads by bilinear weights at the
    # point whose moments match the load, shear split so that Mz = (arm x F)_z + Tz
    a, b, depth = 0.21, 0.13, -0.05
    apparent = cop[:, :2] - depth * force[:, :2] / force[:, 2:3]
    weights = [
        (1 + sx * apparent[:, 0] / a) * (1 + sy * apparent[:, 1] / b) / 4
        for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))
    ]
    twist = cop[:, 0] * force[:, 1] - cop[:, 1] * force[:, 0] + torque
    fx12, fx34 = force[:, 0] / 2 - twist / (4 * b), force[:, 0] / 2 + twist / (4 * b)
    fy14, fy23 = force[:, 1] / 2 + twist / (4 * a), force[:, 1] / 2 - twist / (4 * a)
    channels.append(np.column_stack([fx12, fx34, fy14, fy23] + [w * force[:, 2] for w in weights]))
    plates.append({"type": 3, "origin": [a * mm, b * mm, depth * mm], "corners": _plate_corners(centres[2])})
    # TYPE 4: a full (non-diagonal) calibration matrix applied to "volts"
    cal = np.diag([500.0, 500, 1000, 8e5, 2.5e5, 4e5]) + rng.uniform(-20, 20, (6, 6))
    wrench = np.column_stack([force, (np.cross(arm, force) + np.column_stack([np.zeros((samples, 2)), torque])) * mm])
    channels.append(np.linalg.solve(cal, wrench.T).T)
    plates.append({"type": 4, "origin": origin * mm, "corners": _plate_corners(centres[3]), "cal": cal})
    # lay out the analog channels and name them in FORCE_PLATFORM:CHANNEL
    start = 0
    for plate, block in zip(plates, channels):
        plate["channel"] = np.arange(start + 1, start + block.shape[1] + 1)
        start += block.shape[1]
    analogs = np.concatenate(channels, axis=1).T
    points = rng.uniform(100, 900, (3, 2, frames))
    path = _write(
        tmp_path / "plates.c3d",
        labels=["A", "B"],
        points=points,
        analogs=analogs,
        plates=plates,
        extra=[("TRIAL", "ACTUAL_START_FIELD", [51.0, 0.0])],
    )

    ours = read_c3d_forces(path, cop_threshold=20.0)
    assert ours.names == ("1", "2", "3", "4")
    np.testing.assert_allclose(ours.times, 0.5 + np.arange(samples) / (RATE * RATIO))  # first frame 51 at 100 Hz
    reference = ezc3d.c3d(str(path), extract_forceplat_data=True)["data"]["platform"]
    heavy = np.abs(force[:, 2]) >= 20
    for index, plate in enumerate(plates):
        rotation, centre = plate_frame(np.asarray(plate["corners"]) / mm)
        np.testing.assert_allclose(rotation, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
        # float32 storage: forces to 0.01 N, CoP to 0.1 mm, free moment to 0.01 N·m
        np.testing.assert_allclose(ours.force[:, index], force @ rotation.T, atol=1e-2, err_msg=f"type {plate['type']}")
        np.testing.assert_allclose(
            ours.cop[heavy, index], cop[heavy] @ rotation.T + centre, atol=1e-4, err_msg=f"type {plate['type']}"
        )
        np.testing.assert_allclose(
            ours.moment[heavy, index], torque[heavy, None] * rotation[:, 2], atol=1e-2, err_msg=f"type {plate['type']}"
        )
        assert np.isnan(ours.cop[~heavy, index]).all() and np.isnan(ours.moment[~heavy, index]).all()
        np.testing.assert_allclose(ours.force[:, index], reference[index]["force"].T, atol=1e-6)
        np.testing.assert_allclose(
            ours.cop[heavy, index], reference[index]["center_of_pressure"].T[heavy] / mm, atol=1e-9
        )


def test_units_rate_start_frame_gaps_and_model_outputs(tmp_path):
    rng = np.random.default_rng(3)
    points = rng.uniform(10, 90, (3, 3, 12))
    points[:, 0, 4] = 0.0  # a Fukuchi-style gap
    points[:, 1, 5] = np.nan  # ezc3d writes it with residual -1, the standard's invalid flag
    extra = [("POINT", "ANGLES", ["LHipAngles"]), ("TRIAL", "ACTUAL_START_FIELD", np.array([201.0, 0.0]))]
    path = _write(tmp_path / "cm.c3d", labels=["A ", " B", "LHipAngles"], points=points, units="cm", extra=extra)
    markers = read_c3d_markers(path)
    assert markers.names == ("A", "B")  # stripped; the model output is left out
    np.testing.assert_allclose(markers.times, (200 + np.arange(12)) / RATE)
    assert markers.occluded().sum() == 2 and markers.occluded()[4, 0] and markers.occluded()[5, 1]
    present = ~markers.occluded()
    np.testing.assert_allclose(
        markers.positions[present], np.transpose(points[:, :2], (2, 1, 0))[present] / 100, rtol=1e-6
    )
    kept = read_c3d_markers(path, zero_is_missing=False)
    np.testing.assert_array_equal(kept["A"][4], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(read_c3d_markers(path, units="m").positions, markers.positions * 100, rtol=1e-12)

    odd = _write(tmp_path / "furlong.c3d", labels=["A"], points=points[:, :1], units="furlong")
    with pytest.raises(DataFormatError, match="furlong.c3d") as error:
        read_c3d_markers(odd)
    assert error.value.field == "POINT:UNITS"
    assert read_c3d_markers(odd, units="mm")["A"][0] == pytest.approx(points[:, 0, 0] / 1000, rel=1e-6)


# --- corrupted files ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("size", [100, 3000, 600_000, 2_527_000])
def test_truncated_copy_raises_naming_the_file(tmp_path, size):
    source = data_path(f"{FUKUCHI}/c3d/RBDS001runT35.c3d")
    path = tmp_path / "cut.c3d"
    path.write_bytes(source.read_bytes()[:size])
    with pytest.raises(DataFormatError, match="cut.c3d"):
        read_c3d(path)


def test_text_empty_and_missing_files_raise(tmp_path):
    text = tmp_path / "notes.c3d"
    text.write_text("time,x,y,z\n0,1,2,3\n")
    empty = tmp_path / "empty.c3d"
    empty.write_bytes(b"")
    for path in (text, empty, tmp_path / "absent.c3d"):
        with pytest.raises(DataFormatError, match=path.name):
            read_c3d_markers(path)


def test_directory_is_refused(tmp_path):
    with pytest.raises(DataFormatError, match="is a directory") as error:
        read_c3d(tmp_path)
    assert str(error.value).startswith(f"{tmp_path}: ")


def test_non_finite_plate_channels_and_infinite_points_are_refused(tmp_path):
    """NaN or inf in an analog channel a plate uses would become a NaN force (read downstream as no load), and an
    infinite coordinate is no documented gap: both are refused, naming the file, frame and channel or marker."""
    rng = np.random.default_rng(5)
    frames = 10
    analogs = np.column_stack(
        [
            rng.uniform(-50, 50, (frames * RATIO, 2)),
            rng.uniform(-900, -300, frames * RATIO),
            rng.uniform(-1e4, 1e4, (frames * RATIO, 3)),
        ]
    ).T
    analogs[2, 7 * RATIO + 1] = np.nan  # channel 3 (Fz) in frame 7
    plate = {"type": 2, "origin": [0.0, 0.0, -40.0], "corners": _plate_corners(np.zeros(3)), "channel": np.arange(1, 7)}
    points = rng.uniform(100, 900, (3, 2, frames))
    path = _write(tmp_path / "nan_plate.c3d", labels=["A", "B"], points=points, analogs=analogs, plates=[plate])
    with pytest.raises(DataFormatError, match="analog channel 3 \\('ch2'\\) holds nan") as error:
        read_c3d_forces(path)
    assert error.value.frame == 7 and str(error.value).startswith(f"{path}: frame 7, field 'ANALOG:DATA': ")
    assert read_c3d_markers(path).n_frames == frames  # the markers themselves are fine
    points[1, 1, 3] = np.inf
    path = _write(tmp_path / "inf_point.c3d", labels=["A", "B"], points=points)
    with pytest.raises(DataFormatError, match="marker 'B' has an infinite y coordinate") as error:
        read_c3d_markers(path)
    assert error.value.frame == 3 and str(path) in str(error.value)


def test_whole_copy_still_reads(tmp_path):
    copy = tmp_path / "copy.c3d"
    shutil.copyfile(data_path(f"{FUKUCHI}/c3d/RBDS04static.c3d"), copy)
    assert read_c3d(copy).markers.n_frames == 150
