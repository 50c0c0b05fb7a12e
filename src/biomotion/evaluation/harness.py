"""The evaluation harness: every metric of `biomotion.metrics` that applies to a set of clips, as JSON, Markdown
tables in the layout of PG-BIG Table 2 / PhysPT Table 1 (one row per method or group, mean ± std over clips, units
and the better direction in the header) and PNG plots of the per-clip distributions.

Per-set metrics (docs/metrics.md gives every definition and its paper): the contact family on the sole points with
the absolute ground and PG-BIG's clip-median ground, jerk of the joint centres, energy consistency of the
whole-body COM as a point mass (and, with ``physics=True`` on coordinate clips, of the full-body energy of the
body model, with the ZMP-inside-support share), joint-range violations against the Rajagopal 2016 ranges
(coordinate clips), motion entropy of the body-point heights and the pairwise diversity of the clips.
Paired metrics (a predicted set against a reference set, clips paired by name, else in order): MJE and P-MJE
(PhysPT Sec. 4), ACCL and VEL, and PG-BIG's fidelity (DTW, pelvis-relative) with its Gaussian W2 variant.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from biomotion.data.clips import body_model, build_temporary_cache, cache_clips, coordinate_set, load_clip_set
from biomotion.io.atomic import atomic_write
from biomotion.metrics.clip_set import ClipSet
from biomotion.metrics.registry import (
    DIVERSITY,
    diversity_features,
    metrics,
    record,
    score_pairs,
    score_set,
    set_record,
    summarize_set,
)


def _cell(record: dict) -> str:
    if record["mean"] is None:
        return "–"
    digits = 2 if abs(record["mean"]) < 100 else 1
    return f"{record['mean']:.{digits}f} ± {record['std']:.{digits}f}"


def markdown_table(rows: dict[str, dict], first: str = "Method") -> str:
    """A Markdown table: one row per name in ``rows`` (name -> metric records), one column per metric with its
    label, unit and direction mark (PG-BIG Table 2 / PhysPT Table 1 layout), as `biomotion.metrics.registry.record`
    took them from the metric object (the mark from its ``higher_is_better``); "–" where a metric does not apply."""
    keys: list[str] = []
    for records in rows.values():
        keys += [k for k in records if k not in keys]
    header = {}
    for records in rows.values():
        for k, rec in records.items():
            header.setdefault(k, f"{rec['label']} ({rec['unit']}) {rec['better']}")
    lines = [f"| {first} | N | " + " | ".join(header[k] for k in keys) + " |", "|---|---:|" + "---:|" * len(keys)]
    for name, records in rows.items():
        count = max((rec["count"] for k, rec in records.items() if k != DIVERSITY.name), default=0)
        cells = [_cell(records[k]) if k in records else "–" for k in keys]
        lines.append(f"| {name} | {count} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_json(path: str | Path, payload: dict) -> None:
    """Write ``payload`` as indented UTF-8 JSON, atomically."""
    with atomic_write(Path(path)) as handle:
        json.dump(payload, handle, indent=1, ensure_ascii=False)


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` atomically."""
    with atomic_write(Path(path)) as handle:
        handle.write(text)


def evaluate(pred: ClipSet, ref: ClipSet | None = None, model=None, *, physics: bool = False) -> dict:
    """Every applicable metric of ``pred`` (and ``ref``, and of pred against ref when given) as a JSON-ready dict."""
    result = {
        "format": "biomotion-eval/1",
        "rate_hz": pred.rate,
        "sets": {
            "pred": {
                "kind": pred.kind,
                "clips": list(pred.names),
                "metrics": summarize_set(pred, model, physics=physics),
            }
        },
    }
    if ref is not None:
        result["sets"]["ref"] = {
            "kind": ref.kind,
            "clips": list(ref.names),
            "metrics": summarize_set(ref, model, physics=physics),
        }
        pairs, paired = score_pairs(pred, ref)
        result["pairs"] = [[pred.names[a], ref.names[b]] for a, b in pairs]
        result["paired"] = paired
    return result


def evaluation_markdown(result: dict) -> str:
    """The Markdown report of `evaluate`: per-set table (Reference, Generated) and the paired table."""
    sets = result["sets"]
    rows = {}
    if "ref" in sets:
        rows["Reference"] = sets["ref"]["metrics"]
    rows["Generated"] = sets["pred"]["metrics"]
    text = (
        f"# Evaluation\n\nMean ± std over clips at {result['rate_hz']:g} Hz; ↓ lower is better, ↑ higher, "
        "→ closer to the reference. Definitions: docs/metrics.md.\n\n" + markdown_table(rows)
    )
    if "paired" in result:
        text += f"\n## Generated against reference ({len(result['pairs'])} pairs)\n\n" + markdown_table(
            {"Generated": result["paired"]}
        )
    return text


def plot_distributions(result: dict, plots_dir: str | Path) -> list[str]:
    """PNG (and SVG) histograms of the per-clip values of every per-set and paired metric."""
    from biomotion.viz.plots import plot_metric_distributions

    folder = Path(plots_dir)
    folder.mkdir(parents=True, exist_ok=True)
    names = {"pred": "generated", "ref": "reference"}
    per_set: dict[str, dict[str, list[float]]] = {}
    for key, data in result["sets"].items():
        for rec in data["metrics"].values():
            values = [v for v in rec.get("values", []) if v is not None]
            if values:
                per_set.setdefault(f"{rec['label']} ({rec['unit']})", {})[names[key]] = values
    written = [plot_metric_distributions(per_set, folder / "eval_distributions")[0]]
    paired = {
        f"{rec['label']} ({rec['unit']})": [v for v in rec["values"] if v is not None]
        for rec in result.get("paired", {}).values()
    }
    paired = {k: v for k, v in paired.items() if v}
    if paired:
        written.append(plot_metric_distributions(paired, folder / "eval_paired")[0])
    return [str(p) for p in written]


def eval_command(pred, ref, data_root, json_path, md_path, plots_dir=None, *, physics: bool = False) -> dict:
    """`biomotion eval`: load ``pred`` and ``ref`` (a folder or files each: dataset cache, .mot/.sto, BVH; ``ref``
    may be None), evaluate, write JSON and Markdown where their paths are given (and plots to ``plots_dir``);
    returns the result dict."""
    model = None
    pred_set = load_clip_set(pred, data_root, derivatives=physics)
    ref_set = None if ref is None else load_clip_set(ref, data_root, derivatives=physics)
    if "coordinates" in (pred_set.kind, getattr(ref_set, "kind", None)):
        model = body_model(data_root)
    result = evaluate(pred_set, ref_set, model, physics=physics)
    result["inputs"] = {"pred": _names(pred), "ref": None if ref is None else _names(ref)}
    if plots_dir is not None:
        result["plots"] = plot_distributions(result, plots_dir)
    if json_path is not None:
        write_json(json_path, result)
    if md_path is not None:
        write_text(md_path, evaluation_markdown(result))
    return result


def _names(spec) -> list[str]:
    return [str(spec)] if isinstance(spec, (str, Path)) else [str(s) for s in spec]


def reference_metrics(cache, model, *, physics: bool = True) -> dict:
    """Reference values of real data: every clip of a `DatasetCache`, per source and action and over all clips.

    Each source/action group is batched and scored on its own (a batch pads every clip to the longest one: one
    1900-frame dance among 800 clips would pad them all), and the all-clips row pools the groups' per-clip scores
    and diversity features."""
    groups: dict[str, list] = {}
    for clip in cache_clips(cache):
        groups.setdefault(clip.group, []).append(clip)
    rows, pooled, features, registered = {}, {}, [], []
    for group, members in sorted(groups.items()):
        clips = coordinate_set(members, model, cache.rate, derivatives=physics)
        scores = score_set(clips, model, physics=physics)
        rows[group] = summarize_set(clips, model, physics=physics, scores=scores)
        registered = metrics(clips.kind, model, physics=physics)
        for key, value in scores.items():
            pooled.setdefault(key, []).append(value)
        features.append(diversity_features(clips))
    scores = {key: torch.cat(values) for key, values in pooled.items()}
    everything = {metric.name: record(metric, scores[metric.name]) for metric in registered}
    everything[DIVERSITY.name] = set_record(DIVERSITY, DIVERSITY.score(torch.cat(features)))
    rows["all real data"] = everything
    for records in rows.values():
        for rec in records.values():
            rec.pop("values", None)
    return {
        "format": "biomotion-reference-metrics/1",
        "rate_hz": cache.rate,
        "clips": len(cache),
        "physics": physics,
        "groups": rows,
    }


REFERENCE_NOTE = """\
Every clip of the dataset cache (every source of the dataset registry, canonical Rajagopal 2016 coordinates
resampled to {rate:g} Hz and placed in one frame by `biomotion.data.placement`: pelvis translations at the generic
1.70 m size, treadmill runs made overground, feet on y = 0) run through the generic Rajagopal 2016 model; mean ±
std over clips per source and action. These are the "Reference" column a generator is compared against, in the
frame the generator works in. Written by `biomotion.evaluation.harness.reference_command`
(`biomotion eval reference`); definitions in docs/metrics.md.

Contact points are the 10 sole points of the model feet (`biomotion.body.contact.foot_points`); contact at 5 cm,
skating at 0.5 m/s over 0.25 s, planted (floating) at 0.5 m/s. "clip median" is PG-BIG's public-evaluator ground
(per clip, the median over frames of the lowest sole point). Energy std (COM) treats the whole-body COM as a point
mass; Energy std (body) is the full-body energy with segment rotation (`biomotion.body.balance.mechanical_energy`).
ZMP in support: share of frames with a foot in contact whose ZMP lies in the hull of the contact points. Out of
range: share of coordinate entries outside the Rajagopal 2016 ranges (pelvis translations excluded). Entropy:
heights of the joint centres, 50 bins. Diversity: mean pairwise distance of per-clip features (mean and std of the
joint-centre heights and horizontal distances from the pelvis), within each row.

How to read it. Real capture is not scored as perfect, as the papers report for their references (PG-BIG Table 2:
penetration 2.29 cm, floating 2.07 cm):
- Placement puts the 5th percentile of each clip's lowest sole point on y = 0, so absolute penetration is small by
  construction (the 5 % of frames below the floor) and the clip-median columns measure how far the typical lowest
  point sits above it. Real feet still float, slide and sink against a rigid model floor: skin and shoe are not
  rigid, IK has marker error, and the model's sole points are a generic foot's.
- Treadmill runs made overground keep the belt's speed fluctuations within a stride (the belt is not perfectly
  uniform and IK noise adds to it), which the speed-based tests (planted for floating, skate, foot contact
  velocity) count as sliding.
- OpenCap drop jumps spend most frames standing on the raised start box: placement puts the landing on y = 0, so
  the frames on the box count as floating (about 19 cm) and the clip-median ground lies on the box, which makes
  the clip-median penetration (about 10 cm) count the landing. They are the one source whose floor is not one
  plane.
"""


def reference_command(data_root, md_path, json_path, *, physics: bool = True) -> dict:
    """`biomotion eval reference`: build the dataset cache of ``data_root`` in a temporary folder, compute the
    reference metrics per source and action, write JSON and Markdown; returns the result dict."""
    handle, cache = build_temporary_cache(data_root)
    with handle:
        result = reference_metrics(cache, body_model(data_root), physics=physics)
    write_json(json_path, result)
    text = (
        "# Reference metrics of the real data\n\n"
        + REFERENCE_NOTE.format(rate=result["rate_hz"])
        + "\n"
        + markdown_table(result["groups"], first="source/action")
    )
    write_text(md_path, text)
    return result
