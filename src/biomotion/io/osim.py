"""OpenSim model files (.osim, format versions 40000-40600) and ScaleSet files, parsed into frozen dataclasses.

The layout followed is OpenSim 4's (Seth et al. 2018, PLoS Comput Biol 14:e1006223; the XML reference is the
OpenSim 4 API documentation): ``<BodySet>``, ``<JointSet>`` whose joints name their frames through
``socket_parent_frame``/``socket_child_frame`` and own ``PhysicalOffsetFrame``s in ``<frames>`` and their
``Coordinate``s in ``<coordinates>``, a ``CustomJoint``'s ``SpatialTransform`` of six ``TransformAxis``, and
``CoordinateCouplerConstraint``s. Only what kinematics and rigid-body dynamics need is kept (plus markers,
contact geometry, meshes and credits); forces and muscles are ignored here. Anything the body model cannot
represent raises `ModelError` naming the file, line and element; malformed numbers raise `DataFormatError`.

Frames are named by their absolute OpenSim component path (``/ground``, ``/bodyset/femur_r``,
``/jointset/hip_r/pelvis_offset``), so a reader of the spec never has to resolve sockets again.
"""

from __future__ import annotations

import collections
import math
import posixpath
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from biomotion.errors import DataFormatError, ModelError
from biomotion.io.xml import parse_with_lines

Vec3 = tuple[float, float, float]

#: Oldest and newest OpenSim XML format versions this reader was validated on.
MIN_VERSION = 40000
MAX_VERSION = 40600

GROUND = "/ground"
#: Muscle classes whose parameters biomotion reads (`biomotion.muscles.properties`) and static optimization uses.
MUSCLE_TYPES = ("Thelen2003Muscle", "Millard2012EquilibriumMuscle")


# --- functions -------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ConstantFunction:
    value: float


@dataclass(frozen=True)
class LinearFunction:
    slope: float
    intercept: float


@dataclass(frozen=True)
class SimmSpline:
    x: tuple[float, ...]
    y: tuple[float, ...]


@dataclass(frozen=True)
class NaturalCubicSpline:
    x: tuple[float, ...]
    y: tuple[float, ...]


@dataclass(frozen=True)
class PiecewiseLinearFunction:
    x: tuple[float, ...]
    y: tuple[float, ...]


@dataclass(frozen=True)
class PolynomialFunction:
    coefficients: tuple[float, ...]  # highest order first, as OpenSim stores them


@dataclass(frozen=True)
class MultiplierFunction:
    function: FunctionSpec
    scale: float


FunctionSpec = (
    ConstantFunction
    | LinearFunction
    | SimmSpline
    | NaturalCubicSpline
    | PiecewiseLinearFunction
    | PolynomialFunction
    | MultiplierFunction
)


# --- model parts -----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Inertia:
    """Inertia about the centre of mass, in the body frame (OpenSim's ``<inertia>`` order)."""

    xx: float
    yy: float
    zz: float
    xy: float
    xz: float
    yz: float


@dataclass(frozen=True)
class MeshSpec:
    name: str
    frame: str  # absolute path of the frame the mesh is attached to
    mesh_file: str
    scale_factors: Vec3


@dataclass(frozen=True)
class BodySpec:
    name: str
    path: str
    mass: float
    mass_center: Vec3
    inertia: Inertia
    meshes: tuple[MeshSpec, ...]


@dataclass(frozen=True)
class OffsetFrameSpec:
    """A PhysicalOffsetFrame: ``translation`` and body-fixed X-Y-Z ``orientation`` (rad) in its parent frame."""

    name: str
    path: str
    parent: str  # absolute path of the parent frame
    translation: Vec3
    orientation: Vec3


@dataclass(frozen=True)
class CoordinateSpec:
    name: str
    joint: str
    motion_type: str  # "rotational", "translational" or "coupled"
    default_value: float
    range: tuple[float, float]
    clamped: bool
    locked: bool


@dataclass(frozen=True)
class TransformAxisSpec:
    """One of a CustomJoint's six axes: ``function(coordinates)`` is an angle (rad) or a displacement (m)."""

    name: str  # rotation1..3, translation1..3
    coordinates: tuple[str, ...]
    axis: Vec3
    function: FunctionSpec


@dataclass(frozen=True)
class JointSpec:
    """A joint between ``parent_frame`` (F) and ``child_frame`` (M), both absolute frame paths.

    ``type`` is the OpenSim class name. Every supported type is also given as an equivalent spatial transform
    (``transform``: 3 rotation axes applied in order as body-fixed rotations, then 3 translation axes expressed
    in F), which is what the kinematics evaluates.
    """

    name: str
    type: str
    parent_frame: str
    child_frame: str
    coordinates: tuple[str, ...]
    transform: tuple[TransformAxisSpec, ...]


@dataclass(frozen=True)
class CouplerSpec:
    name: str
    independent: tuple[str, ...]
    dependent: str
    function: FunctionSpec
    scale_factor: float


@dataclass(frozen=True)
class MarkerSpec:
    name: str
    frame: str
    location: Vec3
    fixed: bool


@dataclass(frozen=True)
class ContactGeometrySpec:
    name: str
    type: str  # "ContactSphere" or "ContactHalfSpace"
    frame: str
    location: Vec3
    orientation: Vec3
    radius: float | None  # spheres only


@dataclass(frozen=True)
class ModelSpec:
    """Everything kinematic and inertial in one .osim file, in file order (coordinates in CoordinateSet order)."""

    name: str
    path: str
    version: int
    credits: str
    publications: str
    length_units: str
    force_units: str
    gravity: Vec3
    ground_meshes: tuple[MeshSpec, ...]
    bodies: tuple[BodySpec, ...]
    frames: tuple[OffsetFrameSpec, ...]
    joints: tuple[JointSpec, ...]
    coordinates: tuple[CoordinateSpec, ...]
    couplers: tuple[CouplerSpec, ...]
    markers: tuple[MarkerSpec, ...]
    contact_geometry: tuple[ContactGeometrySpec, ...]

    def body(self, name: str) -> BodySpec:
        for b in self.bodies:
            if b.name == name:
                return b
        raise ModelError(f"{self.path}: no body named {name!r}")


@dataclass(frozen=True)
class ScaleSpec:
    segment: str
    scales: Vec3
    apply: bool


# --- XML plumbing ----------------------------------------------------------------------------------------------


class _Doc:
    """An XML tree that remembers each element's line, for error messages."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.root, self.lines = parse_with_lines(path)

    def line(self, elem: ET.Element) -> int | None:
        return self.lines.get(id(elem))

    def model_error(self, elem: ET.Element, message: str) -> ModelError:
        line = self.line(elem)
        where = f"{self.path}:{line}" if line is not None else str(self.path)
        return ModelError(f"{where}: <{elem.tag} name={elem.get('name')!r}>: {message}")

    def format_error(self, elem: ET.Element, message: str, field: str) -> DataFormatError:
        return DataFormatError(self.path, message, line=self.line(elem), field=field)

    def text(self, elem: ET.Element, tag: str, default: str | None = None) -> str:
        child = elem.find(tag)
        if child is None:
            if default is None:
                raise self.format_error(elem, f"<{elem.tag} name={elem.get('name')!r}> has no <{tag}>", tag)
            return default
        return (child.text or "").strip()

    def floats(self, elem: ET.Element, tag: str, n: int | None = None, default: str | None = None) -> tuple[float, ...]:
        raw = self.text(elem, tag, default)
        try:
            values = tuple(float(v) for v in raw.split())
        except ValueError as exc:
            raise self.format_error(
                elem.find(tag) if elem.find(tag) is not None else elem,
                f"<{tag}> is not a list of numbers: {raw!r}",
                tag,
            ) from exc
        if n is not None and len(values) != n:
            raise self.format_error(elem, f"<{tag}> must hold {n} numbers, found {len(values)}", tag)
        return values

    def vec3(self, elem: ET.Element, tag: str, default: str | None = None) -> Vec3:
        x, y, z = self.floats(elem, tag, 3, default)
        return (x, y, z)

    def scalar(self, elem: ET.Element, tag: str, default: str | None = None) -> float:
        return self.floats(elem, tag, 1, default)[0]

    def boolean(self, elem: ET.Element, tag: str, default: str) -> bool:
        raw = self.text(elem, tag, default).lower()
        if raw not in ("true", "false"):
            raise self.format_error(elem, f"<{tag}> must be true or false, found {raw!r}", tag)
        return raw == "true"


def _objects(elem: ET.Element | None) -> list[ET.Element]:
    if elem is None:
        return []
    objects = elem.find("objects")
    return [] if objects is None else list(objects)


def _socket(doc: _Doc, elem: ET.Element, name: str) -> str:
    """A socket's connectee path (OpenSim 4.0 writes ``socket_X``; early 4.0 betas ``socket_X_connectee_name``)."""
    for tag in (f"socket_{name}", f"socket_{name}_connectee_name"):
        child = elem.find(tag)
        if child is not None and (child.text or "").strip():
            return child.text.strip()
    raise doc.format_error(elem, f"<{elem.tag} name={elem.get('name')!r}> has no socket_{name}", f"socket_{name}")


# --- functions -------------------------------------------------------------------------------------------------

_FUNCTION_TAGS = (
    "Constant",
    "LinearFunction",
    "SimmSpline",
    "NaturalCubicSpline",
    "PiecewiseLinearFunction",
    "PolynomialFunction",
    "MultiplierFunction",
    "GCVSpline",
    "PiecewiseConstantFunction",
    "StepFunction",
    "Sine",
    "MultivariatePolynomialFunction",
    "FunctionAdapter",
)


def _function_child(doc: _Doc, elem: ET.Element) -> ET.Element:
    for child in elem:
        if child.tag in _FUNCTION_TAGS:
            return child
    raise doc.format_error(elem, f"<{elem.tag} name={elem.get('name')!r}> holds no function", "function")


def _function(doc: _Doc, elem: ET.Element) -> FunctionSpec:
    tag = elem.tag
    if tag == "Constant":
        return ConstantFunction(doc.scalar(elem, "value"))
    if tag == "LinearFunction":
        coefficients = doc.floats(elem, "coefficients")
        if len(coefficients) != 2:
            raise doc.model_error(elem, f"LinearFunction needs 2 coefficients, found {len(coefficients)}")
        return LinearFunction(*coefficients)
    if tag in ("SimmSpline", "NaturalCubicSpline", "PiecewiseLinearFunction"):
        x, y = doc.floats(elem, "x"), doc.floats(elem, "y")
        if len(x) != len(y) or len(x) < 2:
            raise doc.format_error(elem, f"{tag} needs x and y of equal length >= 2, found {len(x)} and {len(y)}", "x")
        if any(b <= a for a, b in zip(x, x[1:])):
            raise doc.format_error(elem, f"{tag} x values must increase", "x")
        cls = {
            "SimmSpline": SimmSpline,
            "NaturalCubicSpline": NaturalCubicSpline,
            "PiecewiseLinearFunction": PiecewiseLinearFunction,
        }[tag]
        return cls(x, y)
    if tag == "PolynomialFunction":
        return PolynomialFunction(doc.floats(elem, "coefficients"))
    if tag == "MultiplierFunction":
        inner = elem.find("function")
        if inner is None:
            raise doc.format_error(elem, "MultiplierFunction has no <function>", "function")
        return MultiplierFunction(_function(doc, _function_child(doc, inner)), doc.scalar(elem, "scale", "1"))
    raise doc.model_error(elem, f"function type {tag} is not supported")


# --- frames ----------------------------------------------------------------------------------------------------


class _Frames:
    """Absolute paths of ground, bodies and offset frames, with OpenSim's relative-path resolution."""

    def __init__(self, doc: _Doc) -> None:
        self.doc = doc
        self.known: set[str] = {GROUND}
        self.offsets: list[tuple[OffsetFrameSpec, ET.Element, str]] = []

    def add_offset(self, elem: ET.Element, owner: str) -> None:
        name = elem.get("name") or ""
        path = posixpath.join(owner, name)
        self.offsets.append(
            (
                OffsetFrameSpec(
                    name,
                    path,
                    _socket(self.doc, elem, "parent"),
                    self.doc.vec3(elem, "translation", "0 0 0"),
                    self.doc.vec3(elem, "orientation", "0 0 0"),
                ),
                elem,
                owner,
            )
        )
        self.known.add(path)

    def resolve(self, reference: str, owner: str, elem: ET.Element) -> str:
        """Absolute path of the frame ``reference`` names, seen from the component at ``owner``."""
        if reference.startswith("/"):
            candidate = posixpath.normpath(reference)
        else:
            candidate = posixpath.normpath(posixpath.join(owner, reference))
        if candidate in self.known:
            return candidate
        # OpenSim falls back to a search by name for a bare name (files written before paths were used).
        name = posixpath.basename(reference)
        matches = sorted(p for p in self.known if posixpath.basename(p) == name)
        if len(matches) == 1:
            return matches[0]
        raise self.doc.model_error(
            elem, f"frame {reference!r} not found" if not matches else f"frame {reference!r} is ambiguous: {matches}"
        )

    def resolved_offsets(self) -> tuple[OffsetFrameSpec, ...]:
        out = []
        for spec, elem, _owner in self.offsets:
            parent = self.resolve(spec.parent, spec.path, elem)
            if parent == spec.path:
                raise self.doc.model_error(elem, "offset frame is its own parent")
            out.append(OffsetFrameSpec(spec.name, spec.path, parent, spec.translation, spec.orientation))
        return tuple(out)


def _meshes(doc: _Doc, elem: ET.Element, frame: str) -> list[MeshSpec]:
    geometry = elem.find("attached_geometry")
    if geometry is None:
        return []
    return [
        MeshSpec(mesh.get("name") or "", frame, doc.text(mesh, "mesh_file"), doc.vec3(mesh, "scale_factors", "1 1 1"))
        for mesh in geometry
        if mesh.tag == "Mesh"
    ]


# --- joints ----------------------------------------------------------------------------------------------------

_IDENTITY = LinearFunction(1.0, 0.0)
_ZERO = ConstantFunction(0.0)
_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)

# Simbody mobilizers OpenSim uses for the fixed joint types, as spatial transforms (Sherman et al. 2011,
# Procedia IUTAM 2:241): Pin rotates about the common z axis of F and M, Slider translates along x, Universal
# rotates about x then about the new y; Weld has no mobility.
_FIXED_TYPES: dict[str, tuple[tuple[str, Vec3], ...]] = {
    "WeldJoint": (),
    "PinJoint": (("rotation", _Z),),
    "SliderJoint": (("translation", _X),),
    "UniversalJoint": (("rotation", _X), ("rotation", _Y)),
}


def _fixed_transform(kind: tuple[tuple[str, Vec3], ...], coordinates: tuple[str, ...]) -> tuple[TransformAxisSpec, ...]:
    rotations = [(c, ax) for c, (k, ax) in zip(coordinates, kind) if k == "rotation"]
    translations = [(c, ax) for c, (k, ax) in zip(coordinates, kind) if k == "translation"]
    axes = []
    for prefix, used, defaults in (("rotation", rotations, (_X, _Y, _Z)), ("translation", translations, (_X, _Y, _Z))):
        for i in range(3):
            if i < len(used):
                coord, ax = used[i]
                axes.append(TransformAxisSpec(f"{prefix}{i + 1}", (coord,), ax, _IDENTITY))
            else:
                axes.append(TransformAxisSpec(f"{prefix}{i + 1}", (), defaults[i], _ZERO))
    return tuple(axes)


def _custom_transform(doc: _Doc, joint: ET.Element, coordinates: tuple[str, ...]) -> tuple[TransformAxisSpec, ...]:
    spatial = joint.find("SpatialTransform")
    if spatial is None:
        raise doc.format_error(joint, "CustomJoint has no <SpatialTransform>", "SpatialTransform")
    by_name = {axis.get("name"): axis for axis in spatial.findall("TransformAxis")}
    axes = []
    for name in ("rotation1", "rotation2", "rotation3", "translation1", "translation2", "translation3"):
        elem = by_name.get(name)
        if elem is None:
            raise doc.format_error(joint, f"SpatialTransform lacks TransformAxis {name}", name)
        coords = tuple(doc.text(elem, "coordinates", "").split())
        for c in coords:
            if c not in coordinates:
                raise doc.model_error(elem, f"coordinate {c!r} does not belong to joint {joint.get('name')!r}")
        if len(coords) > 1:
            raise doc.model_error(elem, "transform functions of more than one coordinate are not supported")
        axis = doc.vec3(elem, "axis")
        if sum(a * a for a in axis) == 0.0:
            raise doc.model_error(elem, "transform axis is zero")
        function = (
            _function(doc, _function_child(doc, elem))
            if any(child.tag in _FUNCTION_TAGS for child in elem)
            else (_IDENTITY if coords else _ZERO)
        )
        axes.append(TransformAxisSpec(name, coords, axis, function))
    return tuple(axes)


def _motion_type(joint: JointSpec, coordinate: str) -> str:
    """OpenSim's rule: the first transform axis that uses the coordinate decides rotational or translational;
    a coordinate that only moves a joint through a nonlinear function is coupled."""
    for axis in joint.transform:
        if coordinate in axis.coordinates:
            linear = isinstance(axis.function, LinearFunction) or (
                isinstance(axis.function, MultiplierFunction) and isinstance(axis.function.function, LinearFunction)
            )
            if not linear and joint.type == "CustomJoint":
                return "coupled"
            return "rotational" if axis.name.startswith("rotation") else "translational"
    return "rotational"


# --- the model -------------------------------------------------------------------------------------------------


def _version(doc: _Doc) -> int:
    raw = doc.root.get("Version")
    if doc.root.tag != "OpenSimDocument" or raw is None:
        raise DataFormatError(doc.path, "not an OpenSim document (no <OpenSimDocument Version=...>)", line=1)
    try:
        return int(raw)
    except ValueError as exc:
        raise DataFormatError(doc.path, f"bad OpenSimDocument Version {raw!r}", line=1) from exc


def read_osim(path: str | Path) -> ModelSpec:
    """Parse an OpenSim 4 model file into a `ModelSpec`."""
    path = Path(path)
    doc = _Doc(path)
    version = _version(doc)
    if version < MIN_VERSION:
        raise ModelError(
            f"{path}: OpenSim format version {version} (OpenSim 3 layout, joints inside bodies) is "
            f"not supported; open and save it with OpenSim 4 to upgrade it"
        )
    model = doc.root.find("Model")
    if model is None:
        raise DataFormatError(path, "no <Model> element", line=1)
    frames = _Frames(doc)

    ground = model.find("Ground")
    ground_meshes = tuple(_meshes(doc, ground, GROUND)) if ground is not None else ()
    if ground is not None:
        for frame in (ground.find("components"), ground.find("frames")):
            for elem in [] if frame is None else frame:
                if elem.tag == "PhysicalOffsetFrame":
                    frames.add_offset(elem, GROUND)

    bodies = []
    for elem in _objects(model.find("BodySet")):
        if elem.tag != "Body":
            raise doc.model_error(elem, f"body type {elem.tag} is not supported")
        name = elem.get("name") or ""
        body_path = f"/bodyset/{name}"
        frames.known.add(body_path)
        inertia = doc.floats(elem, "inertia", 6, "0 0 0 0 0 0")
        bodies.append(
            BodySpec(
                name,
                body_path,
                doc.scalar(elem, "mass"),
                doc.vec3(elem, "mass_center", "0 0 0"),
                Inertia(*inertia),
                tuple(_meshes(doc, elem, body_path)),
            )
        )
        for owned in (elem.find("components"), elem.find("frames")):
            for sub in [] if owned is None else owned:
                if sub.tag == "PhysicalOffsetFrame":
                    frames.add_offset(sub, body_path)

    raw_joints = []
    for elem in _objects(model.find("JointSet")):
        name = elem.get("name") or ""
        joint_path = f"/jointset/{name}"
        owned = elem.find("frames")
        for sub in [] if owned is None else owned:
            if sub.tag != "PhysicalOffsetFrame":
                raise doc.model_error(sub, f"joint frame type {sub.tag} is not supported")
            frames.add_offset(sub, joint_path)
        raw_joints.append((elem, joint_path))

    for elem in [] if model.find("components") is None else model.find("components"):
        if elem.tag == "PhysicalOffsetFrame":  # model-level frames
            frames.add_offset(elem, "/")

    joints, coordinates = [], []
    for elem, joint_path in raw_joints:
        coords_elem = elem.find("coordinates")
        coord_elems = [] if coords_elem is None else [c for c in coords_elem if c.tag == "Coordinate"]
        coord_names = tuple(c.get("name") or "" for c in coord_elems)
        if elem.tag == "CustomJoint":
            transform = _custom_transform(doc, elem, coord_names)
        elif elem.tag in _FIXED_TYPES:
            kind = _FIXED_TYPES[elem.tag]
            if len(coord_names) != len(kind):
                raise doc.model_error(elem, f"{elem.tag} needs {len(kind)} coordinates, found {len(coord_names)}")
            transform = _fixed_transform(kind, coord_names)
        else:
            raise doc.model_error(
                elem, f"joint type {elem.tag} is not supported (supported: CustomJoint, {', '.join(_FIXED_TYPES)})"
            )
        if elem.find("reverse") is not None and doc.boolean(elem, "reverse", "false"):
            raise doc.model_error(elem, "reversed joints are not supported")
        joint = JointSpec(
            elem.get("name") or "",
            elem.tag,
            frames.resolve(_socket(doc, elem, "parent_frame"), joint_path, elem),
            frames.resolve(_socket(doc, elem, "child_frame"), joint_path, elem),
            coord_names,
            transform,
        )
        joints.append(joint)
        for c in coord_elems:
            low, high = doc.floats(c, "range", 2, "-99999.9 99999.9")
            coordinates.append(
                CoordinateSpec(
                    c.get("name") or "",
                    joint.name,
                    _motion_type(joint, c.get("name") or ""),
                    doc.scalar(c, "default_value", "0"),
                    (low, high),
                    doc.boolean(c, "clamped", "false"),
                    doc.boolean(c, "locked", "false"),
                )
            )

    couplers = []
    for elem in _objects(model.find("ConstraintSet")):
        enforced = doc.boolean(elem, "isEnforced", "true")
        if elem.tag != "CoordinateCouplerConstraint":
            if enforced:
                raise doc.model_error(elem, f"constraint type {elem.tag} is not supported")
            continue
        if not enforced:
            continue
        holder = elem.find("coupled_coordinates_function")
        if holder is None:
            raise doc.format_error(
                elem, "coupler has no <coupled_coordinates_function>", "coupled_coordinates_function"
            )
        independent = tuple(doc.text(elem, "independent_coordinate_names").split())
        if len(independent) != 1:
            raise doc.model_error(elem, "couplers with more than one independent coordinate are not supported")
        couplers.append(
            CouplerSpec(
                elem.get("name") or "",
                independent,
                doc.text(elem, "dependent_coordinate_name"),
                _function(doc, _function_child(doc, holder)),
                doc.scalar(elem, "scale_factor", "1"),
            )
        )

    marker_elems = _objects(model.find("MarkerSet"))
    contact_elems = _objects(model.find("ContactGeometrySet"))
    offsets = frames.resolved_offsets()

    markers = tuple(
        MarkerSpec(
            m.get("name") or "",
            frames.resolve(_socket(doc, m, "parent_frame"), f"/markerset/{m.get('name')}", m),
            doc.vec3(m, "location", "0 0 0"),
            doc.boolean(m, "fixed", "false"),
        )
        for m in marker_elems
    )
    contacts = []
    for elem in contact_elems:
        if elem.tag not in ("ContactSphere", "ContactHalfSpace"):
            raise doc.model_error(elem, f"contact geometry {elem.tag} is not supported")
        contacts.append(
            ContactGeometrySpec(
                elem.get("name") or "",
                elem.tag,
                frames.resolve(_socket(doc, elem, "frame"), f"/contactgeometryset/{elem.get('name')}", elem),
                doc.vec3(elem, "location", "0 0 0"),
                doc.vec3(elem, "orientation", "0 0 0"),
                doc.scalar(elem, "radius") if elem.tag == "ContactSphere" else None,
            )
        )

    spec = ModelSpec(
        name=model.get("name") or path.stem,
        path=str(path),
        version=version,
        credits=doc.text(model, "credits", ""),
        publications=doc.text(model, "publications", ""),
        length_units=doc.text(model, "length_units", "meters"),
        force_units=doc.text(model, "force_units", "N"),
        gravity=doc.vec3(model, "gravity", "0 -9.80665 0"),
        ground_meshes=ground_meshes,
        bodies=tuple(bodies),
        frames=offsets,
        joints=tuple(joints),
        coordinates=tuple(coordinates),
        couplers=tuple(couplers),
        markers=markers,
        contact_geometry=tuple(contacts),
    )
    _check(spec, doc)
    return spec


def _check(spec: ModelSpec, doc: _Doc) -> None:
    if spec.length_units.lower() not in ("meters", "m"):
        raise ModelError(f"{spec.path}: length units {spec.length_units!r} are not supported (meters only)")
    names = [c.name for c in spec.coordinates]
    if len(set(names)) != len(names):
        raise ModelError(f"{spec.path}: duplicate coordinate names")
    known = set(names)
    for coupler in spec.couplers:
        for c in (*coupler.independent, coupler.dependent):
            if c not in known:
                raise ModelError(f"{spec.path}: coupler {coupler.name!r} names unknown coordinate {c!r}")


def model_summary(spec: ModelSpec) -> dict:
    """What an .osim model holds, for ``biomotion inspect``: counts, total mass, joint types, and each coordinate's
    type and range (degrees for rotations, metres for translations), with the locked and coupled ones named."""
    joint_types = dict(collections.Counter(joint.type for joint in spec.joints))
    coupled = {c.dependent for c in spec.couplers}

    def shown(c: CoordinateSpec) -> str:
        scale, unit = (1.0, "m") if c.motion_type == "translational" else (180.0 / math.pi, "deg")
        tags = [t for t, on in (("locked", c.locked), ("coupled", c.name in coupled)) if on]
        return f"{c.range[0] * scale:.4g} to {c.range[1] * scale:.4g} {unit}" + "".join(f", {t}" for t in tags)

    return {
        "file": spec.path,
        "kind": "OpenSimModel",
        "name": spec.name,
        "version": spec.version,
        "bodies": len(spec.bodies),
        "total_mass_kg": round(sum(b.mass for b in spec.bodies), 4),
        "joints": len(spec.joints),
        "joint_types": joint_types,
        "coordinates": {c.name: shown(c) for c in spec.coordinates},
        "markers": len(spec.markers),
        "contact_geometry": len(spec.contact_geometry),
    }


def _set_items(path: str | Path, set_tag: str, item_tag: str) -> tuple[_Doc, list[ET.Element]]:
    """The document and the ``<item_tag>`` elements of the ``<set_tag>`` (bare or inside <OpenSimDocument>) of an
    OpenSim set file; anything else in the set, or an empty set, is a format error naming the file."""
    path = Path(path)
    doc = _Doc(path)
    _version(doc)
    holder = doc.root if doc.root.tag == set_tag else doc.root.find(set_tag)
    if holder is None:
        raise DataFormatError(path, f"no <{set_tag}> element", line=1)
    items = _objects(holder)
    for elem in items:
        if elem.tag != item_tag:
            raise doc.format_error(elem, f"unexpected <{elem.tag}> in {set_tag}", elem.tag)
    if not items:
        raise DataFormatError(path, f"{set_tag} holds no <{item_tag}>", line=1)
    return doc, items


def read_scale_set(path: str | Path) -> tuple[ScaleSpec, ...]:
    """Parse an OpenSim ``<ScaleSet>`` file (per-segment x, y, z scale factors), as written by the ScaleTool."""
    doc, items = _set_items(path, "ScaleSet", "Scale")
    return tuple(
        ScaleSpec(doc.text(elem, "segment"), doc.vec3(elem, "scales"), doc.boolean(elem, "apply", "true"))
        for elem in items
    )


def read_marker_set(path: str | Path) -> tuple[MarkerSpec, ...]:
    """Parse an OpenSim ``<MarkerSet>`` file (what a ScaleTool's GenericModelMaker ``marker_set_file`` names).

    Each marker's frame is its ``socket_parent_frame`` (OpenSim 4) or, in the OpenSim 3 layout, ``<body>``, read as
    ``/bodyset/<body>`` as OpenSim's own reader does; a bare frame name is resolved against the model later
    (`biomotion.ik.scaling.with_marker_set`)."""
    doc, items = _set_items(path, "MarkerSet", "Marker")
    out = []
    for elem in items:
        body = elem.find("body")
        if body is not None and (body.text or "").strip():
            frame = f"/bodyset/{body.text.strip()}"
        else:
            frame = _socket(doc, elem, "parent_frame")
        out.append(
            MarkerSpec(
                elem.get("name") or "", frame, doc.vec3(elem, "location", "0 0 0"), doc.boolean(elem, "fixed", "false")
            )
        )
    return tuple(out)


#: OpenSim documents besides models that `describe_document` summarises.
DOCUMENTS = ("MarkerSet", "ScaleSet")


def document_kind(path: str | Path) -> str | None:
    """ "MarkerSet" or "ScaleSet" for such an OpenSim document (bare or inside <OpenSimDocument>), else None."""
    root = _Doc(Path(path)).root
    for elem in (root, *root):
        if elem.tag in DOCUMENTS:
            return elem.tag
    return None


def describe_document(path: str | Path) -> dict:
    """A MarkerSet (markers per frame, how many fixed) or ScaleSet (each segment's factors) file, for
    ``biomotion inspect``."""
    kind = document_kind(path)
    if kind == "MarkerSet":
        markers = read_marker_set(path)
        return {
            "file": str(path),
            "kind": kind,
            "markers": len(markers),
            "fixed": sum(m.fixed for m in markers),
            "frames": dict(collections.Counter(m.frame for m in markers)),
        }
    if kind == "ScaleSet":
        return {
            "file": str(path),
            "kind": kind,
            "scales": {s.segment: list(s.scales) for s in read_scale_set(path) if s.apply},
        }
    raise DataFormatError(Path(path), f"not an OpenSim {' or '.join(DOCUMENTS)} document", line=1)
