"""Guidance settings compared on the example profile (never on evaluation subjects); writes
docs/results/guidance_weights.md. The defaults of `biomotion.guidance.refine.GuidanceConfig` and the departures from
PG-BIG Table 5 they make are justified by this table.

    python benchmarks/guidance_weights.py [--data-root ../shared/data]

For each setting: `examples/runner_52_acl.yaml` asked to run at 3.5 m/s, walk and squat, 2 samples of 3 s each,
seed 1; the physics metrics of `biomotion eval` (mean over the 6 clips) of the unguided sample and of each guided
variant: the defaults, the defaults without foot planting (`biomotion.guidance.planting`), planting that may also
bend the toes, planting whose stance threshold is the metrics' 5 cm contact height instead of 3 cm, and without
planting (to compare latent guidance alone) Table 5's weights (l_omega 10, l_foot 1,
l_ground 10, lr 0.05) and re-quantisation at iteration 30, the foot and ground terms' contact mask by height alone
(the rule before the stance speed test of `biomotion.guidance.refine.Guide.contact`), lighter speed terms
(l_speed 100 and 300), without the foot-skim term and with the optional low-pass at 6 Hz
(`GuidanceConfig.smooth_hz`). docs/decisions/guidance-weights.md reads the table.
Speed error: |mean horizontal pelvis speed - requested speed| at the person's size, over the clips whose request
names a speed (the run).
Muscle-limit violations are the share of frames x muscles whose surrogate activation leaves the training 5-95 %
band (as `biomotion eval generation` counts them).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from biomotion.body.kinematics import torch_threads
from biomotion.evaluation.generation import muscle_violation_share, speed_errors
from biomotion.generation.outputs import physics_metrics
from biomotion.generation.pipeline import Generator
from biomotion.guidance.planting import LEG_COORDINATES, PlantingConfig
from biomotion.guidance.refine import GuidanceConfig
from biomotion.io.atomic import atomic_write
from biomotion.io.profiles import read_profile

ACTIONS = ("run at 3.5 m/s", "walk", "squat")
KEYS = (
    "foot_contact_velocity",
    "skate_ratio",
    "floating",
    "penetration",
    "jerk",
    "energy_com",
    "muscle_violations",
    "speed_error",
)
SETTINGS = {
    "unguided": None,
    "defaults": {},
    "no foot planting": {"planting": None},
    "planting also bends the toes": {"planting": PlantingConfig(coordinates=LEG_COORDINATES + ("mtp_angle",))},
    "planting stance below 5 cm (the metrics' contact height)": {"planting": PlantingConfig(stance_height=0.05)},
    "Table 5 weights, no planting": {
        "w_angular_velocity": 10.0,
        "w_foot_contact": 1.0,
        "w_ground": 10.0,
        "lr": 0.05,
        "planting": None,
    },
    "re-quantised at 30, no planting": {"quantize_at": 30, "planting": None},
    "contact by height alone (no stance speed test)": {"stance_speed_ratio": None},
    "no tempo (the speed term alone brings the sample to speed)": {"tempo": None},
    "speed weight 100": {"w_locomotion_speed": 100.0},
    "speed weight 300": {"w_locomotion_speed": 300.0},
    "no foot-skim term": {"w_foot_skim": 0.0},
    "low-pass at 6 Hz before planting": {"smooth_hz": 6.0},
}


def score(generator: Generator, profile, settings: dict | None) -> dict[str, float]:
    values = {k: [] for k in KEYS}
    for text in ACTIONS:
        action = generator.bundle.vocabulary.parse(text)
        out = generator.generate(
            action,
            profile=profile,
            seconds=3,
            seed=1,
            samples=2,
            guidance=settings is not None,
            guidance_config=GuidanceConfig(**settings) if settings is not None else None,
        )
        values["muscle_violations"].extend(
            100 * share for share in muscle_violation_share(out.motions(), generator.surrogate)
        )
        if action.speed is not None:
            values["speed_error"].extend(speed_errors(out.motions(), [action.speed] * 2, [profile.height] * 2))
        for motion in out.motions():
            metrics = physics_metrics(motion, generator.body)
            for k in KEYS[:-2]:
                values[k].append(np.nan if metrics[k]["value"] is None else metrics[k]["value"])
    return {k: float(np.nanmean(v)) for k, v in values.items()}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-root", default="../shared/data")
    parser.add_argument("--out", default="docs/results/guidance_weights.md")
    args = parser.parse_args(argv)
    with torch_threads(1):
        generator = Generator.load(args.data_root)
        profile = read_profile(Path("examples/runner_52_acl.yaml"))
        rows = {name: score(generator, profile, settings) for name, settings in SETTINGS.items()}
    units = {
        "foot_contact_velocity": "m/s",
        "skate_ratio": "%",
        "floating": "cm",
        "penetration": "cm",
        "jerk": "m/s³",
        "energy_com": "J",
        "muscle_violations": "%",
        "speed_error": "m/s",
    }
    text = (
        "# Guidance settings on the example profile\n\nCommand: `python benchmarks/guidance_weights.py`; "
        f"{', '.join(ACTIONS)}, 2 samples of 3 s each, seed 1, mean over the 6 clips.\n\n"
        "| setting | "
        + " | ".join(f"{k} ({units[k]})" for k in KEYS)
        + " |\n|---|"
        + "---|" * len(KEYS)
        + "\n"
        + "".join(f"| {name} | " + " | ".join(f"{row[k]:.3g}" for k in KEYS) + " |\n" for name, row in rows.items())
    )
    with atomic_write(args.out) as handle:
        handle.write(text)
    print(text)


if __name__ == "__main__":
    sys.exit(main())
