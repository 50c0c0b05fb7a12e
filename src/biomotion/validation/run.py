"""Dispatch of ``biomotion validate WHAT``: run the checks, record what was skipped, write the JSON report."""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

from biomotion import __version__
from biomotion.errors import DataSourceMissing
from biomotion.io.atomic import atomic_write

#: Sources each check looks for (relative to the data root); absent ones are reported as skipped.
SOURCES = {
    "kinematics": ("opensim-models", "fukuchi-running", "opencap", "Hamner2013", "SchreiberMoissenet2019"),
    "dynamics": ("opensim-models/Pipelines/Gait2392_Simbody", "opencap", "fukuchi-running/c3d"),
    "muscles": ("opensim-models/Models/Rajagopal", "opensim-models/Pipelines/Gait2392_Simbody"),
    "ik": (
        "opensim-models/Pipelines/Gait2392_Simbody",
        "opensim-models/Pipelines/Rajagopal",
        "opencap",
        "fukuchi-running/c3d",
        "bandai-namco",
    ),
}


def run_validation(
    what: str,
    data_root: Path,
    json_path: Path,
    progress: bool = True,
    md_path: Path | None = None,
    command: str = "biomotion validate",
) -> dict:
    """Run ``what`` on ``data_root``, write the report to ``json_path`` (and tables to ``md_path``)."""
    from biomotion.validation import dynamics
    from biomotion.validation.ik import validate_ik
    from biomotion.validation.muscles import validate_muscles

    data_root = Path(data_root)
    if not data_root.is_dir():
        raise DataSourceMissing(f"data root {data_root} is not a folder")
    skipped = [f"{s} (not under {data_root})" for s in SOURCES[what] if not (data_root / s).exists()]
    started = time.perf_counter()
    checks = {
        "kinematics": dynamics.validate_kinematics,
        "dynamics": dynamics.validate_dynamics,
        "ik": lambda root, progress: validate_ik(root, opencap_trials=("all",), runners=10**6, progress=progress),
        "muscles": lambda root, progress: validate_muscles(root),
    }
    report = {
        "check": what,
        "data_root": str(data_root),
        "biomotion": __version__,
        "python": platform.python_version(),
        "skipped": skipped,
    }
    result = checks[what](data_root, progress=progress)
    report["skipped"] += result.pop("skipped", [])
    report.update(result)
    report["seconds"] = round(time.perf_counter() - started, 1)
    with atomic_write(json_path) as handle:
        json.dump(report, handle, indent=1)
    if md_path is not None:
        with atomic_write(md_path) as handle:
            handle.write(markdown(report, command))
    return report


def _bvh_markdown(rows: list[dict]) -> list[str]:
    """BVH retargeting per dataset and content: clips, joint-centre error, skating (result / source)."""
    groups: dict[str, list[dict]] = {}
    for row in rows:
        dataset, content = row["clip"].split("_")[:2]
        groups.setdefault(f"{dataset} {content}", []).append(row)
    lines = [
        "## BVH retargeting (Bandai-Namco onto Rajagopal 2016)",
        "",
        "| clips | n | mean joint error (cm) | worst clip mean (cm) | range violations | skate source | "
        "skate result | skate result, 10 Hz forced |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, group in sorted(groups.items()):
        errors = [r["mean_err_m"] for r in group]
        mean = lambda key: sum(r[key] for r in group) / len(group)  # noqa: B023 - used at once, in this loop
        lines.append(
            f"| {name} | {len(group)} | {100 * sum(errors) / len(errors):.2f} | {100 * max(errors):.2f} | "
            f"{sum(r['range_violations'] for r in group)} | {mean('skate_source'):.3f} | "
            f"{mean('skate_result'):.3f} | {mean('skate_filtered'):.3f} |"
        )
    return lines + [""]


ZMP_NOTE = (
    "The ZMP comes from the kinematics alone (`biomotion.body.balance.zero_moment_point`), the CoP from the "
    "plates, on frames with every supporting foot on a plate and at least 0.2 body weights on the plates "
    "(`biomotion.analysis.chain.zmp_to_plate_cop`). The Fukuchi runners' models lump head, arms and trunk into the "
    "pelvis (37.9 of RBDS001's 62 kg) and their markers cover pelvis and legs only: the upper body's own "
    "motion is missing from the whole-body moment, which is why their ZMP lies far from the plates' CoP; "
    "OpenCap's full-body models put it within a few cm."
)


LEARNED_NOTE = (
    "Learned: the shipped learned ground reaction (`checkpoints/ground_forces.safetensors`, "
    "`biomotion.models.ground_forces`) on the same frames. It was trained on the Fukuchi runners of this folder, so "
    "their rows (marked *trained on*) are not held-out figures; OpenCap was never trained on. Held-out figures "
    "(leave-subject-out folds over the runners): `biomotion eval ground-forces`, docs/results/eval_ground_forces.md."
)


def _learned_cell(row: dict) -> str:
    if row.get("learned_rmse_bw") is None:
        return "–"
    return f"{row['learned_rmse_bw']:.3f}" + ("" if row.get("learned_held_out") else " (trained on)")


def _cm(value: float | None) -> str:
    return "–" if value is None else f"{100.0 * value:.1f}"


def _bw(value: float | None) -> str:
    return "–" if value is None else f"{value:.3f}"


def markdown(report: dict, command: str) -> str:
    """Tables of a validation report, for docs/results/."""
    lines = [
        f"# Validation: {report['check']}",
        "",
        f"Produced by `{command}` (biomotion {report['biomotion']}, "
        f"{report['seconds']} s). Skipped: {', '.join(report['skipped']) or 'nothing'}.",
        "",
    ]
    scalars = [(k, v) for k, v in report.items() if isinstance(v, (int, float)) and k != "seconds"]
    lines += ["| figure | value |", "|---|---|"] + [f"| `{k}` | {v:.6g} |" for k, v in scalars] + [""]
    if report.get("grf_trials"):
        learned = any("learned_rmse_bw" in r for r in report["grf_trials"])
        lines += [
            "## Vertical GRF inferred from kinematics vs force plates",
            "",
            (
                "| trial | frames | left out | R² | RMSE (BW) | COM baseline R² | COM baseline RMSE (BW) "
                "| RMSE against plates filtered as the coordinates, ours / baseline (BW) "
                "| ZMP to plate CoP RMS (cm), frames |" + (" learned RMSE (BW), shipped weights |" if learned else "")
            ),
            "|---|---|---|---|---|---|---|---|---|" + ("---|" if learned else ""),
        ]
        lines += [
            f"| {r['trial']} | {r['frames']} | {r['frames_left_out']} | {r['r2']:.3f} | {r['rmse_bw']:.3f} | "
            f"{r['baseline_r2']:.3f} | {r['baseline_rmse_bw']:.3f} | "
            f"{_bw(r.get('rmse_bw_plates_filtered'))} / {_bw(r.get('baseline_rmse_bw_plates_filtered'))} | "
            f"{_cm(r.get('zmp_cop_rmse_m'))}, {r.get('zmp_cop_frames', 0)} |"
            + (f" {_learned_cell(r)} |" if learned else "")
            for r in report["grf_trials"]
        ]
        if learned:
            lines += ["", LEARNED_NOTE]
        if report.get("zmp_cop_rmse_m_per_source"):
            lines += [
                "",
                "ZMP to plate CoP per source (RMS, cm): "
                + ", ".join(f"{source} {_cm(value)}" for source, value in report["zmp_cop_rmse_m_per_source"].items())
                + ". "
                + ZMP_NOTE,
            ]
        lines.append("")
    if report.get("surrogate_r2_per_muscle"):
        worst = list(report["surrogate_r2_per_muscle"].items())[:10]
        lines += (
            [
                "## Surrogate vs static-optimization labels: the ten muscles with the lowest R² (held-out clips)",
                "",
                "| muscle | R² |",
                "|---|---|",
            ]
            + [f"| {name} | {value:.3f} |" for name, value in worst]
            + [""]
        )
    if report.get("id_ref_rmse_rel_per_trial"):
        lines += [
            "## Inverse dynamics end to end vs OpenSim's InverseDynamicsTool (RMSE / peak, peak > 10 N·m)",
            "",
            "| trial | worst coordinate | RMSE / peak | coordinates over 2 % |",
            "|---|---|---|---|",
        ]
        for trial, values in report["id_ref_rmse_rel_per_trial"].items():
            name, worst = max(values.items(), key=lambda kv: kv[1])
            over = [k for k, v in values.items() if v > 0.02]
            lines.append(f"| {trial} | {name} | {worst:.4f} | {', '.join(over) or '–'} |")
        lines.append("")
    if report.get("bvh_per_clip"):
        lines += _bvh_markdown(report["bvh_per_clip"])
    if report.get("fk_per_model_max_err_m"):
        lines += ["## Forward kinematics vs OpenSim", "", "| model | max error (m) |", "|---|---|"]
        lines += [f"| {k} | {v:.2e} |" for k, v in report["fk_per_model_max_err_m"].items()] + [""]
    return "\n".join(lines)
