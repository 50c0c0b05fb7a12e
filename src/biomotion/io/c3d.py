"""C3D files: marker trajectories and force platforms, read through ezc3d.

ezc3d decodes the binary file (header, parameters, frames) and applies the analog channel scaling of the C3D
standard, ``(raw - ANALOG:OFFSET) * ANALOG:SCALE * ANALOG:GEN_SCALE``. Everything after that is done here, in
NumPy, from the parameters the C3D standard defines (Motion Lab Systems, *The C3D File Format User Guide*,
c3d.org): units, time axis, occluded samples, and the ground reaction of each force platform in the lab frame.

Frames and units: output is SI (m, N, N·m) in the file's lab frame, optionally rotated by ``axes`` (see
`lab_rotation`) so that a Z-up lab becomes OpenSim's Y-up ground frame. Fukuchi et al. (2017) C3Ds are already
Y-up (X forward, Y up, Z right), so they need no rotation.

Time: sample ``k`` of a trial whose first frame is ``f0`` (1-based, from ``TRIAL:ACTUAL_START_FIELD`` or the
header) is at ``(f0 - 1) / POINT:RATE + k / rate``. For trials that start at frame 1 (all Fukuchi trials) these
are the times OpenSim's C3DFileAdapter gives (``k / rate``); the adapter ignores a later first frame, this reader
keeps it so that a cropped trial stays on the capture's clock.

Gaps: a marker sample is occluded where its residual is negative (ezc3d then gives NaN), where it is NaN, and, with
``zero_is_missing``, where it is exactly (0, 0, 0). An infinite coordinate is no gap but a broken file, and so is a
NaN or infinite value in an analog channel a force platform uses: both are refused with a `DataFormatError` naming
the file, frame and channel.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import ezc3d
import numpy as np

from biomotion.errors import ConfigError, DataFormatError
from biomotion.motion import GroundReaction, Markers
from biomotion.trial import Trial

LENGTH_UNITS = {
    "mm": 1e-3,
    "millimeter": 1e-3,
    "millimeters": 1e-3,
    "millimetre": 1e-3,
    "millimetres": 1e-3,
    "cm": 1e-2,
    "centimeter": 1e-2,
    "centimeters": 1e-2,
    "centimetre": 1e-2,
    "centimetres": 1e-2,
    "m": 1.0,
    "meter": 1.0,
    "meters": 1.0,
    "metre": 1.0,
    "metres": 1.0,
}

# POINT entries that Vicon Nexus and other model-based exporters list here are model outputs, not markers.
NON_MARKER_LISTS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS")

# Analog channels per plate for each supported FORCE_PLATFORM:TYPE (C3D User Guide, "FORCE_PLATFORM:TYPE").
PLATE_CHANNELS = {1: 6, 2: 6, 3: 8, 4: 6}

AxesSpec = str | np.ndarray | Sequence[Sequence[float]] | None


@dataclass(frozen=True)
class _Source:
    """One decoded C3D file: its path, ezc3d's parameters and data, and the POINT clock."""

    path: Path
    parameters: Any
    points: np.ndarray  # [4, M, T] from ezc3d (x, y, z, 1); NaN where the residual is negative
    residuals: np.ndarray  # [M, T]
    analogs: np.ndarray  # [C, T * ratio]
    rate: float
    first_frame: int  # 1-based

    @property
    def n_frames(self) -> int:
        return int(self.points.shape[2])

    def param(self, group: str, name: str, default: Any = ...) -> Any:
        """Value of ``GROUP:NAME``; a missing required parameter is a `DataFormatError` naming it."""
        try:
            return self.parameters[group][name]["value"]
        except KeyError:
            if default is ...:
                raise DataFormatError(self.path, "missing parameter", field=f"{group}:{name}") from None
            return default


def lab_rotation(axes: AxesSpec) -> np.ndarray:
    """3x3 rotation ``R`` that maps file (lab) coordinates to output coordinates, ``p_out = R @ p_file``.

    ``axes`` is None (identity), a 3x3 proper rotation, or a string naming, for each output axis X, Y, Z, the
    signed file axis it takes: ``"x,z,-y"`` turns a Z-up lab (x forward, y left, z up) into OpenSim's Y-up ground
    frame (X forward, Y up, Z right). Reflections are refused, since they would flip the handedness of moments.
    """
    if axes is None:
        return np.eye(3)
    if isinstance(axes, str):
        tokens = [token.strip().lower() for token in axes.split(",")]
        names = [token.lstrip("+-") for token in tokens]
        if len(tokens) != 3 or any(name not in ("x", "y", "z") for name in names):
            raise ConfigError(f"axes {axes!r}: expected three signed file axes such as 'x,z,-y'")
        rotation = np.zeros((3, 3))
        for row, (token, name) in enumerate(zip(tokens, names)):
            rotation[row, "xyz".index(name)] = -1.0 if token.startswith("-") else 1.0
        return _checked_rotation(rotation, axes)
    return _checked_rotation(np.asarray(axes, dtype=float), axes)


def _checked_rotation(rotation: np.ndarray, given: Any) -> np.ndarray:
    if rotation.shape != (3, 3) or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6):
        raise ConfigError(f"axes {given!r} is not a 3x3 rotation (rows must be orthonormal)")
    if np.linalg.det(rotation) < 0:
        raise ConfigError(f"axes {given!r} is a reflection (determinant -1), not a rotation")
    return rotation


def read_c3d_markers(
    path: str | Path, *, zero_is_missing: bool = True, units: str | None = None, axes: AxesSpec = None
) -> Markers:
    """Marker trajectories (POINT data) of a C3D file, in metres, NaN where occluded.

    Args:
        path: the ``.c3d`` file.
        zero_is_missing: treat samples at exactly (0, 0, 0) as occluded; the Fukuchi C3Ds mark gaps that way.
            Samples with a negative residual (the C3D standard's "invalid" flag) are always occluded.
        units: length unit of the POINT data (``mm``, ``cm``, ``m``), overriding ``POINT:UNITS``.
        axes: rotation from the lab frame to the output frame (see `lab_rotation`); default identity.

    Labels are stripped of whitespace; POINT entries listed in ``POINT:ANGLES``/``FORCES``/``MOMENTS``/
    ``POWERS``/``SCALARS``/``REACTIONS`` (model outputs, not markers) are left out.
    """
    return _markers(_load(path), zero_is_missing=zero_is_missing, units=units, axes=lab_rotation(axes))


def read_c3d_forces(
    path: str | Path, *, cop_threshold: float = 20.0, units: str | None = None, axes: AxesSpec = None
) -> GroundReaction:
    """Ground reaction of every force platform in a C3D file, in the lab frame, at the analog rate.

    Channel ``"1"``, ``"2"`` ... is plate 1, 2 ... of ``FORCE_PLATFORM``. Per plate: force [N]; centre of
    pressure [m] on the plate surface, NaN where the plate-normal (vertical) force is below ``cop_threshold`` N;
    free moment [N·m] about the plate normal through the CoP (NaN where the CoP is). See `plate_wrench`.
    Forces keep the sign the file gives (Fukuchi: ``ANALOG:SCALE`` -1, so the vertical force is positive up) and
    are taken to be in N; ``FORCE_PLATFORM:ZERO`` baselines are not subtracted (neither ezc3d nor OpenSim does).
    ``units`` and ``axes`` are as in `read_c3d_markers` (lengths and moments follow ``POINT:UNITS``, as the
    standard requires of every distance in the file).
    """
    source = _load(path)
    forces = _forces(source, cop_threshold=cop_threshold, units=units, axes=lab_rotation(axes))
    if forces is None:
        used = int(np.ravel(source.param("FORCE_PLATFORM", "USED", [0]))[0])
        what = "no force platform" if used == 0 else "force platforms but no analog samples"
        field = "FORCE_PLATFORM:USED" if used == 0 else "ANALOG:USED"
        raise DataFormatError(source.path, f"{what}: nothing to read", field=field)
    return forces


def read_c3d(
    path: str | Path,
    *,
    zero_is_missing: bool = True,
    units: str | None = None,
    axes: AxesSpec = None,
    cop_threshold: float = 20.0,
) -> Trial:
    """A `Trial` with the markers and force platforms of a C3D file (forces None when it has no plate data)."""
    source = _load(path)
    rotation = lab_rotation(axes)
    return Trial(
        markers=_markers(source, zero_is_missing=zero_is_missing, units=units, axes=rotation),
        forces=_forces(source, cop_threshold=cop_threshold, units=units, axes=rotation),
        source=source.path,
    )


def _load(path: str | Path) -> _Source:
    path = Path(path)
    if path.is_dir():
        raise DataFormatError(path, "is a directory, not a C3D file")
    if not path.is_file():
        raise DataFormatError(path, "no such file")
    try:
        c3d = ezc3d.c3d(str(path))
    except Exception as error:  # ezc3d raises OSError/RuntimeError/ValueError for every malformed file
        raise DataFormatError(path, f"not a readable C3D file ({error})") from None
    parameters, header, data = c3d["parameters"], c3d["header"]["points"], c3d["data"]
    points = np.asarray(data["points"], dtype=float)
    if "POINT" not in parameters or points.ndim != 3 or points.shape[1] == 0:
        raise DataFormatError(path, "no POINT data (no markers)", field="POINT:USED")
    if points.shape[2] == 0:
        raise DataFormatError(path, "no frames", field="POINT:FRAMES")
    declared = _declared_frames(path)
    if declared is not None and points.shape[2] < declared:
        raise DataFormatError(
            path,
            f"truncated: the header declares {declared} frames, the file holds {points.shape[2]}",
            frame=points.shape[2],
        )
    residuals = np.asarray(data["meta_points"]["residuals"], dtype=float).reshape(points.shape[1:])
    analogs = np.asarray(data["analogs"], dtype=float)
    analogs = analogs.reshape(analogs.shape[-2:])  # [channels, samples]
    source = _Source(path, parameters, points, residuals, analogs, rate=float(header["frame_rate"]), first_frame=1)
    rate = float(np.ravel(source.param("POINT", "RATE", [source.rate]))[0])
    if not np.isfinite(rate) or rate <= 0:
        raise DataFormatError(path, f"rate must be positive, got {rate}", field="POINT:RATE")
    start = np.ravel(source.param("TRIAL", "ACTUAL_START_FIELD", []))
    if start.size >= 2:
        # two 16-bit words (low, high) so that frame numbers may exceed 65535 (C3D User Guide, TRIAL group)
        first = (int(start[0]) & 0xFFFF) + 65536 * (int(start[1]) & 0xFFFF)
    else:
        first = int(header["first_frame"]) + 1  # ezc3d reports the header's 1-based first frame 0-based
    return replace(source, rate=rate, first_frame=max(first, 1))


def _declared_frames(path: Path) -> int | None:
    """Frame count in the C3D header (words 4-5, first and last frame).

    ezc3d (1.7) silently returns only the frames present in a truncated file, so this is the check that the data
    section is complete. None when the header's 16-bit last frame is saturated (trials over 65535 frames).
    """
    with path.open("rb") as handle:
        header = handle.read(512)
        handle.seek(512 * (header[0] - 1) + 3)
        processor = handle.read(1)
    big_endian = len(processor) == 1 and processor[0] - 83 == 3  # 84 Intel, 85 DEC, 86 MIPS (big-endian)
    first, last = struct.unpack(">HH" if big_endian else "<HH", header[6:10])
    if last == 0xFFFF or last < first:
        return None
    return last - first + 1


def _length_scale(source: _Source, units: str | None) -> float:
    if units is not None:
        key = units.strip().lower()
        if key not in LENGTH_UNITS:
            raise ConfigError(f"units {units!r}: expected one of mm, cm, m")
        return LENGTH_UNITS[key]
    declared = source.param("POINT", "UNITS", [""])
    name = (declared[0] if len(declared) else "").strip()
    if name.lower() not in LENGTH_UNITS:
        raise DataFormatError(
            source.path,
            f"unknown length unit {name!r} (expected mm, cm or m; pass units= to override)",
            field="POINT:UNITS",
        )
    return LENGTH_UNITS[name.lower()]


def _labels(source: _Source, group: str, name: str, count: int) -> list[str]:
    """``GROUP:NAME`` followed by ``NAME2``, ``NAME3`` ... (the standard's continuation for over 255 entries)."""
    labels = [str(label).strip() for label in source.param(group, name, [])]
    extra = 2
    while len(labels) < count and source.param(group, f"{name}{extra}", None) is not None:
        labels += [str(label).strip() for label in source.param(group, f"{name}{extra}")]
        extra += 1
    if len(labels) < count:
        raise DataFormatError(source.path, f"{len(labels)} labels for {count} entries", field=f"{group}:{name}")
    return labels[:count]


def _markers(source: _Source, *, zero_is_missing: bool, units: str | None, axes: np.ndarray) -> Markers:
    scale = _length_scale(source, units)
    count = source.points.shape[1]
    labels = _labels(source, "POINT", "LABELS", count)
    not_markers = {str(label).strip() for kind in NON_MARKER_LISTS for label in source.param("POINT", kind, [])}
    keep = np.array([label not in not_markers for label in labels], dtype=bool)
    positions = np.transpose(source.points[:3], (2, 1, 0))[:, keep]  # [T, M, 3]
    infinite = np.isinf(positions)
    if infinite.any():
        frame, marker, axis = (int(i) for i in np.argwhere(infinite)[0])
        name = [label for label, kept in zip(labels, keep) if kept][marker]
        raise DataFormatError(
            source.path, f"marker {name!r} has an infinite {'xyz'[axis]} coordinate", frame=frame, field="POINT:DATA"
        )
    missing = ~np.isfinite(positions).all(axis=-1) | (source.residuals.T[:, keep] < 0)
    if zero_is_missing:
        missing |= (positions == 0.0).all(axis=-1)
    positions = np.where(missing[..., None], np.nan, positions * scale) @ axes.T
    times = (source.first_frame - 1 + np.arange(source.n_frames)) / source.rate
    return Markers(times=times, names=tuple(label for label, kept in zip(labels, keep) if kept), positions=positions)


def _forces(source: _Source, *, cop_threshold: float, units: str | None, axes: np.ndarray) -> GroundReaction | None:
    used = int(np.ravel(source.param("FORCE_PLATFORM", "USED", [0]))[0])
    if used <= 0 or source.analogs.size == 0:
        return None
    scale = _length_scale(source, units)
    ratio = source.analogs.shape[1] // source.n_frames
    if ratio * source.n_frames != source.analogs.shape[1]:
        raise DataFormatError(
            source.path, f"{source.analogs.shape[1]} analog samples for {source.n_frames} frames", field="ANALOG:RATE"
        )
    types = np.ravel(source.param("FORCE_PLATFORM", "TYPE"))
    channels = np.asarray(source.param("FORCE_PLATFORM", "CHANNEL"))
    channels = channels.reshape(channels.shape[0], -1)
    corners = np.asarray(source.param("FORCE_PLATFORM", "CORNERS"), dtype=float)
    corners = corners.reshape(3, 4, -1, order="F") if corners.size >= 12 else np.zeros((3, 4, 0))
    origins = np.asarray(source.param("FORCE_PLATFORM", "ORIGIN"), dtype=float)
    origins = origins.reshape(3, -1, order="F") if origins.size >= 3 else np.zeros((3, 0))
    for name, plates in (
        ("TYPE", types.size),
        ("CHANNEL", channels.shape[1]),
        ("CORNERS", corners.shape[2]),
        ("ORIGIN", origins.shape[1]),
    ):
        if plates < used:
            raise DataFormatError(
                source.path, f"holds {plates} plates, USED says {used}", field=f"FORCE_PLATFORM:{name}"
            )
    force, cop, moment = [], [], []
    for plate in range(used):
        kind = int(types[plate])
        if kind not in PLATE_CHANNELS:
            raise DataFormatError(
                source.path, f"plate {plate + 1} has TYPE {kind}; supported: 1, 2, 3, 4", field="FORCE_PLATFORM:TYPE"
            )
        index = np.asarray(channels[: PLATE_CHANNELS[kind], plate], dtype=int)
        if index.size < PLATE_CHANNELS[kind] or index.min() < 1 or index.max() > source.analogs.shape[0]:
            raise DataFormatError(
                source.path,
                f"plate {plate + 1} names analog channels {index.tolist()} but the file has {source.analogs.shape[0]}",
                field="FORCE_PLATFORM:CHANNEL",
            )
        signals = source.analogs[index - 1]
        _check_analogs(source, signals, index, plate, ratio)
        if kind == 4:
            signals = _calibration(source, plate) @ signals
        if kind == 3:
            _refuse_cop_polynomial(source, plate)
        wrench = plate_wrench(kind, signals.T, origins[:, plate] * scale, scale, cop_threshold)
        rotation, centre = plate_frame(corners[:, :, plate].T * scale, source.path, plate)
        to_out = axes @ rotation
        force.append(wrench[0] @ to_out.T)
        cop.append((wrench[1] @ rotation.T + centre) @ axes.T)
        moment.append(wrench[2] @ to_out.T)
    analog_rate = source.rate * ratio
    times = ((source.first_frame - 1) * ratio + np.arange(source.analogs.shape[1])) / analog_rate
    return GroundReaction(
        times=times,
        names=tuple(str(p + 1) for p in range(used)),
        force=np.stack(force, axis=1),
        cop=np.stack(cop, axis=1),
        moment=np.stack(moment, axis=1),
    )


def _check_analogs(source: _Source, signals: np.ndarray, index: np.ndarray, plate: int, ratio: int) -> None:
    """DataFormatError at the first NaN or infinite sample of a plate's analog channels (1-based ``index``),
    naming the channel (``ANALOG:LABELS``) and the POINT frame it falls in."""
    bad = ~np.isfinite(signals)
    if not bad.any():
        return
    row, sample = (int(i) for i in np.argwhere(bad)[0])
    channel = int(index[row])
    labels = [str(label).strip() for label in source.param("ANALOG", "LABELS", [])]
    name = labels[channel - 1] if channel <= len(labels) else f"channel {channel}"
    raise DataFormatError(
        source.path,
        f"force platform {plate + 1}: analog channel {channel} ({name!r}) holds "
        f"{signals[row, sample]} at analog sample {sample}, not a finite number",
        frame=sample // ratio,
        field="ANALOG:DATA",
    )


def _calibration(source: _Source, plate: int) -> np.ndarray:
    """6x6 CAL_MATRIX of a TYPE-4 plate; stored column-major, ``CAL_MATRIX(i, j, plate)`` is row i, column j
    (C3D User Guide, "FORCE_PLATFORM:CAL_MATRIX": corrected = CAL_MATRIX @ measured)."""
    values = np.asarray(source.param("FORCE_PLATFORM", "CAL_MATRIX"), dtype=float)
    if values.size == 0:  # Motion Analysis writes an empty matrix for plates whose channels are calibrated
        return np.eye(6)
    if values.ndim == 2:
        values = values[..., None]
    if values.shape[:2] != (6, 6) or values.shape[2] <= plate:
        raise DataFormatError(
            source.path,
            f"shape {values.shape} has no 6x6 matrix for plate {plate + 1}",
            field="FORCE_PLATFORM:CAL_MATRIX",
        )
    return values[:, :, plate]


def _refuse_cop_polynomial(source: _Source, plate: int) -> None:
    poly = np.ravel(np.asarray(source.param("FORCE_PLATFORM", "FPCOPPOLY", []), dtype=float))
    if np.any(poly[12 * plate : 12 * plate + 12] != 0):
        raise DataFormatError(
            source.path,
            f"plate {plate + 1}: Kistler CoP correction polynomials are not supported",
            field="FORCE_PLATFORM:FPCOPPOLY",
        )


def plate_frame(corners: np.ndarray, path: Path | None = None, plate: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (columns = plate x, y, z axes in the lab) and surface centre of a plate from its 4 corners [4, 3].

    The corners are numbered by the plate-frame quadrants +x+y, -x+y, -x-y, +x-y (C3D User Guide,
    "FORCE_PLATFORM:CORNERS"), so x points from corners 2, 3 to 1, 4 and y from 3, 4 to 1, 2; z = x × y
    (downwards for a floor plate), and y is re-orthogonalised.
    """
    x_axis = corners[0] + corners[3] - corners[1] - corners[2]
    y_axis = corners[0] + corners[1] - corners[2] - corners[3]
    z_axis = np.cross(x_axis, y_axis)
    if not np.linalg.norm(z_axis) > 1e-9 * np.linalg.norm(x_axis) * np.linalg.norm(y_axis):
        raise DataFormatError(path, f"corners of plate {plate + 1} do not span a plane", field="FORCE_PLATFORM:CORNERS")
    y_axis = np.cross(z_axis, x_axis)
    rotation = np.stack([axis / np.linalg.norm(axis) for axis in (x_axis, y_axis, z_axis)], axis=1)
    return rotation, corners.mean(axis=0)


def plate_wrench(
    kind: int, signals: np.ndarray, origin: np.ndarray, length_scale: float, cop_threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Force [N], CoP [m] and free moment [N·m] in the plate frame (origin at the surface centre), [N, 3] each.

    ``signals`` [N, 6 or 8] are the scaled (and, for TYPE 4, calibrated) channels; moments and CoP channels are
    in N·(file unit) and (file unit), turned into SI with ``length_scale``; ``origin`` is ``FORCE_PLATFORM:ORIGIN``
    in metres. Per the C3D User Guide ("FORCE_PLATFORM:ORIGIN", TYPE-1 to TYPE-4):

    * TYPE 1 — channels Fx, Fy, Fz, CoPx, CoPy, Tz: the CoP and free moment are given directly.
    * TYPE 2/4 — Fx, Fy, Fz, Mx, My, Mz about the transducer origin; ORIGIN points from that origin to the surface
      centre, so the moment about the centre is ``M + F × ORIGIN``. ORIGIN z must be negative (origin below the
      surface); a positive z is the old AMTI sign and the whole vector is negated, as Visual3D and ezc3d do.
    * TYPE 3 (Kistler, 8 channels Fx12, Fx34, Fy14, Fy23, Fz1..Fz4) — sensors at (±a, ±b) numbered by quadrant,
      ORIGIN = (a, b, az0) with az0 the (negative) depth of the sensor plane: ``Mx = b (Fz1 + Fz2 - Fz3 - Fz4)``,
      ``My = a (-Fz1 + Fz2 + Fz3 - Fz4)``, ``Mz = b (Fx34 - Fx12) + a (Fy14 - Fy23)`` about the sensor centre
      (Kistler force plate formulae), then moved to the surface centre like TYPE 2. A positive az0 (the other
      sign convention) is negated; ezc3d would negate a and b as well.

    From the moment M about the surface centre, CoP = (-My / Fz, Mx / Fz, 0) and the free moment is
    ``M + F × CoP``, whose in-plane components vanish: ``Tz = Mz + Fx CoPy - Fy CoPx``. The CoP and free moment
    are NaN where ``|Fz| < cop_threshold``.
    """
    signals = np.asarray(signals, dtype=float)
    if kind == 1:
        force = signals[:, 0:3]
        light = ~(np.abs(force[:, 2]) >= cop_threshold)
        cop = np.column_stack([signals[:, 3:5] * length_scale, np.zeros(len(signals))])
        free = np.zeros_like(force)
        free[:, 2] = signals[:, 5] * length_scale
    else:
        if kind == 3:
            a, b, depth = origin[0], origin[1], -abs(origin[2])
            fx12, fx34, fy14, fy23, fz1, fz2, fz3, fz4 = signals.T
            force = np.column_stack([fx12 + fx34, fy14 + fy23, fz1 + fz2 + fz3 + fz4])
            about_origin = np.column_stack(
                [b * (fz1 + fz2 - fz3 - fz4), a * (-fz1 + fz2 + fz3 - fz4), b * (fx34 - fx12) + a * (fy14 - fy23)]
            )
            offset = np.array([0.0, 0.0, depth])
        else:
            force = signals[:, 0:3]
            about_origin = signals[:, 3:6] * length_scale
            offset = -origin if origin[2] > 0 else origin
        centre_moment = about_origin + np.cross(force, offset)
        light = ~(np.abs(force[:, 2]) >= cop_threshold)
        normal = np.where(light, 1.0, force[:, 2])
        cop = np.column_stack([-centre_moment[:, 1] / normal, centre_moment[:, 0] / normal, np.zeros(len(force))])
        free = np.zeros_like(force)  # about the CoP only the plate-normal component is left
        free[:, 2] = centre_moment[:, 2] + force[:, 0] * cop[:, 1] - force[:, 1] * cop[:, 0]
    cop[light] = np.nan
    free[light] = np.nan
    return force, cop, free
