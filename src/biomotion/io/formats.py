"""Format dispatch by file suffix: read anything biomotion reads (`read_any`) and say what a file holds (`describe`).

Used by ``biomotion convert``, ``biomotion inspect`` and the analysis of a force file; the format modules stay
independent of each other.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from biomotion.errors import ConfigError, DataFormatError
from biomotion.motion import GroundReaction, Markers, Motion
from biomotion.trial import Trial


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


SKELETON_SUFFIXES = (".bvh", ".bvh.gz")


def is_skeleton(path: str | Path) -> bool:
    """Whether the file is a skeleton (BVH): its points are joint centres, not markers."""
    return suffix_of(Path(path)) in SKELETON_SUFFIXES


def read_trial(path: str | Path, time_range: tuple[float, float] | None = None) -> Trial:
    """Any motion file as a `Trial`: coordinates (``.mot``/``.sto``/``.csv``) as ``motion``; markers (``.trc``,
    ``.c3d`` with its force plates) as ``markers``; a skeleton (``.bvh``/``.bvh.gz``) as its joint centres in
    ``markers`` (End Sites left out). ``time_range`` (s) keeps only the frames inside it."""
    path = Path(path)
    data = read_any(path)
    if isinstance(data, Trial):
        trial = data
    elif isinstance(data, Motion):
        trial = Trial(motion=data, source=path)
    elif isinstance(data, Markers):
        trial = Trial(markers=data, source=path)
    elif hasattr(data, "skeleton"):
        trial = Trial(markers=data.to_markers(end_sites=False), source=path)
    else:
        raise DataFormatError(path, f"holds {type(data).__name__}, not a motion: nothing to analyse")
    return trial if time_range is None else trial.slice(*time_range)


def _describe_model(path: Path) -> dict[str, Any]:
    """`biomotion.io.osim.model_summary` and the model's muscles: how many of each class its ForceSet holds, and
    how many of them biomotion's static optimization can use (`biomotion.io.osim.MUSCLE_TYPES`)."""
    import collections

    from biomotion.io.osim import MUSCLE_TYPES, model_summary, read_osim
    from biomotion.io.xml import parse_tree

    summary = model_summary(read_osim(path))
    forces = [
        force
        for force_set in parse_tree(path).getroot().iter("ForceSet")
        for objects in force_set.findall("objects")
        for force in objects
    ]
    kinds = collections.Counter(force.tag for force in forces if "Muscle" in force.tag)
    summary["muscles"] = sum(kinds.values())
    summary["muscle_types"] = dict(kinds)
    summary["muscles_for_static_optimization"] = sum(n for kind, n in kinds.items() if kind in MUSCLE_TYPES)
    return summary


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
        from biomotion.io.osim import describe_document, document_kind
        from biomotion.io.setup import describe_setup

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
        series = [
            (name, getattr(data, name))
            for name in ("motion", "markers", "forces")
            if getattr(data, name, None) is not None
        ]
    for prefix, item in series:
        key = f"{prefix}_" if prefix else ""
        summary[f"{key}frames"] = item.n_frames
        summary[f"{key}rate_hz"] = round(item.rate, 6) if np.isfinite(item.rate) else None
        summary[f"{key}start_s"] = float(item.times[0])
        summary[f"{key}duration_s"] = round(item.duration, 6)
        summary[f"{key}channels"] = list(item.names)
    return summary
