"""The whole analysis chain — marker IK, inverse dynamics, static optimization — side by side with OpenSim 4.6 on
two walks; writes docs/results/analysis_chain.md.

    python benchmarks/analysis_chain.py [--data-root ../shared/data] [--repeats 3] [--threads 1 2]
                                        [--json docs/results/analysis_chain.json] [--processes 2]

The project's speed north star: IK + ID + SO of a trial at >= 300 frames/s on 2 CPU cores at OpenSim's accuracy.
Each chain runs from the same markers to activations:

- OpenSim: ``InverseKinematicsTool`` (the trial's IK setup: marker weights, coordinate tasks, time range; accuracy
  1e-5 unless the setup says otherwise), then ``InverseDynamicsTool`` and ``AnalyzeTool`` + ``StaticOptimization``
  on OpenSim's own IK result (6 Hz, the trial's external loads, squared activations with muscle physiology, step
  interval 1, the case's actuators); each tool's ``run()`` timed once (OpenSim is single-threaded).
- biomotion: `biomotion.ik.solve_ik` on the same markers and setup; the same 6 Hz filter and spline derivatives
  as OpenSim's ID tool (`Motion.smoothed`) and batched `inverse_dynamics` with the same plate loads; batched
  `optimize_activations` with the shipped path functions and the same actuators on the coordinates it balances.
  Best wall time of ``--repeats`` runs per torch thread count, after one warm-up run.

Cases:
- gait2392 subject01 walk (``Pipelines/Gait2392_Simbody``, ``subject01_simbody.osim``, 92 muscles,
  ``gait2392_SO_Residual_Actuators.xml``: pelvis residuals only, which ours models as pelvis reserves;
  `biomotion.validation.muscles.gait_static_optimization`);
- Rajagopal walk (``Pipelines/Rajagopal``: ``motion_capture_walk.trc`` with ``IK/ik_setup_walk.xml`` on the generic
  Rajagopal 2016 model carrying the walk's markers, 80 muscles, the reserves of
  `biomotion.validation.muscles.write_rajagopal_reserves`; ours leaves out the actuators of coordinates no muscle
  spans, whose rows of the problem do not involve the muscles). OpenSim's IK result is handed to its other tools in
  radians (from degrees, OpenSim 4.6 passes the patella's coupled speeds in deg/s, see
  `biomotion.validation.muscles`).

Accuracy, each chain end to end from the same markers: joint angles (RMSE, deg), joint torques (RMSE / peak on
coordinates whose peak exceeds 10 N·m) and activations (R² per muscle against OpenSim's, mean and worst).

Throughput (``--processes N``): N worker processes, one torch thread each, run the gait2392 chain over and over at
the same time, as `biomotion batch` runs trials; frames/s = frames solved by all of them / wall time. ``--json``
writes the figures; ``chain_frames_per_s`` is the best single-trial gait2392 figure (what the table shows),
``chain_frames_per_s_throughput`` the N-process one.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.analysis.chain import loads_on_frames, model_motion, torque_labels, unwrapped
from biomotion.body.dynamics import ExternalLoad, inverse_dynamics
from biomotion.body.model import BodyModel
from biomotion.ik import solve_ik
from biomotion.ik.markers import evaluate_ik
from biomotion.io.atomic import atomic_write
from biomotion.io.mot import read_ground_reaction, read_storage, write_external_loads_xml, write_motion
from biomotion.io.setup import IKSetup, read_ik_setup
from biomotion.io.trc import read_trc
from biomotion.motion import GroundReaction, Markers
from biomotion.muscles.geometry import MusclePaths, shipped_paths
from biomotion.muscles.properties import MuscleParameters, read_muscles
from biomotion.muscles.static_optimization import optimize_activations
from biomotion.validation import emg
from biomotion.validation.ik import opensim_ik
from biomotion.validation.muscles import (
    GAIT,
    GAIT_MODEL,
    RAJAGOPAL_RESERVE,
    RAJAGOPAL_RESERVE_BOUND,
    RESIDUALS,
    generic_with_walk_markers,
    opensim_static_optimization,
    r_squared,
    write_rajagopal_reserves,
)
from biomotion.validation.oracle import run_inverse_dynamics_tool

REPO = Path(__file__).resolve().parents[1]
CUTOFF_HZ = 6.0
NORTH_STAR_FPS = 300.0


@dataclass
class Case:
    """One trial's inputs for both chains (absolute paths; OpenSim resolves setup paths relative to the setup)."""

    name: str
    model_path: Path
    setup: IKSetup
    markers: Markers
    external_loads: Path  # OpenSim ExternalLoads XML of the plates
    forces: GroundReaction  # the same plates with the bodies they act on
    force_set: Path  # OpenSim's actuators for its StaticOptimization
    paths: MusclePaths
    muscles: MuscleParameters
    balanced: tuple[str, ...]  # coordinates our optimization balances
    reserves: dict[str, float]  # their actuators' optimal forces
    reserve_bound: float
    ik_in_degrees: bool  # how OpenSim's IK result is written for its other tools


def gait2392_case(root: Path, folder: Path) -> Case:
    model_path = (root / GAIT_MODEL).resolve()
    model = BodyModel.from_osim(model_path)
    setup = read_ik_setup(root / GAIT / "subject01_Setup_IK.xml")
    forces = read_ground_reaction(root / GAIT / "subject01_walk1_grf.mot")
    plates = {"ground_force": "calcn_r", "1_ground_force": "calcn_l"}  # subject01_walk1_grf.xml
    forces = forces.assign([plates.get(name) for name in forces.names]).select(list(plates))
    balanced = tuple(n for n, locked in zip(model.coordinate_names, model.locked.tolist()) if not locked)
    return Case(
        "gait2392 subject01 walk",
        model_path,
        setup,
        read_trc(setup.file("marker_file")),
        (root / GAIT / "subject01_walk1_grf.xml").resolve(),
        forces,
        (root / GAIT / "gait2392_SO_Residual_Actuators.xml").resolve(),
        shipped_paths("gait2392_subject01"),
        read_muscles(model_path),
        balanced,
        RESIDUALS,
        1.0,
        True,
    )


def rajagopal_case(root: Path, folder: Path) -> Case:
    model_path = generic_with_walk_markers(root, folder / "Rajagopal2016_walk_markers.osim").resolve()
    model = BodyModel.from_osim(model_path)
    setup = read_ik_setup(root / emg.IK_SETUP)
    forces = read_ground_reaction(root / emg.GRF_FILE)
    forces = forces.assign(emg.external_load_bodies(root / emg.GRF_LOADS, forces.names))
    loads = write_external_loads_xml(folder / "grf_walk.xml", forces, str((root / emg.GRF_FILE).resolve()))
    force_set, balanced = write_rajagopal_reserves(model, folder / "reserves.xml")
    return Case(
        "Rajagopal walk",
        model_path,
        setup,
        read_trc(root / emg.MARKER_FILE),
        loads.resolve(),
        forces,
        force_set.resolve(),
        shipped_paths("rajagopal2016"),
        read_muscles(model_path),
        balanced,
        {name: RAJAGOPAL_RESERVE for name in balanced},
        RAJAGOPAL_RESERVE_BOUND,
        False,
    )


def opensim_chain(case: Case, folder: Path) -> dict:
    """OpenSim's three tools in sequence; seconds per tool, its q, torques and activations."""
    setup = case.setup
    ik = opensim_ik(
        case.model_path,
        case.markers,
        weights=setup.marker_weights,
        coordinate_tasks=setup.coordinate_tasks,
        time_range=setup.time_range,
        accuracy=setup.accuracy,
    )
    coordinates = write_motion(folder / "opensim_ik.mot", ik.motion, in_degrees=case.ik_in_degrees).resolve()
    start, end = float(ik.motion.times[0]), float(ik.motion.times[-1])
    began = time.perf_counter()
    torques = read_storage(
        run_inverse_dynamics_tool(case.model_path, coordinates, case.external_loads, folder / "id", start, end)
    )
    id_seconds = time.perf_counter() - began
    so = opensim_static_optimization(
        case.model_path, coordinates, case.external_loads, case.force_set, start, end, workdir=folder
    )
    return {
        "ik": ik.motion,
        "torques": torques,
        "so": so,
        "seconds": {"ik": ik.seconds, "id": id_seconds, "so": so.seconds},
    }


def biomotion_chain(case: Case, model: BodyModel) -> dict:
    """Our three stages in sequence; seconds per stage and what each produced."""
    setup = case.setup
    began = time.perf_counter()
    ik = solve_ik(
        model,
        case.markers,
        weights=setup.marker_weights,
        coordinate_tasks=setup.coordinate_tasks,
        time_range=setup.time_range,
    )
    after_ik = time.perf_counter()
    coordinates, qd, qdd = unwrapped(model_motion(ik.motion, model), model).smoothed(CUTOFF_HZ)
    on_frames = loads_on_frames(case.forces, coordinates.times)
    loads = [
        ExternalLoad(
            on_frames.bodies[j],
            torch.from_numpy(on_frames.force[:, j]),
            torch.from_numpy(np.nan_to_num(on_frames.cop[:, j])),
            torch.from_numpy(on_frames.moment[:, j]),
        )
        for j in range(on_frames.n_channels)
    ]
    q, qd_t, qdd_t = (torch.from_numpy(np.ascontiguousarray(a)) for a in (coordinates.values, qd, qdd))
    with torch.no_grad():
        tau = inverse_dynamics(model, q, qd_t, qdd_t, loads)
    after_id = time.perf_counter()
    order = [model.coordinate_names.index(n) for n in case.paths.coordinate_names]
    result = optimize_activations(
        case.paths,
        case.muscles,
        q[:, order],
        qd_t[:, order],
        tau[:, [model.coordinate_names.index(n) for n in case.balanced]],
        case.balanced,
        case.reserves,
        reserve_bound=case.reserve_bound,
    )
    done = time.perf_counter()
    return {
        "ik": ik.motion,
        "q": coordinates,
        "torques": tau.numpy(),
        "so": result,
        "seconds": {"ik": after_ik - began, "id": after_id - after_ik, "so": done - after_id},
    }


def marker_fit(case: Case, model: BodyModel, ours: dict, theirs: dict) -> dict:
    """Marker RMS error (m) and mean IK objective of both IK results, with the same forward kinematics."""
    setup = case.setup
    scored = {
        name: evaluate_ik(
            model,
            case.markers,
            motion,
            weights=setup.marker_weights,
            coordinate_tasks=setup.coordinate_tasks,
            time_range=setup.time_range,
        )
        for name, motion in (("ours", ours["ik"]), ("opensim", theirs["ik"]))
    }
    return {
        f"{name}_{key}": value
        for name, result in scored.items()
        for key, value in (("marker_rmse_m", result.rmse), ("objective", float(result.cost.mean())))
    }


def accuracy(model: BodyModel, ours: dict, theirs: dict, trim: float = 0.0) -> dict:
    """Angles (the two IK results), torques and activations of our chain against OpenSim's, on OpenSim's frames
    inside our trial, leaving out ``trim`` seconds at each end: OpenSim's ID and SO tools resample the IK onto
    their own time grid (126 frames from 8 ms before the IK's first frame here) and pad the ends their own way,
    so the first and last frames of the two chains are not the same computation."""
    first, last = ours["q"].times[0] + trim, ours["q"].times[-1] - trim
    reference = theirs["ik"].select(model.coordinate_names)
    rotational = [c for c, kind in enumerate(model.motion_types) if kind == "rotational" and not bool(model.locked[c])]
    frames = (reference.times >= first) & (reference.times <= last)
    ours_ik = ours["ik"].select(model.coordinate_names)
    ours_q = np.stack(
        [np.interp(reference.times[frames], ours_ik.times, ours_ik.values[:, c]) for c in range(model.n_q)], 1
    )
    difference = (ours_q - reference.values[frames])[:, rotational]
    angle_rmse = np.degrees(np.sqrt(np.mean(difference**2, axis=0)))
    torque_errors = {}
    table = theirs["torques"]
    frames = (table.times >= first) & (table.times <= last)
    for c, label in enumerate(torque_labels(model)):
        if label in table.labels:
            expected = table.data[:, table.labels.index(label)]
            got = np.interp(table.times[frames], ours["q"].times, ours["torques"][:, c])
            peak = float(np.abs(expected).max())
            if peak > 10.0:
                torque_errors[label] = float(np.sqrt(np.mean((got - expected[frames]) ** 2)) / peak)
    so = theirs["so"]
    result = ours["so"]
    frames = (so.times >= first) & (so.times <= last)
    activations = result.activations.numpy()[:, [result.muscle_names.index(m) for m in so.muscle_names]]
    ours_a = np.stack(
        [np.interp(so.times[frames], ours["q"].times, activations[:, k]) for k in range(activations.shape[1])], 1
    )
    r2 = r_squared(ours_a, so.activations[frames])
    return {
        "trim_s": trim,
        "frames": int(frames.sum()),
        "angle_rmse_deg_max": float(angle_rmse.max()),
        "angle_worst": model.coordinate_names[rotational[int(angle_rmse.argmax())]],
        "torque_rmse_rel_max": max(torque_errors.values()),
        "torque_worst": max(torque_errors, key=torque_errors.get),
        "activation_r2_mean": float(r2.mean()),
        "activation_r2_median": float(np.median(r2)),
        "activation_r2_min": float(r2.min()),
        "activation_worst": so.muscle_names[int(r2.argmin())],
    }


def case_section(
    case: Case,
    frames: int,
    theirs: dict,
    timings: dict[int, dict],
    figures: tuple[dict, dict],
    converged: str,
    fit: dict,
) -> tuple[list[str], float]:
    """The markdown section of one case and its best frames/s."""
    os_seconds = theirs["seconds"]
    os_total = sum(os_seconds.values())
    fps = lambda seconds: frames / seconds
    times = theirs["ik"].times
    lines = [
        f"## {case.name}",
        "",
        f"{frames} frames ({times[0]:.2f}-{times[-1]:.2f} s at {(len(times) - 1) / (times[-1] - times[0]):.0f} Hz), "
        f"`{case.model_path.name}`, {len(case.paths.muscle_names)} muscles; our optimization balances "
        f"{len(case.balanced)} coordinates.",
        "",
        "| stage | OpenSim 4.6 (ms/frame) | "
        + " | ".join(f"biomotion, {t} thread{'s' * (t > 1)} (ms/frame)" for t in timings)
        + " |",
        "|---|---|" + "---|" * len(timings),
    ]
    for stage, label in (
        ("ik", "inverse kinematics"),
        ("id", "inverse dynamics (6 Hz, plates)"),
        ("so", "static optimization"),
    ):
        lines.append(
            f"| {label} | {1000 * os_seconds[stage] / frames:.2f} | "
            + " | ".join(f"{1000 * t[stage] / frames:.2f}" for t in timings.values())
            + " |"
        )
    lines.append(
        f"| **whole chain** | {1000 * os_total / frames:.1f} | "
        + " | ".join(f"**{1000 * sum(t.values()) / frames:.2f}**" for t in timings.values())
        + " |"
    )
    lines.append(
        f"| frames/s | {fps(os_total):.1f} | "
        + " | ".join(f"**{fps(sum(t.values())):.0f}**" for t in timings.values())
        + " |"
    )
    lines.append(
        "| ratio to OpenSim | 1 | " + " | ".join(f"{os_total / sum(t.values()):.0f}x" for t in timings.values()) + " |"
    )
    whole, inner = figures
    lines += [
        "",
        "Our chain against OpenSim's; frames of OpenSim's outputs inside our trial, all of them and without the "
        "first and last 0.05 s (see `accuracy` in the script):",
        "",
        "| figure | all frames | without the ends |",
        "|---|---|---|",
        f"| frames compared (SO) | {whole['frames']} | {inner['frames']} |",
        f"| marker RMS error of the IK, ours / OpenSim's (cm) | {100 * fit['ours_marker_rmse_m']:.3f} / "
        f"{100 * fit['opensim_marker_rmse_m']:.3f} | |",
        f"| mean IK objective, ours / OpenSim's | {fit['ours_objective']:.4g} / {fit['opensim_objective']:.4g} | |",
        f"| joint angles, worst coordinate RMSE (deg) | {whole['angle_rmse_deg_max']:.3f} ({whole['angle_worst']}) | "
        f"{inner['angle_rmse_deg_max']:.3f} ({inner['angle_worst']}) |",
        f"| joint torques, worst RMSE / peak (peak > 10 N·m) | {100 * whole['torque_rmse_rel_max']:.2f} % "
        f"({whole['torque_worst']}) | {100 * inner['torque_rmse_rel_max']:.2f} % ({inner['torque_worst']}) |",
        f"| activations, mean R² over {len(theirs['so'].muscle_names)} muscles | {whole['activation_r2_mean']:.4f} | "
        f"{inner['activation_r2_mean']:.4f} |",
        f"| activations, median R² | {whole['activation_r2_median']:.4f} | {inner['activation_r2_median']:.4f} |",
        f"| activations, worst muscle R² | {whole['activation_r2_min']:.3f} ({whole['activation_worst']}) | "
        f"{inner['activation_r2_min']:.3f} ({inner['activation_worst']}) |",
        f"| our static optimization: balanced frames | {converged} | |",
        "",
    ]
    return lines, max(fps(sum(t.values())) for t in timings.values())


def _throughput_worker(job: tuple[str, float, int]) -> tuple[int, float, float]:
    """One process of the throughput run: build the gait2392 case, warm up, wait for ``start`` (a wall-clock
    time), then run the chain ``runs`` times; (frames solved, start, end)."""
    root, start, runs = job
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory(prefix="biomotion-chain-") as tmp:
        case = gait2392_case(Path(root), Path(tmp))
        model = BodyModel.from_osim(case.model_path)
        biomotion_chain(case, model)
        while time.time() < start:
            time.sleep(0.001)
        began, frames = time.time(), 0
        for _ in range(runs):
            frames += int(biomotion_chain(case, model)["q"].n_frames)
        return frames, began, time.time()


def throughput(root: Path, processes: int, runs: int) -> dict:
    """Frames/s of ``processes`` processes running the gait2392 chain together (module docstring)."""
    context = multiprocessing.get_context("spawn")
    with context.Pool(processes) as pool:
        start = time.time() + 20.0  # every worker loaded and warmed up by then
        results = pool.map(_throughput_worker, [(str(root), start, runs)] * processes)
    frames = sum(r[0] for r in results)
    wall = max(r[2] for r in results) - min(r[1] for r in results)
    return {"processes": processes, "runs_per_process": runs, "frames": frames, "seconds": wall, "fps": frames / wall}


def _load() -> tuple[float, ...]:
    try:
        import os

        return os.getloadavg()
    except OSError:
        return (float("nan"),) * 3


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", default=str(REPO.parent / "shared" / "data"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--out", default=str(REPO / "docs" / "results" / "analysis_chain.md"))
    parser.add_argument("--json", help="also write the figures as JSON")
    parser.add_argument("--processes", type=int, default=2, help="processes of the throughput run (0: none)")
    parser.add_argument("--runs", type=int, default=20, help="chains per process in the throughput run")
    args = parser.parse_args(argv)
    root = Path(args.data_root).resolve()
    sections, best = [], {}
    with tempfile.TemporaryDirectory(prefix="biomotion-chain-") as tmp:
        for make in (gait2392_case, rajagopal_case):
            folder = Path(tmp) / make.__name__
            folder.mkdir()
            case = make(root, folder)
            theirs = opensim_chain(case, folder)
            model = BodyModel.from_osim(case.model_path)
            timings, ours = {}, None
            for threads in args.threads:
                torch.set_num_threads(threads)
                biomotion_chain(case, model)  # warm-up
                runs = [biomotion_chain(case, model) for _ in range(args.repeats)]
                fastest = min(runs, key=lambda run: sum(run["seconds"].values()))
                timings[threads], ours = fastest["seconds"], fastest
            figures = accuracy(model, ours, theirs), accuracy(model, ours, theirs, trim=0.05)
            converged = f"{int(ours['so'].converged.sum())}/{len(ours['so'].converged)}"
            lines, best[case.name] = case_section(
                case,
                int(ours["q"].n_frames),
                theirs,
                timings,
                figures,
                converged,
                marker_fit(case, model, ours, theirs),
            )
            sections += lines
    verdict = "; ".join(f"{name} {fps:.0f} frames/s" for name, fps in best.items())
    met = all(fps >= NORTH_STAR_FPS for fps in best.values())
    parallel = throughput(root, args.processes, args.runs) if args.processes > 0 else None
    if parallel is not None:
        sections += [
            f"## Throughput: {parallel['processes']} processes, one thread each",
            "",
            f"gait2392 subject01 walk, the whole chain {parallel['runs_per_process']} times per process at once: "
            f"{parallel['frames']} frames in {parallel['seconds']:.2f} s, **{parallel['fps']:.0f} frames/s**.",
            "",
        ]
    text = "\n".join(
        [
            "# Whole analysis chain: IK + inverse dynamics + static optimization vs OpenSim 4.6",
            "",
            f"Produced by `python benchmarks/analysis_chain.py --repeats {args.repeats} --threads "
            f"{' '.join(map(str, args.threads))}`; each chain runs from the same markers end to end (see the script's "
            "docstring). OpenSim's tools are single-threaded and timed once; ours is the best of the repeats after a "
            "warm-up run. Absolute times vary with the machine and its load; the ratios, measured in the same run, are "
            "the result.",
            "",
            f"Machine: {platform.processor() or platform.machine()}, load average "
            f"{', '.join(f'{x:.1f}' for x in _load())}; Python {platform.python_version()}, torch {torch.__version__}; "
            f"{time.strftime('%Y-%m-%d')}.",
            "",
            f"North star: {NORTH_STAR_FPS:.0f} frames/s on 2 cores. Best measured here: {verdict} "
            f"({'met on both' if met else 'not met on every case'}).",
            "",
            *sections,
        ]
    )
    with atomic_write(args.out) as handle:
        handle.write(text)
    if args.json:
        figures = {
            "command": f"python benchmarks/analysis_chain.py --repeats {args.repeats} --threads "
            f"{' '.join(map(str, args.threads))} --processes {args.processes} --runs {args.runs}",
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average "
            f"{', '.join(f'{x:.1f}' for x in _load())}",
            "torch": torch.__version__,
            "chain_frames_per_s": best["gait2392 subject01 walk"],
            "chain_frames_per_s_by_case": best,
            "chain_frames_per_s_throughput": None if parallel is None else parallel["fps"],
            "throughput": parallel,
        }
        with atomic_write(args.json) as handle:
            json.dump(figures, handle, indent=1)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
