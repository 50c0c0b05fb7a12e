"""Plots on real data: each writes a PNG that is not blank and an SVG holding the expected panels and legends."""

import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from biomotion.errors import ConfigError
from biomotion.io.mot import read_ground_reaction, read_motion
from biomotion.io.trc import read_trc
from biomotion.motion import GroundReaction, lowpass
from biomotion.viz.plots import (
    contact_cycles,
    normalize_cycles,
    plot_activations,
    plot_balance,
    plot_ground_reaction,
    plot_joint_angles,
    plot_metric_distributions,
)
from tests.conftest import data_path

OPENCAP = "opencap/Subject4"
GAIT2392 = "opensim-models/Pipelines/Gait2392_Simbody"
RAJAGOPAL = "opensim-models/Pipelines/Rajagopal/ExpData"
MASS = 62.6  # kg, OpenCap subject 4 (SOURCE.md)


def _check(paths, *, texts=()):
    """The PNG has drawn content (not blank) and the SVG is well-formed with the expected text."""
    from PIL import Image

    png, svg = paths
    assert png.suffix == ".png" and svg.suffix == ".svg" and png.stem == svg.stem
    pixels = np.asarray(Image.open(png).convert("RGB"))
    ink = (pixels < 235).any(axis=-1).mean()
    assert 0.03 < ink < 0.9, ink  # something drawn, not a solid fill
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 50  # lines, fills and text in several colours
    text = svg.read_text()
    root = ET.fromstring(text)
    assert sum(1 for e in root.iter() if e.tag.endswith("path")) > 30
    comments = set(re.findall(r"<!-- (.*?) -->", text))  # matplotlib keeps each text as a comment
    for expected in texts:
        assert any(expected in c for c in comments), (expected, sorted(comments)[:20])


def test_cycle_helpers_on_real_force_plates():
    forces = read_ground_reaction(data_path(f"{OPENCAP}/ID/walking4_grf.mot"))
    cycles = contact_cycles(forces, "ground_force_1")  # plate 1 = right foot (SOURCE.md)
    assert cycles == [(pytest.approx(0.02), pytest.approx(1.14))]  # one right stride: 1.12 s, a normal gait cycle
    ramp = normalize_cycles(np.linspace(0, 2, 201), np.linspace(0, 2, 201)[:, None] * [1, -1], [(0.5, 1.5)])
    np.testing.assert_allclose(ramp[0, :, 0], np.linspace(0.5, 1.5, 101), atol=1e-12)
    with pytest.raises(ConfigError, match="not inside the data"):
        normalize_cycles(np.linspace(0, 2, 201), np.zeros(201), [(1.5, 2.5)])


def test_joint_angles_against_a_reference_band(tmp_path):
    motion = read_motion(data_path(f"{OPENCAP}/IK/walking1_ik.mot"))
    reference = [read_motion(data_path(f"{OPENCAP}/IK/{t}_ik.mot")) for t in ("walking2", "walking4")]
    paths = plot_joint_angles(
        motion, tmp_path / "angles.svg", reference=reference, label="walking1", reference_label="walking2, walking4"
    )
    assert paths[0] == tmp_path / "angles.png"
    _check(paths, texts=("knee_angle_r", "ankle_angle_l", "walking2, walking4 mean ± 1 SD (n=2)", "cycle (%)"))
    forces = read_ground_reaction(data_path(f"{OPENCAP}/ID/walking4_grf.mot"))
    stride = plot_joint_angles(
        reference[1],
        tmp_path / "stride",
        coordinates=["knee_angle_r", "pelvis_ty"],
        cycles=contact_cycles(forces, "ground_force_1"),
    )
    _check(stride, texts=("pelvis_ty", "deg", "m"))
    _check(
        plot_joint_angles(motion, tmp_path / "time", coordinates=["hip_flexion_r", "knee_angle_r"]),
        texts=("time (s)", "hip_flexion_r"),
    )


def test_inferred_vs_measured_ground_reaction(tmp_path):
    measured = read_ground_reaction(data_path(f"{OPENCAP}/ID/walking1_grf.mot"))
    markers = read_trc(data_path(f"{OPENCAP}/MarkerData/walking1.trc"))
    pelvis = np.nanmean(markers.select(["r.ASIS", "L.ASIS", "r.PSIS", "L.PSIS"]).positions, axis=1)
    # Newton's second law on a point mass at the pelvis centre: total GRF = m (a + g), g = 9.81 m/s^2 up
    smooth = lowpass(pelvis, markers.rate, 6.0)
    acceleration = np.gradient(np.gradient(smooth, markers.times, axis=0), markers.times, axis=0)
    inferred_force = MASS * (acceleration + [0.0, 9.81, 0.0])
    total = measured.force.sum(axis=1)
    assert np.corrcoef(inferred_force[10:-10, 1], total[10:-10, 1])[0, 1] > 0.5  # the inference is real physics
    cop = np.full((markers.n_frames, 1, 3), np.nan)
    inferred = GroundReaction(markers.times, ("pelvis point mass",), inferred_force[:, None], cop, np.zeros_like(cop))
    total_measured = GroundReaction(measured.times, ("plates 1+2",), total[:, None], cop, np.zeros_like(cop))
    paths = plot_ground_reaction(total_measured, tmp_path / "grf", inferred=inferred, body_weight=MASS * 9.81)
    _check(paths, texts=("measured plates 1+2", "inferred pelvis point mass", "vertical (y)", "(BW)"))
    _check(plot_ground_reaction(measured, tmp_path / "plates"), texts=("ground_force_1", "ground_force_2"))


def _cmc_excitations():
    """CMC muscle excitations of gait2392 subject01 walk1 (OpenSim's stored reference results), 92 muscles."""
    root = ET.parse(data_path(f"{GAIT2392}/OutputReference/ResultsCMC/subject01_walk1_controls.xml")).getroot()
    actuators = ("FX", "FY", "FZ", "MX", "MY", "MZ")  # residual and reserve actuators are not muscles
    controls = [
        c
        for c in root.iter("ControlLinear")
        if c.get("name", "").endswith(".excitation")
        and c.get("name").split(".")[0] not in actuators
        and "_reserve." not in c.get("name")
    ]
    times = np.array([float(n.findtext("t")) for n in controls[0].iter("ControlLinearNode")])
    values = np.array([[float(n.findtext("value")) for n in c.iter("ControlLinearNode")] for c in controls]).T
    return times, [c.get("name").removesuffix(".excitation") for c in controls], values


def test_activation_heatmap_with_emg_envelopes(tmp_path):
    times, names, excitation = _cmc_excitations()
    assert excitation.shape == (147, 92) and excitation.min() >= 0.0 and excitation.max() <= 1.0
    cycle = contact_cycles(read_ground_reaction(data_path(f"{GAIT2392}/subject01_walk1_grf.mot")), "ground_force")
    activation = normalize_cycles(times, excitation, cycle)[0]
    table = np.loadtxt(data_path(f"{RAJAGOPAL}/emg_walk_raw.anc"), skiprows=11)
    channels = ["SOL", "GAS", "TA", "MH", "BF", "VL", "VM", "RF", "GMAX", "GMED"]
    raw = table[:, 19:29]
    # linear envelope: remove offset, full-wave rectify, 6 Hz zero-lag low-pass (Winter 2009)
    envelope = lowpass(np.abs(raw - raw.mean(axis=0)), 2000.0, 6.0)
    emg_cycle = contact_cycles(read_ground_reaction(data_path(f"{RAJAGOPAL}/grf_walk.mot")), "ground_force_r")
    emg = normalize_cycles(table[:, 0], envelope, emg_cycle)[0]
    percent = np.linspace(0, 100, 101)
    right = [k for k, n in enumerate(names) if n.endswith("_r")]
    pairs = {"soleus_r": "SOL", "med_gas_r": "GAS", "tib_ant_r": "TA", "vas_lat_r": "VL", "rect_fem_r": "RF"}
    paths = plot_activations(
        percent,
        [names[k] for k in right],
        activation[:, right],
        tmp_path / "act",
        emg=(percent, channels, emg),
        pairs=pairs,
        xlabel="gait cycle (%)",
    )
    _check(paths, texts=("soleus_r vs SOL", "tib_ant_r vs TA", "gait cycle (%)", "activation"))
    with pytest.raises(ConfigError, match="cannot pair"):
        plot_activations(
            percent, names, activation, tmp_path / "bad", emg=(percent, channels, emg), pairs={"soleus_r": "EMG9"}
        )


def test_com_and_zmp_over_the_support_polygon(tmp_path):
    markers = read_trc(data_path(f"{OPENCAP}/MarkerData/walking1.trc"))
    forces = read_ground_reaction(data_path(f"{OPENCAP}/ID/walking1_grf.mot"))
    com = np.nanmean(
        markers.select(["r.ASIS", "L.ASIS", "r.PSIS", "L.PSIS"]).positions, axis=1
    )  # pelvis centre as the COM proxy
    # on flat ground the ZMP is the centre of pressure of the total ground reaction (Sardain & Bessonnet 2004)
    force, cop = np.nan_to_num(forces.force[..., 1]), np.nan_to_num(forces.cop)
    total = force.sum(axis=1)
    zmp = np.where(total[:, None] > 20, (cop * force[..., None]).sum(axis=1) / np.maximum(total, 1e-9)[:, None], np.nan)
    feet = markers.select(["r_calc", "r_toe", "r_5meta", "L_calc", "L_toe", "L_5meta"]).positions
    loaded = np.repeat(force > 20, 3, axis=1)  # plate 1 = right foot, plate 2 = left (SOURCE.md)
    support = np.full((markers.n_frames, 6, 3), np.nan)
    for frame in np.flatnonzero(loaded.any(axis=1)):  # convex hull of the loaded feet's markers, on the floor
        points = feet[frame, loaded[frame]][:, [0, 2]]
        hull = ConvexHull(points).vertices if len(points) >= 3 else np.arange(len(points))
        support[frame, : len(hull)] = np.insert(points[hull], 1, 0.0, axis=1)
    paths = plot_balance(com, zmp, tmp_path / "balance", support=support)
    _check(paths, texts=("COM (ground projection)", "ZMP", "support polygon"))


def test_metric_distributions(tmp_path):
    knee_range, peak_force = {}, {}
    for group, trials in (
        ("walking", ("walking1", "walking2", "walking4")),
        ("toe-in/out", ("walkingTI1", "walkingTI2", "walkingTI3", "walkingTO1", "walkingTO2", "walkingTO3")),
    ):
        motions = [read_motion(data_path(f"{OPENCAP}/IK/{t}_ik.mot")) for t in trials]
        knee_range[group] = [np.degrees(np.ptp(m["knee_angle_r"])) for m in motions]
        peak_force[group] = [
            np.nanmax(read_ground_reaction(data_path(f"{OPENCAP}/ID/{t}_grf.mot")).force[..., 1]) for t in trials
        ]
    assert all(50 < v < 80 for v in knee_range["walking"])  # knee flexion range in walking: about 60 degrees
    paths = plot_metric_distributions(
        {
            "knee flexion range (deg)": knee_range,
            "peak vertical GRF (N)": peak_force,
            "all knee ranges": np.concatenate(list(knee_range.values())),
        },
        tmp_path / "metrics",
        bins=6,
    )
    _check(paths, texts=("knee flexion range (deg)", "walking (n=3)", "toe-in/out (n=6)", "n=9"))
    with pytest.raises(ConfigError, match="no finite value"):
        plot_metric_distributions({"empty": [np.nan]}, tmp_path / "none")
