"""Format dispatch by file suffix: read anything biomotion reads, write what the output suffix names.

Used by ``biomotion convert`` and ``biomotion inspect``; the format modules stay independent of each other.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from biomotion.errors import ConfigError
from biomotion.motion import GroundReaction, Markers, Motion


def suffix_of(path: Path) -> str:
    """Lower-case suffix, with ``.bvh.gz`` kept whole."""
    name = path.name.lower()
    return ".bvh.gz" if name.endswith(".bvh.gz") else path.suffix.lower()


def read_any(path: str | Path) -> Any:
    """`Motion`, `GroundReaction`, `Markers`, `Trial` (C3D) or `BVHMotion`, by suffix (and columns for .mot)."""
    path = Path(path)
    suffix = suffix_of(path)
    if suffix in (".mot", ".sto"):
        from biomotion.io.mot import read_ground_reaction, read_motion, read_storage

        labels = read_storage(path).labels
        return read_ground_reaction(path) if any(label.endswith("_vx") for label in labels) else read_motion(path)
    if suffix == ".trc":
        from biomotion.io.trc import read_trc

        return read_trc(path)
    if suffix == ".c3d":
        from biomotion.io.c3d import read_c3d

        return read_c3d(path)
    if suffix in (".bvh", ".bvh.gz"):
        from biomotion.io.bvh import read_bvh

        return read_bvh(path)
    if suffix == ".csv":
        from biomotion.io.csvfile import read_motion_csv

        return read_motion_csv(path)
    raise ConfigError(f"{path}: unsupported format {suffix!r} (supported: .mot .sto .trc .c3d .bvh .bvh.gz .csv)")


def _describe_model(path: Path) -> dict[str, Any]:
    """`biomotion.io.osim.model_summary` and the model's muscles: how many of each class its ForceSet holds, and
    how many of them biomotion's static optimization can use (`biomotion.muscles.properties.MUSCLE_TYPES`)."""
    import collections
    import xml.etree.ElementTree as ET

    from biomotion.io.osim import model_summary, read_osim
    from biomotion.muscles.properties import MUSCLE_TYPES

    summary = model_summary(read_osim(path))
    forces = [force for force_set in ET.parse(path).getroot().iter("ForceSet")
              for objects in force_set.findall("objects") for force in objects]
    kinds = collections.Counter(force.tag for force in forces if "Muscle" in force.tag)
    summary["muscles"] = sum(kinds.values())
    summary["muscle_types"] = dict(kinds)
    summary["muscles_for_static_optimization"] = sum(n for kind, n in kinds.items() if kind in MUSCLE_TYPES)
    return summary


def _markers_of(data: Any) -> Markers | None:
    if isinstance(data, Markers):
        return data
    if hasattr(data, "to_markers"):
        return data.to_markers()
    return getattr(data, "markers", None)


def _on_model(motion: Motion, model_path: Path, source: Path, suffix: str) -> Any:
    """What coordinates on their model become for ``suffix``: a BVH clip of the model's bodies
    (`biomotion.body.bvh_export`), the model's markers by forward kinematics (.trc, .c3d), or the coordinates in
    model order with coupled ones filled (.mot, .sto, .csv)."""
    import torch

    from biomotion.analysis import model_motion
    from biomotion.body.kinematics import marker_positions
    from biomotion.body.model import BodyModel

    from biomotion.errors import ModelError

    model = BodyModel.from_osim(model_path)
    try:
        coordinates = model_motion(motion, model)
    except ModelError as error:
        raise ConfigError(f"{source} on {model_path.name}: {error}") from None
    if suffix in (".bvh", ".bvh.gz"):
        from biomotion.body.bvh_export import motion_to_bvh

        return motion_to_bvh(model, coordinates)
    if suffix in (".trc", ".c3d"):
        if not model.marker_names:
            raise ConfigError(f"{model_path}: the model has no markers to write as {suffix}")
        with torch.no_grad():
            positions = marker_positions(model, torch.tensor(coordinates.values, dtype=model.dtype))
        return Markers(times=coordinates.times, names=model.marker_names, positions=positions.numpy())
    return coordinates


def convert(source: str | Path, target: str | Path, *, model: str | Path | None = None) -> Path:
    """Read ``source`` and write ``target`` in the format its suffix names; raises ConfigError if impossible.

    ``model`` (an .osim file): ``source`` holds coordinates of that model, which then become what ``target``
    asks for (`_on_model`: a BVH skeleton, the model's markers, or the coordinates completed)."""
    source, target = Path(source), Path(target)
    data = read_any(source)
    suffix = suffix_of(target)
    if model is not None:
        if not isinstance(data, Motion):
            raise ConfigError(f"{source}: --model is for coordinates (.mot, .sto, .csv); this file holds "
                              f"{type(data).__name__}")
        data = _on_model(data, Path(model), source, suffix)
    if suffix in (".bvh", ".bvh.gz"):
        if isinstance(data, Motion):
            raise ConfigError(f"{source}: coordinates become a BVH skeleton only on their model: pass --model OSIM")
        if not hasattr(data, "skeleton"):
            raise ConfigError(f"{source}: only BVH input can be written as BVH (retarget other motion first)")
        from biomotion.io.bvh import write_bvh

        write_bvh(target, data)
        return target
    if suffix in (".mot", ".sto"):
        from biomotion.io.mot import write_ground_reaction, write_motion

        if isinstance(data, Motion):
            return write_motion(target, data)
        forces = data if isinstance(data, GroundReaction) else getattr(data, "forces", None)
        if forces is not None:
            return write_ground_reaction(target, forces)
        raise ConfigError(f"{source}: holds no coordinates or forces to write as {suffix}")
    if suffix in (".trc", ".c3d"):
        from biomotion.io.c3d_writer import write_c3d
        from biomotion.io.trc import write_trc

        markers = _markers_of(data)
        if markers is None:
            hint = " (coordinates: pass --model OSIM for the model's markers)" if isinstance(data, Motion) else ""
            raise ConfigError(f"{source}: holds no markers or joint positions to write as {suffix}{hint}")
        return (write_trc if suffix == ".trc" else write_c3d)(target, markers)
    if suffix == ".csv":
        from biomotion.io.csvfile import write_markers_csv, write_motion_csv

        if isinstance(data, Motion):
            return write_motion_csv(target, data)
        markers = _markers_of(data)
        if markers is not None:
            return write_markers_csv(target, markers)
        raise ConfigError(f"{source}: nothing to write as CSV")
    raise ConfigError(f"{target}: unsupported output format {suffix!r} (use .mot .sto .trc .c3d .bvh .bvh.gz .csv)")


def describe(path: str | Path) -> dict[str, Any]:
    """A short JSON-able summary of a file: kind, frames, rate, duration, channel names; for a subject table
    (`biomotion.io.tables`: Fukuchi participantInfo, ANSUR II, ...) its schema, subjects and fields; for an .osim
    model its bodies, mass, joints, coordinates with their ranges, markers and muscles; for an IK or Scale setup
    (.xml) the files it names and its tasks; for a MarkerSet or ScaleSet (.xml) its markers or factors."""
    from biomotion.io.tables import describe_subject_table, table_schema

    schema = table_schema(path) if suffix_of(Path(path)) in (".csv", ".tsv", ".txt", ".xlsx", ".xlsm") else None
    if schema is not None:
        return describe_subject_table(path, schema)
    if suffix_of(Path(path)) == ".osim":
        return _describe_model(Path(path))
    if suffix_of(Path(path)) == ".xml":
        from biomotion.ik.setup import describe_setup
        from biomotion.io.osim import describe_document, document_kind

        return describe_document(path) if document_kind(path) else describe_setup(path)
    data = read_any(path)
    summary: dict[str, Any] = {"file": str(path), "kind": type(data).__name__}
    series = []
    if isinstance(data, (Motion, Markers, GroundReaction)):
        series = [("", data)]
    elif hasattr(data, "skeleton"):
        series = [("", data.to_markers())]
        summary["units_in_file"] = getattr(data, "units", None)
    else:
        series = [(name, getattr(data, name)) for name in ("motion", "markers", "forces")
                  if getattr(data, name, None) is not None]
    for prefix, item in series:
        key = f"{prefix}_" if prefix else ""
        summary[f"{key}frames"] = item.n_frames
        summary[f"{key}rate_hz"] = round(item.rate, 6) if np.isfinite(item.rate) else None
        summary[f"{key}start_s"] = float(item.times[0])
        summary[f"{key}duration_s"] = round(item.duration, 6)
        summary[f"{key}channels"] = list(item.names)
    return summary
