"""Dataset registry: the cache built from the real data matches the data (counts, labels, masks, splits)."""

import json
import shutil

import numpy as np
import pytest

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.cli import main
from biomotion.data.placement import GENERIC_HEIGHT
from biomotion.data.registry import DatasetCache, build_cache, subject_split
from biomotion.data.sources import to_canonical
from biomotion.io.mot import read_motion
from tests.conftest import DATA_ROOT

#: every source but the retargeted BVH one, whose 664 clips take minutes of IK (tested on a few clips below)
FILE_SOURCES = ["fukuchi", "opencap", "hamner", "schreiber"]


@pytest.fixture(scope="module")
def cache(tmp_path_factory, data_root):
    out = tmp_path_factory.mktemp("cache")
    build_cache(data_root, out, sources=FILE_SOURCES, progress=False)
    return DatasetCache(out)


def test_counts_match_the_files(cache):
    counts = cache.manifest["counts"]
    fukuchi_files = list(DATA_ROOT.glob("fukuchi-running/ik/T*/*_ik_simple.mot"))
    runners = {p.name.split("_")[0] for p in fukuchi_files}
    assert counts["per_source"]["fukuchi"] == len(fukuchi_files) == 3 * len(runners)
    assert counts["subjects_per_source"]["fukuchi"] == len(runners)
    opencap = [p for p in DATA_ROOT.glob("opencap/Subject4/IK/*_ik.mot") if "manual" not in p.name]
    assert counts["per_source"]["opencap"] == len(opencap) == 24
    assert counts["per_source"]["hamner"] == len(list(DATA_ROOT.glob("Hamner2013/subject*/Run_?.mot")))
    assert counts["per_source"]["schreiber"] == len(list(DATA_ROOT.glob("SchreiberMoissenet2019/*/C*_ik.mot")))
    assert counts["clips"] == len(cache) == sum(counts["per_source"].values())
    assert counts["frames"] == cache.values.shape[0]
    assert counts["per_action"]["opencap/drop jump"] == 6  # DJ1-3 + DJAsym1-3


def test_splits_are_by_subject(cache):
    split_of = {}
    for record in cache.records:
        key = (record["source"], record["subject"])
        assert split_of.setdefault(key, record["split"]) == record["split"], key
        assert record["split"] == subject_split(*key)
    assert set(split_of.values()) == {"train", "val", "test"}


def test_canonical_mapping_masks_and_knee_sign(cache):
    assert cache.coordinates == CANONICAL_COORDINATES and cache.rate == 30.0
    fukuchi = cache.indices(source="fukuchi")
    motion = cache.motion(fukuchi[0])
    assert motion.mask.sum() == 16  # the 16 coordinates of the Fukuchi simple model
    assert not motion.mask[motion.index("lumbar_extension")]
    assert motion["knee_angle_r"].max() > 1.2  # flexion made positive (swing ~ 100+ deg while running)
    assert motion.rate == pytest.approx(30.0)
    hamner = cache.motion(cache.indices(source="hamner")[0])
    assert hamner["knee_angle_r"].max() > 1.2 and hamner.mask[hamner.index("arm_flex_r")]
    schreiber = cache.motion(cache.indices(source="schreiber")[0])
    assert schreiber.mask.all()


def test_cached_values_equal_the_resampled_source(cache):
    index = next(i for i, r in enumerate(cache.records) if r["clip_id"] == "opencap/Subject4/walking1")
    record = cache.records[index]
    source = read_motion(DATA_ROOT / record["file"]).resample(30.0)
    cached = cache.motion(index)
    shared = [n for n in source.names if n in CANONICAL_COORDINATES]
    rotations = [n for n in shared if n not in ("pelvis_tx", "pelvis_ty", "pelvis_tz")]
    np.testing.assert_allclose(cached.select(rotations).values, source.select(rotations).values, atol=1e-5)
    # translations are placed (biomotion.data.placement): scaled to 1.70 m / 1.68 m, shifted, never distorted
    scale = GENERIC_HEIGHT / 1.68
    for name in ("pelvis_tx", "pelvis_ty", "pelvis_tz"):
        np.testing.assert_allclose(np.diff(cached[name]), scale * np.diff(source[name]), atol=1e-5)
    assert record["labels"]["action"] == "walk" and 1.0 < record["labels"]["speed"] < 1.8  # measured, m/s
    assert record["profile"]["mass"] == 62.6


def test_labels_and_profiles(cache):
    runner = next(r for r in cache.records if r["clip_id"] == "fukuchi/RBDS001/T35")
    assert runner["labels"]["speed"] == 3.5 and runner["labels"]["action"] == "run"
    assert runner["profile"]["mass"] == 62 and runner["profile"]["injuries"][0]["location"] == "Right knee"


def test_cli_build_on_a_subset_data_root(tmp_path, data_root):
    """A data root holding only some sources/subjects works and names what it skipped."""
    root = tmp_path / "root"
    (root / "fukuchi-running" / "ik" / "T35").mkdir(parents=True)
    shutil.copy(data_root / "fukuchi-running" / "participantInfo.csv", root / "fukuchi-running")
    for runner in ("RBDS002", "RBDS010"):
        shutil.copy(data_root / f"fukuchi-running/ik/T35/{runner}_T35_ik_simple.mot", root / "fukuchi-running/ik/T35")
    out = tmp_path / "cache"
    assert main(["data", "build", "--data-root", str(root), "--out", str(out), "--quiet"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["counts"]["clips"] == 2
    assert any(s.startswith("opencap") for s in manifest["skipped_sources"])
    assert main(["data", "build", "--data-root", str(tmp_path / "nothing"), "--out", str(out), "--quiet"]) == 2


def test_excluded_subjects_are_left_out_unread(tmp_path, data_root):
    """`biomotion eval generation` builds only the people a model never saw; excluding everyone is an error."""
    from biomotion.errors import BiomotionError

    manifest = build_cache(
        data_root,
        tmp_path / "some",
        sources=["schreiber"],
        progress=False,
        exclude_subjects=["schreiber/2014001", "schreiber/2014004"],
    )
    subjects = {c["subject"] for c in manifest["clips"]}
    assert subjects and not subjects & {"2014001", "2014004"}
    everyone = {f"schreiber/{s}" for s in subjects | {"2014001", "2014004"}}
    with pytest.raises(BiomotionError, match="excluded subject"):
        build_cache(data_root, tmp_path / "none", sources=["schreiber"], progress=False, exclude_subjects=everyone)


def test_percentile_bounds_are_stored_with_the_cache(cache):
    from biomotion.metrics.bounds import PercentileBounds

    assert cache.manifest["bounds"]["coordinate_speeds"] == "bounds_coordinate_speeds.json"
    speeds = PercentileBounds.load(cache.folder / "bounds_coordinate_speeds.json")
    knee = speeds.names.index("knee_angle_r")
    assert speeds.low[knee] < -3.0 and speeds.high[knee] > 3.0  # running knee flexion speeds exceed 3 rad/s
    angles = PercentileBounds.load(cache.folder / "bounds_coordinates.json")
    hip = angles.names.index("hip_flexion_r")
    assert -0.6 < angles.low[hip] < 0.0 < 0.4 < angles.high[hip] < 1.6  # rad: extension to flexion in gait
    com = PercentileBounds.load(cache.folder / cache.manifest["bounds"]["com"])
    speed, acceleration = (com.names.index(n) for n in ("com_speed", "com_acceleration"))
    # training clips are walks (1-2 m/s), runs at 2.5-5 m/s and squats or jumps: the 95th percentile of COM speed
    # is a fast run's, the 5th a squat's; COM acceleration reaches about 1.5 g in running and landing
    assert com.low[speed] < 0.5 and 4.0 < com.high[speed] < 5.5
    assert 8.0 < com.high[acceleration] < 25.0


def test_report_writes_the_counts(tmp_path, data_root):
    report = tmp_path / "dataset.md"
    assert (
        main(
            [
                "data",
                "build",
                "--data-root",
                str(data_root),
                "--out",
                str(tmp_path / "c"),
                "--quiet",
                "--report",
                str(report),
                *[a for s in FILE_SOURCES for a in ("--source", s)],
            ]
        )
        == 0
    )
    text = report.read_text()
    runners = {p.name.split("_")[0] for p in DATA_ROOT.glob("fukuchi-running/ik/T*/*_ik_simple.mot")}
    assert f"| fukuchi | {3 * len(runners)} | {len(runners)} |" in text


def test_bandai_clips_are_retargeted_into_the_cache(tmp_path, data_root):
    """A root with three Bandai-Namco clips (and the model they are retargeted onto): canonical coordinates that
    move like the clip says, labels from the name, the actor group as subject."""
    root = tmp_path / "root"
    for name in (
        "dataset-2/dataset-2_walk_elderly_001.bvh.gz",
        "dataset-2/dataset-2_run_normal_001.bvh.gz",
        "dataset-1/dataset-1_bow_happy_001.bvh.gz",
    ):
        (root / "bandai-namco" / name).parent.mkdir(parents=True, exist_ok=True)
        (root / "bandai-namco" / name).symlink_to(data_root / "bandai-namco" / name)
    model = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
    (root / model).parent.mkdir(parents=True)
    (root / model).symlink_to(data_root / model)
    out = tmp_path / "cache"
    build_cache(root, out, progress=False)
    cache = DatasetCache(out)
    records = {r["clip_id"]: (i, r) for i, r in enumerate(cache.records)}
    i, walk = records["bandai-namco/dataset-2/walk_elderly_001"]
    assert walk["labels"]["action"] == "walk" and walk["labels"]["style"] == "elderly"
    assert walk["labels"]["text"] == "walk, elderly" and 0.3 < walk["labels"]["speed"] < 1.6  # m/s, measured
    assert walk["subject"] == "dataset-2/hips@5,91,-427"  # active/elderly/exhausted share an actor
    motion = cache.motion(i)
    assert motion.mask.all() and motion.rate == pytest.approx(30.0)
    assert np.degrees(motion["knee_angle_r"]).max() > 40  # swing flexion
    run = cache.motion(records["bandai-namco/dataset-2/run_normal_001"][0])
    assert np.degrees(run["knee_angle_r"]).max() > np.degrees(motion["knee_angle_r"]).max()
    bow = cache.motion(records["bandai-namco/dataset-1/bow_happy_001"][0])
    assert np.degrees(bow["pelvis_tilt"]).min() < -30 and np.degrees(bow["hip_flexion_r"]).max() > 30  # bent forward


def test_a_runner_with_only_raw_c3d_is_solved_into_the_cache(tmp_path, data_root):
    """A new runner's capture without shipped IK goes through the source's own chain (biomotion.data.fukuchi_chain)
    and lands where the shipped IK of the same trial is."""
    base = data_root / "fukuchi-running"
    root = tmp_path / "root" / "fukuchi-running"
    for name in ("c3d/RBDS09runT35.c3d", "c3d/RBDS09static.c3d", "RBDS09", "participantInfo.csv", "generic-models"):
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).symlink_to(base / name)
    out = tmp_path / "cache"
    build_cache(tmp_path / "root", out, progress=False)
    cache = DatasetCache(out)
    (record,) = cache.records
    assert record["clip_id"] == "fukuchi/RBDS09/T35" and record["labels"]["speed"] == 3.5
    solved = cache.motion(0)
    assert solved.mask.sum() == 16
    reference = to_canonical(read_motion(base / "ik/T35/RBDS09_T35_ik_simple.mot"), knee_flipped=True)
    reference = reference.resample(30.0)
    for name in ("hip_flexion_r", "knee_angle_r", "ankle_angle_r", "knee_angle_l", "hip_adduction_l"):
        rms = np.degrees(np.sqrt(np.mean((solved[name] - reference[name][: solved.n_frames]) ** 2)))
        assert rms < 1.0, name  # the chain reproduces RBDS09 within 0.54 deg (tests/ik/test_fukuchi_chain.py)


def test_a_damaged_cache_names_its_file(tmp_path):
    """A manifest.json cut short, or clips.safetensors overwritten, surfaced as JSONDecodeError and SafetensorError
    (internal errors of `biomotion data augment` and `train`); an unknown --source as a KeyError."""
    from biomotion.data.sources import discover_all
    from biomotion.errors import BiomotionError, ConfigError, DataFormatError

    cache = tmp_path / "cache"
    cache.mkdir()
    with pytest.raises(BiomotionError, match="is not a dataset cache"):
        DatasetCache(cache)
    (cache / "manifest.json").write_text('{"clips": [{"source": "opencap", ')
    with pytest.raises(DataFormatError, match=r"manifest\.json:1: not valid JSON"):
        DatasetCache(cache)
    (cache / "manifest.json").write_text('{"clips": []}')
    with pytest.raises(DataFormatError, match=r"manifest\.json: not a dataset-cache manifest: no rate_hz, coordinates"):
        DatasetCache(cache)
    (cache / "manifest.json").write_text(json.dumps({"clips": [], "rate_hz": 30.0, "coordinates": ["pelvis_tx"]}))
    (cache / "clips.safetensors").write_bytes(b"\x10" * 600)
    with pytest.raises(DataFormatError, match=r"clips\.safetensors: cannot read the dataset cache arrays"):
        DatasetCache(cache)
    with pytest.raises(ConfigError, match="unknown source 'nosuch'; registered: fukuchi"):
        discover_all(tmp_path, ["nosuch"])
