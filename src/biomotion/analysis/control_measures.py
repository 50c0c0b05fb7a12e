"""Control targets measured on a generated clip's written outputs: each target's quantity over time, read back
from the files that `biomotion generate` wrote, and whether the target is met.

A control spec (`biomotion.guidance.control`) is met during generation through guidance, on the guidance's own
estimates (unfiltered, at the canonical size). What a user gets are the files, recomputed from the generated
kinematics by the analysis (`biomotion.analysis.chain`: 6 Hz low-pass, inverse dynamics with the contact model's
ground reaction), so this module judges every target on those files, the same numbers a user would read there:

- ``grf_vertical``: the total vertical force of ``grf.mot`` (every channel) over the written model's body weight
  (BW);
- ``joint_angle``: the coordinate's column of ``motion.mot`` (degrees; m for pelvis translations);
- ``com_height``: ``com_y`` of ``com_zmp.sto`` (m);
- ``joint_position``: the named body's origin by forward kinematics (`biomotion.body.kinematics`) of
  ``motion.mot`` on the written model (m);
- ``joint_torque``: ``<coordinate>_moment`` of ``torques.sto`` over the written model's mass (N·m/kg, OpenSim's
  sign: an extension moment of the knee is negative);
- ``muscle_activation``: the muscle's column of ``activations.sto`` (0-1).

Lengths (body positions, COM height, pelvis translations) are brought back to the canonical size the spec is
written at (1.70 m) by ``length_scale`` (the canonical height over the person's; 1 for a clip generated without a
height). Moments per kg are the written model's, as ``torques.sto`` holds them.

A bound (``max``/``min``) is met when the measured extreme over its window (the whole clip without one; frames
whose times round into it, as the guidance picks them) lies within the bound, with no tolerance. A ``value``
(nearest frame to each time) or a ``path`` has no exact meeting: it is met when every time's error lies within
`tolerance` of the target (`TOLERANCE`: 0.05 BW, 2 degrees or 1 cm of a pelvis translation, 1 cm of COM height,
0.02 of activation, 2 cm of a body position, the per-point size of issue 47's mean joint-error bar).

Targets are taken duck-typed (`TargetSpec`: the attributes of `biomotion.guidance.control.Target`), since the
spec's type lives in a layer above this one; the measuring needs only their fields.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from biomotion.analysis.chain import STANDARD_GRAVITY, model_motion
from biomotion.body.kinematics import forward_kinematics
from biomotion.body.model import BodyModel
from biomotion.body.scaling.stature import RAJAGOPAL_2016_HEIGHT
from biomotion.errors import BiomotionError
from biomotion.io.mot import StorageTable, read_ground_reaction, read_motion, read_storage
from biomotion.motion import GroundReaction, Motion

#: how far a value or path target may miss and still count as met, in the unit the measure reports it in
TOLERANCE = {
    "grf_vertical": 0.05,  # BW
    "joint_angle": 2.0,  # degrees (pelvis translations: `TRANSLATION_TOLERANCE`)
    "com_height": 0.01,  # m
    "joint_position": 0.02,  # m, distance
    "muscle_activation": 0.02,
}
TRANSLATION_TOLERANCE = 0.01  # m, a pelvis translation's value target
#: the file each quantity is read from, in a generated clip's folder
FILES = {
    "grf_vertical": "grf.mot",
    "joint_angle": "motion.mot",
    "com_height": "com_zmp.sto",
    "joint_position": "motion.mot",
    "joint_torque": "torques.sto",
    "muscle_activation": "activations.sto",
}
UNITS = {
    "grf_vertical": "BW",
    "joint_angle": "deg",
    "com_height": "m",
    "joint_position": "m",
    "joint_torque": "N·m/kg",
    "muscle_activation": "activation",
}
AXES = ("x", "y", "z")


class TargetSpec(Protocol):
    """The fields of one control target (`biomotion.guidance.control.Target`) the measuring reads: ``value`` in
    SI (a joint angle in rad), ``window`` (s) or None, ``times`` (s), ``points`` [(x, y, z) m per time]."""

    quantity: str
    kind: str
    value: float
    window: tuple[float, float] | None
    times: tuple[float, ...]
    coordinate: str | None
    body: str | None
    points: tuple[tuple[float, float, float], ...]
    muscle: str | None


class ControlSpec(Protocol):
    """A control spec (`biomotion.guidance.control.Control`): its targets and the file it came from."""

    targets: tuple[TargetSpec, ...]
    source: str


@dataclass(frozen=True)
class ClipOutputs:
    """A generated clip's written outputs, read (`read_outputs`): the model they were written on, ``motion.mot``
    (SI), and where present ``grf.mot``, ``torques.sto``, ``activations.sto`` and ``com_zmp.sto``;
    ``length_scale`` multiplies lengths to bring them to the canonical size (module docstring)."""

    model: BodyModel
    motion: Motion
    grf: GroundReaction | None = None
    torques: StorageTable | None = None
    activations: StorageTable | None = None
    com: StorageTable | None = None
    length_scale: float = 1.0
    folder: Path | None = None


@dataclass(frozen=True)
class TargetMeasure:
    """One target measured on one clip, in the unit `UNITS` gives (degrees for a rotational joint angle).

    ``index``: the target's place in its spec (1-based); ``name``: the coordinate, body or muscle it names;
    ``times`` [T] and ``series`` [T] ([T, 3] for a body position): the measured quantity; ``value``: the bound or
    the value (None for a body position, whose targets are ``points`` [P, 3]); ``window``: the window applied
    (the whole clip when the spec gives none; None for value and path kinds); ``target_times``: the value's or
    the points' times; ``achieved``: the extreme (bounds), the values at ``target_times`` (scalar value targets)
    or the positions there [P, 3] (body positions); ``at``: when the extreme falls; ``errors``: per target time,
    the absolute error or the distance (None for bounds); ``tolerance``: the allowed error (None for bounds);
    ``met``: whether the target is met (module docstring)."""

    index: int
    quantity: str
    name: str | None
    kind: str
    unit: str
    times: np.ndarray
    series: np.ndarray
    value: float | None
    window: tuple[float, float] | None
    target_times: tuple[float, ...]
    points: np.ndarray | None
    achieved: float | np.ndarray
    at: float | None
    errors: np.ndarray | None
    tolerance: float | None
    met: bool

    @property
    def margin(self) -> float | None:
        """How far inside its bound the extreme lies (negative: beyond it, by that much); None for other kinds."""
        if self.kind == "max":
            return float(self.value - self.achieved)
        if self.kind == "min":
            return float(self.achieved - self.value)
        return None

    def describe(self) -> str:
        """What the target asks, in one line: ``grf_vertical max 2.2 BW over 0-2 s``."""
        what = self.quantity if self.name is None else f"{self.quantity} {self.name}"
        if self.kind in ("max", "min"):
            return f"{what} {self.kind} {self.value:g} {self.unit} over {self.window[0]:.3g}-{self.window[1]:.3g} s"
        times = ", ".join(f"{t:g}" for t in self.target_times)
        if self.points is not None and len(self.target_times) > 3:
            times = f"{min(self.target_times):g}-{max(self.target_times):g}"
        if self.points is not None:
            return f"{what} {self.kind} through {len(self.target_times)} point(s) at {times} s"
        return f"{what} value {self.value:g} {self.unit} at {times} s"

    def outcome(self) -> str:
        """Met or not, with the measured extreme: ``met (peak 1.97 BW at 0.63 s)``."""
        verdict = "met" if self.met else "NOT met"
        if self.kind in ("max", "min"):
            word = "peak" if self.kind == "max" else "lowest"
            return f"{verdict} ({word} {self.achieved:.3g} {self.unit} at {self.at:.2f} s)"
        unit = "m" if self.points is not None else self.unit
        what = "distance" if self.points is not None else "error"
        return f"{verdict} (largest {what} {float(self.errors.max()):.3g} {unit}, {self.tolerance:g} allowed)"

    def record(self) -> dict:
        """The measure as JSON values: ``index`` (in the spec), ``quantity``, what it names, ``kind``, ``unit``,
        ``target`` (the bound, the value, or the points [[x, y, z], ...]), ``achieved`` (the extreme, or the values or
        positions at the target's times), ``met``, and the window, times, errors and tolerance that go with them."""
        out: dict = {
            "index": self.index,
            "quantity": self.quantity,
            **({} if self.name is None else {_NAME_KEY[self.quantity]: self.name}),
            "kind": self.kind,
            "unit": self.unit,
        }
        if self.kind in ("max", "min"):
            out |= {
                "target": self.value,
                "window_s": list(self.window),
                "achieved": float(self.achieved),
                "at_s": self.at,
                "margin": self.margin,
            }
        elif self.points is not None:
            out |= {
                "target": self.points.tolist(),
                "times_s": list(self.target_times),
                "achieved": np.asarray(self.achieved).tolist(),
                "distances_m": self.errors.tolist(),
                "mean_distance_m": float(self.errors.mean()),
                "largest_distance_m": float(self.errors.max()),
                "tolerance_m": self.tolerance,
            }
        else:
            out |= {
                "target": self.value,
                "times_s": list(self.target_times),
                "achieved": np.asarray(self.achieved).tolist(),
                "errors": self.errors.tolist(),
                "largest_error": float(self.errors.max()),
                "tolerance": self.tolerance,
            }
        out["met"] = bool(self.met)
        return out


_NAME_KEY = {
    "joint_angle": "coordinate",
    "joint_torque": "coordinate",
    "joint_position": "body",
    "muscle_activation": "muscle",
}


def length_scale(height: float | None) -> float:
    """The factor that brings lengths of a clip written for a person of ``height`` (m; None: the canonical size)
    back to the canonical size the control spec is written at."""
    return 1.0 if not height else RAJAGOPAL_2016_HEIGHT / float(height)


def read_outputs(folder: str | Path, *, model: BodyModel | None = None, scale: float | None = None) -> ClipOutputs:
    """Read the outputs of one generated clip from ``folder`` (``motion.mot`` must be there; the other files are
    read when present). ``model``: the model they were written on (default ``model.osim`` in ``folder`` or its
    parent, where `biomotion generate` writes it for several samples); ``scale``: `length_scale` (default from
    the profile height that ``metrics.json`` records, 1 without one)."""
    folder = Path(folder)
    if model is None:
        found = next((p for p in (folder / "model.osim", folder.parent / "model.osim") if p.is_file()), None)
        if found is None:
            raise BiomotionError(f"{folder}: no model.osim here or in the folder above; pass the model")
        model = BodyModel.from_osim(found)
    if scale is None:
        scale = length_scale(_recorded_height(folder / "metrics.json"))
    present = {name: folder / name for name in set(FILES.values()) if (folder / name).is_file()}
    if "motion.mot" not in present:
        raise BiomotionError(f"{folder}: no motion.mot, so nothing to measure the control targets on")
    return ClipOutputs(
        model=model,
        motion=read_motion(present["motion.mot"]),
        grf=read_ground_reaction(present["grf.mot"]) if "grf.mot" in present else None,
        torques=read_storage(present["torques.sto"]) if "torques.sto" in present else None,
        activations=read_storage(present["activations.sto"]) if "activations.sto" in present else None,
        com=read_storage(present["com_zmp.sto"]) if "com_zmp.sto" in present else None,
        length_scale=scale,
        folder=folder,
    )


def _recorded_height(path: Path) -> float | None:
    """The profile height (m) a generated clip's metrics.json records, None when it has none."""
    if not path.is_file():
        return None
    try:
        profile = json.loads(path.read_text()).get("request", {}).get("profile") or {}
    except (json.JSONDecodeError, AttributeError):
        return None
    height = profile.get("height") if isinstance(profile, dict) else None
    return float(height) if isinstance(height, (int, float)) and height > 0 else None


def _column(table: StorageTable | None, label: str, outputs: ClipOutputs, quantity: str) -> tuple[np.ndarray, ...]:
    if table is None:
        raise BiomotionError(f"{outputs.folder or 'outputs'}: {quantity} is measured from {FILES[quantity]}, absent")
    if label not in table.labels:
        where = table.path or FILES[quantity]
        raise BiomotionError(f"{where}: no column {label!r} to measure {quantity} on")
    return table.times, table.data[:, table.labels.index(label)]


def body_positions(outputs: ClipOutputs, body: str) -> tuple[np.ndarray, np.ndarray]:
    """Times [T] and the origin [T, 3] (m, canonical size) of ``body`` by forward kinematics of ``motion.mot`` on
    the written model."""
    coordinates = model_motion(outputs.motion, outputs.model)
    with torch.no_grad():
        poses = forward_kinematics(outputs.model, torch.as_tensor(coordinates.values, dtype=outputs.model.dtype))
    return coordinates.times, poses.positions[:, outputs.model.body_index(body)].double().numpy() * outputs.length_scale


def quantity_series(outputs: ClipOutputs, target: TargetSpec) -> tuple[np.ndarray, np.ndarray]:
    """Times [T] and the target's quantity over them, [T] ([T, 3] for a body position), in `UNITS` (module
    docstring)."""
    q = target.quantity
    if q == "grf_vertical":
        if outputs.grf is None:
            raise BiomotionError(f"{outputs.folder or 'outputs'}: grf_vertical is measured from grf.mot, absent")
        weight = float(outputs.model.total_mass) * STANDARD_GRAVITY
        return outputs.grf.times, np.nansum(outputs.grf.force[:, :, 1], axis=1) / weight
    if q == "joint_angle":
        values = outputs.motion[target.coordinate]
        if _translation(target):
            return outputs.motion.times, values * outputs.length_scale
        return outputs.motion.times, np.rad2deg(values)
    if q == "com_height":
        times, values = _column(outputs.com, "com_y", outputs, q)
        return times, values * outputs.length_scale
    if q == "joint_position":
        return body_positions(outputs, target.body)
    if q == "joint_torque":
        times, values = _column(outputs.torques, f"{target.coordinate}_moment", outputs, q)
        return times, values / float(outputs.model.total_mass)
    if q == "muscle_activation":
        return _column(outputs.activations, target.muscle, outputs, q)
    raise BiomotionError(f"unknown control quantity {q!r}")


def _translation(target: TargetSpec) -> bool:
    return target.quantity == "joint_angle" and str(target.coordinate).startswith("pelvis_t")


def _unit(target: TargetSpec) -> str:
    return "m" if _translation(target) else UNITS[target.quantity]


def _nearest(times: np.ndarray, at: Sequence[float]) -> np.ndarray:
    return np.asarray([int(np.argmin(np.abs(times - t))) for t in at], dtype=int)


def measure_series(target: TargetSpec, times: np.ndarray, series: np.ndarray, index: int = 1) -> TargetMeasure:
    """Judge ``target`` on its quantity ``series`` over ``times`` (as `quantity_series` gives them; module
    docstring for when a target is met)."""
    times = np.asarray(times, dtype=float)
    series = np.asarray(series, dtype=float)
    name = next((x for x in (target.coordinate, target.body, target.muscle) if x is not None), None)
    unit = _unit(target)
    common = {"index": index, "quantity": target.quantity, "name": name, "kind": target.kind, "unit": unit}
    if target.quantity == "joint_position":
        frames = _nearest(times, target.times)
        points = np.asarray(target.points, dtype=float).reshape(-1, 3)
        at_points = series[frames]
        distances = np.linalg.norm(at_points - points, axis=-1)
        tolerance = TOLERANCE["joint_position"]
        return TargetMeasure(
            **common, times=times, series=series, value=None, window=None, target_times=tuple(target.times),
            points=points, achieved=at_points, at=None, errors=distances, tolerance=tolerance,
            met=bool(np.all(distances <= tolerance)),
        )  # fmt: skip
    value = float(target.value)
    if target.quantity == "joint_angle" and not _translation(target):
        value = math.degrees(value)
    if target.kind == "value":
        frames = _nearest(times, target.times)
        achieved = series[frames]
        errors = np.abs(achieved - value)
        tolerance = TRANSLATION_TOLERANCE if _translation(target) else TOLERANCE[target.quantity]
        return TargetMeasure(
            **common, times=times, series=series, value=value, window=None, target_times=tuple(target.times),
            points=None, achieved=achieved, at=None, errors=errors, tolerance=tolerance,
            met=bool(np.all(errors <= tolerance)),
        )  # fmt: skip
    window = (float(times[0]), float(times[-1])) if target.window is None else tuple(map(float, target.window))
    half = 0.5 * float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    inside = (times >= window[0] - half + 1e-9) & (times <= window[1] + half - 1e-9)
    if not inside.any():
        raise BiomotionError(f"target {index}: window {window[0]:g}-{window[1]:g} s holds no frame of the clip")
    chosen = np.where(inside, series, np.nan)
    frame = int(np.nanargmax(chosen) if target.kind == "max" else np.nanargmin(chosen))
    extreme = float(series[frame])
    met = extreme <= value if target.kind == "max" else extreme >= value
    return TargetMeasure(
        **common, times=times, series=series, value=value, window=window, target_times=(), points=None,
        achieved=extreme, at=float(times[frame]), errors=None, tolerance=None, met=bool(met),
    )  # fmt: skip


def measure_target(target: TargetSpec, outputs: ClipOutputs, index: int = 1) -> TargetMeasure:
    """One target measured on a clip's written outputs (module docstring)."""
    return measure_series(target, *quantity_series(outputs, target), index=index)


def measure_control(control: ControlSpec, outputs: ClipOutputs) -> list[TargetMeasure]:
    """Every target of ``control`` measured on a clip's written outputs, in the spec's order."""
    return [measure_target(t, outputs, n) for n, t in enumerate(control.targets, 1)]


def control_record(
    control: ControlSpec,
    measures: Sequence[TargetMeasure],
    *,
    uncontrolled: Sequence[TargetMeasure] | None = None,
    extra: dict | None = None,
) -> dict:
    """What ``control.json`` holds: the spec, how many targets are met, and per target its `TargetMeasure.record`
    (with ``uncontrolled``, the measures of the same targets on a run without control, each record also gets
    ``uncontrolled_achieved`` and ``uncontrolled_met``); ``extra`` fields are added after the spec."""
    records = [m.record() for m in measures]
    if uncontrolled is not None:
        for record, other in zip(records, uncontrolled):
            free = other.record()
            record["uncontrolled_achieved"] = free["achieved"]
            record["uncontrolled_met"] = free["met"]
    return {
        "spec": control.source,
        **(extra or {}),
        "targets": len(records),
        "targets_met": sum(r["met"] for r in records),
        "all_met": all(r["met"] for r in records),
        "measured_from": "the written outputs (grf.mot, motion.mot, com_zmp.sto, torques.sto, activations.sto), "
        "recomputed from the generated kinematics by the analysis; lengths at the canonical size",
        "per_target": records,
    }
