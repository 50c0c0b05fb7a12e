"""A scaled model written as an ``.osim`` file OpenSim loads, and its ``ScaleSet`` file.

The scaled model file is the generic ``.osim`` edited element by element (what OpenSim's ``Model::scale`` changes):
body masses, centres of mass and inertias (`biomotion.body.scaling.bodies.scale_model`), mesh scale factors,
offset-frame translations, CustomJoint translation functions (wrapped in a MultiplierFunction by ``axis . factors`` of
the parent body, OpenSim's ``CustomJoint::extendScale``), marker locations, muscle path points (fixed, conditional and
moving), wrap objects (translation, and cylinder/ellipsoid/sphere dimensions as OpenSim's ``extendScale``), and
muscle optimal fibre and tendon slack lengths scaled by the change of path length in the default pose. That path
length is measured along the path points; wrapping surfaces are not followed, so for wrapped muscles the two
lengths are an approximation of what OpenSim writes. Model markers absent from the static trial keep their scaled
location (OpenSim's MarkerPlacer deletes them).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from biomotion.body.functions import build_function
from biomotion.body.kinematics import forward_kinematics
from biomotion.body.model import BodyModel
from biomotion.body.spatial import body_fixed_xyz
from biomotion.errors import DataFormatError, ModelError
from biomotion.io import osim
from biomotion.io.atomic import atomic_write
from biomotion.io.xml import parse_tree

_F64 = torch.float64


@dataclass(frozen=True)
class ScaleResult:
    """A generic model scaled and calibrated on a static trial.

    Attributes:
        factors: body -> (sx, sy, sz), every body of the model (the ScaleSet).
        measurements: measurement -> factor.
        mass: total mass the model was scaled to (None: mass distribution only).
        preserve_mass_distribution: as the setup said.
        model: the scaled model with placed markers.
        placement: the marker placement, a `biomotion.ik.scaling.Placement` (None when there was none).
        generic: the model before scaling.
    """

    factors: dict[str, tuple[float, float, float]]
    measurements: dict[str, float]
    mass: float | None
    preserve_mass_distribution: bool
    model: BodyModel
    placement: Any
    generic: BodyModel


# --- writing ----------------------------------------------------------------------------------------------------------


def write_scale_set(path: str | Path, factors: Mapping[str, Sequence[float]]) -> Path:
    """Write an OpenSim ``ScaleSet`` file (what the ScaleTool's ``output_scale_file`` holds)."""
    root = ET.Element("OpenSimDocument", Version="40000")
    holder = ET.SubElement(ET.SubElement(root, "ScaleSet", name="ScaleSet"), "objects")
    for segment, scales in factors.items():
        scale = ET.SubElement(holder, "Scale")
        ET.SubElement(scale, "scales").text = " ".join(repr(float(v)) for v in scales)
        ET.SubElement(scale, "segment").text = segment
        ET.SubElement(scale, "apply").text = "true"
    return _write(path, root)


def _write(path: str | Path, root: ET.Element) -> Path:
    ET.indent(root, space="\t")
    path = Path(path)
    with atomic_write(path) as handle:
        handle.write('<?xml version="1.0" encoding="UTF-8" ?>\n')
        handle.write(ET.tostring(root, encoding="unicode"))
        handle.write("\n")
    return path


def _numbers(elem: ET.Element | None) -> np.ndarray | None:
    return None if elem is None or elem.text is None else np.array([float(v) for v in elem.text.split()])


def _set(elem: ET.Element | None, values: Sequence[float] | np.ndarray) -> None:
    if elem is not None:
        elem.text = " ".join(repr(float(v)) for v in np.ravel(values))


class _Frames:
    """Base body of every frame an .osim names: bodies by name, offset frames by their parent chain."""

    def __init__(self, spec: osim.ModelSpec) -> None:
        self.bodies = {b.name: b.path for b in spec.bodies}
        self.frames = {f.path: f for f in spec.frames}
        self.by_name: dict[str, list[str]] = {}
        for path in [osim.GROUND, *self.bodies.values(), *self.frames]:
            self.by_name.setdefault(path.rsplit("/", 1)[-1], []).append(path)

    def path(self, reference: str) -> str:
        """Absolute path of a socket's connectee (absolute, or matched by its last name as OpenSim falls back)."""
        reference = reference.strip()
        if reference in self.frames or reference == osim.GROUND or reference in self.bodies.values():
            return reference
        candidates = self.by_name.get(reference.rsplit("/", 1)[-1], [])
        if len(candidates) != 1:
            raise ModelError(f"frame {reference!r} is {'ambiguous' if candidates else 'unknown'}")
        return candidates[0]

    def body(self, reference: str) -> str | None:
        """Name of the body a frame is fixed on (None for ground)."""
        path = self.path(reference)
        for _ in range(64):
            if path == osim.GROUND:
                return None
            if path.startswith("/bodyset/") and path.count("/") == 2:
                return path.rsplit("/", 1)[-1]
            path = self.frames[path].parent
        raise ModelError(f"frame {reference!r}: offset frames form a loop")


def _socket(elem: ET.Element, name: str) -> str | None:
    child = elem.find(f"socket_{name}")
    return None if child is None or not (child.text or "").strip() else child.text.strip()


def _function_spec(elem: ET.Element) -> osim.FunctionSpec:
    """The `biomotion.io.osim` spec of an OpenSim function element (the kinds path points use)."""
    values = {child.tag: _numbers(child) for child in elem if child.tag in ("x", "y", "value", "coefficients", "scale")}
    if elem.tag == "Constant":
        return osim.ConstantFunction(float(values["value"][0]))
    if elem.tag == "LinearFunction":
        return osim.LinearFunction(*(float(v) for v in values["coefficients"]))
    if elem.tag in ("SimmSpline", "NaturalCubicSpline", "PiecewiseLinearFunction"):
        kind = {
            "SimmSpline": osim.SimmSpline,
            "NaturalCubicSpline": osim.NaturalCubicSpline,
            "PiecewiseLinearFunction": osim.PiecewiseLinearFunction,
        }[elem.tag]
        return kind(tuple(values["x"]), tuple(values["y"]))
    if elem.tag == "PolynomialFunction":
        return osim.PolynomialFunction(tuple(values["coefficients"]))
    if elem.tag == "MultiplierFunction":
        inner = next(iter(elem.find("function")))
        return osim.MultiplierFunction(_function_spec(inner), float(values.get("scale", [1.0])[0]))
    raise ModelError(f"function type {elem.tag} in a path point is not supported")


def _function_element(holder: ET.Element) -> ET.Element:
    for child in holder:
        if child.tag not in ("coordinates", "axis") and not child.tag.startswith("socket"):
            return child
    raise ModelError(f"<{holder.tag} name={holder.get('name')!r}> holds no function")


def _multiply_function(holder: ET.Element, factor: float) -> None:
    """Scale the function inside ``holder`` by ``factor``: multiply a MultiplierFunction's scale, else wrap the
    function in one (what OpenSim's scaling writes)."""
    function = _function_element(holder)
    if function.tag == "MultiplierFunction":
        scale = function.find("scale")
        if scale is None:
            scale = ET.SubElement(function, "scale")
            scale.text = "1"
        _set(scale, [float(scale.text) * factor])
        return
    index = list(holder).index(function)
    holder.remove(function)
    wrapper = ET.Element("MultiplierFunction", name=function.get("name", "function"))
    ET.SubElement(wrapper, "function").append(function)
    ET.SubElement(wrapper, "scale").text = repr(float(factor))
    holder.insert(index, wrapper)


class _PathPoints:
    """Ground positions of muscle path points in the default pose (for path lengths before and after scaling)."""

    def __init__(self, model: BodyModel, frames: _Frames) -> None:
        self.model = model
        self.frames = frames
        self.q = model.default_q().to(_F64)
        self.poses = forward_kinematics(model, self.q)

    def position(self, point: ET.Element) -> np.ndarray | None:
        """Position in ground, or None for a conditional point inactive in the default pose."""
        parent = _socket(point, "parent_frame")
        if parent is None:
            raise ModelError(f"path point {point.get('name')!r} has no socket_parent_frame")
        body_name = self.frames.body(parent)
        body, rotation, translation = self.model.frame_in_body(self.frames.path(parent))
        if point.tag == "MovingPathPoint":
            local = np.zeros(3)
            for i, axis in enumerate("xyz"):
                holder = point.find(f"{axis}_location")
                coordinate = _socket(point, f"{axis}_coordinate")
                if holder is None or len(holder) == 0:
                    continue
                value = float(self.q[self.model.coordinate_index(coordinate.rsplit("/", 1)[-1])]) if coordinate else 0.0
                function = build_function(_function_spec(next(iter(holder))))
                local[i] = float(function(torch.tensor(value, dtype=_F64)))
        else:
            local = _numbers(point.find("location"))
            if point.tag == "ConditionalPathPoint":
                coordinate = _socket(point, "coordinate")
                low, high = _numbers(point.find("range"))
                value = float(self.q[self.model.coordinate_index(coordinate.rsplit("/", 1)[-1])])
                if not low <= value <= high:
                    return None
        in_body = translation.numpy() + rotation.numpy() @ local
        if body_name is None:
            return in_body
        b = self.model.body_index(body_name)
        return self.poses.positions[b].numpy() + self.poses.rotations[b].numpy() @ in_body


def _path_length(points: list[np.ndarray | None]) -> float:
    active = [p for p in points if p is not None]
    return float(sum(np.linalg.norm(b - a) for a, b in zip(active, active[1:])))


def write_scaled_osim(
    source: str | Path, destination: str | Path, result: ScaleResult, name: str | None = None
) -> Path:
    """Write the scaled, calibrated model: the generic ``source`` .osim (the file ``result.generic`` was read
    from) edited as OpenSim's scaling edits it (see the module docstring), with ``result``'s factors, inertial
    properties and placed markers."""
    source = Path(source)
    tree = parse_tree(source)  # DataFormatError for a missing, malformed or DOCTYPE-bearing file
    root = tree.getroot()
    model_elem = root.find("Model")
    if model_elem is None:
        raise DataFormatError(source, "no <Model> element", line=1)
    if name is not None:
        model_elem.set("name", name)
    generic = result.generic.to(_F64)
    if generic.body_names != tuple(b.get("name") for b in model_elem.iter("Body")):
        raise ModelError(f"{source}: its bodies are not those of the model that was scaled")
    scaled = result.model
    frames = _Frames(generic.spec)
    factor = {body: np.asarray(result.factors.get(body, (1.0, 1.0, 1.0)), dtype=float) for body in generic.body_names}

    def factors_of(reference: str | None) -> np.ndarray | None:
        body = frames.body(reference) if reference is not None else None
        return None if body is None else factor[body]

    lengths_before = _muscle_lengths(model_elem, _PathPoints(generic, frames))

    for elem in model_elem.iter("Body"):
        b = generic.body_index(elem.get("name"))
        _set(elem.find("mass"), [float(scaled.masses[b])])
        _set(elem.find("mass_center"), scaled.coms[b].numpy())
        i = scaled.inertias[b].numpy()
        _set(elem.find("inertia"), [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]])
    _scale_geometry(model_elem, frames, factor)
    for elem in model_elem.iter("PhysicalOffsetFrame"):
        s = factors_of(_socket(elem, "parent"))
        if s is not None and elem.find("translation") is not None:
            _set(elem.find("translation"), _numbers(elem.find("translation")) * s)
    for elem in model_elem.iter("CustomJoint"):
        _scale_custom_joint(elem, frames, factors_of)
    _scale_wrap_objects(model_elem, factor)
    _scale_path_points(model_elem, factors_of)
    _marker_elements(model_elem, generic.spec.markers, frames)
    _place_markers(model_elem, scaled, frames)
    lengths_after = _muscle_lengths(model_elem, _PathPoints(scaled, frames))
    for force, before in lengths_before.items():
        ratio = lengths_after[force] / before if before > 0 else 1.0
        for tag in ("optimal_fiber_length", "tendon_slack_length", "resting_length"):
            value = force.find(tag)
            if value is not None:
                _set(value, [float(value.text) * ratio])
    return _write(destination, root)


def _scale_geometry(model_elem: ET.Element, frames: _Frames, factor: dict[str, np.ndarray]) -> None:
    """Mesh (and other geometry) ``scale_factors`` of everything attached to a body or its offset frames."""
    owners = [(b, b.get("name")) for b in model_elem.iter("Body")]
    owners += [(f, frames.body(_socket(f, "parent") or "/ground")) for f in model_elem.iter("PhysicalOffsetFrame")]
    for owner, body in owners:
        geometry = owner.find("attached_geometry")
        if geometry is None or body is None:
            continue
        for shape in geometry:
            scales = shape.find("scale_factors")
            if scales is not None:
                _set(scales, _numbers(scales) * factor[body])


def _scale_custom_joint(elem: ET.Element, frames: _Frames, factors_of) -> None:
    parent = _socket(elem, "parent_frame")
    s = factors_of(frames.path(_resolve_joint_frame(elem, parent)))
    transform = elem.find("SpatialTransform")
    if s is None or transform is None:
        return
    for axis in transform.findall("TransformAxis"):
        if not (axis.get("name") or "").startswith("translation"):
            continue
        direction = _numbers(axis.find("axis"))
        direction = direction / np.linalg.norm(direction)
        if not any(child.tag not in ("coordinates", "axis") for child in axis):
            if not (axis.findtext("coordinates") or "").strip():
                continue  # no function and no coordinate: Constant(0), nothing to scale
            identity = ET.SubElement(axis, "LinearFunction", name="function")
            ET.SubElement(identity, "coefficients").text = "1 0"
        _multiply_function(axis, float(direction @ s))


def _resolve_joint_frame(joint: ET.Element, reference: str) -> str:
    """A joint's socket names its own offset frame relatively (``hip_r_offset`` or ``pelvis_offset``)."""
    name = reference.rsplit("/", 1)[-1]
    owned = joint.find("frames")
    if owned is not None and any(f.get("name") == name for f in owned):
        return f"/jointset/{joint.get('name')}/{name}"
    return reference


def _scale_wrap_objects(model_elem: ET.Element, factor: dict[str, np.ndarray]) -> None:
    """OpenSim's WrapObject, WrapCylinder, WrapEllipsoid and WrapSphere ``extendScale``."""
    for body in model_elem.iter("Body"):
        s = factor[body.get("name")]
        holder = body.find("WrapObjectSet")
        objects = None if holder is None else holder.find("objects")
        for wrap in [] if objects is None else objects:
            translation = wrap.find("translation")
            if translation is not None:
                _set(translation, _numbers(translation) * s)
            angles = _numbers(wrap.find("xyz_body_rotation"))
            rotation = body_fixed_xyz(torch.tensor(angles if angles is not None else np.zeros(3))).numpy()
            local = [np.linalg.norm(rotation[:, i] * s) for i in range(3)]
            if wrap.tag == "WrapCylinder":
                _set(wrap.find("radius"), [float(_numbers(wrap.find("radius"))[0]) * (local[0] + local[1]) / 2])
                _set(wrap.find("length"), [float(_numbers(wrap.find("length"))[0]) * local[2]])
            elif wrap.tag == "WrapEllipsoid":
                _set(wrap.find("dimensions"), _numbers(wrap.find("dimensions")) * np.array(local))
            elif wrap.tag == "WrapSphere":
                _set(wrap.find("radius"), [float(_numbers(wrap.find("radius"))[0]) * float(s.sum()) / 3])


def _path_elements(model_elem: ET.Element) -> list[tuple[ET.Element, list[ET.Element]]]:
    """(force, its path points in order) for every force with a GeometryPath."""
    out = []
    for force in model_elem.iter():
        path = force.find("GeometryPath")
        if path is None:
            continue
        holder = path.find("PathPointSet")
        points = [] if holder is None or holder.find("objects") is None else list(holder.find("objects"))
        out.append((force, points))
    return out


def _scale_path_points(model_elem: ET.Element, factors_of) -> None:
    for _, points in _path_elements(model_elem):
        for point in points:
            s = factors_of(_socket(point, "parent_frame"))
            if s is None:
                continue
            if point.tag == "MovingPathPoint":
                for i, axis in enumerate("xyz"):
                    holder = point.find(f"{axis}_location")
                    if holder is not None and len(holder):
                        _multiply_function(holder, float(s[i]))
            elif point.find("location") is not None:
                _set(point.find("location"), _numbers(point.find("location")) * s)


def _muscle_lengths(model_elem: ET.Element, points: _PathPoints) -> dict[ET.Element, float]:
    """Path length along the path points in the default pose, per force that has a fibre or resting length."""
    lengths = {}
    for force, path in _path_elements(model_elem):
        if not any(
            force.find(t) is not None for t in ("optimal_fiber_length", "tendon_slack_length", "resting_length")
        ):
            continue
        lengths[force] = _path_length([points.position(p) for p in path])
    return lengths


def _marker_elements(model_elem: ET.Element, markers: Sequence[osim.MarkerSpec], frames: _Frames) -> None:
    """The file's MarkerSet made to hold ``markers`` (the scaled model's, which a GenericModelMaker marker set may
    have changed or extended): a marker whose frame or ``fixed`` differs from its element is rewritten, a missing
    one added (OpenSim 4 layout); the locations follow in `_place_markers`."""
    holder = model_elem.find("MarkerSet")
    if holder is None:
        holder = ET.SubElement(model_elem, "MarkerSet", name="markerset")
    objects = holder.find("objects")
    if objects is None:
        objects = ET.SubElement(holder, "objects")
    existing = {elem.get("name"): elem for elem in objects if elem.tag == "Marker"}
    for marker in markers:
        elem = existing.get(marker.name)
        if (
            elem is not None
            and frames.path(_socket(elem, "parent_frame") or "/ground") == marker.frame
            and (elem.findtext("fixed", "false").strip().lower() == "true") == marker.fixed
        ):
            continue
        if elem is None:
            elem = ET.SubElement(objects, "Marker", name=marker.name)
            ET.SubElement(elem, "location").text = "0 0 0"
        socket = elem.find("socket_parent_frame")
        if socket is None:
            socket = ET.SubElement(elem, "socket_parent_frame")
        socket.text = marker.frame
        fixed = elem.find("fixed")
        if fixed is None:
            fixed = ET.SubElement(elem, "fixed")
        fixed.text = "true" if marker.fixed else "false"


def _place_markers(model_elem: ET.Element, scaled: BodyModel, frames: _Frames) -> None:
    """Marker locations from the scaled model (body-frame offsets) back into each marker's parent frame."""
    holder = model_elem.find("MarkerSet")
    objects = None if holder is None else holder.find("objects")
    for marker in [] if objects is None else objects:
        name = marker.get("name")
        if name not in scaled.marker_names:
            continue
        m = scaled.marker_index(name)
        parent = frames.path(_socket(marker, "parent_frame") or "/ground")
        _, rotation, translation = scaled.frame_in_body(parent)
        location = rotation.T @ (scaled.marker_offsets[m].to(_F64) - translation)
        _set(marker.find("location"), location.numpy())
