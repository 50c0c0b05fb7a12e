"""BVH reading, forward kinematics and writing, on the Bandai-Namco clips and on hand-built files."""

from __future__ import annotations

import csv
import gzip
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from biomotion.errors import DataFormatError
from biomotion.io.bvh import CHANNEL_NAMES, BVHMotion, Skeleton, read_bvh, write_bvh
from tests.conftest import data_path

BANDAI = "bandai-namco"
JOINTS = (
    "joint_Root",
    "Hips",
    "Spine",
    "Chest",
    "Neck",
    "Head",
    "Shoulder_L",
    "UpperArm_L",
    "LowerArm_L",
    "Hand_L",
    "Shoulder_R",
    "UpperArm_R",
    "LowerArm_R",
    "Hand_R",
    "UpperLeg_L",
    "LowerLeg_L",
    "Foot_L",
    "Toes_L",
    "UpperLeg_R",
    "LowerLeg_R",
    "Foot_R",
    "Toes_R",
)
BANDAI_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")


def _write_text(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def _assert_same(a: BVHMotion, b: BVHMotion, tol: float = 1e-6) -> None:
    assert a.skeleton.names == b.skeleton.names
    assert a.skeleton.parents == b.skeleton.parents
    assert a.skeleton.channels == b.skeleton.channels
    assert a.skeleton.end_sites == b.skeleton.end_sites
    np.testing.assert_allclose(a.skeleton.offsets, b.skeleton.offsets, rtol=0, atol=tol)
    assert a.frame_time == pytest.approx(b.frame_time, rel=1e-9)
    np.testing.assert_allclose(a.values, b.values, rtol=0, atol=tol)
    np.testing.assert_allclose(a.global_positions(), b.global_positions(), rtol=0, atol=tol)


# --- every real clip -------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_every_bandai_namco_clip_reads_with_plausible_kinematics():
    root = data_path(BANDAI)
    expected_frames = {}
    for dataset in ("dataset-1", "dataset-2"):
        with open(root / dataset / "index.csv", newline="") as handle:
            expected_frames.update({row["file"]: int(row["frames"]) for row in csv.DictReader(handle) if row["file"]})
    files = sorted(root.glob("dataset-[12]/*.bvh.gz"))
    assert len(files) == 664
    start = time.perf_counter()
    hips_means, toe_minima = [], []
    for file in files:
        motion = read_bvh(file)
        skeleton = motion.skeleton
        assert tuple(n for n, end in zip(skeleton.names, skeleton.end_sites) if not end) == JOINTS, file.name
        assert sum(skeleton.end_sites) == 5  # after Head, both Hands and both Toes
        assert all(c == BANDAI_CHANNELS for c, end in zip(skeleton.channels, skeleton.end_sites) if not end)
        assert motion.values.shape == (expected_frames[file.name], 132), file.name
        assert motion.frame_time == pytest.approx(1 / 30, abs=1e-6)
        assert (motion.units, motion.units_inferred) == ("cm", True)
        height = motion.global_positions()[..., 1]
        hips_means.append(height[:, skeleton.index("Hips")].mean())
        toe_minima.append(height[:, [skeleton.index("Toes_L"), skeleton.index("Toes_R")]].min())
    elapsed = time.perf_counter() - start
    # Measured: hips mean height 0.833-0.943 m, toe-joint minimum 0.025-0.054 m over the 664 clips.
    assert 0.7 < min(hips_means) and max(hips_means) < 1.0
    assert 0.0 < min(toe_minima) and max(toe_minima) < 0.1
    assert elapsed < 40, f"reading + FK of 664 clips took {elapsed:.1f} s"


def test_joint_root_carries_the_travel_in_run_normal_001():
    motion = read_bvh(data_path(f"{BANDAI}/dataset-1/dataset-1_run_normal_001.bvh.gz"))
    root_z = motion.channel("joint_Root", "Zposition")
    assert root_z[0] == pytest.approx(0.0, abs=1e-3) and root_z[-1] == pytest.approx(200.0, abs=0.5)
    hips_local = motion.local_translations()[:, motion.skeleton.index("Hips")]
    assert np.ptp(hips_local[:, 2]) < 0.05  # Hips runs in place in its parent's frame ...
    hips = motion.global_positions()[:, motion.skeleton.index("Hips")]
    # ... so its global forward travel is joint_Root's (no joint_Root rotation in this clip): 2.0 m.
    np.testing.assert_allclose(hips[:, 2] - hips_local[:, 2], root_z / 100, atol=1e-9)
    assert hips[-1, 2] - hips[0, 2] == pytest.approx(2.0, abs=0.01)
    markers = motion.to_markers(end_sites=False)
    assert markers.names == JOINTS
    np.testing.assert_allclose(markers["Hips"], hips)
    assert markers.rate == pytest.approx(30.0, rel=1e-5)


@pytest.mark.parametrize(
    "clip", ["dataset-1/dataset-1_run_normal_001.bvh.gz", "dataset-2/dataset-2_walk_normal_004.bvh.gz"]
)
@pytest.mark.parametrize("suffix", [".bvh", ".bvh.gz"])
def test_real_clip_round_trip(tmp_path, clip, suffix):
    original = read_bvh(data_path(f"{BANDAI}/{clip}"))
    target = tmp_path / f"copy{suffix}"
    write_bvh(target, original)
    assert (target.read_bytes()[:2] == b"\x1f\x8b") == suffix.endswith(".gz")
    text = gzip.decompress(target.read_bytes()).decode() if suffix.endswith(".gz") else target.read_text()
    assert text.count("CHANNELS 6 " + " ".join(BANDAI_CHANNELS)) == 22
    assert "Frame Time: 0.0333333\n" in text
    again = read_bvh(target)
    assert again.units == "cm"
    _assert_same(original, again)


def test_writing_in_metres_keeps_positions(tmp_path):
    original = read_bvh(data_path(f"{BANDAI}/dataset-1/dataset-1_run_normal_001.bvh.gz"))
    write_bvh(tmp_path / "m.bvh", original, units="m")
    metres = read_bvh(tmp_path / "m.bvh")
    assert (metres.units, metres.units_inferred) == ("m", True)
    np.testing.assert_allclose(metres.global_positions(), original.global_positions(), atol=1e-9)
    column = original.skeleton.column("Hips", "Yposition")
    np.testing.assert_allclose(metres.values[:, column], original.values[:, column] / 100, atol=1e-12)


# --- hand-built files ------------------------------------------------------------------------------------------

TWO_JOINTS = """HIERARCHY
ROOT base
{
  OFFSET 1 2 3
  CHANNELS 4 Xposition Zrotation Xrotation Yrotation
  JOINT tip
  {
    OFFSET 2 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0 0 0 0 0 0 0
1 90 0 0 0 0 0
"""


def test_two_joint_chain_by_hand(tmp_path):
    motion = read_bvh(_write_text(tmp_path / "chain.bvh", TWO_JOINTS), units="m")
    positions = motion.global_positions()
    # The Xposition channel replaces the x of the root's offset (1, 2, 3), y and z stay; frame 0: no rotation,
    # the tip 2 m along +x; frame 1: a 90 deg turn about z takes the tip's +x offset to +y.
    np.testing.assert_allclose(positions[0], [[0, 2, 3], [2, 2, 3]], atol=1e-12)
    np.testing.assert_allclose(positions[1], [[1, 2, 3], [1, 4, 3]], atol=1e-12)
    np.testing.assert_allclose(motion.times, [0.0, 0.5])
    assert (motion.units, motion.units_inferred) == ("m", False)


SYNTHETIC_XYZ = """HIERARCHY
ROOT pelvis
{
\tOFFSET 0.0 0.9 0.0
\tCHANNELS 6 Zposition Xrotation Xposition Yrotation Yposition Zrotation
\tJOINT thigh
\t{
\t\tOFFSET 0.1 -0.05 0.0
\t\tCHANNELS 3 Xrotation Yrotation Zrotation
\t\tJOINT shank
\t\t{
\t\t\tOFFSET 0.0 -0.42 0.02
\t\t\tCHANNELS 3 Yrotation Zrotation Xrotation
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0.0 -0.4 0.0
\t\t\t}
\t\t}
\t}
}
MOTION
Frames: {frames}
Frame Time: 0.01
{rows}
"""


def test_synthetic_xyz_order_in_metres_matches_scipy(tmp_path):
    rng = np.random.default_rng(3)
    frames = 7
    values = rng.uniform(-170, 170, (frames, 12))
    values[:, [0, 2, 4]] = rng.uniform(-2, 2, (frames, 3))  # Zposition, Xposition, Yposition columns
    rows = "\n".join(" ".join(f"{v:.12g}" for v in row) for row in values)
    path = _write_text(tmp_path / "xyz.bvh", SYNTHETIC_XYZ.replace("{frames}", str(frames)).replace("{rows}", rows))
    motion = read_bvh(path)
    assert (motion.units, motion.units_inferred) == ("m", True)
    assert motion.skeleton.names == ("pelvis", "thigh", "shank", "shank_end")
    assert motion.skeleton.channels[0] == ("Zposition", "Xrotation", "Xposition", "Yrotation", "Yposition", "Zrotation")

    # Direct computation: scipy's upper-case sequences are intrinsic rotations, BVH's definition.
    pelvis = Rotation.from_euler("XYZ", values[:, [1, 3, 5]], degrees=True)
    thigh = Rotation.from_euler("XYZ", values[:, 6:9], degrees=True)
    shank = Rotation.from_euler("YZX", values[:, 9:12], degrees=True)
    root = values[:, [2, 4, 0]]
    knee = root + pelvis.apply([0.1, -0.05, 0.0])
    ankle = knee + (pelvis * thigh).apply([0.0, -0.42, 0.02])
    toe = ankle + (pelvis * thigh * shank).apply([0.0, -0.4, 0.0])
    np.testing.assert_allclose(motion.global_positions(), np.stack([root, knee, ankle, toe], axis=1), atol=1e-12)
    np.testing.assert_allclose(motion.local_rotations()[:, 2], shank.as_matrix(), atol=1e-12)


@pytest.mark.parametrize("scale, units", [(1.0, "m"), (100.0, "cm"), (1000.0, "mm")])
def test_units_detected_from_skeleton_size(tmp_path, scale, units):
    bone = 0.45 * scale  # two 0.45 m bones: L = 0.9, 90 or 900 file units
    text = (
        f"HIERARCHY\nROOT a\n{{\nOFFSET 0 {2 * bone} 0\nCHANNELS 3 Xposition Yposition Zposition\n"
        f"JOINT b\n{{\nOFFSET {bone} 0 0\nCHANNELS 1 Zrotation\nEnd Site\n{{\nOFFSET 0 {-bone} 0\n}}\n}}\n}}\n"
        f"MOTION\nFrames: 2\nFrame Time: 0.1\n0 0 0 10\n{bone} 0 0 20\n"
    )
    motion = read_bvh(_write_text(tmp_path / "size.bvh", text))
    assert (motion.units, motion.units_inferred) == (units, True)
    np.testing.assert_allclose(np.abs(motion.skeleton.offsets[1:]).sum(axis=1), [0.45, 0.45])
    np.testing.assert_allclose(motion.local_translations()[1, 0], [0.45, 0, 0])
    forced = read_bvh(tmp_path / "size.bvh", units="cm")
    assert (forced.units, forced.units_inferred) == ("cm", False)
    np.testing.assert_allclose(forced.skeleton.offsets[1, 0], 0.0045 * scale)


# --- errors: file and line -------------------------------------------------------------------------------------


def _error(tmp_path, text: str, name: str = "bad.bvh") -> DataFormatError:
    path = _write_text(tmp_path / name, text)
    with pytest.raises(DataFormatError) as caught:
        read_bvh(path)
    assert caught.value.path == path and str(path) in str(caught.value)
    return caught.value


def test_truncated_frames(tmp_path):
    error = _error(tmp_path, TWO_JOINTS.replace("Frames: 2", "Frames: 3"))
    assert "Frames: says 3" in str(error) and error.line is not None


def test_frame_line_with_a_missing_value_is_named(tmp_path):
    error = _error(tmp_path, TWO_JOINTS.replace("1 90 0 0 0 0 0", "1 90 0 0 0 0"))
    assert (error.line, error.frame) == (16, 1)
    assert "6 values, expected 7" in str(error)


def test_unknown_channel(tmp_path):
    error = _error(tmp_path, TWO_JOINTS.replace("3 Zrotation Xrotation", "3 Zrotation Wrotation"))
    assert error.line == 9 and "Wrotation" in str(error)


def test_missing_motion_section(tmp_path):
    error = _error(tmp_path, TWO_JOINTS.split("MOTION")[0])
    assert "MOTION" in str(error) and error.line == 12


def test_nan_in_data(tmp_path):
    error = _error(tmp_path, TWO_JOINTS.replace("1 90 0 0", "1 90 nan 0"))
    assert (error.line, error.frame) == (16, 1) and "not finite" in str(error)


@pytest.mark.parametrize("content", ["", "  \n\n"])
def test_empty_file(tmp_path, content):
    assert "empty" in str(_error(tmp_path, content))


def test_empty_and_broken_gzip(tmp_path):
    (tmp_path / "empty.bvh.gz").write_bytes(gzip.compress(b""))
    with pytest.raises(DataFormatError, match="empty"):
        read_bvh(tmp_path / "empty.bvh.gz")
    (tmp_path / "cut.bvh.gz").write_bytes(gzip.compress(TWO_JOINTS.encode())[:40])
    with pytest.raises(DataFormatError, match="cannot read"):
        read_bvh(tmp_path / "cut.bvh.gz")


def test_unclosed_joint_and_bad_offset(tmp_path):
    error = _error(
        tmp_path,
        TWO_JOINTS.replace(
            "    CHANNELS 3 Zrotation Xrotation Yrotation\n  }\n", "    CHANNELS 3 Zrotation Xrotation Yrotation\n"
        ),
    )
    assert "never closed" in str(error)
    error = _error(tmp_path, TWO_JOINTS.replace("OFFSET 2 0 0", "OFFSET 2 x 0"))
    assert error.line == 8 and "'x'" in str(error)


# --- property-based: random skeletons and corruptions ----------------------------------------------------------


@st.composite
def motions(draw) -> BVHMotion:
    count = draw(st.integers(1, 6))
    names, parents, channels, end_sites = [], [], [], []
    path: list[int] = []  # depth-first file order: a joint hangs below the previous joint or an ancestor of it
    for j in range(count):
        candidates = [k for k in path if not end_sites[k]]
        parent = -1 if not candidates or draw(st.integers(0, 9)) == 0 else draw(st.sampled_from(candidates))
        path = (path[: path.index(parent) + 1] if parent >= 0 else []) + [j]
        is_end = parent >= 0 and draw(st.booleans())
        chans = () if is_end else tuple(draw(st.permutations(CHANNEL_NAMES))[: draw(st.sampled_from([3, 6]))])
        if not is_end and draw(st.booleans()):
            chans = tuple(c for c in chans if c.endswith("rotation"))  # 3-channel joints
        if is_end:  # the reader's names for End Sites: <parent>_end, then <parent>_end2 ...
            taken = sum(name.startswith(f"{names[parent]}_end") for name in names)
            names.append(f"{names[parent]}_end" + (str(taken + 1) if taken else ""))
        else:
            names.append(f"joint{j}")
        parents.append(parent)
        channels.append(chans)
        end_sites.append(is_end)
    if not any(channels):
        channels[0] = ("Zrotation", "Xrotation", "Yrotation")
    offsets = draw(st.lists(st.tuples(*[st.floats(-0.5, 0.5)] * 3), min_size=count, max_size=count))
    skeleton = Skeleton(tuple(names), tuple(parents), np.array(offsets), tuple(channels), tuple(end_sites))
    frames = draw(st.integers(1, 4))
    values = np.array(
        draw(
            st.lists(st.floats(-180, 180), min_size=frames * skeleton.n_channels, max_size=frames * skeleton.n_channels)
        )
    ).reshape(frames, -1)
    frame_time = draw(st.floats(1e-3, 1.0))
    return BVHMotion(skeleton, values, frame_time, units="cm")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(motion=motions(), gz=st.booleans())
def test_random_motion_round_trip(tmp_path, motion, gz):
    target = tmp_path / ("random.bvh.gz" if gz else "random.bvh")
    write_bvh(target, motion)
    _assert_same(motion, read_bvh(target, units="cm"))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(motion=motions(), data=st.data())
def test_truncated_file_raises_data_format_error(tmp_path, motion, data):
    target = tmp_path / "whole.bvh"
    write_bvh(target, motion)
    text = target.read_text().rstrip()
    last_token = max(text.rfind(" "), text.rfind("\n")) + 1  # cutting inside it may leave a valid number
    cut = data.draw(st.integers(0, last_token - 1))
    broken = _write_text(tmp_path / "cut.bvh", text[:cut])
    with pytest.raises(DataFormatError):
        read_bvh(broken, units="cm")


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(motion=motions(), data=st.data())
def test_missing_value_on_a_frame_line_raises_data_format_error(tmp_path, motion, data):
    target = tmp_path / "whole.bvh"
    write_bvh(target, motion)
    lines = target.read_text().split("\n")
    first = lines.index(next(line for line in lines if line.startswith("Frame Time:"))) + 1
    row = data.draw(st.integers(first, first + motion.n_frames - 1))
    words = lines[row].split()
    del words[data.draw(st.integers(0, len(words) - 1))]
    lines[row] = " ".join(words)
    with pytest.raises(DataFormatError) as caught:
        read_bvh(_write_text(tmp_path / "short.bvh", "\n".join(lines)), units="cm")
    if words:  # a line left with values is named; an emptied one reads as a missing frame line
        assert caught.value.line == row + 1 and caught.value.frame == row - first
