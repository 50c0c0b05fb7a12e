"""The HTML viewer: one self-contained, offline file that plays a `Scene` in 3D.

The file holds three things, all inline: plotly.js, read at generation time from the installed ``plotly`` Python
package (it does the WebGL drawing); the scene as compact typed arrays (float32, base64) in a JSON block; and a
small control script (``viewer.js`` beside this module) that poses the bone meshes frame by frame and hands the
new coordinates to ``Plotly.react``. Nothing is fetched when the page is viewed.

Array layout in the JSON block (every array is ``{"dtype", "shape", "b64"}``, little-endian):

- bodies: ``quat`` [T, B, 4] (x, y, z, w), ``pos`` [T, B, 3]; ``vertices`` [V, 3] in the body frames, body b owns
  vertices ``starts[b]:starts[b + 1]``; triangles as three index arrays ``i``, ``j``, ``k`` [F];
- points, arrows (origin and vector) and support polygons: [T, 3, K] (x, y and z rows per frame, so one frame's
  coordinates are contiguous runs), NaN = hidden;
- com, zmp, centre (the followed point): [T, 3]; activations: uint8 [T, M], value x 254, 255 = unknown;
- compare scene: ``frame_map`` [T] gives its frame shown with each frame of the main scene (nearest in time).
"""

from __future__ import annotations

import base64
import html
import json
import re
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from biomotion.errors import ConfigError, DataFormatError
from biomotion.io.atomic import atomic_write
from biomotion.viz.scene import Body, Scene, bvh_scene, geometry_folders, markers_scene, model_scene

COMPARE_MODES = ("overlay", "side")
FOLLOW_MARGIN = 0.3
"""Metres added around the figure in the follow view."""
GRID_STEP = 0.5
"""Metres between ground grid lines."""


def plotly_js() -> str:
    """plotly.js as shipped inside the installed ``plotly`` Python package."""
    try:
        from plotly.offline import get_plotlyjs
    except ImportError as error:
        raise ConfigError("the viewer needs the `plotly` package (pip install plotly)") from error
    return get_plotlyjs()


def write_viewer(
    scene: Scene,
    path: str | Path,
    *,
    compare: Scene | None = None,
    title: str | None = None,
    compare_mode: str = "overlay",
    follow: bool | None = None,
    plotly_src: str | None = None,
) -> Path:
    """Write the viewer of ``scene`` (and ``compare``, drawn over it or beside it) to ``path``; returns the path.

    Args:
        compare: a second motion (e.g. generated vs reference), shown at the frame nearest in time.
        compare_mode: ``"overlay"`` (one 3D view) or ``"side"`` (two views with linked cameras); the page can
            switch between them.
        follow: keep the camera on the figure (default: when it travels farther than one view's width).
        plotly_src: a relative URL of plotly.js to load instead of embedding it, for many pages sharing one copy
            beside them (a batch's trials); the page then needs that file to open, still offline.
    """
    text = viewer_html(
        scene, compare=compare, title=title, compare_mode=compare_mode, follow=follow, plotly_src=plotly_src
    )
    path = Path(path)
    with atomic_write(path) as handle:
        handle.write(text)
    return path


def viewer_html(
    scene: Scene,
    *,
    compare: Scene | None = None,
    title: str | None = None,
    compare_mode: str = "overlay",
    follow: bool | None = None,
    plotly_src: str | None = None,
) -> str:
    """The viewer page as a string (see `write_viewer`)."""
    if compare_mode not in COMPARE_MODES:
        raise ConfigError(f"compare mode must be one of {', '.join(COMPARE_MODES)}, got {compare_mode!r}")
    scenes = [scene] + ([compare] if compare is not None else [])
    lo, hi, half = _extent(scenes)
    travel = float(max(hi[0] - lo[0], hi[2] - lo[2]))
    follow = bool(travel > 2 * half + 1.0) if follow is None else bool(follow)
    ground_lo = np.floor((lo - FOLLOW_MARGIN) / GRID_STEP) * GRID_STEP
    ground_hi = np.ceil((hi + FOLLOW_MARGIN) / GRID_STEP) * GRID_STEP
    data = {
        "mode": compare_mode,
        "follow": follow,
        "follow_half": half,
        "times": _encode(scene.times, np.float32),
        "bounds": {
            "lo": [float(ground_lo[0]), float(lo[1]), float(ground_lo[2])],
            "hi": [float(ground_hi[0]), float(hi[1]), float(ground_hi[2])],
        },
        "ground": {
            "x": [float(ground_lo[0]), float(ground_hi[0])],
            "z": [float(ground_lo[2]), float(ground_hi[2])],
            "step": GRID_STEP,
        },
        "main": _scene_data(scene),
        "compare": None if compare is None else _scene_data(compare, frame_map=compare.frame_of(scene.times)),
    }
    blob = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    parts = {
        "TITLE": html.escape(title or scene.name),
        "PLOTLY": "" if plotly_src else plotly_js(),
        "DATA": blob,
        "VIEWER": _resource("viewer.js"),
    }
    template = _resource("viewer_template.html")
    if plotly_src:
        template = template.replace(
            "<script>{{PLOTLY}}</script>", f'<script src="{html.escape(plotly_src, quote=True)}"></script>'
        )
    return re.sub(r"\{\{(TITLE|PLOTLY|DATA|VIEWER)\}\}", lambda m: parts[m[1]], template)


def _resource(name: str) -> str:
    return resources.files("biomotion.viz").joinpath(name).read_text(encoding="utf-8")


def _encode(array: np.ndarray, dtype: type) -> dict:
    array = np.ascontiguousarray(array, dtype=np.dtype(dtype).newbyteorder("<"))
    return {
        "dtype": np.dtype(dtype).name,
        "shape": list(array.shape),
        "b64": base64.b64encode(array.tobytes()).decode("ascii"),
    }


def _planar(array: np.ndarray) -> dict:
    """[T, K, 3] -> float32 [T, 3, K]."""
    return _encode(np.swapaxes(array, 1, 2), np.float32)


def _scene_data(scene: Scene, frame_map: np.ndarray | None = None) -> dict:
    data: dict = {
        "name": scene.name,
        "n": scene.n_frames,
        "centre": _encode(_centre(scene), np.float32),
        "frame_map": None if frame_map is None else _encode(frame_map, np.int32),
        "bodies": None,
    }
    if scene.bodies:
        data["bodies"] = _bodies_data(scene)
    data["points"] = [
        {
            "name": p.name,
            "labels": list(p.labels),
            "count": p.positions.shape[1],
            "xyz": _planar(p.positions),
            "links": _encode(p.links, np.int32),
        }
        for p in scene.points
    ]
    data["arrows"] = [
        {"name": a.name, "count": a.origins.shape[1], "origin": _planar(a.origins), "vector": _planar(a.vectors)}
        for a in scene.arrows
    ]
    data["com"] = None if scene.com is None else _encode(scene.com, np.float32)
    data["zmp"] = None if scene.zmp is None else _encode(scene.zmp, np.float32)
    data["support"] = (
        None if scene.support is None else {"count": scene.support.shape[1], "xyz": _planar(scene.support)}
    )
    data["activations"] = None
    if scene.activations is not None:
        values = scene.activations.values
        coded = np.where(np.isfinite(values), np.round(np.clip(np.nan_to_num(values), 0, 1) * 254), 255)
        data["activations"] = {"names": list(scene.activations.names), "values": _encode(coded, np.uint8)}
    return data


def _bodies_data(scene: Scene) -> dict:
    surfaces = [body.surface() for body in scene.bodies]
    counts = [len(s.vertices) for s in surfaces]
    starts = np.concatenate([[0], np.cumsum(counts)])
    triangles = np.concatenate([s.triangles + start for s, start in zip(surfaces, starts[:-1])])
    rotations = np.stack([body.rotations for body in scene.bodies], axis=1)  # [T, B, 3, 3]
    positions = np.stack([body.positions for body in scene.bodies], axis=1)  # [T, B, 3]
    valid = np.isfinite(rotations).all(axis=(-1, -2))
    rotations = np.where(valid[..., None, None], rotations, np.eye(3))
    quaternions = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_quat().reshape(rotations.shape[:2] + (4,))
    positions = np.where(valid[..., None], positions, np.nan)
    return {
        "count": len(scene.bodies),
        "names": [b.name for b in scene.bodies],
        "quat": _encode(quaternions, np.float32),
        "pos": _encode(positions, np.float32),
        "vertices": _encode(np.concatenate([s.vertices for s in surfaces]), np.float32),
        "starts": _encode(starts, np.int32),
        "i": _encode(triangles[:, 0], np.int32),
        "j": _encode(triangles[:, 1], np.int32),
        "k": _encode(triangles[:, 2], np.int32),
    }


def _posed_box(body: Body) -> np.ndarray:
    """[T, 8, 3] corners of the body's surface bounding box (its origin alone if it has none), posed per frame."""
    vertices = body.surface().vertices
    if not len(vertices):
        return body.positions[:, None]
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    corners = np.array(
        [[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    )
    return np.einsum("tij,cj->tci", body.rotations, corners) + body.positions[:, None]


def _samples(scene: Scene) -> list[np.ndarray]:
    """Positions [T, K, 3] that bound everything the scene draws: bodies (their posed bounding boxes) and points
    first, then arrows, COM, ZMP and support polygons."""
    out = [_posed_box(b) for b in scene.bodies] + [p.positions for p in scene.points]
    out += [a.origins for a in scene.arrows] + [a.origins + a.vectors for a in scene.arrows]
    out += [array[:, None] for array in (scene.com, scene.zmp) if array is not None]
    if scene.support is not None:
        out.append(scene.support)
    return out


def _centre(scene: Scene) -> np.ndarray:
    """[T, 3] per-frame mean of the drawn bodies and points (arrows excluded), gaps filled, for the follow view."""
    samples = (
        [b.positions[:, None] for b in scene.bodies] + [p.positions for p in scene.points]
        or _samples(scene)
        or [np.zeros((scene.n_frames, 1, 3))]
    )
    stacked = np.concatenate(samples, axis=1)
    finite = np.isfinite(stacked).all(axis=-1)
    count = finite.sum(axis=1)
    centre = np.where(finite[..., None], stacked, 0.0).sum(axis=1) / np.maximum(count, 1)[:, None]
    seen = count > 0
    if not seen.any():
        return np.zeros((scene.n_frames, 3))
    frames = np.arange(scene.n_frames)
    return np.stack([np.interp(frames, frames[seen], centre[seen, a]) for a in range(3)], axis=1)


def _extent(scenes: Sequence[Scene]) -> tuple[np.ndarray, np.ndarray, float]:
    """Lower and upper corners of everything drawn (the ground y = 0 included) and the follow view half-width."""
    lo, hi, half = np.array([np.inf, 0.0, np.inf]), np.array([-np.inf, 0.0, -np.inf]), 1.0
    for scene in scenes:
        centre = _centre(scene)
        for positions in _samples(scene):
            if not np.isfinite(positions).any():
                continue
            lo = np.minimum(lo, np.nanmin(positions.reshape(-1, 3), axis=0))
            hi = np.maximum(hi, np.nanmax(positions.reshape(-1, 3), axis=0))
            offset = np.abs(positions - centre[:, None])[..., [0, 2]]
            half = max(half, float(np.nanmax(offset)) + FOLLOW_MARGIN)
    if not np.all(np.isfinite(lo)):
        lo, hi = np.array([-1.0, 0.0, -1.0]), np.array([1.0, 2.0, 1.0])
    hi[1] = max(hi[1], lo[1] + 0.5)
    return lo, hi, half


# ---- the `biomotion view` command ------------------------------------------------------------------------------

MOTION_SUFFIXES = (".bvh", ".bvh.gz", ".trc", ".c3d", ".mot", ".sto")


def _suffix(path: Path) -> str:
    name = path.name.lower()
    return next((s for s in sorted(MOTION_SUFFIXES, key=len, reverse=True) if name.endswith(s)), path.suffix.lower())


def read_scene(path: str | Path, *, model: str | Path | None = None, geometry: Sequence[str | Path] = ()) -> Scene:
    """A scene from a motion file: BVH (bones as capsules), TRC or C3D markers as points (plus a C3D's force
    plates as GRF arrows), or an OpenSim coordinate file (``.mot``/``.sto``) moving ``model`` (an ``.osim``),
    whose meshes are looked for in ``geometry`` folders and then where OpenSim looks (`geometry_folders`)."""
    path = Path(path)
    suffix = _suffix(path)
    name = path.name[: -len(suffix)] if suffix else path.name
    if suffix in (".bvh", ".bvh.gz"):
        from biomotion.io.bvh import read_bvh

        return bvh_scene(read_bvh(path), name=name)
    if suffix == ".trc":
        from biomotion.io.trc import read_trc

        return markers_scene(read_trc(path), name=name)
    if suffix == ".c3d":
        from biomotion.io.c3d import read_c3d

        trial = read_c3d(path)
        scene = markers_scene(trial.markers, name=name)
        return scene if trial.forces is None else scene.with_ground_reaction(trial.forces)
    if suffix in (".mot", ".sto"):
        if model is None:
            raise ConfigError(f"{path}: an OpenSim coordinate file is drawn through a model; pass --model OSIM")
        from biomotion.body.model import BodyModel
        from biomotion.io.mot import read_motion

        folders = [Path(g) for g in geometry] + geometry_folders(model)
        return model_scene(BodyModel.from_osim(model), read_motion(path), folders=folders, name=name)
    raise ConfigError(
        f"{path}: cannot view {suffix or 'a file without suffix'} (expected one of {', '.join(MOTION_SUFFIXES)})"
    )


ACTIVATION_SUFFIXES = ("/activation", ".activation")


def read_activations(path: str | Path) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """(times [N], muscle names, activations [N, M]) from an OpenSim storage file.

    A states file (CMC, forward simulation, Moco) names its activation columns ``<muscle>.activation`` or
    ``/forceset/<muscle>/activation``: those are taken. A static optimization result names columns after the
    actuators: the columns whose values all lie in [0, 1], the range of a muscle activation, are taken, and the
    reserve and residual actuators (N or N·m) left out.
    """
    from biomotion.io.mot import read_storage

    table = read_storage(path)
    marked = np.array([label.endswith(ACTIVATION_SUFFIXES) for label in table.labels])
    finite = np.isfinite(table.data)
    bounded = np.all(~finite | ((table.data >= -1e-6) & (table.data <= 1 + 1e-6)), axis=0) & finite.any(axis=0)
    keep = marked if marked.any() else bounded
    if not keep.any():
        raise DataFormatError(path, "no activation column (none named */activation, none with values in [0, 1])")
    names = tuple(_muscle(label) for label, kept in zip(table.labels, keep) if kept)
    return table.times, names, table.data[:, keep]


def _muscle(label: str) -> str:
    for suffix in ACTIVATION_SUFFIXES:
        if label.endswith(suffix):
            return label[: -len(suffix)].rsplit("/", 1)[-1]
    return label


COM_ZMP_COLUMNS = ("com_x", "com_y", "com_z", "zmp_x", "zmp_y", "zmp_z")


def read_com_zmp(path: str | Path) -> dict:
    """Balance quantities from a storage file: columns ``com_x com_y com_z`` and/or ``zmp_x zmp_y zmp_z`` (m,
    ground frame) and support polygon vertices ``support_<k>_x/_y/_z`` for k = 0, 1, ... (NaN after the last vertex
    of a frame). Returns keyword arguments for `Scene.with_balance`."""
    from biomotion.io.mot import read_storage

    table = read_storage(path)
    labels = list(table.labels)
    out: dict = {"times": table.times}
    for key in ("com", "zmp"):
        columns = [f"{key}_{axis}" for axis in "xyz"]
        if all(c in labels for c in columns):
            out[key] = table.data[:, [labels.index(c) for c in columns]]
    vertices = sorted({int(m[1]) for label in labels if (m := re.fullmatch(r"support_(\d+)_x", label))})
    if vertices:
        columns = [[f"support_{k}_{axis}" for axis in "xyz"] for k in vertices]
        missing = [c for row in columns for c in row if c not in labels]
        if missing:
            raise DataFormatError(path, f"support polygon columns missing: {', '.join(missing)}")
        out["support"] = np.stack([table.data[:, [labels.index(c) for c in row]] for row in columns], axis=1)
    if len(out) == 1:
        raise DataFormatError(
            path, f"no balance columns (expected {' '.join(COM_ZMP_COLUMNS)} and/or support_<k>_x/_y/_z)"
        )
    return out


def read_forces(path: str | Path):
    """Ground reaction from an OpenSim external-loads ``.mot`` or a C3D file's force plates."""
    path = Path(path)
    if path.suffix.lower() == ".c3d":
        from biomotion.io.c3d import read_c3d_forces

        return read_c3d_forces(path)
    from biomotion.io.mot import read_ground_reaction

    return read_ground_reaction(path)


def view_command(
    motion_path: str | Path,
    *,
    model: str | Path | None = None,
    grf: str | Path | None = None,
    activations: str | Path | None = None,
    com_zmp: str | Path | None = None,
    compare: str | Path | None = None,
    out: str | Path = "viewer.html",
    compare_mode: str = "overlay",
    title: str | None = None,
    geometry: Sequence[str | Path] = (),
    plotly_src: str | None = None,
) -> Path:
    """``biomotion view``: read the files, build the scenes, write the viewer to ``out``; returns its path.

    ``grf`` (``.mot`` or ``.c3d``) adds arrows at the centres of pressure, ``activations`` (``.sto``) the activation
    bars, ``com_zmp`` (``.sto``, see `read_com_zmp`) the COM, ZMP and support polygon; ``compare`` is a second
    motion file of any supported kind, drawn over the first or beside it. An OpenSim coordinate file (``.mot``)
    needs ``model``; ``geometry`` adds folders to look for its ``.vtp`` meshes in (bodies without one are drawn as
    capsules between their joints). ``plotly_src``: see `write_viewer`.
    """
    scene = read_scene(motion_path, model=model, geometry=geometry)
    if grf is not None:
        scene = scene.with_ground_reaction(read_forces(grf))
    if activations is not None:
        scene = scene.with_activations(*read_activations(activations))
    if com_zmp is not None:
        scene = scene.with_balance(**read_com_zmp(com_zmp))
    other = None if compare is None else read_scene(compare, model=model, geometry=geometry)
    return write_viewer(scene, out, compare=other, title=title, compare_mode=compare_mode, plotly_src=plotly_src)
