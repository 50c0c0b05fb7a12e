"""Static calibration: OpenSim ScaleTool measurements, marker placement on a static trial, scaled ``.osim`` output.

Scale factors follow OpenSim's ModelScaler (Delp et al. 2007, IEEE TBME 54:1940; OpenSim 4 API documentation of
ModelScaler, Measurement, MarkerPair): for each applied measurement, the factor is the mean over its marker pairs of
experimental distance (averaged over the static trial's frames in the time range where both markers are seen)
divided by the model distance (markers of the generic model in its default pose); the factor is written onto the
measurement's axes of its bodies, measurements in setup order, then manual scales, as ``scaling_order`` says.
Time ranges select frames as OpenSim's MarkerData does (`frame_range`: the frames enclosing the range). A setup's
GenericModelMaker ``marker_set_file`` is merged into the generic model first (`with_marker_set`, OpenSim's
``Model::updateMarkerSet``), and a measurement's body the model lacks is skipped with a warning, as OpenSim skips it.

Marker placement follows OpenSim's MarkerPlacer: marker positions averaged over the time range, one IK solve of
that average pose with the placer's marker weights and coordinate tasks on the scaled model, then every non-fixed
model marker seen in the trial is moved to its experimental position, expressed in its body. The alternative
``method="percentile"`` is the registration of PG-BIG (Appendix A.2, Eq. 1): IK on every static frame, per-frame
body-frame offsets, and per coordinate the mean of the offsets between the 5th and 95th percentiles.

The scaled model file is the generic ``.osim`` edited element by element (what OpenSim's ``Model::scale`` changes):
body masses, centres of mass and inertias (`biomotion.body.scaling.scale_model`), mesh scale factors, offset-frame
translations, CustomJoint translation functions (wrapped in a MultiplierFunction by ``axis . factors`` of the
parent body, OpenSim's ``CustomJoint::extendScale``), marker locations, muscle path points (fixed, conditional and
moving), wrap objects (translation, and cylinder/ellipsoid/sphere dimensions as OpenSim's ``extendScale``), and
muscle optimal fibre and tendon slack lengths scaled by the change of path length in the default pose. That path
length is measured along the path points; wrapping surfaces are not followed, so for wrapped muscles the two
lengths are an approximation of what OpenSim writes. Model markers absent from the static trial keep their scaled
location (OpenSim's MarkerPlacer deletes them).
"""

from __future__ import annotations

import dataclasses
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.body.functions import build_function
from biomotion.body.kinematics import forward_kinematics, points_in_ground
from biomotion.body.model import BodyModel, body_fixed_xyz
from biomotion.body.scaling import scale_model
from biomotion.errors import BiomotionWarning, ConfigError, DataFormatError, ModelError
from biomotion.ik.markers import IKResult, solve_ik
from biomotion.ik.setup import CoordinateTask, Measurement, ScaleSetup
from biomotion.io import osim
from biomotion.io.atomic import atomic_write
from biomotion.motion import Markers, Motion

_F64 = torch.float64


# --- scale factors -----------------------------------------------------------------------------------------------

def measurement_factors(model: BodyModel, markers: Markers, measurements: Sequence[Measurement],
                        time_range: tuple[float, float] | None = None) -> dict[str, float]:
    """Scale factor of each measurement: mean over its marker pairs of experimental / model distance.

    Pairs naming a marker the model lacks are skipped with a warning, as OpenSim does; a measurement left with
    no pair gets no factor. A pair marker missing from the trial (or never seen) is a `DataFormatError`.
    """
    if time_range is not None:
        markers = frame_range(markers, time_range)
    default = torch.as_tensor(_model_markers(model), dtype=_F64)
    factors = {}
    for measurement in measurements:
        ratios = []
        for a, b in measurement.pairs:
            if a not in model.marker_names or b not in model.marker_names:
                warnings.warn(f"measurement {measurement.name!r}: pair ({a}, {b}) skipped, the model has no "
                              f"marker {a if a not in model.marker_names else b!r}", BiomotionWarning, stacklevel=2)
                continue
            for name in (a, b):
                if name not in markers.names:
                    raise DataFormatError(None, f"measurement {measurement.name!r} needs marker {name!r}, which "
                                                f"the static trial lacks", field=name)
            distance = np.linalg.norm(markers[a] - markers[b], axis=-1)
            seen = np.isfinite(distance)
            if not seen.any():
                raise DataFormatError(None, f"measurement {measurement.name!r}: markers {a!r} and {b!r} are never "
                                            f"both visible in the static trial", field=a)
            model_distance = float(torch.linalg.vector_norm(default[model.marker_index(a)]
                                                            - default[model.marker_index(b)]))
            ratios.append(float(distance[seen].mean()) / model_distance)
        if ratios:
            factors[measurement.name] = float(np.mean(ratios))
        else:
            warnings.warn(f"measurement {measurement.name!r} has no usable marker pair: not applied",
                          BiomotionWarning, stacklevel=2)
    return factors


def _model_markers(model: BodyModel, q: torch.Tensor | None = None) -> np.ndarray:
    """[M, 3] model markers in ground at ``q`` (default pose)."""
    poses = forward_kinematics(model, model.default_q() if q is None else q)
    return points_in_ground(poses, model.marker_bodies, model.marker_offsets).numpy()


def frame_range(markers: Markers, time_range: tuple[float, float]) -> Markers:
    """The frames OpenSim's ``MarkerData::findFrameRange`` picks: from the last frame at or before the start to
    the first frame at or after the end (the whole trial when the range misses it on one side)."""
    start, end = time_range
    if start > end:
        raise DataFormatError(None, f"time range {start}-{end} s ends before it starts", field="time_range")
    times = markers.times
    before = np.flatnonzero(times <= start)
    first = int(before[-1]) if before.size else 0
    after = np.flatnonzero(times[first:] >= end)
    last = first + int(after[0]) if after.size else markers.n_frames - 1
    return markers.frames(slice(first, last + 1))


def body_scale_factors(model: BodyModel, markers: Markers | None, setup: ScaleSetup
                       ) -> tuple[dict[str, tuple[float, float, float]], dict[str, float]]:
    """(factors per body, factor per measurement) from a ScaleTool setup, in its ``scaling_order``.

    Every body of the model gets an entry (1, 1, 1 when nothing scales it). A body a measurement names that the
    model lacks is skipped with a warning, as OpenSim's ScaleTool skips it (gait2392's subject01 setup scales
    patellae that the gait2392 models shipped with OpenSim do not have).
    """
    factors = {name: [1.0, 1.0, 1.0] for name in model.body_names}
    per_measurement: dict[str, float] = {}
    for step in setup.scaling_order if setup.scaler_apply else ():
        if step == "measurements" and setup.measurements:
            if markers is None:
                raise ConfigError(f"{setup.path}: measurements need a static trial")
            per_measurement = measurement_factors(model, markers, setup.measurements, setup.scale_time_range)
            for measurement in setup.measurements:
                if measurement.name not in per_measurement:
                    continue
                for body, axes in measurement.bodies:
                    if body not in factors:
                        warnings.warn(f"{setup.path}: measurement {measurement.name!r} scales body {body!r}, which "
                                      f"model {model.name!r} lacks: skipped, as OpenSim does", BiomotionWarning,
                                      stacklevel=2)
                        continue
                    for axis in axes:
                        factors[body]["XYZ".index(axis)] = per_measurement[measurement.name]
        elif step == "manualScale":
            for scale in setup.manual_scales:
                if scale.segment in factors:
                    factors[scale.segment] = list(scale.scales)
    return {name: (v[0], v[1], v[2]) for name, v in factors.items()}, per_measurement


# --- marker placement ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Placement:
    """Markers registered on a static trial: the model with moved markers, the static pose, the markers moved."""
    model: BodyModel
    pose: Motion
    moved: tuple[str, ...]
    ik: IKResult


def _fixed(model: BodyModel) -> set[str]:
    return {m.name for m in model.spec.markers if m.fixed}


def place_markers(model: BodyModel, static: Markers, *, weights: Mapping[str, float] | None,
                  coordinate_tasks: Sequence[CoordinateTask] = (), time_range: tuple[float, float] | None = None,
                  method: str = "average", percentiles: tuple[float, float] = (5.0, 95.0),
                  max_movement: float = -1.0) -> Placement:
    """Move the model's non-fixed markers onto a static trial (see the module docstring for both methods).

    Args:
        weights, coordinate_tasks: the placement IK's tasks (a ScaleSetup's ``placer_tasks``).
        method: ``"average"`` (OpenSim's MarkerPlacer) or ``"percentile"`` (PG-BIG A.2 Eq. 1).
        max_movement: OpenSim's ``max_marker_movement`` check of the averaged frames (m; <= 0: none).
    """
    if method not in ("average", "percentile"):
        raise ValueError(f"method must be 'average' or 'percentile', got {method!r}")
    if time_range is not None:
        static = frame_range(static, time_range)
    if method == "average":
        static = average_frames(static, max_movement)
    ik = solve_ik(model, static, weights=weights, coordinate_tasks=coordinate_tasks)
    placed, moved = register_markers(model, static, ik.motion, percentiles=percentiles)
    return Placement(placed, ik.motion, moved, ik)


def average_frames(markers: Markers, max_movement: float = -1.0) -> Markers:
    """One frame: each marker's mean over the frames where it is seen (OpenSim's ``MarkerData::averageFrames``);
    NaN for a marker never seen. With ``max_movement`` > 0 (m), a marker whose positions span a box with a longer
    diagonal is a `DataFormatError`, as OpenSim's ``max_marker_movement`` check."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(markers.positions, axis=0, keepdims=True)
        span = np.linalg.norm(np.nanmax(markers.positions, axis=0) - np.nanmin(markers.positions, axis=0), axis=-1)
    if max_movement > 0 and np.any(span > max_movement):
        worst = int(np.nanargmax(span))
        raise DataFormatError(None, f"marker {markers.names[worst]!r} moves {span[worst]:.4f} m over the static "
                                    f"frames, more than max_marker_movement {max_movement} m",
                              field=markers.names[worst])
    return Markers(times=markers.times[:1], names=markers.names, positions=mean)


def register_markers(model: BodyModel, static: Markers, pose: Motion,
                     percentiles: tuple[float, float] = (5.0, 95.0)) -> tuple[BodyModel, tuple[str, ...]]:
    """(model with moved markers, names moved): every non-fixed model marker seen in ``static`` is put, in its
    body's frame, where the trial saw it with the model at ``pose`` (a motion on the same frames).

    With one frame this is OpenSim's ``MarkerPlacer::moveModelMarkersToPose``; with several, each coordinate of
    a marker's body-frame offset is the mean of its per-frame values between the two ``percentiles``
    (PG-BIG A.2 Eq. 1).
    """
    q = torch.as_tensor(pose.select(model.coordinate_names).values, dtype=_F64)
    if q.shape[0] != static.n_frames:
        raise DataFormatError(None, f"pose has {q.shape[0]} frames, the static trial {static.n_frames}",
                              field="pose")
    poses = forward_kinematics(model, q)
    fixed = _fixed(model)
    offsets = model.marker_offsets.clone().to(_F64)
    moved = []
    for m, name in enumerate(model.marker_names):
        if name in fixed or name not in static.names:
            continue
        body = int(model.marker_bodies[m])
        observed = torch.as_tensor(static[name], dtype=_F64)            # [T, 3]
        if body < 0:
            local = observed
        else:
            local = ((observed - poses.positions[:, body])[:, None, :] @ poses.rotations[:, body])[:, 0]
        seen = torch.isfinite(local).all(-1)
        if not bool(seen.any()):
            continue
        offsets[m] = _trimmed_mean(local[seen], percentiles) if static.n_frames > 1 else local[seen].mean(0)
        moved.append(name)
    return dataclasses.replace(model, marker_offsets=offsets.to(model.marker_offsets.dtype)), tuple(moved)


def _trimmed_mean(values: torch.Tensor, percentiles: tuple[float, float]) -> torch.Tensor:
    """Per column, the mean of the values between the two percentiles (inclusive)."""
    low = torch.quantile(values, percentiles[0] / 100.0, dim=0)
    high = torch.quantile(values, percentiles[1] / 100.0, dim=0)
    keep = (values >= low) & (values <= high)
    return (values * keep).sum(0) / keep.sum(0).clamp(min=1)


# --- the whole static calibration ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ScaleResult:
    """A generic model scaled and calibrated on a static trial.

    Attributes:
        factors: body -> (sx, sy, sz), every body of the model (the ScaleSet).
        measurements: measurement -> factor.
        mass: total mass the model was scaled to (None: mass distribution only).
        preserve_mass_distribution: as the setup said.
        model: the scaled model with placed markers.
        placement: the marker placement (None when the setup's MarkerPlacer is off).
        generic: the model before scaling.
    """
    factors: dict[str, tuple[float, float, float]]
    measurements: dict[str, float]
    mass: float | None
    preserve_mass_distribution: bool
    model: BodyModel
    placement: Placement | None
    generic: BodyModel


def with_marker_set(model: BodyModel, markers: Sequence[osim.MarkerSpec], source: str | Path) -> BodyModel:
    """The unscaled ``model`` with the markers of a MarkerSet file (``source``) merged in, as OpenSim's
    GenericModelMaker does with its ``marker_set_file`` (``Model::updateMarkerSet``): a model marker of the same
    name takes the set's frame, location and ``fixed``; the others are added, after the model's own."""
    if not bool((model.body_scales == 1).all()):
        raise ModelError(f"{source}: markers are merged into the generic model, before it is scaled")
    merged = {m.name: m for m in model.spec.markers}
    for marker in markers:
        frame = marker.frame if marker.frame.startswith("/") else f"/bodyset/{marker.frame}"
        try:
            model.frame_in_body(frame)
        except ModelError:
            raise ModelError(f"{source}: marker {marker.name!r} is on {marker.frame!r}, which model "
                             f"{model.name!r} does not have") from None
        merged[marker.name] = dataclasses.replace(marker, frame=frame)
    return BodyModel.from_spec(dataclasses.replace(model.spec, markers=tuple(merged.values())), model.dtype)


def scale_static(generic: BodyModel, static: Markers | None, setup: ScaleSetup, *, mass: float | None = None,
                 method: str = "average") -> ScaleResult:
    """OpenSim's ScaleTool on an in-memory static trial: scale ``generic`` (factors from the setup's
    measurements and manual scales), then place the markers (unless the setup's MarkerPlacer is off).

    ``static`` may be None when the setup needs no markers (manual scales only, no placement). ``mass`` (kg)
    overrides the setup's subject mass; a setup mass <= 0 keeps the generic model's mass.
    """
    needs_markers = setup.placer_apply or (setup.scaler_apply and "measurements" in setup.scaling_order
                                           and setup.measurements)
    if static is None and needs_markers:
        raise ConfigError(f"{setup.path}: this setup measures or places markers, so it needs a static trial")
    if setup.marker_set_file.strip().lower() not in ("", "unassigned"):
        marker_set = setup.file("marker_set_file")
        if marker_set is None or not marker_set.exists():
            raise ConfigError(f"{setup.path}: its GenericModelMaker's marker set {setup.marker_set_file!r} is not "
                              "found from here")
        generic = with_marker_set(generic, osim.read_marker_set(marker_set), marker_set)
    factors, per_measurement = body_scale_factors(generic, static, setup)
    target = mass if mass is not None else (setup.mass if setup.mass > 0 else None)
    scaled = scale_model(generic.to(_F64), factors, mass=target,
                         preserve_mass_distribution=setup.preserve_mass_distribution)
    placement = None
    if setup.placer_apply:
        placement = place_markers(scaled, static, weights=setup.placer_tasks.marker_weights,
                                  coordinate_tasks=setup.placer_tasks.coordinate_tasks,
                                  time_range=setup.placer_time_range, method=method,
                                  max_movement=setup.max_marker_movement)
        scaled = placement.model
    return ScaleResult(factors, per_measurement, target, setup.preserve_mass_distribution, scaled, placement,
                       generic)


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
    values = {child.tag: _numbers(child) for child in elem if child.tag in ("x", "y", "value", "coefficients",
                                                                          "scale")}
    if elem.tag == "Constant":
        return osim.ConstantFunction(float(values["value"][0]))
    if elem.tag == "LinearFunction":
        return osim.LinearFunction(*(float(v) for v in values["coefficients"]))
    if elem.tag in ("SimmSpline", "NaturalCubicSpline", "PiecewiseLinearFunction"):
        kind = {"SimmSpline": osim.SimmSpline, "NaturalCubicSpline": osim.NaturalCubicSpline,
                "PiecewiseLinearFunction": osim.PiecewiseLinearFunction}[elem.tag]
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
                value = float(self.q[self.model.coordinate_index(coordinate.rsplit("/", 1)[-1])]) if coordinate \
                    else 0.0
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


def write_scaled_osim(source: str | Path, destination: str | Path, result: ScaleResult,
                      name: str | None = None) -> Path:
    """Write the scaled, calibrated model: the generic ``source`` .osim (the file ``result.generic`` was read
    from) edited as OpenSim's scaling edits it (see the module docstring), with ``result``'s factors, inertial
    properties and placed markers."""
    source = Path(source)
    try:
        tree = ET.parse(source)
    except ET.ParseError as error:
        raise DataFormatError(source, f"not well-formed XML: {error}", line=error.position[0]) from None
    except OSError as error:
        raise DataFormatError(source, f"cannot read: {error.strerror}") from None
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
        if not any(force.find(t) is not None for t in ("optimal_fiber_length", "tendon_slack_length",
                                                       "resting_length")):
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
        if elem is not None and frames.path(_socket(elem, "parent_frame") or "/ground") == marker.frame and \
                (elem.findtext("fixed", "false").strip().lower() == "true") == marker.fixed:
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
