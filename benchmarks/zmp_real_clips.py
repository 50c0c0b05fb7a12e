"""How the kinematic ZMP judges real motion: the ZMP-in-support share of every real clip, scored exactly as
`biomotion eval generation` scores its clips, with what lies behind it; writes docs/results/zmp_real_clips.md.

    python benchmarks/zmp_real_clips.py [--data-root ../shared/data] [--out docs/results/zmp_real_clips.md]

Issue 7 asks for generated motion with the ZMP inside the support on >= 90 % of supported frames. This script
puts the real clips of the sources the generator learns from (Fukuchi, Hamner, OpenCap, Schreiber) through the
evaluation's own path: the cache's canonical coordinates at 30 Hz on the canonical Rajagopal body
(`biomotion.data.clips.coordinate_set`, quintic-spline derivatives), the ZMP of
`biomotion.body.balance.zero_moment_point` and the support of `biomotion.metrics.stability` (the convex hull of the
foot points within 5 cm of the floor). Per source and action (and speed) it reports:

- the share of supported frames whose ZMP lies inside the support (the evaluation's figure) and the median signed
  distance of the ZMP to the support boundary (cm, positive inside);
- the whole-body COM acceleration on the airborne frames (no foot point within 5 cm of the floor), from the same
  spline: physics says (0, -9.81) m/s^2 there, so its departure shows how far the smoothed, 30 Hz kinematics are
  from the dynamics the ZMP needs.

A second table asks what the trunk does to these figures. The Fukuchi runners' models (``*_simple.osim``) have no
trunk: head, arms and trunk are lumped into the pelvis body, so their clips reach the canonical body with the lumbar
joint at its default, the trunk rigid to the pelvis. Hamner's full-body runs measure the trunk, so they are scored
three ways: as captured; with the lumbar coordinates at their defaults (the trunk rigid to the pelvis, as the
Fukuchi clips have it); and with the lumbar coordinates counter-rotating the pelvis about its clip mean
(lumbar = default - (pelvis angle - its clip mean), per axis: the trunk held about steady in the ground).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

from biomotion.body.balance import zero_moment_point
from biomotion.body.kinematics import torch_threads
from biomotion.data.clips import CoordinateClip, body_model, build_temporary_cache, coordinate_set
from biomotion.errors import BiomotionError
from biomotion.evaluation.generation import TRUNK_COORDINATES
from biomotion.io.atomic import atomic_write
from biomotion.metrics.contact import CONTACT_HEIGHT
from biomotion.metrics.stability import support_margin
from biomotion.motion import Motion

REPO = Path(__file__).resolve().parents[1]
SOURCES = ("fukuchi", "hamner", "opencap", "schreiber")
GRAVITY = 9.80665


def group_of(record: dict) -> str:
    """Source, action and (where labelled) speed of a cache record: the rows of the table."""
    labels = record["labels"]
    speed = f" {labels['speed']:g} m/s" if labels.get("speed") is not None else ""
    return f"{record['source']}: {labels['action']}{speed}"


def clip_figures(model, clips: list[CoordinateClip]) -> list[dict[str, np.ndarray]]:
    """Per clip: signed ZMP-to-support distance per frame (NaN where unsupported), COM acceleration [T, 3] and the
    airborne frames."""
    s = coordinate_set(clips, model, derivatives=True)
    with torch_threads(1), torch.no_grad():
        zmp = s.q.new_full((*s.valid.shape, 3), float("nan"))
        zmp[s.valid] = zero_moment_point(model, s.q[s.valid], s.qd[s.valid], s.qdd[s.valid])
        margin = support_margin(zmp, s.feet, s.valid).numpy()
    out = []
    for k in range(len(clips)):
        valid = s.valid[k].numpy()
        com = s.com[k].numpy()[valid]
        times = np.arange(len(com)) / s.rate
        acceleration = Motion(times=times, values=com, names=("x", "y", "z")).derivatives()[1]
        airborne = (s.feet[k].numpy()[valid][..., 1] > CONTACT_HEIGHT).all(-1)
        out.append({"margin": margin[k][valid], "acceleration": acceleration, "airborne": airborne})
    return out


PELVIS = ("pelvis_tilt", "pelvis_list", "pelvis_rotation")


def trunk_variants(motion: Motion, defaults: np.ndarray) -> dict[str, Motion]:
    """A measured-trunk clip as captured, with the trunk rigid to the pelvis, and with the trunk held about steady
    in the ground (module docstring); ``defaults`` are the canonical body's default coordinates."""
    lumbar = [motion.names.index(n) for n in TRUNK_COORDINATES]
    pelvis = [motion.names.index(n) for n in PELVIS]
    rigid, steady = motion.values.copy(), motion.values.copy()
    rigid[:, lumbar] = defaults[lumbar]
    steady[:, lumbar] = defaults[lumbar] - (motion.values[:, pelvis] - motion.values[:, pelvis].mean(0))
    return {
        "as captured": motion,
        "trunk rigid to the pelvis": motion.with_values(rigid),
        "trunk held steady in the ground": motion.with_values(steady),
    }


def table(groups: dict[str, list[dict[str, np.ndarray]]]) -> list[str]:
    lines = [
        "| clips | n | supported frames | ZMP in support (%) | median ZMP distance to support (cm) | airborne "
        "frames | COM acceleration when airborne, forward / vertical (m/s²) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in sorted(groups):
        figures = groups[name]
        margin = np.concatenate([f["margin"] for f in figures])
        supported = margin[np.isfinite(margin)]
        airborne = np.concatenate([f["acceleration"][f["airborne"]] for f in figures])
        share = f"{100 * np.mean(supported >= 0):.1f}" if supported.size else "–"
        median = f"{100 * np.median(supported):+.1f}" if supported.size else "–"
        flight = f"{np.mean(airborne[:, 0]):+.2f} / {np.mean(airborne[:, 1]):+.2f}" if len(airborne) else "–"
        lines.append(
            f"| {name} | {len(figures)} | {supported.size} | {share} | {median} | {len(airborne)} | {flight} |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", default=str(REPO.parent / "shared" / "data"))
    parser.add_argument("--out", default=str(REPO / "docs" / "results" / "zmp_real_clips.md"))
    args = parser.parse_args(argv)
    started = time.perf_counter()
    try:
        model = body_model(args.data_root)
        handle, cache = build_temporary_cache(args.data_root, sources=SOURCES)
    except BiomotionError as error:  # no canonical model or no clip of these sources under the data root
        print(f"zmp_real_clips: {error}", file=sys.stderr)
        return 1
    with handle:
        records = cache.records
        clips = [CoordinateClip(r["clip_id"], group_of(r), cache.motion(i)) for i, r in enumerate(records)]
    groups: dict[str, list[dict[str, np.ndarray]]] = {}
    for clip, figures in zip(clips, clip_figures(model, clips)):
        groups.setdefault(clip.group, []).append(figures)
    defaults = model.defaults.numpy()
    measured_trunk = [c for c, r in zip(clips, records) if r["source"] == "hamner" and r["labels"]["action"] == "run"]
    trunk = [
        CoordinateClip(c.name, name, variant)
        for c in measured_trunk
        for name, variant in trunk_variants(c.motion, defaults).items()
    ]
    trunk_groups: dict[str, list[dict[str, np.ndarray]]] = {}
    for clip, figures in zip(trunk, clip_figures(model, trunk) if trunk else []):
        trunk_groups.setdefault(f"hamner runs, {clip.group}", []).append(figures)
    lines = [
        "# The kinematic ZMP on real clips",
        "",
        "Produced by `python benchmarks/zmp_real_clips.py` (see its docstring): every real clip of "
        f"{', '.join(SOURCES)} under the data root, scored as `biomotion eval generation` scores ZMP in support "
        "(30 Hz canonical coordinates on the canonical Rajagopal body, quintic-spline derivatives, support = convex "
        f"hull of the foot points within {100 * CONTACT_HEIGHT:g} cm of the floor). Airborne: no foot point within "
        f"that height; there physics gives a COM acceleration of 0 forward and {-GRAVITY:.2f} m/s² vertical.",
        "",
        *table(groups),
        "",
        "All clips pooled:",
        "",
        *table({"all": [f for figures in groups.values() for f in figures]}),
        "",
        "## What the trunk does to it",
        "",
        "The Fukuchi runners' clips have no trunk of their own (their models lump head, arms and trunk into the "
        "pelvis), so the canonical body carries its trunk rigidly on the pelvis. Hamner's runs measure the trunk; "
        "scored as captured, with the trunk rigid to the pelvis, and with the trunk held about steady in the "
        "ground (lumbar counter-rotating the pelvis about its clip mean):",
        "",
        *(table(trunk_groups) if trunk_groups else ["No Hamner run under the data root."]),
        "",
        f"{time.perf_counter() - started:.0f} s on this machine.",
    ]
    with atomic_write(args.out) as file:
        file.write("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
