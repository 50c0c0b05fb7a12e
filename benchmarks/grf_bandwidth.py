"""Where kinematics-only vertical GRF misses the Fukuchi treadmill plates, and whether wider-band kinematics
help; writes docs/results/grf_bandwidth.md.

    python benchmarks/grf_bandwidth.py [--data-root ../shared/data] [--runners RBDS010 ...] [--out ...]

Issue 3 asks for vertical GRF within 0.15 body weights RMSE of the plates. ``biomotion validate dynamics``
measures about 0.2 on the Fukuchi runners, and so does the plain whole-body estimate m(g + a_COM,y) beside it.
This script asks why, on every runner under the data root with a T35 C3D, its ``*_simple.osim`` and shipped
``ik/T35`` IK. It changes no setting: the evaluation keeps its 10 Hz, and nothing here feeds back into a default.

1. Phases, at the evaluation's setting (shipped IK, coordinates low-passed at 10 Hz, `biomotion.analysis.chain.analyze`,
   frames of `biomotion.analysis.chain.plate_frames`): each frame is flight (plates under 0.05 body weights) or a
   tenth of its stance (time from touch-down over stance duration, both from the plates). Per phase group the
   share of the squared error and the mean signed error (ours minus plates) show where the RMSE comes from.
2. Bandwidth: the same runner's coordinates solved afresh from the C3D markers by the source's own chain
   (`biomotion.data.fukuchi_chain.solve_trial`) with the markers low-passed at 10, 20 and 30 Hz instead of the
   source's 10, each analysed at the same cutoff; and the shipped IK analysed at 15 and 20 Hz. If a sharp
   loading or unloading were in the markers and only the filter hid it, a wider band would lower the error.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from biomotion.analysis.chain import Analysis, analyze, plate_frames, vertical_agreement
from biomotion.body.model import BodyModel
from biomotion.data.fukuchi_chain import as_simple, runner_files, solve_trial
from biomotion.io.atomic import atomic_write
from biomotion.io.c3d import read_c3d_forces
from biomotion.io.mot import read_motion
from biomotion.motion import Motion

REPO = Path(__file__).resolve().parents[1]
FUKUCHI = "fukuchi-running"
GRAVITY = 9.80665
EVALUATION_CUTOFF = 10.0
STANCE_BW = 0.05
#: (label, first and last stance tenth) of the phase table; flight is its own group
GROUPS = (("first 30 % of stance", 0, 2), ("middle 40 %", 3, 6), ("last 30 %", 7, 9))
PHASES = ("flight", *(label for label, _, _ in GROUPS))
MARKER_CUTOFFS = (10.0, 20.0, 30.0)
SHIPPED_CUTOFFS = (10.0, 15.0, 20.0)


def vertical(result: Analysis, model: BodyModel) -> dict[str, np.ndarray]:
    """Plates, ours and the whole-body estimate (body weights) on the compared frames."""
    keep = plate_frames(result)
    weight = result.body_weight
    return {
        "plates": result.measured.force[keep, :, 1].sum(1) / weight,
        "ours": result.inferred.force[keep, :, 1].sum(1) / weight,
        "base": float(model.total_mass) * (GRAVITY + result.com_acceleration[keep, 1]) / weight,
    }


def rmse(predicted: np.ndarray, plates: np.ndarray) -> float:
    """RMSE in body weights of series already in body weights (`vertical_agreement`)."""
    return vertical_agreement(predicted, plates, 1.0)["rmse_bw"]


def stance_tenths(plates: np.ndarray) -> np.ndarray:
    """[T] the tenth of stance (0-9) of each frame, -1 in flight and in a stance cut by the trial's ends."""
    on = plates > STANCE_BW
    tenth = np.full(len(on), -1)
    starts = np.flatnonzero(on[1:] & ~on[:-1]) + 1
    ends = np.flatnonzero(on[:-1] & ~on[1:]) + 1
    for start in starts:
        after = ends[ends > start]
        if after.size:
            stop = after[0]
            tenth[start:stop] = np.minimum((10 * np.arange(stop - start)) // (stop - start), 9)
    return tenth


def phase_rows(series: dict[str, np.ndarray]) -> list[tuple[str, float, float]]:
    """(phase group, share of the squared error, mean signed error) of ours against the plates."""
    error = series["ours"] - series["plates"]
    tenth = stance_tenths(series["plates"])
    total = float(np.sum(error**2))
    groups = [("flight", series["plates"] <= STANCE_BW)]
    groups += [(label, (tenth >= lo) & (tenth <= hi)) for label, lo, hi in GROUPS]
    return [
        (label, float(np.sum(error[mask] ** 2)) / total, float(np.mean(error[mask])) if mask.any() else np.nan)
        for label, mask in groups
    ]


def analysed(motion: Motion, model: BodyModel, c3d: Path, cutoff: float) -> dict[str, np.ndarray]:
    forces = read_c3d_forces(c3d).slice(motion.times[0] - 0.1, motion.times[-1] + 0.1)
    return vertical(analyze(motion, model, forces, cutoff_hz=cutoff), model)


def runners(base: Path) -> list[str]:
    found = []
    for c3d in sorted(base.glob("c3d/*runT35.c3d")):
        runner = c3d.name.removesuffix("runT35.c3d")
        files = runner_files(base, runner)
        if (
            all(files[k].exists() for k in ("generic", "scale_setup", "ik_setup", "static", "reference"))
            and (base / runner / f"{runner}_simple.osim").exists()
        ):
            found.append(runner)
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", default=str(REPO.parent / "shared" / "data"))
    parser.add_argument("--runners", nargs="*", help="runner ids (default: every runner with the files)")
    parser.add_argument("--out", default=str(REPO / "docs" / "results" / "grf_bandwidth.md"))
    args = parser.parse_args(argv)
    base = Path(args.data_root) / FUKUCHI
    chosen = args.runners or runners(base)
    if not chosen:
        print(f"no Fukuchi runner with a T35 C3D, scaled simple model and shipped IK under {base}")
        return 1
    started = time.perf_counter()
    phases, bandwidth = {}, {}
    pooled: dict[str, dict[str, list[np.ndarray]]] = {}
    for runner in tqdm(chosen, desc="runners", unit="runner"):
        model = BodyModel.from_osim(base / runner / f"{runner}_simple.osim")
        c3d = base / "c3d" / f"{runner}runT35.c3d"
        shipped = read_motion(runner_files(base, runner)["reference"])
        cells = {}
        for cutoff in SHIPPED_CUTOFFS:
            series = analysed(shipped, model, c3d, cutoff)
            cells[f"shipped IK, {cutoff:g} Hz"] = series
            if cutoff == EVALUATION_CUTOFF:
                phases[runner] = phase_rows(series)
        for cutoff in MARKER_CUTOFFS:
            motion = as_simple(solve_trial(base, runner, "T35", marker_cutoff_hz=cutoff)[0].motion)
            cells[f"chain IK, markers {cutoff:g} Hz"] = analysed(motion, model, c3d, cutoff)
        bandwidth[runner] = {
            name: (rmse(s["ours"], s["plates"]), rmse(s["base"], s["plates"])) for name, s in cells.items()
        }
        for name, s in cells.items():
            for key, value in s.items():
                pooled.setdefault(name, {}).setdefault(key, []).append(value)
    columns = list(next(iter(bandwidth.values())))
    lines = [
        "# Kinematics-only vertical GRF on the Fukuchi runners: where the error lies, and bandwidth",
        "",
        f"Produced by `python benchmarks/grf_bandwidth.py` (see its docstring) on {len(chosen)} runners; "
        f"{time.perf_counter() - started:.0f} s on this machine. Vertical GRF in body weights against the treadmill "
        "plate on the frames `biomotion validate dynamics` compares. Nothing here sets a default.",
        "",
        "## Where the error lies (shipped IK, 10 Hz, as evaluated)",
        "",
        "Share of the squared error of our estimate, and in brackets its mean signed error (BW; positive: ours "
        "above the plates). Stance and flight are read from the plates (stance above "
        f"{STANCE_BW:g} BW); the shares leave out the stances the trial's ends cut.",
        "",
        "| runner | " + " | ".join(PHASES) + " |",
        "|---|" + "---|" * len(PHASES),
    ]
    for runner, rows in phases.items():
        lines.append(
            f"| {runner} | " + " | ".join(f"{100 * share:.0f} % ({mean:+.2f})" for _, share, mean in rows) + " |"
        )
    lines += [
        "",
        "## Bandwidth: RMSE (BW), ours / m(g + a_COM,y) on the same frames and filtering",
        "",
        "| runner | " + " | ".join(columns) + " |",
        "|---|" + "---|" * len(columns),
    ]
    for runner, cells in bandwidth.items():
        lines.append(f"| {runner} | " + " | ".join(f"{o:.3f} / {b:.3f}" for o, b in cells.values()) + " |")
    pooled_cells = []
    for name in columns:
        s = {key: np.concatenate(parts) for key, parts in pooled[name].items()}
        pooled_cells.append(f"**{rmse(s['ours'], s['plates']):.3f}** / {rmse(s['base'], s['plates']):.3f}")
    lines += ["| all runners | " + " | ".join(pooled_cells) + " |", ""]
    text = "\n".join(lines)
    with atomic_write(args.out) as handle:
        handle.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
