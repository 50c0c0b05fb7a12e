"""``biomotion scale``: an OpenSim ScaleTool setup run end to end from files.

The setup (`biomotion.io.setup.read_scale_setup`) says how: its measurements (marker pairs whose distances in
the static trial against the generic model give each body's scale factors), manual scales, subject mass and
MarkerPlacer (the static pose solved by IK, then the non-fixed markers moved onto the data: PG-BIG A.2 Eq. 1).
`biomotion.ik.scaling.scale_static` does the work; this module finds the files, reads the static trial and writes
what OpenSim's ScaleTool writes: the scaled and calibrated ``.osim``, its ScaleSet and the static pose.

Setups name their generic model and static trial by paths relative to where they were written (often Windows
paths that lead nowhere elsewhere, as in the Fukuchi runners' setups): ``model`` and ``static`` override them,
and a missing one is named together with the option that gives it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from biomotion.body.model import BodyModel
from biomotion.body.scaling.osim_file import ScaleResult, write_scale_set, write_scaled_osim
from biomotion.errors import ConfigError
from biomotion.ik.markers import check_marker_scale
from biomotion.ik.retarget import MARKER_SUFFIXES, read_markers
from biomotion.ik.scaling import scale_static
from biomotion.io.atomic import atomic_write
from biomotion.io.mot import write_motion
from biomotion.io.setup import ScaleSetup, read_scale_setup


@dataclass(frozen=True)
class Calibration:
    """What `calibrate` wrote (``model``: the scaled ``.osim``; ``pose``: the static pose, None without marker
    placement) and its summary, also written as ``summary``'s JSON file."""

    model: Path
    scale_set: Path
    pose: Path | None
    summary_file: Path
    summary: dict
    result: ScaleResult


def _generic_model(setup: ScaleSetup, model: Path | None) -> Path:
    path = model if model is not None else setup.file("model_file")
    if path is None or not Path(path).exists():
        named = f"{model}" if model is not None else f"its generic model {setup.model_file!r}"
        raise ConfigError(f"{setup.path}: {named} is not found from here; give the generic .osim with --model")
    return Path(path)


def _static_trial(setup: ScaleSetup, static: Path | None) -> Path | None:
    """The static trial: ``static``, else the file the setup's ModelScaler or MarkerPlacer names (None when it
    names none, which `scale_static` accepts for setups that measure and place nothing)."""
    if static is not None:
        if not Path(static).exists():
            raise ConfigError(f"static trial not found: {static}")
        return Path(static)
    for which in ("scale_marker_file", "placer_marker_file"):
        raw = getattr(setup, which).strip()
        if raw and raw.lower() != "unassigned":
            path = setup.file(which)
            if path is None or not path.exists():
                raise ConfigError(
                    f"{setup.path}: its static trial {raw!r} is not found from here; give the "
                    "static .trc/.c3d with --static"
                )
            return path
    return None


def calibrate(
    setup_path: str | Path,
    out: str | Path,
    *,
    model: str | Path | None = None,
    static: str | Path | None = None,
    mass: float | None = None,
    filter_hz: float | None = None,
    name: str | None = None,
) -> Calibration:
    """Scale the generic model of the ScaleTool setup ``setup_path`` to its static trial and write, into ``out``:
    ``<name>.osim`` (scaled, markers placed; OpenSim opens it), ``<name>_scale_set.xml`` (OpenSim's ScaleSet),
    ``<name>_static_pose.mot`` (the placement's static pose) and ``<name>_scale.json`` (factors, measurements,
    mass, placement error). ``model``/``static`` override the setup's files, ``mass`` (kg) its subject mass,
    ``filter_hz`` low-passes the static markers first (zero-lag Butterworth), ``name`` defaults to the setup's."""
    setup = read_scale_setup(setup_path)
    generic_path = _generic_model(setup, None if model is None else Path(model))
    static_path = _static_trial(setup, None if static is None else Path(static))
    if static_path is not None and static_path.suffix.lower() not in MARKER_SUFFIXES:
        raise ConfigError(f"{static_path}: a static trial is a marker file (.trc or .c3d)")
    markers = None
    if static_path is not None:
        markers = read_markers(static_path)
        markers = markers.filtered(filter_hz) if filter_hz else markers
    generic = BodyModel.from_osim(generic_path)
    if markers is not None:
        check_marker_scale(markers, generic, static_path)
    result = scale_static(generic, markers, setup, mass=mass)
    name = name or setup.name
    out = Path(out)
    osim_path = write_scaled_osim(generic_path, out / f"{name}.osim", result, name=name)
    scale_set = write_scale_set(out / f"{name}_scale_set.xml", result.factors)
    pose = None
    if result.placement is not None:
        pose = write_motion(out / f"{name}_static_pose.mot", result.placement.pose)
    summary = {
        "setup": str(setup_path),
        "generic_model": str(generic_path),
        "static_trial": None if static_path is None else str(static_path),
        "marker_filter_hz": filter_hz,
        "mass_kg": float(result.model.total_mass),
        "preserve_mass_distribution": result.preserve_mass_distribution,
        "scale_factors": {body: [round(float(v), 6) for v in scales] for body, scales in result.factors.items()},
        "measurements": {key: round(float(value), 6) for key, value in result.measurements.items()},
        "markers_placed": None if result.placement is None else len(result.placement.moved),
        "placement_marker_rms_m": None if result.placement is None else float(result.placement.ik.rmse),
        "model": osim_path.name,
        "scale_set": scale_set.name,
        "static_pose": None if pose is None else pose.name,
    }
    summary_file = out / f"{name}_scale.json"
    with atomic_write(summary_file) as handle:
        json.dump(summary, handle, indent=1)
    return Calibration(osim_path, scale_set, pose, summary_file, summary, result)
