"""`generate`: one request end to end — the person (`biomotion.io.profiles.person`), the action in free text, the
shipped bundle that knows it, sampling and guidance, and every output written (`biomotion.generation.outputs`).

This is ``biomotion generate`` without its argument parsing and printing.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path

from biomotion.errors import ConfigError
from biomotion.generation.adapt import Body
from biomotion.io.profiles import person
from biomotion.profile import Profile

#: torch threads for sampling and guidance: the decoder's and the surrogate's convolutions gain a little from a
#: second core (3 s guided clip, example profile, this shared 2-core machine, `python benchmarks/generation.py`:
#: faster on 2 threads in 4 of 5 runs alternating 1 and 2 in one process, medians 0.70-1.07 s against 0.80-1.04 s;
#: 0.74-0.88 s against 0.89-1.04 s in three pairs of separate processes)
GENERATION_THREADS = 2


def profile_record(profile) -> dict | None:
    """Every field of the profile a request used (None without one), as JSON values: what metrics.json records."""
    import json

    return None if profile is None else json.loads(json.dumps(profile.to_dict(), default=str))


#: with --shape, clips are generated this many times the asked length and cut to it after the adapter has re-timed
#: them to the body's stride (a 1.55 m and a 1.95 m runner's strides differ by about 1.3x)
SHAPE_LENGTH_MARGIN = 1.5

#: how far a profile's height (m) and mass (kg) may lie from a --shape body's before a note says the body wins
SHAPE_TOLERANCE = {"height": 0.005, "mass": 0.5}


def shape_notes(profile: Profile, body: Body, given: Body | str | Path) -> list[str]:
    """One note when the profile's height or mass contradicts the ``body`` (given as ``given``) the clips are
    written on, beyond `SHAPE_TOLERANCE`: the body, not the profile, sets the model (the profile still conditions
    the generator unless the request ignores it). Empty otherwise: a body that contradicts nothing needs no note."""
    differ = [
        f"{name} {mine:g} {unit} against the body's {theirs:.3g}"
        for name, unit, mine, theirs in (
            ("height", "m", profile.height, body.shape.height),
            ("mass", "kg", profile.mass, body.shape.mass),
        )
        if mine is not None and theirs is not None and abs(mine - theirs) > SHAPE_TOLERANCE[name]
    ]
    if not differ:
        return []
    return [
        f"--shape {given if not isinstance(given, Body) else body.source} sets the body, not the profile "
        f"({', '.join(differ)})"
    ]


def versions() -> dict[str, str]:
    """biomotion's, torch's, NumPy's and Python's versions, recorded with every generated clip."""
    import platform

    import numpy
    import torch

    from biomotion import __version__

    return {
        "biomotion": __version__,
        "torch": torch.__version__,
        "numpy": numpy.__version__,
        "python": platform.python_version(),
    }


def generate(
    *,
    action: str,
    out: Path,
    data_root: Path,
    checkpoints: Path | None = None,
    profile_file: Path | None = None,
    subject_table: Path | None = None,
    subject_id: str | None = None,
    references: Sequence[Path] = (),
    reference_actions: Sequence[str] = (),
    seconds: float = 3.0,
    seed: int = 0,
    samples: int = 1,
    guidance: bool = True,
    personalised: bool = True,
    figures: bool = True,
    command: str = "",
    threads: int | None = None,
    smooth_hz: float | None = None,
    refine: bool = False,
    refiner: Path | None = None,
    generator: str = "pgbig",
    control: Path | None = None,
    shape: Body | str | Path | None = None,
    shape_height: float | None = None,
    adapter: str | Path | None = None,
) -> dict:
    """Run the whole request; returns a summary (files per sample, timings, the action understood, and `notes`
    on how it was understood: `ActionVocabulary.notes`, also written to each sample's metrics.json).

    ``reference_actions``: what each reference clip shows, free text like ``action`` ("run at 2.5 m/s"), one per
    reference in order, or none (each clip's action is then inferred and its speed taken as the action's mean).

    ``threads``: torch intra-op threads for sampling and guidance (default `GENERATION_THREADS`, at most the
    machine's cores); the rest runs as the caller set it. Results differ between thread counts only by float
    rounding.

    ``smooth_hz``: low-pass the guided coordinates at this cutoff before planting (`GuidanceConfig.smooth_hz`).

    ``refine``: pass every sample through the PhysPT refiner after guidance (`biomotion.models.refiner`; weights
    ``refiner``, default the shipped ones); the files then describe the refined motion, and metrics.json's
    ``foot_planting`` change counts the refiner's change to the legs too.

    ``generator``: ``"pgbig"`` (the above) or ``"flexmotion"`` (`biomotion.generation.flexmotion.generate`: one
    window per sample with its torques, ground reaction and activations as generated; the profile is read as here,
    references, guidance, smoothing and refinement do not apply).

    ``control``: a control spec file (`biomotion.guidance.control`), with PG-BIG met through guidance (which must
    be on), each sample's folder then also holding control.json and control.png/.svg, every target against what the
    written files achieve (`biomotion.generation.outputs.write_control`); with FlexMotion met through its control
    module (`biomotion.generation.flexmotion_control`, FlexMotion Sec. 3.3), the bounds recorded in metrics.json.

    ``shape``: the body to write the clips on (PG-BIG only): a `biomotion.generation.adapt.Body`, or what
    ``biomotion adapt --to`` takes, a scaled .osim or a shape file (`biomotion.generation.adapt.read_body`;
    ``shape_height`` (m) gives the standing height of a model without head or torso). Each clip, generated at the
    canonical body, is moved onto it by the HUMOS shape adapter (weights ``adapter``, default the shipped ones;
    `biomotion.generation.outputs.shaped_clips`, the call behind ``biomotion adapt``), and model.osim is its
    scaled model instead of the canonical one scaled uniformly to the profile. The profile still conditions the
    generator; where its height or mass disagrees with the body's, the body wins and a note says so. A body that
    cannot be read is refused before anything is generated."""
    if generator not in ("pgbig", "flexmotion"):
        raise ConfigError(f"--generator {generator!r}: choose pgbig or flexmotion")
    if generator == "flexmotion" and shape is not None:
        raise ConfigError("--shape moves PG-BIG clips onto a body: --generator flexmotion takes no --shape")
    if shape_height is not None and shape is None:
        raise ConfigError("--shape-height gives the standing height of the --shape body: give --shape too")
    spec = None
    if control is not None:
        from biomotion.guidance.control import Control

        if generator == "pgbig" and not guidance:
            raise ConfigError("--control is met through guidance with --generator pgbig: it needs guidance on")
        spec = control if isinstance(control, Control) else Control.load(control)
        if generator == "pgbig":
            spec.check(seconds)
    if generator == "flexmotion":
        from biomotion.generation import flexmotion

        if references or refine or smooth_hz is not None:
            raise ConfigError("--generator flexmotion takes no --reference, --refine or --smooth")
        chosen_profile = person(profile_file, subject_table, subject_id) if personalised else None
        return flexmotion.generate(
            action=action, out=Path(out), data_root=Path(data_root), checkpoints=checkpoints,
            profile=chosen_profile, seed=seed, samples=samples, seconds=seconds, command=command, control=spec,
        )  # fmt: skip
    from biomotion.body.kinematics import torch_threads
    from biomotion.data.clips import MODEL_FILE
    from biomotion.generation.outputs import write_generation
    from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE, Generator
    from biomotion.generation.routing import Route, full_body_checkpoints, route
    from biomotion.guidance.refine import GuidanceConfig
    from biomotion.io.mot import read_motion
    from biomotion.models.bundle import GeneratorBundle

    if threads is not None and threads < 1:
        raise ConfigError(f"--threads must be at least 1, got {threads}")
    if smooth_hz is not None and not guidance:
        raise ConfigError("--smooth filters the guided motion: it has no effect with --no-guidance")
    profile = person(profile_file, subject_table, subject_id)
    body = None
    if shape is not None:
        from biomotion.generation.adapt import load_adapter, read_body
        from biomotion.models.shape_vae import STRIDE_RANGE

        shortest = 1.5 * STRIDE_RANGE[1]  # `stride_time` searches strides up to STRIDE_RANGE[1] in 1.5 of it
        if seconds < shortest:
            raise ConfigError(
                f"--seconds {seconds:g}: --shape moves a gait onto the body, and the shape adapter needs at least "
                f"{shortest:g} s of it to find the stride"
            )

        body = (
            shape
            if isinstance(shape, Body)
            else read_body(shape, height=shape_height, data_root=data_root, what="--shape")
        )
        load_adapter(adapter)  # missing weights are refused before anything is generated
    if reference_actions and len(reference_actions) != len(references):
        raise ConfigError(
            f"--reference-action given {len(reference_actions)} times for {len(references)} "
            "--reference clips: give one per clip, in the same order, or none"
        )
    motions = [read_motion(p) for p in references]
    started = time.perf_counter()
    # the sentence encoder loads here unless the text names an action exactly
    chosen = Route(Path(checkpoints), "", 1.0) if checkpoints is not None else route(action, CHECKPOINTS)
    generator = Generator.load(data_root, chosen.checkpoints)
    vocabulary = generator.bundle.vocabulary
    if smooth_hz is not None and not 0 < smooth_hz < generator.rate / 2:
        raise ConfigError(
            f"--smooth {smooth_hz:g} Hz: the cutoff must lie between 0 and {generator.rate / 2:g} Hz "
            f"(half the generator's {generator.rate:g} Hz)"
        )
    try:
        request = vocabulary.resolve(action)
    except ConfigError as error:
        if chosen.full_body or chosen.full_body_label is None:  # the error lists that vocabulary's actions
            raise
        folder = full_body_checkpoints(chosen.checkpoints)
        full_body = GeneratorBundle.load(folder / GENERATOR_FILE).vocabulary
        raise ConfigError(
            f"{error}; the full-body bundle ({folder}) also knows "
            f"{', '.join(a for a in full_body.actions if a not in vocabulary.actions)}, with styles "
            f"({', '.join(full_body.styles)})"
        ) from None
    notes = vocabulary.notes(action, request)
    if body is not None and profile is not None:
        notes = [*notes, *shape_notes(profile, body, shape)]
    shown = [vocabulary.parse(text) for text in reference_actions]
    loaded = time.perf_counter()
    with torch_threads(threads or min(GENERATION_THREADS, os.cpu_count() or 1)):
        generated = generator.generate(
            request,
            profile=profile,
            references=motions,
            reference_actions=[r.action for r in shown],
            reference_speeds=[r.speed for r in shown],
            seconds=seconds if body is None else seconds * SHAPE_LENGTH_MARGIN,
            samples=samples,
            seed=seed,
            guidance=guidance,
            personalised=personalised,
            biodata=chosen.biodata,
            guidance_config=GuidanceConfig(smooth_hz=smooth_hz),
            **({} if spec is None else {"control": spec}),
        )
    if refine:
        from dataclasses import replace

        import torch

        from biomotion.generation.refinement import load_refiner

        model = load_refiner(refiner, data_root)
        every = torch.ones(generated.q.shape[-1], dtype=torch.bool)
        refined = torch.stack([model.refine(clip.float(), every).q for clip in generated.q.detach()])
        generated = replace(generated, q=refined.to(generated.q.dtype))
    done = time.perf_counter()
    files = write_generation(
        out,
        generated,
        generator,
        profile,
        Path(data_root) / MODEL_FILE,
        figures=figures,
        request={
            "command": command,
            "text": action,
            "seconds": seconds,
            "seed": seed,
            "guidance": guidance,
            "smooth_hz": smooth_hz,
            "refined": bool(refine),
            **({} if control is None else {"control": str(control)}),
            "personalised": personalised,
            "bundle": ("full-body" if chosen.full_body else "lab") if checkpoints is None else str(checkpoints),
            "biodata_used": personalised and chosen.biodata and profile is not None,
            "references": [str(p) for p in references],
            "reference_actions": list(reference_actions),
            "notes": notes,
            "inputs": {
                "profile": None if profile_file is None else str(profile_file),
                "subject_table": None if subject_table is None else str(subject_table),
                "subject_id": subject_id,
                "references": [str(p) for p in references],
                "data_root": str(data_root),
                "checkpoints": str(chosen.checkpoints),
            },
            "profile": profile_record(profile),
            **({} if body is None else {"shape": str(body.source)}),
            "versions": versions(),
        },
        control=spec,
        shape=body,
        adapter=adapter,
    )
    return {
        "action": request,
        "route": chosen,
        "notes": notes,
        "files": files,
        "load_seconds": loaded - started,
        "generate_seconds": done - loaded,
        "write_seconds": time.perf_counter() - done,
        "profile": profile,
    }
