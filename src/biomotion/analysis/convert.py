"""``biomotion convert``: a motion file into another format, through the model when coordinates must become a
skeleton or markers.

Reading is `biomotion.io.formats.read_any` (by suffix); writing is the format module the target's suffix names.
Coordinates of an ``.osim`` model become a BVH clip of its bodies (`biomotion.body.bvh_export`), the model's
markers by forward kinematics (``.trc``, ``.c3d``), or the coordinates in model order with coupled ones filled.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from biomotion.errors import ConfigError
from biomotion.io.formats import read_any, suffix_of
from biomotion.motion import GroundReaction, Markers, Motion


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

    from biomotion.analysis.chain import model_motion
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
            raise ConfigError(
                f"{source}: --model is for coordinates (.mot, .sto, .csv); this file holds {type(data).__name__}"
            )
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
