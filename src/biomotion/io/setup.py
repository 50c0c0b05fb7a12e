"""OpenSim tool setup files for marker IK and scaling: ``InverseKinematicsTool`` and ``ScaleTool`` XML.

The layout is OpenSim's (Delp et al. 2007, IEEE TBME 54:1940; the OpenSim 4 API documentation of
InverseKinematicsTool, IKTaskSet, ScaleTool, ModelScaler, Measurement and MarkerPlacer), as written by format
versions 20302 through 40600:

- an ``IKTaskSet`` holds ``IKMarkerTask`` (a marker's weight) and ``IKCoordinateTask`` (a coordinate pulled
  towards its default, a manual value or a value from a coordinates file) entries; each has ``apply``
  (default true) and ``weight`` (default 1). Only applied tasks count, as in OpenSim's InverseKinematicsTool:
  markers without an applied task are not tracked;
- a ``Measurement`` averages the experimental/model distance ratios of its ``MarkerPair``\\ s and writes that
  factor onto the listed axes of the listed bodies (``BodyScale``);
- a set may live in another file (``<IKTaskSet file="tasks.xml"/>``), resolved against the setup's folder.

File names inside setups are kept as written (``raw``) and resolved with `locate`, which also accepts the
Windows separators and the folder-relative quirks of the shipped data.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from biomotion.errors import DataFormatError
from biomotion.io.xml import parse_with_lines

UNASSIGNED = ("", "unassigned")


# --- documents with line numbers ------------------------------------------------------------------------------


class _Xml:
    """An XML file parsed with expat so that every element knows its line (for error messages)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.root, self.lines = parse_with_lines(path)

    def error(self, elem: ET.Element, message: str, field: str | None = None) -> DataFormatError:
        return DataFormatError(self.path, message, line=self.lines.get(id(elem)), field=field)

    def tool(self, tag: str) -> ET.Element:
        found = self.root if self.root.tag == tag else self.root.find(tag)
        if found is None:
            raise DataFormatError(self.path, f"no <{tag}> element (is this an OpenSim {tag} setup?)", line=1)
        return found

    def text(self, elem: ET.Element, tag: str, default: str = "") -> str:
        child = elem.find(tag)
        return default if child is None or child.text is None else child.text.strip()

    def number(self, elem: ET.Element, tag: str, default: float) -> float:
        raw = self.text(elem, tag)
        if not raw:
            return default
        try:
            value = float(raw.replace("Inf", "inf"))
        except ValueError:
            raise self.error(elem.find(tag), f"<{tag}> is not a number: {raw!r}", tag) from None
        if math.isnan(value):  # float() reads "nan"; no setting of a setup means anything by it
            raise self.error(elem.find(tag), f"<{tag}> is NaN", tag)
        return value

    def numbers(self, elem: ET.Element, tag: str) -> tuple[float, ...]:
        raw = self.text(elem, tag)
        try:
            values = tuple(float(v) for v in raw.split())
        except ValueError:
            raise self.error(elem.find(tag), f"<{tag}> is not a list of numbers: {raw!r}", tag) from None
        if any(math.isnan(v) for v in values):
            raise self.error(elem.find(tag), f"<{tag}> holds NaN: {raw!r}", tag)
        return values

    def flag(self, elem: ET.Element, tag: str, default: bool) -> bool:
        raw = self.text(elem, tag).lower()
        if not raw:
            return default
        if raw not in ("true", "false"):
            raise self.error(elem.find(tag), f"<{tag}> must be true or false, found {raw!r}", tag)
        return raw == "true"

    def objects(self, elem: ET.Element | None) -> list[tuple[_Xml, ET.Element]]:
        """Children of a set's ``<objects>``, following a ``file=`` reference to another document."""
        if elem is None:
            return []
        reference = elem.get("file", "").strip()
        if reference and reference.lower() not in UNASSIGNED:
            located = locate(reference, self.path)
            if located is None:
                raise self.error(elem, f"<{elem.tag} file={reference!r}>: file not found", elem.tag)
            other = _Xml(located)
            inner = other.root if other.root.tag == elem.tag else other.root.find(f".//{elem.tag}")
            return other.objects(inner if inner is not None else other.root)
        holder = elem.find("objects")
        return [] if holder is None else [(self, child) for child in holder]


def locate(raw: str | None, setup: str | Path, levels: int = 2) -> Path | None:
    """The file a setup names, or None when it names none or the file is absent.

    Relative names are tried against the setup's folder, then up to ``levels`` parent folders (OpenSim resolves
    against the working directory, which setups in the shared data assume to be one level up). Backslashes
    are read as separators.
    """
    if raw is None or raw.strip().lower() in UNASSIGNED:
        return None
    name = Path(raw.strip().replace("\\", "/"))
    if name.is_absolute():
        return name if name.exists() else None
    base = Path(setup).resolve().parent
    for folder in [base, *base.parents][: levels + 1]:
        candidate = folder / name
        if candidate.exists():
            return candidate.resolve()
    return None


# --- IK tasks --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CoordinateTask:
    """An ``IKCoordinateTask``: weight x (q - target)^2 added to the IK objective.

    ``value_type`` is ``default_value`` (the model's default), ``manual_value`` (``value``, in the model's
    internal units: rad or m) or ``from_file`` (the coordinates file, interpolated at the marker times).
    """

    name: str
    weight: float
    value_type: str = "default_value"
    value: float = 0.0


@dataclass(frozen=True)
class TaskSet:
    """The applied tasks of an ``IKTaskSet``: marker weights (only markers listed here are tracked) and
    coordinate tasks."""

    marker_weights: dict[str, float]
    coordinate_tasks: tuple[CoordinateTask, ...]


_VALUE_TYPES = ("default_value", "manual_value", "from_file")


def _task_set(doc: _Xml, elem: ET.Element | None) -> TaskSet:
    weights: dict[str, float] = {}
    coordinates = []
    for owner, task in doc.objects(elem):
        name = task.get("name") or ""
        if task.tag not in ("IKMarkerTask", "IKCoordinateTask"):
            raise owner.error(task, f"unknown IK task <{task.tag}>", task.tag)
        if not owner.flag(task, "apply", True):
            continue
        weight = owner.number(task, "weight", 1.0)
        if not 0 <= weight < math.inf:
            raise owner.error(task, f"task {name!r} has weight {weight}: a weight is a finite number >= 0", "weight")
        if task.tag == "IKMarkerTask":
            weights[name] = weight
            continue
        value_type = owner.text(task, "value_type", "default_value")
        if value_type not in _VALUE_TYPES:
            raise owner.error(
                task, f"task {name!r}: value_type {value_type!r} is not one of {_VALUE_TYPES}", "value_type"
            )
        coordinates.append(CoordinateTask(name, weight, value_type, owner.number(task, "value", 0.0)))
    return TaskSet(weights, tuple(coordinates))


def _time_range(doc: _Xml, elem: ET.Element) -> tuple[float, float] | None:
    values = doc.numbers(elem, "time_range")
    if not values:
        return None
    if len(values) != 2 or values[1] < values[0]:
        raise doc.error(elem.find("time_range"), f"<time_range> must be 'start end', found {values}", "time_range")
    return values[0], values[1]


# --- InverseKinematicsTool -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class IKSetup:
    """An OpenSim ``InverseKinematicsTool`` setup. File names are as written; see `IKSetup.file`."""

    path: Path
    name: str
    model_file: str
    marker_file: str
    coordinate_file: str
    output_motion_file: str
    time_range: tuple[float, float] | None  # None: the whole marker file
    accuracy: float
    constraint_weight: float  # inf: constraints enforced exactly
    tasks: TaskSet

    @property
    def marker_weights(self) -> dict[str, float]:
        return self.tasks.marker_weights

    @property
    def coordinate_tasks(self) -> tuple[CoordinateTask, ...]:
        return self.tasks.coordinate_tasks

    def file(self, which: str) -> Path | None:
        """The resolved ``model_file``, ``marker_file`` or ``coordinate_file`` (None when absent)."""
        return locate(getattr(self, which), self.path)


def read_ik_setup(path: str | Path) -> IKSetup:
    """Parse an OpenSim ``InverseKinematicsTool`` setup file."""
    path = Path(path)
    doc = _Xml(path)
    tool = doc.tool("InverseKinematicsTool")
    return IKSetup(
        path=path,
        name=tool.get("name") or path.stem,
        model_file=doc.text(tool, "model_file"),
        marker_file=doc.text(tool, "marker_file"),
        coordinate_file=doc.text(tool, "coordinate_file") or doc.text(tool, "coordinates_file"),
        output_motion_file=doc.text(tool, "output_motion_file"),
        time_range=_time_range(doc, tool),
        accuracy=doc.number(tool, "accuracy", 1e-5),
        constraint_weight=doc.number(tool, "constraint_weight", float("inf")),
        tasks=_task_set(doc, tool.find("IKTaskSet")),
    )


# --- ScaleTool -------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Measurement:
    """A ScaleTool measurement: the factor is the mean over ``pairs`` of experimental / model marker distance,
    applied to ``axes`` (a subset of ``"XYZ"``) of each body in ``bodies``."""

    name: str
    pairs: tuple[tuple[str, str], ...]
    bodies: tuple[tuple[str, str], ...]  # (body, axes)


@dataclass(frozen=True)
class ManualScale:
    segment: str
    scales: tuple[float, float, float]


@dataclass(frozen=True)
class ScaleSetup:
    """An OpenSim ``ScaleTool`` setup: generic model, ModelScaler and MarkerPlacer settings."""

    path: Path
    name: str
    mass: float  # kg; <= 0: keep the model's mass
    height: float
    model_file: str
    marker_set_file: str
    scaler_apply: bool
    scaling_order: tuple[str, ...]  # "measurements", "manualScale"
    measurements: tuple[Measurement, ...]  # applied ones only
    manual_scales: tuple[ManualScale, ...]
    scale_marker_file: str
    scale_time_range: tuple[float, float] | None
    preserve_mass_distribution: bool
    placer_apply: bool
    placer_tasks: TaskSet
    placer_marker_file: str
    placer_coordinate_file: str
    placer_time_range: tuple[float, float] | None
    max_marker_movement: float  # < 0: no check

    def file(self, which: str) -> Path | None:
        """A resolved file of the setup (``model_file``, ``scale_marker_file`` ...), None when absent."""
        return locate(getattr(self, which), self.path)


_AXES = ("X", "Y", "Z")


def _measurement(doc: _Xml, elem: ET.Element) -> Measurement | None:
    name = elem.get("name") or ""
    if not doc.flag(elem, "apply", True):
        return None
    pairs = []
    for owner, pair in doc.objects(elem.find("MarkerPairSet")):
        markers = owner.text(pair, "markers").split()
        if len(markers) != 2:
            raise owner.error(
                pair, f"measurement {name!r}: a MarkerPair needs 2 marker names, found {markers}", "markers"
            )
        pairs.append((markers[0], markers[1]))
    bodies = []
    for owner, scale in doc.objects(elem.find("BodyScaleSet")):
        axes = owner.text(scale, "axes").upper().split()
        if not axes or any(a not in _AXES for a in axes):
            raise owner.error(scale, f"measurement {name!r}: BodyScale axes must be among X Y Z, found {axes}", "axes")
        bodies.append((scale.get("name") or "", "".join(axes)))
    return Measurement(name, tuple(pairs), tuple(bodies))


def read_scale_setup(path: str | Path) -> ScaleSetup:
    """Parse an OpenSim ``ScaleTool`` setup file."""
    path = Path(path)
    doc = _Xml(path)
    tool = doc.tool("ScaleTool")
    maker = tool.find("GenericModelMaker")
    scaler = tool.find("ModelScaler")
    placer = tool.find("MarkerPlacer")
    # a step whose element is absent is not run (OpenSim's ScaleTool skips default-constructed steps)
    scaler_present, placer_present = scaler is not None, placer is not None
    empty = ET.Element("none")
    maker, scaler, placer = (e if e is not None else empty for e in (maker, scaler, placer))
    measurements = tuple(
        m for m in (_measurement(owner, e) for owner, e in doc.objects(scaler.find("MeasurementSet"))) if m is not None
    )
    manual = []
    for owner, scale in doc.objects(scaler.find("ScaleSet")):
        if not owner.flag(scale, "apply", True):
            continue
        factors = owner.numbers(scale, "scales")
        if len(factors) != 3:
            raise owner.error(scale, f"<scales> must hold 3 numbers, found {len(factors)}", "scales")
        manual.append(ManualScale(owner.text(scale, "segment"), (factors[0], factors[1], factors[2])))
    order = tuple(doc.text(scaler, "scaling_order", "measurements").split())
    for token in order:
        if token not in ("measurements", "manualScale"):
            raise doc.error(scaler.find("scaling_order"), f"unknown scaling_order entry {token!r}", "scaling_order")
    return ScaleSetup(
        path=path,
        name=tool.get("name") or path.stem,
        mass=doc.number(tool, "mass", -1.0),
        height=doc.number(tool, "height", -1.0),
        model_file=doc.text(maker, "model_file"),
        marker_set_file=doc.text(maker, "marker_set_file"),
        scaler_apply=scaler_present and doc.flag(scaler, "apply", True),
        scaling_order=order,
        measurements=measurements,
        manual_scales=tuple(manual),
        scale_marker_file=doc.text(scaler, "marker_file"),
        scale_time_range=_time_range(doc, scaler),
        preserve_mass_distribution=doc.flag(scaler, "preserve_mass_distribution", False),
        placer_apply=placer_present and doc.flag(placer, "apply", True),
        placer_tasks=_task_set(doc, placer.find("IKTaskSet")),
        placer_marker_file=doc.text(placer, "marker_file"),
        placer_coordinate_file=doc.text(placer, "coordinate_file"),
        placer_time_range=_time_range(doc, placer),
        max_marker_movement=doc.number(placer, "max_marker_movement", -1.0),
    )


TOOLS = ("InverseKinematicsTool", "ScaleTool")


def _file_entry(raw: str, setup: Path) -> str | None:
    """A file a setup names, as written, marked when it cannot be found (`locate`)."""
    if raw is None or raw.strip().lower() in UNASSIGNED:
        return None
    return raw.strip() if locate(raw, setup) is not None else f"{raw.strip()} (not found)"


def describe_setup(path: str | Path) -> dict:
    """What an IK or Scale setup holds, for ``biomotion inspect``: the files it names (marked where absent, as
    `locate` resolves them), the time range, and its tasks (marker weights, coordinate tasks, measurements)."""
    path = Path(path)
    root = _Xml(path).root
    tags = [root.tag, *(child.tag for child in root)]  # the tool, or <OpenSimDocument> around it
    tool = next((tag for tag in tags if tag in TOOLS), tags[min(1, len(tags) - 1)])
    if tool == "InverseKinematicsTool":
        ik = read_ik_setup(path)
        return {
            "file": str(path),
            "kind": "IKSetup",
            "name": ik.name,
            "model_file": _file_entry(ik.model_file, path),
            "marker_file": _file_entry(ik.marker_file, path),
            "coordinate_file": _file_entry(ik.coordinate_file, path),
            "time_range_s": ik.time_range,
            "accuracy": ik.accuracy,
            "marker_tasks": len(ik.marker_weights),
            "marker_weights": ik.marker_weights,
            "coordinate_tasks": [task.name for task in ik.coordinate_tasks],
        }
    if tool == "ScaleTool":
        scale = read_scale_setup(path)
        return {
            "file": str(path),
            "kind": "ScaleSetup",
            "name": scale.name,
            "mass_kg": scale.mass,
            "height_m": scale.height,
            "model_file": _file_entry(scale.model_file, path),
            "marker_set_file": _file_entry(scale.marker_set_file, path),
            "scale_marker_file": _file_entry(scale.scale_marker_file, path),
            "scaling_order": list(scale.scaling_order),
            "measurements": [m.name for m in scale.measurements],
            "manual_scales": [m.segment for m in scale.manual_scales],
            "preserve_mass_distribution": scale.preserve_mass_distribution,
            "placer_marker_tasks": len(scale.placer_tasks.marker_weights),
            "placer_time_range_s": scale.placer_time_range,
        }
    raise DataFormatError(
        path,
        f"inspect reads InverseKinematicsTool and ScaleTool setups, MarkerSets and ScaleSets; this file holds <{tool}>",
    )
