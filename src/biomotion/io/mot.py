"""OpenSim storage files: ``.mot`` and ``.sto`` (version 1 and 3 headers, and the older SIMM motion header).

Layout: free header lines (``key=value`` or SIMM ``key value``) up to ``endheader``, one line of tab-separated
column labels starting with ``time``, then one row of numbers per frame. Angles are in degrees when the header says
``inDegrees=yes``; SIMM motion files without that line are in degrees by convention. Values are converted to SI at
this boundary (see `biomotion.motion.is_translation` for which columns are angles).

Ground reaction ``.mot`` files (OpenSim external loads) group their columns per channel: ``<prefix>_v{x,y,z}``
force, ``<prefix>_p{x,y,z}`` point, and the torque either as ``<prefix>_m{x,y,z}`` or as the prefix with
``force`` replaced by ``torque`` (``ground_torque_r_x``). `read_ground_reaction` and `write_ground_reaction`
handle every naming found in the OpenSim example data.

Values are checked before anything computes with them: every row holds one value per column label, an infinite
value is refused, and so is NaN in a coordinate or ground reaction file unless the caller passes
``allow_gaps=True`` (`read_motion`, `read_ground_reaction`); `read_storage`, the raw table, keeps NaN by default
(result tables such as biomotion's balance output pad with it). Each refusal names the file, line and column.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from biomotion.errors import BiomotionWarning, DataFormatError
from biomotion.io.atomic import atomic_write
from biomotion.motion import GroundReaction, Motion, is_translation

Angles = Literal["header", "degrees", "radians"]

_SIMM_KEYS = {"datacolumns": "nColumns", "datarows": "nRows"}


@dataclass(frozen=True)
class StorageTable:
    """A storage file as written: header fields, column labels (without ``time``), times [T], data [T, C]."""

    path: Path | None
    name: str
    header: dict[str, str]
    labels: tuple[str, ...]
    times: np.ndarray
    data: np.ndarray
    simm: bool = False
    header_lines: tuple[str, ...] = field(default=(), repr=False)
    line_numbers: tuple[int, ...] = field(default=(), repr=False)
    """1-based file line of each row (for error messages)."""

    @property
    def in_degrees(self) -> bool | None:
        """What the header says (None when it says nothing)."""
        value = self.header.get("inDegrees")
        if value is None:
            return None
        return value.strip().lower() in ("yes", "true", "1")


def _split_labels(line: str) -> list[str]:
    tokens = line.split("\t") if "\t" in line else line.split()
    return [t.strip() for t in tokens if t.strip()]


def read_storage(path: str | Path, *, allow_gaps: bool = True) -> StorageTable:
    """Read any ``.mot``/``.sto`` file into a `StorageTable` (no unit conversion).

    Raises DataFormatError naming the line (and column) for a row whose value count differs from the labels', a
    token that is not a number, a missing or non-increasing time, or an infinite value; with ``allow_gaps=False``
    for a NaN value too (with the default True, NaN cells are kept as written).
    """
    path = Path(path)
    if path.is_dir():
        raise DataFormatError(path, "is a directory, not a storage file")
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise DataFormatError(path, "no such file") from None
    except OSError as error:
        raise DataFormatError(path, f"cannot read: {error.strerror}") from None
    lines = text.splitlines()
    if not lines or not text.strip():
        raise DataFormatError(path, "empty file")
    end = next((i for i, line in enumerate(lines) if line.strip().lower() == "endheader"), None)
    if end is None:
        raise DataFormatError(path, "no 'endheader' line: not an OpenSim storage file")
    header: dict[str, str] = {}
    simm = False
    name = lines[0].strip()
    for line in lines[:end]:
        stripped = line.strip()
        if "=" in stripped:
            key, _, value = stripped.partition("=")
            header[key.strip()] = value.strip()
        elif stripped.startswith("#") and "SIMM" in stripped:
            simm = True
        elif stripped:
            key, _, value = stripped.partition(" ")
            if key in _SIMM_KEYS or key in ("name", "range", "otherdata"):
                simm = simm or key in _SIMM_KEYS
                header.setdefault(_SIMM_KEYS.get(key, key), value.strip())
    label_index = next((i for i in range(end + 1, len(lines)) if lines[i].strip()), None)
    if label_index is None:
        raise DataFormatError(path, "no column labels after 'endheader'", line=end + 1)
    labels = _split_labels(lines[label_index])
    if not labels or labels[0].lower() != "time":
        raise DataFormatError(path, f"first column must be 'time', found {labels[:1]}", line=label_index + 1)
    width = len(labels)
    rows: list[list[str]] = []
    for number in range(label_index + 1, len(lines)):
        tokens = lines[number].split()
        if not tokens:
            continue
        if len(tokens) != width:
            raise DataFormatError(path, f"{len(tokens)} values but {width} column labels", line=number + 1)
        rows.append(tokens)
        rows[-1].append(str(number + 1))
    if not rows:
        raise DataFormatError(path, "no data rows", line=label_index + 2)
    table = np.array(rows, dtype=object)
    line_numbers = table[:, -1].astype(int)
    try:
        values = table[:, :-1].astype(float)
    except ValueError:
        for tokens, line_number in zip(rows, line_numbers):
            for column, token in enumerate(tokens[:-1]):
                try:
                    float(token)
                except ValueError:
                    raise DataFormatError(
                        path, f"not a number: {token!r}", line=int(line_number), field=labels[column]
                    ) from None
        raise
    declared = header.get("nRows")
    if declared is not None and declared.strip().isdigit() and int(declared) > len(values):
        raise DataFormatError(
            path, f"truncated: header declares {declared} rows, file has {len(values)}", line=int(line_numbers[-1])
        )
    bad_time = ~np.isfinite(values[:, 0])
    if bad_time.any():
        raise DataFormatError(
            path,
            f"time is {'NaN' if np.isnan(values[bad_time, 0][0]) else 'infinite'}",
            line=int(line_numbers[bad_time][0]),
            field=labels[0],
        )
    _check_finite(path, values[:, 1:], labels[1:], line_numbers, allow_gaps=allow_gaps)
    steps = np.diff(values[:, 0])
    if np.any(steps <= 0):
        row = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise DataFormatError(
            path, f"time does not increase ({values[row - 1, 0]} then {values[row, 0]})", line=int(line_numbers[row])
        )
    return StorageTable(
        path=path,
        name=name,
        header=header,
        labels=tuple(labels[1:]),
        times=values[:, 0],
        data=values[:, 1:],
        simm=simm,
        header_lines=tuple(lines[:end]),
        line_numbers=tuple(int(n) for n in line_numbers),
    )


def _check_finite(
    path: Path | None, data: np.ndarray, labels: Sequence[str], line_numbers: Sequence[int], *, allow_gaps: bool
) -> None:
    """DataFormatError at the first infinite value of ``data`` [rows, columns], or the first NaN unless
    ``allow_gaps``, naming its line (``line_numbers[row]``) and column label."""
    bad = np.isinf(data) if allow_gaps else ~np.isfinite(data)
    if not bad.any():
        return
    row, column = (int(i) for i in np.argwhere(bad)[0])
    line = int(line_numbers[row]) if len(line_numbers) > row else None
    if np.isnan(data[row, column]):
        raise DataFormatError(
            path,
            "value is NaN: every cell needs a number (a caller that handles gaps reads the file with allow_gaps=True)",
            line=line,
            field=labels[column],
        )
    raise DataFormatError(path, f"value is {data[row, column]}: not a finite number", line=line, field=labels[column])


def _angles_in_degrees(table: StorageTable, angles: Angles, rotational: np.ndarray) -> bool:
    if angles != "header":
        return angles == "degrees"
    declared = table.in_degrees
    if declared is None:
        return True  # SIMM motion files and OpenSim's legacy convention: degrees
    if not declared and rotational.any():
        peak = float(np.nanmax(np.abs(table.data[:, rotational])))
        if peak > 2 * np.pi + 0.1:
            warnings.warn(
                f"{table.path}: header says inDegrees=no but angles reach {peak:.1f}, which looks like "
                "degrees; reading as the header says (pass angles='degrees' to override)",
                BiomotionWarning,
                stacklevel=3,
            )
    return declared


def read_motion(
    path: str | Path, *, angles: Angles = "header", columns: Sequence[str] | None = None, allow_gaps: bool = False
) -> Motion:
    """Read a coordinate file (IK output, states) as a `Motion` in SI units.

    Args:
        angles: ``"header"`` trusts ``inDegrees`` (and warns when the values contradict it); ``"degrees"`` or
            ``"radians"`` overrides a header known to be wrong.
        columns: keep only these columns (error if one is absent); default all.
        allow_gaps: keep NaN values (of the kept columns) as gaps in the `Motion`; by default a NaN is a
            `DataFormatError` naming its line and column, since filtering and dynamics cannot use it.
    """
    table = read_storage(path)
    labels = table.labels
    data = table.data
    if columns is not None:
        missing = [c for c in columns if c not in labels]
        if missing:
            raise DataFormatError(path, f"columns not in file: {', '.join(missing)}")
        index = [labels.index(c) for c in columns]
        labels, data = tuple(columns), data[:, index]
    _check_finite(table.path, data, labels, table.line_numbers, allow_gaps=allow_gaps)
    if len(set(labels)) != len(labels):
        duplicate = next(label for label in labels if labels.count(label) > 1)
        raise DataFormatError(path, "duplicate column label", field=duplicate)
    rotational = np.array([not is_translation(n) for n in labels], dtype=bool)
    view = StorageTable(table.path, table.name, table.header, labels, table.times, data, table.simm)
    if _angles_in_degrees(view, angles, rotational):
        data = data.copy()
        data[:, rotational] = np.deg2rad(data[:, rotational])
    return Motion(times=table.times, names=labels, values=data)


def _format_rows(times: np.ndarray, data: np.ndarray) -> str:
    """The rows, tab-separated, each number Python's ``repr`` of the float (shortest round trip; ``nan``, ``inf``).
    Formatted through the repr of a nested list, which writes floats with that same ``repr`` in C: several times
    faster than a ``repr`` call per number, which was most of writing an IK result."""
    block = np.column_stack([times, data])
    if block.size == 0:
        return "\n"
    text = repr(block.tolist())  # "[[t, a, b], [t, a, b]]"
    return text[2:-2].replace("], [", "\n").replace(", ", "\t") + "\n"


def write_storage(
    path: str | Path,
    labels: Sequence[str],
    times: np.ndarray,
    data: np.ndarray,
    *,
    name: str | None = None,
    in_degrees: bool = False,
    extra_header: dict[str, str] | None = None,
) -> Path:
    """Write a version-1 storage file that OpenSim's `TimeSeriesTable` and `Storage` read back exactly.

    Numbers are written with the shortest decimal that round-trips the float64 value.
    """
    path = Path(path)
    times = np.asarray(times, dtype=float)
    data = np.asarray(data, dtype=float).reshape(len(times), -1)
    if data.shape[1] != len(labels):
        raise ValueError(f"{data.shape[1]} data columns for {len(labels)} labels")
    header = [
        name or path.stem,
        "version=1",
        f"nRows={len(times)}",
        f"nColumns={len(labels) + 1}",
        f"inDegrees={'yes' if in_degrees else 'no'}",
    ]
    header += [f"{k}={v}" for k, v in (extra_header or {}).items()]
    header.append("endheader")
    with atomic_write(path) as handle:
        handle.write("\n".join(header) + "\n")
        handle.write("\t".join(["time", *labels]) + "\n")
        handle.write(_format_rows(times, data))
    return path


def write_motion(path: str | Path, motion: Motion, *, in_degrees: bool = True, name: str | None = None) -> Path:
    """Write a `Motion` as ``.mot``/``.sto``; angles in degrees by default, as OpenSim's IK tool writes them."""
    values = motion.values.copy()
    if in_degrees:
        rotational = motion.rotational()
        values[:, rotational] = np.rad2deg(values[:, rotational])
    return write_storage(path, motion.names, motion.times, values, name=name or "Coordinates", in_degrees=in_degrees)


_FORCE_COLUMN = re.compile(r"^(?P<prefix>.+)_v(?P<axis>[xyz])$")


def torque_columns(prefix: str, labels: Sequence[str]) -> list[str] | None:
    """The three torque columns of GRF channel ``prefix`` in ``labels`` (any of the namings), or None."""
    candidates = [
        [f"{prefix}_m{a}" for a in "xyz"],
        [f"{prefix.replace('force', 'torque')}_{a}" for a in "xyz"],
        [f"{prefix.replace('force', 'moment')}_{a}" for a in "xyz"],
    ]
    return next((c for c in candidates if all(name in labels for name in c)), None)


def read_ground_reaction(path: str | Path, *, allow_gaps: bool = False) -> GroundReaction:
    """Read an OpenSim external-loads ``.mot`` (GRF) into a `GroundReaction`; one channel per column prefix.

    Channel names are the column prefixes (``ground_force_r``, ``1_ground_force``, ``R_ground_force`` ...), which
    is what an ExternalLoads XML refers to. Channels without torque columns get a zero moment. A NaN value is a
    `DataFormatError` naming its line and column unless ``allow_gaps`` (then kept: NaN force, point or moment).
    """
    table = read_storage(path)
    _check_finite(table.path, table.data, table.labels, table.line_numbers, allow_gaps=allow_gaps)
    labels = table.labels
    prefixes: list[str] = []
    for label in labels:
        match = _FORCE_COLUMN.match(label)
        if match and match["axis"] == "x" and match["prefix"] not in prefixes:
            prefixes.append(match["prefix"])
    if not prefixes:
        raise DataFormatError(path, "no force columns named <prefix>_vx/_vy/_vz: not a ground reaction file")
    force, cop, moment = [], [], []
    for prefix in prefixes:
        triples = {}
        for kind in ("v", "p"):
            names = [f"{prefix}_{kind}{a}" for a in "xyz"]
            missing = [n for n in names if n not in labels]
            if missing:
                raise DataFormatError(path, f"channel {prefix!r} lacks columns {', '.join(missing)}")
            triples[kind] = table.data[:, [labels.index(n) for n in names]]
        torque = torque_columns(prefix, labels)
        force.append(triples["v"])
        cop.append(triples["p"])
        moment.append(
            np.zeros_like(triples["v"]) if torque is None else table.data[:, [labels.index(n) for n in torque]]
        )
    return GroundReaction(
        times=table.times,
        names=tuple(prefixes),
        force=np.stack(force, axis=1),
        cop=np.stack(cop, axis=1),
        moment=np.stack(moment, axis=1),
    )


def ground_reaction_labels(name: str) -> tuple[list[str], list[str], list[str]]:
    """Column labels OpenSim's convention gives channel ``name``: force, point and torque triples."""
    prefix = name if "force" in name else f"ground_force_{name}"
    torque = prefix.replace("force", "torque")
    return ([f"{prefix}_v{a}" for a in "xyz"], [f"{prefix}_p{a}" for a in "xyz"], [f"{torque}_{a}" for a in "xyz"])


def write_ground_reaction(path: str | Path, forces: GroundReaction, *, name: str | None = None) -> Path:
    """Write a `GroundReaction` as an OpenSim external-loads ``.mot``.

    A NaN centre of pressure or free moment (load too light) is written as 0 beside the force, which is what
    OpenSim's tools expect; use `write_external_loads_xml` for the matching setup.
    """
    labels: list[str] = []
    columns: list[np.ndarray] = []
    for j, channel in enumerate(forces.names):
        force_labels, point_labels, torque_labels = ground_reaction_labels(channel)
        labels += force_labels + point_labels + torque_labels
        columns += [
            forces.force[:, j],
            np.nan_to_num(forces.cop[:, j], nan=0.0),
            np.nan_to_num(forces.moment[:, j], nan=0.0),
        ]
    data = np.concatenate(columns, axis=1)
    return write_storage(path, labels, forces.times, data, name=name or "ground_reaction")


def write_external_loads_xml(path: str | Path, forces: GroundReaction, data_file: str) -> Path:
    """Write the OpenSim ``ExternalLoads`` XML that applies each channel of ``forces`` to its body.

    Every channel must have a body (see `GroundReaction.assign`). Forces and points are expressed in ground.
    """
    if any(body is None for body in forces.bodies):
        raise ValueError("every channel needs a body: call forces.assign([...]) first")
    entries = []
    for channel, body in zip(forces.names, forces.bodies):
        force_labels, point_labels, torque_labels = ground_reaction_labels(channel)
        entries.append(
            f'\t\t\t<ExternalForce name="{channel}">\n'
            f"\t\t\t\t<applied_to_body>{body}</applied_to_body>\n"
            "\t\t\t\t<force_expressed_in_body>ground</force_expressed_in_body>\n"
            "\t\t\t\t<point_expressed_in_body>ground</point_expressed_in_body>\n"
            f"\t\t\t\t<force_identifier>{force_labels[0][:-1]}</force_identifier>\n"
            f"\t\t\t\t<point_identifier>{point_labels[0][:-1]}</point_identifier>\n"
            f"\t\t\t\t<torque_identifier>{torque_labels[0][:-1]}</torque_identifier>\n"
            "\t\t\t</ExternalForce>\n"
        )
    xml = (
        '<?xml version="1.0" encoding="UTF-8" ?>\n<OpenSimDocument Version="40000">\n'
        '\t<ExternalLoads name="externalloads">\n\t\t<objects>\n'
        + "".join(entries)
        + "\t\t</objects>\n\t\t<groups />\n"
        f"\t\t<datafile>{data_file}</datafile>\n"
        "\t</ExternalLoads>\n</OpenSimDocument>\n"
    )
    with atomic_write(path) as handle:
        handle.write(xml)
    return Path(path)
