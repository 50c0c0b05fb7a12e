"""Regenerate the README's plot images from real data with the project's own API.

    .venv/bin/python docs/figures.py [--data-root ../shared/data] [--out docs/images]

Joint angles (OpenCap walking1 against walking2/4), inferred vs measured GRF and the COM/ZMP path come from
`biomotion.analysis.chain.analyze`; the activation heatmap shows OpenSim's stored CMC excitations of gait2392 subject01
with the Rajagopal walk's EMG envelopes; the metric panel shows knee range and peak GRF over OpenCap walking trials;
the viewer screenshot is `biomotion view` of walking1 at frame 60 in headless Chromium; the generated run is
`biomotion generate` for `examples/runner_52_acl.yaml` (its joint angles).
"""

from __future__ import annotations

import argparse
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from biomotion.analysis.chain import analyze, support_polygons, write_analysis
from biomotion.body.model import BodyModel
from biomotion.io.mot import read_ground_reaction, read_motion
from biomotion.motion import lowpass
from biomotion.viz.browser import Page
from biomotion.viz.plots import (
    contact_cycles,
    normalize_cycles,
    plot_activations,
    plot_balance,
    plot_ground_reaction,
    plot_joint_angles,
    plot_metric_distributions,
)
from biomotion.viz.viewer import view_command


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-root", type=Path, default=Path("../shared/data"))
    parser.add_argument("--out", type=Path, default=Path("docs/images"))
    args = parser.parse_args()
    root, out = args.data_root, args.out
    subject4 = root / "opencap/Subject4"
    model = BodyModel.from_osim(subject4 / "Models/optimized_scale_and_markers.osim")

    walking = read_motion(subject4 / "IK/walking1_ik.mot")
    reference = [read_motion(subject4 / f"IK/{t}_ik.mot") for t in ("walking2", "walking4")]
    plot_joint_angles(
        walking, out / "plot_joint_angles", reference=reference, label="walking1", reference_label="walking2, walking4"
    )

    plates = read_ground_reaction(subject4 / "ID/walking1_grf.mot")
    result = analyze(walking, model, plates)
    plot_ground_reaction(result.measured, out / "plot_grf", inferred=result.inferred, body_weight=result.body_weight)
    plot_balance(
        result.com,
        result.zmp,
        out / "plot_balance",
        support=support_polygons(result.contact_points, result.contact_loaded),
    )

    gait = root / "opensim-models/Pipelines/Gait2392_Simbody"
    controls = ET.parse(gait / "OutputReference/ResultsCMC/subject01_walk1_controls.xml").getroot()
    muscles = [
        c
        for c in controls.iter("ControlLinear")
        if c.get("name", "").endswith(".excitation")
        and c.get("name").split(".")[0] not in ("FX", "FY", "FZ", "MX", "MY", "MZ")
        and "_reserve." not in c.get("name")
    ]
    times = np.array([float(n.findtext("t")) for n in muscles[0].iter("ControlLinearNode")])
    excitation = np.array([[float(n.findtext("value")) for n in c.iter("ControlLinearNode")] for c in muscles]).T
    names = [c.get("name").removesuffix(".excitation") for c in muscles]
    cycle = contact_cycles(read_ground_reaction(gait / "subject01_walk1_grf.mot"), "ground_force")
    activation = normalize_cycles(times, excitation, cycle)[0]
    emg_file = root / "opensim-models/Pipelines/Rajagopal/ExpData"
    table = np.loadtxt(emg_file / "emg_walk_raw.anc", skiprows=11)
    raw = table[:, 19:29]
    envelope = lowpass(np.abs(raw - raw.mean(axis=0)), 2000.0, 6.0)  # rectified, 6 Hz linear envelope
    emg = normalize_cycles(
        table[:, 0], envelope, contact_cycles(read_ground_reaction(emg_file / "grf_walk.mot"), "ground_force_r")
    )[0]
    percent = np.linspace(0, 100, 101)
    right = [k for k, n in enumerate(names) if n.endswith("_r")]
    plot_activations(
        percent,
        [names[k] for k in right],
        activation[:, right],
        out / "plot_activations",
        emg=(percent, ["SOL", "GAS", "TA", "MH", "BF", "VL", "VM", "RF", "GMAX", "GMED"], emg),
        pairs={"soleus_r": "SOL", "med_gas_r": "GAS", "tib_ant_r": "TA", "vas_lat_r": "VL", "rect_fem_r": "RF"},
        xlabel="gait cycle (%)",
    )

    knee_range, peak_force = {}, {}
    for group, trials in (
        ("normal", ("walking1", "walking2", "walking4")),
        ("toe-in", ("walkingTI1", "walkingTI2", "walkingTI3")),
        ("toe-out", ("walkingTO1", "walkingTO2", "walkingTO3")),
    ):
        knee_range[group] = [
            np.degrees(np.ptp(read_motion(subject4 / f"IK/{t}_ik.mot")["knee_angle_r"])) for t in trials
        ]
        peak_force[group] = [
            np.nanmax(read_ground_reaction(subject4 / f"ID/{t}_grf.mot").force[..., 1]) for t in trials
        ]
    plot_metric_distributions(
        {"knee flexion range (deg)": knee_range, "peak vertical GRF (N)": peak_force}, out / "plot_metrics"
    )
    scratch = Path(tempfile.mkdtemp())
    balance = write_analysis(result, scratch)["com_zmp"]
    viewer = view_command(
        subject4 / "IK/walking1_ik.mot",
        model=subject4 / "Models/optimized_scale_and_markers.osim",
        grf=subject4 / "ID/walking1_grf.mot",
        com_zmp=balance,
        out=scratch / "viewer.html",
        geometry=(root / "opensim-models/Geometry", root / "opensim-models/Models/Rajagopal/Geometry"),
    )
    with Page(1200, 700) as page:  # headless Chromium, as in the viewer's browser tests
        page.open(viewer)
        page.evaluate("window.viewer.ready")
        page.evaluate("window.viewer.setFrame(60)")
        (out / "viewer_walking.png").write_bytes(page.screenshot())
    generated_figure(root, out, scratch)
    print(f"figures written to {out}")


def generated_figure(root: Path, out: Path, scratch: Path) -> None:
    """Joint angles of `biomotion generate` for the example profile running at 3.5 m/s (seed 0)."""
    from biomotion.generation.request import generate as generate_command

    result = generate_command(
        action="running at 3.5 m/s",
        out=scratch / "generated",
        data_root=root,
        profile_file=Path("examples/runner_52_acl.yaml"),
        seconds=3.0,
    )
    files = result["files"][next(iter(result["files"]))]
    (out / "plot_generated_joint_angles.png").write_bytes(files["plot_joint_angles"].read_bytes())


if __name__ == "__main__":
    main()
