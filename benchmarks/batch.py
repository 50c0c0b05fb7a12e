"""The whole Fukuchi study through `biomotion batch`, timed, and Ray against the local executor; writes
docs/results/batch.json and batch.md.

    python benchmarks/batch.py [--data-root ../shared/data] [--workers 2] [--ray-subjects 3] [--out FOLDER]

1. Every static and running C3D of ``fukuchi-running`` (23 runners: 23 static + 69 running trials here) as
   `biomotion.analysis.batch.batch` runs them from the folder layout (scaling from each static trial, IK with the
   runner's IK setup and window, inverse dynamics with the treadmill plate assigned to the feet, COM/ZMP, the
   quality verdicts, OpenSim files and viewer pages per trial), on ``--workers`` local processes. Wall clock of the
   whole call, report included: ``batch_fukuchi_minutes``; trials processed or reported with a reason:
   ``batch_fukuchi_trials``. Which trials the a-priori rules flag, and why, is listed (fukuchi-running/SOURCE.md
   knows RBDS001's swapped R.MT1/R.MT5).
2. The first ``--ray-subjects`` runners again, once on the local executor and once as Ray tasks on a local Ray
   instance with the same number of CPUs: ``batch_ray_local_max_abs_diff`` is the largest difference between any
   two numbers of their ``.sto``/``.mot`` outputs.

The machine's load (load average, the busiest other processes) is recorded with the figures: on a shared machine
the minutes move with it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from biomotion.analysis.batch import batch
from biomotion.analysis.study import load_study
from biomotion.io.atomic import atomic_write
from biomotion.io.mot import read_storage

REPO = Path(__file__).resolve().parents[1]


def machine() -> dict:
    """Load average and the busiest processes (what else was running): CPU %, elapsed time and the program's name
    only, no arguments (they carry machine paths)."""
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    try:
        top = subprocess.run(
            ["ps", "-eo", "pcpu,etime,comm", "--sort=-pcpu"], capture_output=True, text=True, timeout=10
        ).stdout.splitlines()[1:8]
    except (OSError, subprocess.SubprocessError):
        top = []
    return {"load_average": load, "busiest_processes": [line.strip()[:160] for line in top]}


def numbers(folder: Path) -> dict[str, np.ndarray]:
    """Every number of every .sto/.mot file under a batch folder, by relative path."""
    return {
        str(path.relative_to(folder)): read_storage(path).data
        for path in sorted(folder.rglob("*"))
        if path.suffix in (".sto", ".mot")
    }


def ray_against_local(study, workers: int, folder: Path) -> dict:
    """The same study on both executors; the largest difference between their numbers."""
    import ray

    local = batch(study, folder / "local", workers=workers, progress=False, report=False)
    ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    try:
        remote = batch(study, folder / "ray", executor="ray", progress=False, report=False)
    finally:
        ray.shutdown()
    ours, theirs = numbers(folder / "local"), numbers(folder / "ray")
    if ours.keys() != theirs.keys():
        raise RuntimeError(f"the executors wrote different files: {sorted(ours.keys() ^ theirs.keys())}")
    differences = [float(np.nanmax(np.abs(ours[k] - theirs[k]))) if ours[k].size else 0.0 for k in ours]
    return {
        "subjects": [s.name for s in study.subjects],
        "trials": study.n_trials,
        "files_compared": len(ours),
        "numbers_compared": int(sum(a.size for a in ours.values())),
        "max_abs_diff": max(differences),
        "verdicts_equal": [o.verdict for o in local.outcomes] == [o.verdict for o in remote.outcomes],
        "local_seconds": local.seconds,
        "ray_seconds": remote.seconds,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", default=str(REPO.parent / "shared" / "data"))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--ray-subjects", type=int, default=3)
    parser.add_argument("--out", help="keep the batch output here (default: a temporary folder)")
    parser.add_argument("--json", default=str(REPO / "docs" / "results" / "batch.json"))
    parser.add_argument("--md", default=str(REPO / "docs" / "results" / "batch.md"))
    args = parser.parse_args(argv)
    root = Path(args.data_root)
    before = machine()
    with tempfile.TemporaryDirectory(prefix="biomotion-batch-bench-") as tmp:
        out = Path(args.out) if args.out else Path(tmp) / "fukuchi"
        if out.exists():
            shutil.rmtree(out)
        began = time.perf_counter()
        result = batch(root / "fukuchi-running", out, workers=args.workers, progress=False)
        minutes = (time.perf_counter() - began) / 60
        during = machine()
        outcomes = result.outcomes
        reported = [o for o in outcomes if o.status == "done" or (o.status == "error" and o.error)]
        flagged = {
            f"{o.subject}/{o.name}": [r["message"] for r in o.verdict.get("reasons", []) if r["verdict"] == "fail"]
            for o in outcomes
            if o.verdict.get("verdict") == "fail"
        }
        seconds = [o.seconds.get("total", 0.0) for o in outcomes if o.kind == "trial" and o.status == "done"]
        frames = sum(int(o.figures.get("frames", 0) or 0) for o in outcomes if o.kind == "trial")
        study = load_study(root / "fukuchi-running")
        subset = study.select([s.name for s in study.subjects[: args.ray_subjects]])
        ray = ray_against_local(subset, args.workers, Path(tmp) / "ray")
    rbds001 = next((o for o in outcomes if o.subject == "RBDS001" and o.name == "runT35"), None)
    figures = {
        "command": f"python benchmarks/batch.py --workers {args.workers} --ray-subjects {args.ray_subjects}",
        "machine": f"{platform.machine()}, {os.cpu_count()} cores; Python {platform.python_version()}",
        "load_before": before,
        "load_during": during,
        "batch_fukuchi_trials": len(reported),
        "batch_fukuchi_minutes": round(minutes, 2),
        "batch_ray_local_max_abs_diff": ray["max_abs_diff"],
        "fukuchi": {
            "statics": sum(o.kind == "static" for o in outcomes),
            "running_trials": sum(o.kind == "trial" for o in outcomes),
            "errors": {f"{o.subject}/{o.name}": o.error for o in outcomes if o.status == "error"},
            "verdicts": {v: sum(o.verdict.get("verdict") == v for o in outcomes) for v in ("ok", "warn", "fail")},
            "frames_analysed": frames,
            "trial_seconds_median": float(np.median(seconds)) if seconds else None,
            "flagged_fail": flagged,
            "rbds001_runT35": None if rbds001 is None else rbds001.verdict,
        },
        "ray_vs_local": ray,
    }
    with atomic_write(args.json) as handle:
        json.dump(figures, handle, indent=1)
    verdicts = figures["fukuchi"]["verdicts"]
    lines = [
        "# The Fukuchi study in one command, and Ray against the local executor",
        "",
        f"`{figures['command']}` on {figures['machine']}. Load average before {before['load_average']}, at the end "
        f"of the study {during['load_average']} (2 cores shared with other jobs: minutes move with the load).",
        "",
        "| figure | value |",
        "|---|---|",
        f"| batch_fukuchi_trials (processed or reported with a reason) | {len(reported)} of {len(outcomes)} "
        f"({figures['fukuchi']['statics']} static + {figures['fukuchi']['running_trials']} running) |",
        f"| batch_fukuchi_minutes (whole study, report included, {args.workers} workers) | {minutes:.2f} |",
        f"| frames analysed | {frames} |",
        f"| verdicts ok / warn / fail | {' / '.join(str(verdicts[v]) for v in ('ok', 'warn', 'fail'))} |",
        f"| batch_ray_local_max_abs_diff ({ray['trials']} trials of {', '.join(ray['subjects'])}, "
        f"{ray['numbers_compared']} numbers) | {ray['max_abs_diff']:.3g} |",
        f"| Ray verdicts equal to local | {ray['verdicts_equal']} |",
        "",
        "RBDS001 3.5 m/s: "
        + (
            "; ".join(r["message"] for r in rbds001.verdict.get("reasons", []) if r["verdict"] == "fail")
            if rbds001
            else "missing"
        ),
        "",
        "## Failed by the a-priori rules",
        "",
        *[f"- {name}: {' | '.join(messages)}" for name, messages in flagged.items()],
        "",
        "## What else was running (at the end of the study)",
        "",
        *[f"    {line}" for line in during["busiest_processes"]],
        "",
    ]
    with atomic_write(args.md) as handle:
        handle.write("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
