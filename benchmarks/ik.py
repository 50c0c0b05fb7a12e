"""Marker IK and static scaling, side by side with OpenSim 4.6 on the same trials; writes docs/results/ik.md.

    python benchmarks/ik.py [--data-root ../shared/data] [--repeats 3] [--threads 1] [--out docs/results/ik.md]
                            [--json docs/results/ik.json] [--nimble-python PYTHON]

IK: for each trial, OpenSim's ``InverseKinematicsTool`` (fresh, same model, marker weights, coordinate tasks and
frames; logging off) and `biomotion.ik.solve_ik` read the same TRC file and write a .mot; OpenSim's ``run()`` is
timed once, ours is the best of ``--repeats`` runs, with ``--threads`` torch threads (1 by default: OpenSim's IK
is single-threaded). Accuracy as in `biomotion.validation.ik.compare`: per-coordinate RMSE between the two solutions
over all frames (coordinates no tracked marker moves are listed, not scored), marker RMSE of both with the same
forward kinematics, and the frames where one objective is lower.

Scaling: ScaleTool measurement factors from every Fukuchi runner's static C3D against the shipped ScaleSets, and
the whole static calibration (factors, marker placement, scaled .osim written) against OpenSim's ScaleTool on
RBDS001.

Peer: with ``--nimble-python``, an interpreter that has nimblephysics (AddBiomechanics' engine; it needs numpy < 2,
see `benchmarks/nimble_peer.py`), the Fukuchi trials are also solved by nimble on the same markers and model, in
its own process: time and marker RMS error. ``--json`` writes the figures, ``ik_speedup_vs_opensim_min`` the worst
trial's ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from biomotion.body.model import BodyModel
from biomotion.body.scaling.osim_file import write_scaled_osim
from biomotion.ik.scaling import scale_static
from biomotion.io.atomic import atomic_write
from biomotion.io.setup import read_scale_setup
from biomotion.io.trc import read_trc, write_trc
from biomotion.validation import ik as validate

REPO = Path(__file__).resolve().parents[1]
OPENCAP_TRIALS = ("walking1", "DJ1", "squats1", "STS1")
RUNNERS = ("RBDS002", "RBDS010")


def _cases(root: Path, repeats: int) -> dict[str, dict]:
    cases = {"gait2392 subject01 walk1": validate.gait2392_case(root, repeats)}
    for trial in OPENCAP_TRIALS:
        cases[f"OpenCap Subject4 {trial}"] = validate.opencap_case(root, trial, repeats)
    for runner in RUNNERS:
        cases[f"Fukuchi {runner} 3.5 m/s"] = validate.fukuchi_case(root, runner, repeats)
    cases["Rajagopal walk"] = validate.rajagopal_case(root, repeats)
    return cases


def _nimble(root: Path, runner: str, python: str, folder: Path) -> dict:
    """nimble's solve of a runner's 3.5 m/s trial (`benchmarks/nimble_peer.py` in ``python``), on the markers and
    window `biomotion.validation.ik.fukuchi_case` uses."""
    from biomotion.io.setup import read_ik_setup

    base = root / validate.FUKUCHI
    setup = read_ik_setup(base / runner / f"{runner}_T35_ikSetup.xml")
    markers = validate.fukuchi_markers(base / "c3d" / f"{runner}runT35.c3d").slice(*setup.time_range)
    trial = folder / f"{runner}.npz"
    np.savez(
        trial,
        positions=markers.positions,
        names=np.array(markers.names),
        weight_names=np.array(list(setup.marker_weights)),
        weights=np.array(list(setup.marker_weights.values()), dtype=float),
        model=str(base / runner / f"{runner}_simple.osim"),
    )
    done = subprocess.run(
        [python, str(Path(__file__).with_name("nimble_peer.py")), str(trial)], capture_output=True, text=True
    )
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode != 0 or not lines:
        return {"error": f"exit {done.returncode}: {done.stderr.strip().splitlines()[-1:] or done.stdout[-200:]}"}
    return json.loads(lines[-1])


def _opensim_scaletool(root: Path, runner: str, folder: Path) -> float:
    """OpenSim's ScaleTool on the runner's setup, pointed at the same static markers; seconds of ``run()``."""
    from biomotion.settings import opensim_oracle

    opensim = opensim_oracle()

    setup_path = root / validate.FUKUCHI / runner / f"{runner}_scaleSetup_simple.xml"
    write_trc(
        folder / "static.trc",
        validate.fukuchi_markers(root / validate.FUKUCHI / "c3d" / f"{runner}static.c3d"),
        units="mm",
    )
    text = (
        setup_path.read_text()
        .replace(f"{runner}\\{runner}static.trc", "static.trc")
        .replace(
            "..\\model\\Denton2023_LowerLimb_Fukuchi2017.osim",
            str(root / validate.FUKUCHI / "generic-models" / "Denton2023_LowerLimb_Fukuchi2017.osim"),
        )
    )
    text = re.sub(
        r"<output_(model|scale|motion)_file>[^<]*</output_\1_file>",
        lambda m: f"<output_{m.group(1)}_file>out_{m.group(1)}_{m.start()}</output_{m.group(1)}_file>",
        text,
    )
    (folder / "setup.xml").write_text(text)
    tool = opensim.ScaleTool(str(folder / "setup.xml"))
    began = time.perf_counter()
    if not tool.run():
        raise RuntimeError("OpenSim's ScaleTool failed")
    return time.perf_counter() - began


def _scaling(root: Path, repeats: int) -> dict:
    base = root / validate.FUKUCHI
    runners = sorted(
        p.name
        for p in base.iterdir()
        if (p / f"{p.name}_scaleSetup_simple.xml").exists() and (base / "c3d" / f"{p.name}static.c3d").exists()
    )
    errors = validate.scaling_errors(root, runners)
    runner = "RBDS001"
    generic_path = base / "generic-models" / "Denton2023_LowerLimb_Fukuchi2017.osim"
    setup = read_scale_setup(base / runner / f"{runner}_scaleSetup_simple.xml")
    with tempfile.TemporaryDirectory(prefix="biomotion-bench-scale-") as folder:
        with validate.quiet_stdout():
            opensim_seconds = _opensim_scaletool(root, runner, Path(folder))
        seconds = float("inf")
        for _ in range(repeats):
            began = time.perf_counter()
            static = read_trc(Path(folder) / "static.trc")
            result = scale_static(BodyModel.from_osim(generic_path), static, setup)
            write_scaled_osim(generic_path, Path(folder) / "ours.osim", result)
            seconds = min(seconds, time.perf_counter() - began)
    return {
        "runners": len(errors),
        "max_rel_err": max(errors.values()),
        "worst": max(errors, key=errors.get),
        "seconds": seconds,
        "opensim_seconds": opensim_seconds,
        "placement_rms": result.placement.ik.rmse,
    }


def _load() -> str:
    try:
        return ", ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


def _table(cases: dict[str, dict], scaling: dict, args: argparse.Namespace, peers: dict | None = None) -> str:
    lines = [
        "# Marker IK and static scaling vs OpenSim 4.6",
        "",
        f"`python benchmarks/ik.py --repeats {args.repeats} --threads {args.threads}` on {platform.machine()} "
        f"({platform.processor() or 'CPU'}), torch {torch.__version__}, {args.threads} torch thread(s); OpenSim 4.6 "
        f"(PyPI) in the same process, logging off. Both read the same TRC file (ours parses only the rows "
        f"inside the setup's time range) and write a .mot; OpenSim's `InverseKinematicsTool.run()`, at the "
        f"setup's accuracy, timed once, ours best of {args.repeats}: reading the TRC, solving and "
        f"writing the .mot, and in brackets the solve alone (OpenSim's reading cannot be timed apart). Machine "
        f"shared with other work: wall times, run interleaved; load average at the end {_load()}.",
        "",
        "RMSE columns: worst per-coordinate RMSE between the two solutions over all frames, over coordinates some "
        "tracked marker moves (deg for rotations, m for translations). Marker RMSE: all visible (frame, marker) "
        "samples of the tracked markers, both solutions through the same forward kinematics.",
        "",
        "| trial | frames | coords | OpenSim s | biomotion s (solve) | speed-up (solve) | RMSE deg | RMSE m "
        "| marker RMSE m (ours / OpenSim) | frames OpenSim objective lower | coordinates over 2 deg |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---|",
    ]
    for name, c in cases.items():
        over = ", ".join(f"{k} {v['rmse']:.1f}" for k, v in c["over_bar"].items()) or "-"
        lines.append(
            f"| {name} | {c['frames']} | {c['coordinates']} | {c['opensim_seconds']:.2f} | "
            f"{c['seconds']:.3f} ({c['solve_seconds']:.3f}) | {c['ik_speedup_vs_opensim']:.0f}x "
            f"({c['solve_speedup_vs_opensim']:.0f}x) | {c['ik_rmse_deg']:.2f} | "
            f"{c['ik_rmse_m']:.5f} | {c['ik_marker_rmse_m']:.5f} / {c['opensim_marker_rmse_m']:.5f} | "
            f"{c['frames_opensim_objective_lower']} | {over} |"
        )
    unscored = sorted({n for c in cases.values() for n in c["no_marker_moves"]})
    over_bar = any(c["over_bar"] for c in cases.values())
    lines += [
        "",
        f"Not scored (no tracked marker moves them; OpenSim leaves them wherever its optimizer drifts): "
        f"{', '.join(unscored) or 'none'}.",
        "",
        f"The agreement columns compare with OpenSim run again to accuracy {validate.ORACLE_ACCURACY:g} (at the "
        "setups' 1e-5 its assembler stops short of the minimum where the objective is flat, forearm pronation "
        "above all); "
        + (
            "coordinates over 2 deg are listed, and the column 'frames OpenSim objective lower' "
            "counts the frames where OpenSim found a lower objective than ours."
            if over_bar
            else "no coordinate of these trials differs by more than 2 deg."
        ),
        "",
        "## Static scaling (Fukuchi runners, Denton 2023 generic model)",
        "",
        "| check | value |",
        "|---|---|",
        f"| measurement factors vs shipped ScaleSets, {scaling['runners']} runners | max relative error "
        f"{scaling['max_rel_err']:.2e} ({scaling['worst']}) |",
        f"| RBDS001 full static calibration (factors, placement IK, scaled .osim written) | "
        f"{scaling['seconds']:.3f} s vs OpenSim ScaleTool {scaling['opensim_seconds']:.3f} s "
        f"({scaling['opensim_seconds'] / scaling['seconds']:.0f}x) |",
        f"| RBDS001 placement marker RMS | {scaling['placement_rms']:.4f} m |",
        "",
    ]
    if peers:
        lines += [
            "## Peer: nimblephysics (AddBiomechanics' engine) on the Fukuchi trials",
            "",
            "Same markers, window and scaled model; nimble in its own interpreter (`benchmarks/nimble_peer.py`). "
            "MarkerFitter's pipeline cannot run on these models (its anthropometric step needs bone meshes the data "
            "leaves out); nimble's own IK solver, frame after frame, can. Its markers weigh 1 (with the setup's "
            "weights it diverges); ours use the setup's weights.",
            "",
            "| trial | frames | nimble IK s | nimble marker RMSE m | biomotion s | biomotion marker RMSE m "
            "| MarkerFitter |",
            "|---|---:|---:|---:|---:|---:|---|",
        ]
        for name, peer in peers.items():
            ours = cases[name]
            ik = peer.get("sequential_ik", {})
            fitter = peer.get("marker_fitter", {}).get("error") or peer.get("error") or "ran"
            lines.append(
                f"| {name} | {peer.get('frames', '-')} | {ik.get('seconds', float('nan')):.2f} | "
                f"{ik.get('marker_rmse_m', float('nan')):.5f} | {ours['seconds']:.3f} | {ours['ik_marker_rmse_m']:.5f} "
                f"| {fitter} |"
            )
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", default=str(REPO.parent / "shared" / "data"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default=str(REPO / "docs" / "results" / "ik.md"))
    parser.add_argument("--json", help="also write the figures as JSON (ik_speedup_vs_opensim_min: the worst trial)")
    parser.add_argument(
        "--nimble-python", help="an interpreter with nimblephysics: adds the peer on the Fukuchi trials"
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    root = Path(args.data_root)
    cases = _cases(root, args.repeats)
    scaling = _scaling(root, args.repeats)
    peers = {}
    if args.nimble_python:
        with tempfile.TemporaryDirectory(prefix="biomotion-nimble-") as folder:
            for runner in RUNNERS:
                peers[f"Fukuchi {runner} 3.5 m/s"] = _nimble(root, runner, args.nimble_python, Path(folder))
    text = _table(cases, scaling, args, peers)
    with atomic_write(args.out) as handle:
        handle.write(text)
    if args.json:
        speedups = {name: c["ik_speedup_vs_opensim"] for name, c in cases.items()}
        figures = {
            "command": f"python benchmarks/ik.py --repeats {args.repeats} --threads {args.threads}"
            + (" --nimble-python PYTHON" if args.nimble_python else ""),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {_load()}",
            "torch": torch.__version__,
            "ik_speedup_vs_opensim_min": min(speedups.values()),
            "ik_speedup_vs_opensim_worst_trial": min(speedups, key=speedups.get),
            "cases": cases,
            "scaling": scaling,
            "nimble_peer": peers,
        }
        with atomic_write(args.json) as handle:
            json.dump(figures, handle, indent=1, default=float)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
