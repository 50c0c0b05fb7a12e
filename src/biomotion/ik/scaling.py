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

import dataclasses
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.body.kinematics import forward_kinematics, points_in_ground
from biomotion.body.model import BodyModel
from biomotion.body.scaling.bodies import scale_model
from biomotion.body.scaling.osim_file import ScaleResult
from biomotion.errors import BiomotionWarning, ConfigError, DataFormatError, ModelError
from biomotion.ik.markers import IKResult, solve_ik
from biomotion.io import osim
from biomotion.io.setup import CoordinateTask, Measurement, ScaleSetup
from biomotion.motion import Markers, Motion

_F64 = torch.float64


# --- scale factors -----------------------------------------------------------------------------------------------


def measurement_factors(
    model: BodyModel,
    markers: Markers,
    measurements: Sequence[Measurement],
    time_range: tuple[float, float] | None = None,
) -> dict[str, float]:
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
                warnings.warn(
                    f"measurement {measurement.name!r}: pair ({a}, {b}) skipped, the model has no "
                    f"marker {a if a not in model.marker_names else b!r}",
                    BiomotionWarning,
                    stacklevel=2,
                )
                continue
            for name in (a, b):
                if name not in markers.names:
                    raise DataFormatError(
                        None,
                        f"measurement {measurement.name!r} needs marker {name!r}, which the static trial lacks",
                        field=name,
                    )
            distance = np.linalg.norm(markers[a] - markers[b], axis=-1)
            seen = np.isfinite(distance)
            if not seen.any():
                raise DataFormatError(
                    None,
                    f"measurement {measurement.name!r}: markers {a!r} and {b!r} are never "
                    f"both visible in the static trial",
                    field=a,
                )
            model_distance = float(
                torch.linalg.vector_norm(default[model.marker_index(a)] - default[model.marker_index(b)])
            )
            ratios.append(float(distance[seen].mean()) / model_distance)
        if ratios:
            factors[measurement.name] = float(np.mean(ratios))
        else:
            warnings.warn(
                f"measurement {measurement.name!r} has no usable marker pair: not applied",
                BiomotionWarning,
                stacklevel=2,
            )
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


def body_scale_factors(
    model: BodyModel, markers: Markers | None, setup: ScaleSetup
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
                        warnings.warn(
                            f"{setup.path}: measurement {measurement.name!r} scales body {body!r}, which "
                            f"model {model.name!r} lacks: skipped, as OpenSim does",
                            BiomotionWarning,
                            stacklevel=2,
                        )
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


def place_markers(
    model: BodyModel,
    static: Markers,
    *,
    weights: Mapping[str, float] | None,
    coordinate_tasks: Sequence[CoordinateTask] = (),
    time_range: tuple[float, float] | None = None,
    method: str = "average",
    percentiles: tuple[float, float] = (5.0, 95.0),
    max_movement: float = -1.0,
) -> Placement:
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
        raise DataFormatError(
            None,
            f"marker {markers.names[worst]!r} moves {span[worst]:.4f} m over the static "
            f"frames, more than max_marker_movement {max_movement} m",
            field=markers.names[worst],
        )
    return Markers(times=markers.times[:1], names=markers.names, positions=mean)


def register_markers(
    model: BodyModel, static: Markers, pose: Motion, percentiles: tuple[float, float] = (5.0, 95.0)
) -> tuple[BodyModel, tuple[str, ...]]:
    """(model with moved markers, names moved): every non-fixed model marker seen in ``static`` is put, in its
    body's frame, where the trial saw it with the model at ``pose`` (a motion on the same frames).

    With one frame this is OpenSim's ``MarkerPlacer::moveModelMarkersToPose``; with several, each coordinate of
    a marker's body-frame offset is the mean of its per-frame values between the two ``percentiles``
    (PG-BIG A.2 Eq. 1).
    """
    q = torch.as_tensor(pose.select(model.coordinate_names).values, dtype=_F64)
    if q.shape[0] != static.n_frames:
        raise DataFormatError(None, f"pose has {q.shape[0]} frames, the static trial {static.n_frames}", field="pose")
    poses = forward_kinematics(model, q)
    fixed = _fixed(model)
    offsets = model.marker_offsets.clone().to(_F64)
    moved = []
    for m, name in enumerate(model.marker_names):
        if name in fixed or name not in static.names:
            continue
        body = int(model.marker_bodies[m])
        observed = torch.as_tensor(static[name], dtype=_F64)  # [T, 3]
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
            raise ModelError(
                f"{source}: marker {marker.name!r} is on {marker.frame!r}, which model {model.name!r} does not have"
            ) from None
        merged[marker.name] = dataclasses.replace(marker, frame=frame)
    return BodyModel.from_spec(dataclasses.replace(model.spec, markers=tuple(merged.values())), model.dtype)


def scale_static(
    generic: BodyModel, static: Markers | None, setup: ScaleSetup, *, mass: float | None = None, method: str = "average"
) -> ScaleResult:
    """OpenSim's ScaleTool on an in-memory static trial: scale ``generic`` (factors from the setup's
    measurements and manual scales), then place the markers (unless the setup's MarkerPlacer is off).

    ``static`` may be None when the setup needs no markers (manual scales only, no placement). ``mass`` (kg)
    overrides the setup's subject mass; a setup mass <= 0 keeps the generic model's mass.
    """
    needs_markers = setup.placer_apply or (
        setup.scaler_apply and "measurements" in setup.scaling_order and setup.measurements
    )
    if static is None and needs_markers:
        raise ConfigError(f"{setup.path}: this setup measures or places markers, so it needs a static trial")
    if setup.marker_set_file.strip().lower() not in ("", "unassigned"):
        marker_set = setup.file("marker_set_file")
        if marker_set is None or not marker_set.exists():
            raise ConfigError(
                f"{setup.path}: its GenericModelMaker's marker set {setup.marker_set_file!r} is not found from here"
            )
        generic = with_marker_set(generic, osim.read_marker_set(marker_set), marker_set)
    factors, per_measurement = body_scale_factors(generic, static, setup)
    target = mass if mass is not None else (setup.mass if setup.mass > 0 else None)
    scaled = scale_model(
        generic.to(_F64), factors, mass=target, preserve_mass_distribution=setup.preserve_mass_distribution
    )
    placement = None
    if setup.placer_apply:
        placement = place_markers(
            scaled,
            static,
            weights=setup.placer_tasks.marker_weights,
            coordinate_tasks=setup.placer_tasks.coordinate_tasks,
            time_range=setup.placer_time_range,
            method=method,
            max_movement=setup.max_marker_movement,
        )
        scaled = placement.model
    return ScaleResult(factors, per_measurement, target, setup.preserve_mass_distribution, scaled, placement, generic)
