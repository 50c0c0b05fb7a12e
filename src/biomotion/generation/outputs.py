"""Everything `biomotion generate` writes for a generated clip, on the person's scaled model.

Per clip: ``motion.mot`` (OpenSim coordinates of the scaled model, degrees, couplers applied), ``motion.bvh``
(the same motion as a BVH skeleton of the model's bodies), ``grf.mot`` + ``grf_loads.xml`` (ground reaction
inferred from the motion alone, PhysPT Eq. 4-5), ``torques.sto`` (inverse dynamics with that ground reaction),
``com_zmp.sto``, ``activations.sto`` (muscle surrogate, PG-BIG Sec. 3.3), ``metrics.json`` (the physics metrics of
`biomotion eval` plus the guidance terms before and after latent guidance, how much foot planting changed the
legs, the person's posture offset taken from the reference clips and the tempo the sample was played at to reach
the asked speed, `biomotion.guidance.tempo`) and plots; with a control spec, ``control.json`` and the plot
``control.png`` + ``control.svg``: each target against what the written files achieve (`write_control`).
``model.osim`` (the person's model) is written once per request. Files are written atomically by the writers they
come from.

With a ``shape`` (a `biomotion.generation.adapt.Body`: a scaled .osim or a shape file, what ``biomotion adapt --to``
takes), the person's model is that body's scaled model rather than the canonical model scaled uniformly to the
profile's height and mass, and each clip, generated at the canonical body, is first moved onto it by the HUMOS
shape adapter (`shaped_clips`, the same call as ``biomotion adapt``: `biomotion.generation.adapt.adapt`); the
ground reaction, torques and COM/ZMP are then the analysis of the adapted motion on that model, the activations the
surrogate's on it, and metrics.json's ``shape`` records the body, the adapter's file and SHA-256, the stride times
and what was done to fit the body (`shape_record`).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.errors import ConfigError
from biomotion.generation.adapt import Adapted, Body
from biomotion.generation.pipeline import Generated
from biomotion.guidance.control import Control
from biomotion.io.atomic import atomic_write
from biomotion.motion import Motion


def physics_metrics(motion: Motion, model) -> dict[str, dict]:
    """The per-clip metrics of `biomotion eval` (contact, smoothness, energy, joint range, ZMP) of one motion."""
    from biomotion.data.clips import CoordinateClip, coordinate_set
    from biomotion.metrics.registry import metrics, summarize_set

    clips = coordinate_set([CoordinateClip("generated", "generated", motion)], model, motion.rate, derivatives=True)
    records = summarize_set(clips, model, physics=True)
    return {
        m.name: {"label": records[m.name]["label"], "unit": records[m.name]["unit"], "value": records[m.name]["mean"]}
        for m in metrics(clips.kind, model, physics=True)
    }


def planting_changes(generated) -> list[dict]:
    """Per sample, how much foot planting (`biomotion.guidance.planting`) changed the legs: the largest and the
    mean absolute change of a leg coordinate (deg) and the share of frames it changed by more than 1 deg; empty
    when planting did not run."""
    from biomotion.body.canonical import CANONICAL_COORDINATES
    from biomotion.guidance.planting import leg_columns

    change = (generated.q - generated.unplanted)[..., leg_columns(CANONICAL_COORDINATES)].abs().rad2deg()
    if not bool((change > 0).any()):
        return []
    return [
        {
            "max_change_deg": float(c.max()),
            "mean_change_deg": float(c.mean()),
            "frames_changed_over_1deg": float((c.amax(-1) > 1.0).float().mean()),
        }
        for c in change.detach()
    ]


def write_clip(
    out: Path,
    motion: Motion,
    model,
    model_file: Path,
    activations: np.ndarray | None,
    muscle_names: tuple[str, ...],
    extra_metrics: dict,
    *,
    figures: bool = True,
    geometry: tuple[Path, ...] = (),
) -> dict[str, Path]:
    """Write one generated clip's files into ``out`` (see the module docstring); returns them by role."""
    from biomotion.analysis.chain import (
        analyze,
        model_motion,
        support_polygons,
        write_analysis,
    )
    from biomotion.body.bvh_export import motion_to_bvh
    from biomotion.io.bvh import write_bvh
    from biomotion.io.mot import write_motion, write_storage

    out.mkdir(parents=True, exist_ok=True)
    coordinates = model_motion(motion, model)
    files = {"motion": write_motion(out / "motion.mot", coordinates, name="generated")}
    bvh = out / "motion.bvh"
    write_bvh(bvh, motion_to_bvh(model, coordinates))
    files["bvh"] = bvh
    result = analyze(coordinates, model)
    written = write_analysis(result, out, grf_file="grf.mot")
    written.pop("coordinates", None)
    (out / "coordinates_filtered.mot").unlink(missing_ok=True)
    written.pop("summary", None)
    (out / "summary.json").unlink(missing_ok=True)
    files.update(written)
    if activations is not None:
        files["activations"] = write_storage(
            out / "activations.sto",
            list(muscle_names),
            motion.times,
            activations,
            name="Muscle activations (surrogate)",
        )
    metrics = {"physics": physics_metrics(motion, model), **extra_metrics}
    with atomic_write(out / "metrics.json") as handle:
        json.dump(metrics, handle, indent=1)
    files["metrics"] = out / "metrics.json"
    if figures:
        from biomotion.viz.plots import (
            plot_activations,
            plot_balance,
            plot_ground_reaction,
            plot_joint_angles,
        )
        from biomotion.viz.viewer import view_command

        files["plot_joint_angles"] = plot_joint_angles(coordinates, out / "joint_angles")[0]
        files["plot_grf"] = plot_ground_reaction(
            result.inferred,
            out / "grf",
            body_weight=result.body_weight,
            label="inferred",
            title="ground reaction inferred from the motion",
        )[0]
        files["plot_balance"] = plot_balance(
            result.com,
            result.zmp,
            out / "balance",
            support=support_polygons(result.contact_points, result.contact_loaded),
        )[0]
        if activations is not None:
            files["plot_activations"] = plot_activations(motion.times, muscle_names, activations, out / "activations")[
                0
            ]
        files["viewer"] = view_command(
            files["motion"],
            model=model_file,
            grf=files["grf_inferred"],
            activations=files.get("activations"),
            com_zmp=files["com_zmp"],
            out=out / "viewer.html",
            title="biomotion generate",
            geometry=geometry,
        )
    return files


def write_control(
    folder: str | Path,
    control: Control,
    *,
    model=None,
    scale: float | None = None,
    uncontrolled: str | Path | None = None,
    figures: bool = True,
) -> dict[str, Path]:
    """Measure every target of ``control`` on the clip written in ``folder`` (`biomotion.analysis.control_measures`:
    from grf.mot, motion.mot, com_zmp.sto, torques.sto and activations.sto, the files a user reads) and write
    ``control.json`` (per target: quantity, kind, target, achieved, met) and, with ``figures``, ``control.png`` +
    ``control.svg`` (`biomotion.viz.control_plot`), from the same measures so that they agree. ``model``: the model
    the files were written on (default the folder's model.osim); ``scale``: the length scale to the canonical size
    (`biomotion.analysis.control_measures.length_scale`; default from metrics.json's profile height);
    ``uncontrolled``: the folder of the same request generated without control, measured and drawn beside it.
    Returns the files by role (``control_json``, ``plot_control``)."""
    from biomotion.analysis.control_measures import control_record, measure_control, read_outputs

    folder = Path(folder)
    outputs = read_outputs(folder, model=model, scale=scale)
    measures = measure_control(control, outputs)
    free = None
    if uncontrolled is not None:
        free = measure_control(control, read_outputs(uncontrolled, model=model, scale=scale))
    extra = {"length_scale": outputs.length_scale}
    if uncontrolled is not None:
        extra["uncontrolled"] = str(uncontrolled)
    record = control_record(control, measures, uncontrolled=free, extra=extra)
    with atomic_write(folder / "control.json") as handle:
        json.dump(record, handle, indent=1, ensure_ascii=False)
    files = {"control_json": folder / "control.json"}
    if figures:
        from biomotion.viz.control_plot import write_control_plot

        files["plot_control"] = write_control_plot(control, measures, folder / "control", uncontrolled=free)[0]
    return files


def shaped_clips(
    motions: list[Motion], generic_osim: Path, shape: Body, adapter: str | Path | None = None
) -> list[Adapted]:
    """Each canonical clip (``Generated.motions()`` at the canonical size, on the canonical model ``generic_osim``)
    moved onto the body ``shape`` by the HUMOS shape adapter (``humos.md``; `biomotion.generation.adapt.adapt`, the
    call behind ``biomotion adapt``, with its knee sign, floor and foot planting). ``adapter``: the weights (default
    the shipped ``checkpoints/shape_adapter.safetensors``). Contract: the adapter finds a stride in the clip and in
    its output (`biomotion.models.shape_vae.stride_time`); a clip without one, or too short, is a one-line
    `ConfigError` naming the body."""
    from biomotion.generation.adapt import adapt, read_body

    canonical = read_body(generic_osim, what="the canonical model")
    try:
        return [adapt(motion, canonical, shape, adapter=adapter) for motion in motions]
    except ConfigError as error:
        raise ConfigError(
            f"--shape {shape.source}: {error} (the adapter moves a gait and re-times the clip with the body's "
            "stride: a shorter stride makes a shorter clip; ask more --seconds)"
        ) from None


def trimmed(adapted: Adapted, seconds: float) -> Adapted:
    """The adapted clip cut to its first ``seconds`` (as it is when shorter). `biomotion.generation.request` has
    the canonical clip generated longer than asked (``SHAPE_LENGTH_MARGIN``), because the adapter re-times it to the
    body's stride, so that the written clip is as long as the request."""
    import dataclasses

    motion = adapted.motion
    frames = round(seconds * motion.rate)
    if motion.n_frames <= frames:
        return adapted
    return dataclasses.replace(adapted, motion=motion.frames(slice(0, frames)))


def shaped_activations(surrogate, adapted: Adapted) -> np.ndarray:
    """The muscle surrogate's activations [T, M] for an adapted clip: its coordinates in canonical order and knee
    sign (`biomotion.data.sources.to_canonical`), those the target body lacks masked (the surrogate reads them as
    0)."""
    from biomotion.data.sources import to_canonical

    canonical = to_canonical(adapted.motion, knee_flipped=adapted.knee_negative["target"])
    q = torch.as_tensor(np.where(canonical.mask[None], canonical.values, 0.0), dtype=torch.float32)[None]
    mask = torch.as_tensor(canonical.mask)[None]
    with torch.no_grad():
        return surrogate.predict_symmetric(q, mask)[0][0].double().numpy()


def shape_record(adapted: Adapted, given: str | None = None) -> dict:
    """What metrics.json records of a clip moved onto a body (`shaped_clips`): the body given (``given``, the path
    as the user wrote it), its `Shape`, its model's name, the adapter's file name and SHA-256, the stride times
    before and after, the floor shift, the ground velocity, whether the feet were planted, and the clip's length
    (s): the request's ``seconds`` unless the adapter, re-timing the (longer) generated clip with the body's stride,
    left less (`trimmed`)."""
    from biomotion.generation.adapt import _finite

    velocity = adapted.ground_velocity_m_s
    return _finite(
        {
            "input": given,
            "shape": adapted.target.shape.as_dict(),
            "model": adapted.target.model.name,
            "adapter": {"weights": adapted.adapter_file.name, "sha256": adapted.adapter_sha256},
            "stride_time_s": adapted.stride_time_s,
            "floor_shift_m": adapted.floor_shift_m,
            "ground_velocity_m_s": None if velocity is None else dict(zip(("x", "z"), velocity)),
            "feet_planted": adapted.planted,
            "seconds": float(adapted.motion.times[-1] - adapted.motion.times[0] + 1.0 / adapted.motion.rate),
            "coordinates_at_model_defaults": list(adapted.filled),
        }
    )


def write_generation(
    out: str | Path,
    generated: Generated,
    generator,
    profile,
    generic_osim: Path,
    *,
    figures: bool = True,
    request: dict | None = None,
    control: Control | None = None,
    shape: Body | None = None,
    adapter: str | Path | None = None,
) -> dict[str, dict[str, Path]]:
    """Scale the model to ``profile``, write ``model.osim`` and each sample's files (``out`` itself for one
    sample, ``out/sample_01`` ... for several); returns the files per sample. The viewer takes its meshes from
    the Geometry folders beside ``generic_osim`` and in ``opensim-models/Geometry`` when present. ``control``:
    the spec the clips were generated under; each sample then also gets its `write_control` files.

    ``shape``: the body to write the clips on instead (module docstring): ``model.osim`` is its scaled model (the
    profile's height and mass do not scale it), each clip is moved onto it by the shape adapter at ``adapter``
    (`shaped_clips`) and metrics.json gets ``shape`` (`shape_record`; ``request["shape"]``, when given, is the path
    recorded as its input)."""
    from biomotion.analysis.control_measures import length_scale
    from biomotion.body.scaling.stature import scale_to_profile

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    height = profile.height if profile is not None else None
    mass = profile.mass if profile is not None else None
    model_file = out / "model.osim"
    adapted: list[Adapted] = []
    if shape is None:
        model = scale_to_profile(generic_osim, height, mass, model_file, name="biomotion_generated_subject")
        motions = generated.motions(height)
    else:
        adapted = shaped_clips(generated.motions(), generic_osim, shape, adapter)
        if request is not None and request.get("seconds"):  # the request's length, from a longer generated clip
            adapted = [trimmed(a, float(request["seconds"])) for a in adapted]
        shape.write_osim(model_file)
        model = shape.model
        height = shape.shape.height
        motions = [a.motion for a in adapted]
    activations = None
    names: tuple[str, ...] = ()
    if generator.surrogate is not None:
        if adapted:
            activations = [shaped_activations(generator.surrogate, a) for a in adapted]
        else:
            with torch.no_grad():
                activations = generator.surrogate.predict_symmetric(generated.q.float())[0].double().numpy()
        names = tuple(generator.surrogate.names)
    guide_terms = {}
    if generated.history:
        guide_terms = {
            "guidance_first_iteration": generated.history[0],
            "guidance_last_iteration": generated.history[-1],
            "guidance_iterations": len(generated.history),
        }
    geometry = tuple(p for p in (generic_osim.parent / "Geometry", generic_osim.parents[2] / "Geometry") if p.is_dir())
    if shape is not None:
        geometry = (*geometry, *(p for p in shape.geometry if p.is_dir() and p not in geometry))
    planting = planting_changes(generated)
    if generated.posture is not None:  # the person's posture offset, in the units of motion.mot
        guide_terms["posture_offset"] = {
            n: round(float(v) * (1.0 if n.startswith("pelvis_t") else 180.0 / math.pi), 3)
            for n, v in zip(CANONICAL_COORDINATES, generated.posture.tolist())
            if math.isfinite(v)
        }
    result = {}
    for k, motion in enumerate(motions):
        folder = out if len(motions) == 1 else out / f"sample_{k + 1:02d}"
        extra = {
            "request": {**(request or {}), "sample": k + 1, "action": asdict(generated.action)},
            **guide_terms,
            **({"foot_planting": planting[k]} if planting else {}),
            **({} if generated.tempo is None else {"tempo": round(float(generated.tempo[k]), 4)}),
            **({"shape": shape_record(adapted[k], (request or {}).get("shape"))} if adapted else {}),
        }
        result[folder.name] = write_clip(
            folder,
            motion,
            model,
            model_file.resolve(),
            None if activations is None else activations[k],
            names,
            extra,
            figures=figures,
            geometry=geometry,
        )
        result[folder.name]["model"] = model_file
        if control is not None:
            result[folder.name].update(
                write_control(folder, control, model=model, scale=length_scale(height), figures=figures)
            )
    return result
