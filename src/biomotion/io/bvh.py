"""BVH (Biovision Hierarchy) motion capture files: read, forward kinematics, write.

The format (Biovision, as documented by Meredith & Maddock 2001, "Motion capture file formats explained",
University of Sheffield, section 2.2) is a ``HIERARCHY`` of joints, each with an ``OFFSET`` from its parent and a
list of ``CHANNELS``, followed by a ``MOTION`` block of ``Frames:``, ``Frame Time:`` and one line of channel values
per frame, in the order the channels were declared. Rotation channels are Euler angles in degrees, applied as
intrinsic rotations in the order listed, so channels ``Zrotation Xrotation Yrotation`` give the local rotation
``Rz(z) @ Rx(x) @ Ry(y)``; position channels replace the matching component of the joint's offset. A joint's
global transform is its parent's global transform composed with ``[R | t]``.

Lengths are converted to metres for the `Skeleton` and for forward kinematics; the raw channel values of a
`BVHMotion` stay as in the file (degrees, file units) so that writing it back reproduces the file.
"""

from __future__ import annotations

import gzip
import io
import re
import zlib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from biomotion.errors import DataFormatError
from biomotion.io.atomic import atomic_write
from biomotion.motion import Markers

CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
UNIT_SCALES = {"m": 1.0, "cm": 0.01, "mm": 0.001}
"""Metres per file unit."""

_CANONICAL = {name.lower(): name for name in CHANNEL_NAMES}
_AXIS = {"X": 0, "Y": 1, "Z": 2}
_MOTION_LINE = re.compile(r"^[ \t]*MOTION[ \t]*$", re.MULTILINE)
_NUMBER_FORMAT = "%.10g"


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A BVH joint hierarchy.

    Attributes:
        names: one name per joint in the file's order: depth first, each joint right after its parent's earlier
            descendants. End Sites, which have no name in BVH, are called ``<parent>_end``.
        parents: index of each joint's parent, -1 for a root.
        offsets: [J, 3] offset of each joint from its parent, in metres.
        channels: per joint, its channel names in file order (``"Zrotation"``, ``"Xposition"`` ...); empty for
            End Sites.
        end_sites: per joint, True for an End Site (a leaf with an offset and no channels).
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_sites: tuple[bool, ...] = field(default=())

    def __post_init__(self) -> None:
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "parents", tuple(int(p) for p in self.parents))
        object.__setattr__(self, "offsets", np.asarray(self.offsets, dtype=float))
        object.__setattr__(self, "channels", tuple(tuple(c) for c in self.channels))
        object.__setattr__(self, "end_sites", tuple(bool(e) for e in self.end_sites) or (False,) * len(self.names))
        count = len(self.names)
        if not count:
            raise DataFormatError(None, "a skeleton needs at least one joint")
        if self.offsets.shape != (count, 3) or not np.all(np.isfinite(self.offsets)):
            raise DataFormatError(None, f"offsets must be finite [{count}, 3], got shape {self.offsets.shape}")
        if not len(self.parents) == len(self.channels) == len(self.end_sites) == count:
            raise DataFormatError(None, "names, parents, channels and end_sites differ in length")
        if len(set(self.names)) != count:
            raise DataFormatError(None, "duplicate joint names")
        path: list[int] = []  # the joints whose blocks are open when joint j starts, as in the file
        for j, (name, parent, chans, end) in enumerate(zip(self.names, self.parents, self.channels, self.end_sites)):
            if parent >= 0 and parent not in path:
                raise DataFormatError(
                    None,
                    f"joint {name!r}: parent {parent} is not the previous joint or one of "
                    f"its ancestors (joints must be in depth-first file order)",
                )
            path = path[: path.index(parent) + 1] if parent >= 0 else []
            path.append(j)
            if not name.split() or " ".join(name.split()) != name or "{" in name.split():
                raise DataFormatError(None, f"joint name {name!r} cannot be written in BVH")
            if len(set(chans)) != len(chans) or any(c not in CHANNEL_NAMES for c in chans):
                raise DataFormatError(None, f"joint {name!r}: bad channels {chans}")
            if end and (chans or parent < 0):
                raise DataFormatError(None, f"End Site {name!r} must have a parent and no channels")
            if parent >= 0 and self.end_sites[parent]:
                raise DataFormatError(None, f"joint {name!r} cannot hang below End Site {self.names[parent]!r}")

    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no joint {name!r} (has {', '.join(self.names)})") from None

    def column(self, joint: str, channel: str) -> int:
        """Column of ``channel`` of ``joint`` in a [T, C] channel array."""
        j = self.index(joint)
        if channel not in self.channels[j]:
            raise KeyError(f"joint {joint!r} has no channel {channel!r} (has {', '.join(self.channels[j])})")
        return int(self._starts[j]) + self.channels[j].index(channel)

    @cached_property
    def _starts(self) -> np.ndarray:
        sizes = np.array([len(c) for c in self.channels], dtype=int)
        return np.concatenate([[0], np.cumsum(sizes)[:-1]])

    @cached_property
    def _position_columns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(joint, axis, column) of every position channel."""
        rows = [
            (j, _AXIS[c[0]], int(self._starts[j]) + k)
            for j, chans in enumerate(self.channels)
            for k, c in enumerate(chans)
            if c.endswith("position")
        ]
        return tuple(np.array(v, dtype=int) for v in zip(*rows)) if rows else (np.zeros(0, int),) * 3

    @cached_property
    def _rotation_groups(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Rotation order (``"ZXY"``) -> (joints [G], columns [G, k]) of the joints rotating in that order."""
        groups: dict[str, list[tuple[int, list[int]]]] = {}
        for j, chans in enumerate(self.channels):
            rotations = [(c[0], int(self._starts[j]) + k) for k, c in enumerate(chans) if c.endswith("rotation")]
            if rotations:
                order = "".join(axis for axis, _ in rotations)
                groups.setdefault(order, []).append((j, [col for _, col in rotations]))
        return {
            order: (np.array([j for j, _ in rows]), np.array([cols for _, cols in rows]))
            for order, rows in groups.items()
        }


def axis_rotation(axis: str, radians: np.ndarray) -> np.ndarray:
    """[..., 3, 3] right-handed rotation matrices about ``axis`` ("X", "Y" or "Z") by ``radians`` [...]."""
    c, s = np.cos(radians), np.sin(radians)
    one, zero = np.ones_like(c), np.zeros_like(c)
    rows = {
        "X": ((one, zero, zero), (zero, c, -s), (zero, s, c)),
        "Y": ((c, zero, s), (zero, one, zero), (-s, zero, c)),
        "Z": ((c, -s, zero), (s, c, zero), (zero, zero, one)),
    }[axis]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def forward_kinematics(
    parents: tuple[int, ...] | list[int], rotations: np.ndarray, translations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Global joint rotations [..., J, 3, 3] and positions [..., J, 3] from local ones.

    ``rotations`` [..., J, 3, 3] and ``translations`` [..., J, 3] are each joint's transform in its parent's
    frame; parents must precede their children. ``R_j = R_parent @ r_j``, ``p_j = p_parent + R_parent @ t_j``.
    """
    global_rotations = np.empty_like(rotations)
    positions = np.empty_like(translations)
    for j, parent in enumerate(parents):
        if parent < 0:
            global_rotations[..., j, :, :] = rotations[..., j, :, :]
            positions[..., j, :] = translations[..., j, :]
        else:
            parent_rotation = global_rotations[..., parent, :, :]
            positions[..., j, :] = positions[..., parent, :] + np.einsum(
                "...ab,...b->...a", parent_rotation, translations[..., j, :]
            )
            global_rotations[..., j, :, :] = parent_rotation @ rotations[..., j, :, :]
    return global_rotations, positions


@dataclass(frozen=True, eq=False)
class BVHMotion:
    """A BVH clip: skeleton plus raw channel values.

    Attributes:
        skeleton: the joint hierarchy (offsets in metres).
        values: [T, C] channel values as in the file: degrees for rotations, ``units`` for positions.
        frame_time: seconds between frames.
        units: length unit of the position channels (and of the file's offsets): "m", "cm" or "mm".
        units_inferred: True when ``units`` was decided from the skeleton size (see `detect_units`), False when
            the caller gave it.
    """

    skeleton: Skeleton
    values: np.ndarray
    frame_time: float
    units: str = "m"
    units_inferred: bool = False

    def __post_init__(self) -> None:
        values = np.asarray(self.values, dtype=float)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "frame_time", float(self.frame_time))
        if self.units not in UNIT_SCALES:
            raise DataFormatError(None, f"units must be one of {', '.join(UNIT_SCALES)}, got {self.units!r}")
        if self.skeleton.n_channels == 0:
            raise DataFormatError(None, "a BVH skeleton needs at least one channel")
        if values.ndim != 2 or values.shape[1] != self.skeleton.n_channels or values.shape[0] < 1:
            raise DataFormatError(
                None, f"values shape {values.shape} does not match [T >= 1, {self.skeleton.n_channels} channels]"
            )
        if not (np.isfinite(self.frame_time) and self.frame_time > 0):
            raise DataFormatError(None, f"frame time must be positive, got {self.frame_time}")
        bad = ~np.isfinite(values)
        if bad.any():
            frame, column = np.argwhere(bad)[0]
            raise DataFormatError(None, f"channel value {values[frame, column]} in column {column}", frame=int(frame))

    @property
    def n_frames(self) -> int:
        return int(self.values.shape[0])

    @property
    def times(self) -> np.ndarray:
        """[T] seconds from the first frame."""
        return np.arange(self.n_frames) * self.frame_time

    @property
    def rate(self) -> float:
        return 1.0 / self.frame_time

    def channel(self, joint: str, channel: str) -> np.ndarray:
        """[T] raw values of one channel (degrees or file units)."""
        return self.values[:, self.skeleton.column(joint, channel)]

    def local_rotations(self) -> np.ndarray:
        """[T, J, 3, 3] each joint's rotation in its parent's frame: intrinsic Euler rotations in channel order."""
        rotations = np.broadcast_to(np.eye(3), (self.n_frames, self.skeleton.n_joints, 3, 3)).copy()
        for order, (joints, columns) in self.skeleton._rotation_groups.items():
            angles = np.radians(self.values[:, columns])
            composed = axis_rotation(order[0], angles[..., 0])
            for k, axis in enumerate(order[1:], start=1):
                composed = composed @ axis_rotation(axis, angles[..., k])
            rotations[:, joints] = composed
        return rotations

    def local_translations(self) -> np.ndarray:
        """[T, J, 3] each joint's origin in its parent's frame, metres: offset, with position channels in place."""
        translations = np.broadcast_to(self.skeleton.offsets, (self.n_frames, self.skeleton.n_joints, 3)).copy()
        joints, axes, columns = self.skeleton._position_columns
        translations[:, joints, axes] = self.values[:, columns] * UNIT_SCALES[self.units]
        return translations

    def global_transforms(self) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations [T, J, 3, 3] and positions [T, J, 3] (metres) by forward kinematics."""
        return forward_kinematics(self.skeleton.parents, self.local_rotations(), self.local_translations())

    def global_positions(self) -> np.ndarray:
        """[T, J, 3] joint positions in the file's world frame, metres."""
        return self.global_transforms()[1]

    def to_markers(self, *, end_sites: bool = True) -> Markers:
        """Joint positions as `Markers` named after the joints (End Sites included unless ``end_sites=False``)."""
        positions = self.global_positions()
        keep = [j for j, end in enumerate(self.skeleton.end_sites) if end_sites or not end]
        return Markers(
            times=self.times, names=tuple(self.skeleton.names[j] for j in keep), positions=positions[:, keep]
        )


def detect_units(skeleton: Skeleton, values: np.ndarray) -> str:
    """Length unit of a skeleton whose offsets, like the position channels ``values`` [T, C], are in file units.

    Rule: L = the longest chain of bone lengths from a root to a leaf, where a joint's bone length is the length of
    its first-frame translation (offset, with its position channels in place), and counts as 0 for roots and for
    joints whose position channels move during the clip (peak-to-peak > 1e-3 x (1 + largest magnitude)): those
    place the figure in the room (the Bandai-Namco ``Hips`` offset is 4.5 m off), they are not bones. A human
    figure measures about 1-3 m along such a chain, so L < 10 -> "m", 10 <= L < 400 -> "cm", L >= 400 -> "mm".
    Pass ``units`` to `read_bvh` explicitly for other figures.
    """
    joints, axes, columns = skeleton._position_columns
    translations = skeleton.offsets.copy()
    translations[joints, axes] = values[0, columns]
    moving = np.zeros(skeleton.n_joints, dtype=bool)
    span = np.ptp(values[:, columns], axis=0)
    np.logical_or.at(moving, joints, span > 1e-3 * (1.0 + np.abs(values[:, columns]).max(axis=0)))
    lengths = np.where(moving, 0.0, np.linalg.norm(translations, axis=1))
    chain = np.zeros(skeleton.n_joints)
    for j, parent in enumerate(skeleton.parents):
        if parent >= 0:
            chain[j] = chain[parent] + lengths[j]
    longest = float(chain.max())
    return "m" if longest < 10 else "cm" if longest < 400 else "mm"


def read_bvh(path: str | Path, *, units: str = "auto") -> BVHMotion:
    """Read a ``.bvh`` or ``.bvh.gz`` file.

    ``units`` is the file's length unit ("m", "cm", "mm"), or "auto" to decide it with `detect_units`; the
    unit applied is stored on the result (``units``, ``units_inferred``).
    """
    if units != "auto" and units not in UNIT_SCALES:
        raise ValueError(f"units must be 'auto' or one of {', '.join(UNIT_SCALES)}, got {units!r}")
    path = Path(path)
    text = _read_text(path)
    if not text.strip():
        raise DataFormatError(path, "empty file", line=1)
    motion_match = _MOTION_LINE.search(text)
    if motion_match is None:
        raise DataFormatError(path, "no MOTION section", line=text.count("\n") + 1)
    header = text[: motion_match.start()]
    skeleton = _parse_hierarchy(path, header)
    if skeleton.n_channels == 0:
        raise DataFormatError(path, "HIERARCHY declares no channels", line=1)
    motion_line = header.count("\n") + 1
    frames, frame_time, block, first_data_line = _parse_motion_header(path, text, motion_match.end(), motion_line)
    values = _parse_frames(path, block, first_data_line, frames, skeleton.n_channels)
    chosen = detect_units(skeleton, values) if units == "auto" else units
    metres = Skeleton(
        skeleton.names, skeleton.parents, skeleton.offsets * UNIT_SCALES[chosen], skeleton.channels, skeleton.end_sites
    )
    return BVHMotion(metres, values, frame_time, units=chosen, units_inferred=units == "auto")


def _read_text(path: Path) -> str:
    if path.is_dir():
        raise DataFormatError(path, "is a directory, not a BVH file")
    try:
        raw = path.read_bytes()
        if path.name.endswith(".gz"):
            raw = gzip.decompress(raw)
    except FileNotFoundError:
        raise DataFormatError(path, "no such file") from None
    except (OSError, EOFError, zlib.error) as error:
        raise DataFormatError(path, f"cannot read: {getattr(error, 'strerror', None) or error}") from error
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        line = raw[: error.start].count(b"\n") + 1
        raise DataFormatError(path, f"not UTF-8 text: {error.reason}", line=line) from error
    return text.replace("\r\n", "\n").replace("\r", "\n") if "\r" in text else text


class _Tokens:
    """Whitespace-separated tokens of the hierarchy, each with its 1-based line number."""

    def __init__(self, path: Path, header: str) -> None:
        self.path = path
        self.items = [
            (token, number) for number, line in enumerate(header.split("\n"), start=1) for token in line.split()
        ]
        self.position = 0
        self.last_line = header.count("\n") + 1

    def error(self, message: str, line: int | None = None) -> DataFormatError:
        return DataFormatError(self.path, message, line=self.last_line if line is None else line)

    def next(self, what: str) -> tuple[str, int]:
        if self.position >= len(self.items):
            raise self.error(f"hierarchy ends where {what} was expected")
        item = self.items[self.position]
        self.position += 1
        return item

    def peek(self) -> tuple[str, int] | None:
        return self.items[self.position] if self.position < len(self.items) else None

    def rest_of_line(self, line: int) -> list[str]:
        """Tokens left on ``line``, a trailing ``{`` excluded (it stays to be read)."""
        words = []
        while (item := self.peek()) is not None and item[1] == line and item[0] != "{":
            words.append(item[0])
            self.position += 1
        return words

    def number(self, what: str) -> float:
        token, line = self.next(what)
        try:
            value = float(token)
        except ValueError:
            raise self.error(f"{what}: {token!r} is not a number", line) from None
        if not np.isfinite(value):
            raise self.error(f"{what}: {token!r} is not finite", line)
        return value


def _parse_hierarchy(path: Path, header: str) -> Skeleton:
    """Joints of the HIERARCHY section, offsets in file units."""
    tokens = _Tokens(path, header)
    token, line = tokens.next("HIERARCHY")
    if token.upper() != "HIERARCHY":
        raise tokens.error(f"expected HIERARCHY, found {token!r}", line)
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float] | None] = []
    channels: list[tuple[str, ...]] = []
    end_sites: list[bool] = []
    stack: list[int] = []
    while tokens.peek() is not None:
        token, line = tokens.next("a keyword")
        keyword = token.upper()
        current = stack[-1] if stack else None
        if keyword in ("ROOT", "JOINT") or (keyword == "END" and current is not None):
            if (keyword == "ROOT") != (current is None) or (current is not None and end_sites[current]):
                raise tokens.error(f"unexpected {token}", line)
            words = tokens.rest_of_line(line)
            if keyword == "END":
                if [w.upper() for w in words] != ["SITE"]:
                    raise tokens.error(f"expected 'End Site', found {' '.join([token, *words])!r}", line)
                name = _unique(f"{names[current]}_end", names)
            elif not words:
                raise tokens.error(f"{token} without a name", line)
            else:
                name = " ".join(words)
                if name in names:
                    raise tokens.error(f"duplicate joint name {name!r}", line)
            brace, brace_line = tokens.next("'{'")
            if brace != "{":
                raise tokens.error(f"expected '{{' after {token} {name}, found {brace!r}", brace_line)
            names.append(name)
            parents.append(-1 if current is None else current)
            offsets.append(None)
            channels.append(())
            end_sites.append(keyword == "END")
            stack.append(len(names) - 1)
        elif keyword == "OFFSET" and current is not None:
            if offsets[current] is not None or current != len(names) - 1:
                raise tokens.error(f"OFFSET of {names[current]!r} repeated or after a child joint", line)
            offsets[current] = [tokens.number(f"OFFSET of {names[current]!r}") for _ in range(3)]
        elif keyword == "CHANNELS" and current is not None and not end_sites[current]:
            if channels[current] or current != len(names) - 1:
                raise tokens.error(f"CHANNELS of {names[current]!r} repeated or after a child joint", line)
            count_token, count_line = tokens.next("the channel count")
            if not count_token.isdigit() or int(count_token) > len(CHANNEL_NAMES):
                raise tokens.error(f"bad channel count {count_token!r}", count_line)
            declared = []
            for _ in range(int(count_token)):
                name_token, name_line = tokens.next("a channel name")
                canonical = _CANONICAL.get(name_token.lower())
                if canonical is None:
                    raise tokens.error(
                        f"unknown channel {name_token!r} (expected one of {', '.join(CHANNEL_NAMES)})", name_line
                    )
                if canonical in declared:
                    raise tokens.error(f"channel {name_token!r} repeated", name_line)
                declared.append(canonical)
            channels[current] = tuple(declared)
        elif token == "}" and current is not None:
            if offsets[current] is None:
                raise tokens.error(f"{names[current]!r} has no OFFSET", line)
            stack.pop()
        else:
            raise tokens.error(f"unexpected {token!r}", line)
    if stack:
        raise tokens.error(f"'{{' of {names[stack[-1]]!r} is never closed")
    if not names:
        raise tokens.error("HIERARCHY holds no joint")
    return Skeleton(tuple(names), tuple(parents), np.array(offsets, dtype=float), tuple(channels), tuple(end_sites))


def _unique(name: str, taken: list[str]) -> str:
    candidate, suffix = name, 2
    while candidate in taken:
        candidate, suffix = f"{name}{suffix}", suffix + 1
    return candidate


def _parse_motion_header(path: Path, text: str, start: int, motion_line: int) -> tuple[int, float, str, int]:
    """(frames, frame time, data block, line number of the block's first line) after the MOTION line."""
    position, line = start + 1, motion_line + 1
    fields = {}
    for key in ("frames", "frame time"):
        while True:
            end = text.find("\n", position)
            end = len(text) if end < 0 else end
            content = text[position:end].strip()
            if content or end >= len(text):
                break
            position, line = end + 1, line + 1
        label, _, value = content.partition(":")
        if " ".join(label.lower().split()) != key or not value.strip():
            raise DataFormatError(path, f"expected '{key.title()}: <number>', found {content!r}", line=line)
        fields[key] = (value.strip(), line)
        position, line = end + 1, line + 1
    frames_text, frames_line = fields["frames"]
    if not frames_text.isdigit() or int(frames_text) < 1:
        raise DataFormatError(path, f"Frames: {frames_text!r} is not a positive whole number", line=frames_line)
    time_text, time_line = fields["frame time"]
    try:
        frame_time = float(time_text)
    except ValueError:
        frame_time = float("nan")
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise DataFormatError(path, f"Frame Time: {time_text!r} is not a positive number", line=time_line)
    return int(frames_text), frame_time, text[position:], line


def _parse_frames(path: Path, block: str, first_line: int, frames: int, n_channels: int) -> np.ndarray:
    """[frames, n_channels] values of the data block (np.loadtxt; a line-by-line pass only to explain errors)."""
    values = None
    if block.strip():
        try:
            values = np.loadtxt(io.StringIO(block), dtype=float, comments=None, ndmin=2)
        except ValueError:
            values = None
    if values is None or values.shape != (frames, n_channels) or not np.all(np.isfinite(values)):
        _explain_frames(path, block, first_line, frames, n_channels)
    return values


def _explain_frames(path: Path, block: str, first_line: int, frames: int, n_channels: int) -> None:
    """Raise the DataFormatError that names the first bad frame line of a block np.loadtxt rejected."""
    frame = 0
    lines = block.split("\n")
    for number, text in enumerate(lines, start=first_line):
        words = text.split()
        if not words:
            continue
        if frame >= frames:
            raise DataFormatError(path, f"more frame lines than Frames: {frames}", line=number, frame=frame)
        if len(words) != n_channels:
            raise DataFormatError(
                path, f"{len(words)} values, expected {n_channels} (one per channel)", line=number, frame=frame
            )
        for column, word in enumerate(words):
            try:
                value = float(word)
            except ValueError:
                raise DataFormatError(
                    path, f"{word!r} in column {column + 1} is not a number", line=number, frame=frame
                ) from None
            if not np.isfinite(value):
                raise DataFormatError(path, f"{word!r} in column {column + 1} is not finite", line=number, frame=frame)
        frame += 1
    if frame == frames:
        raise DataFormatError(path, "frame lines hold values NumPy cannot read as numbers", line=first_line)
    raise DataFormatError(
        path,
        f"file ends after {frame} frame lines but Frames: says {frames} (truncated?)",
        line=first_line + len(lines) - 1,
    )


def write_bvh(path: str | Path, motion: BVHMotion, *, units: str = "cm") -> None:
    """Write ``motion`` as BVH (gzip-compressed when ``path`` ends in ``.gz``), atomically.

    Offsets and position channels are written in ``units``; rotations in degrees, channels in the skeleton's
    order, numbers with 10 significant digits. End Sites are written as ``End Site`` blocks (their names are
    not stored by the format and come back as ``<parent>_end``).
    """
    if units not in UNIT_SCALES:
        raise ValueError(f"units must be one of {', '.join(UNIT_SCALES)}, got {units!r}")
    skeleton = motion.skeleton
    lines = ["HIERARCHY"]
    children: list[list[int]] = [[] for _ in range(skeleton.n_joints)]
    for j, parent in enumerate(skeleton.parents):
        if parent >= 0:
            children[parent].append(j)
    offsets = skeleton.offsets / UNIT_SCALES[units]

    def emit(j: int, depth: int) -> None:
        pad = "  " * depth
        if skeleton.end_sites[j]:
            lines.append(f"{pad}End Site")
        else:
            lines.append(f"{pad}{'ROOT' if skeleton.parents[j] < 0 else 'JOINT'} {skeleton.names[j]}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET " + " ".join(_NUMBER_FORMAT % v for v in offsets[j]))
        if not skeleton.end_sites[j]:
            lines.append(f"{pad}  CHANNELS " + " ".join([str(len(skeleton.channels[j])), *skeleton.channels[j]]))
        for child in children[j]:
            emit(child, depth + 1)
        lines.append(pad + "}")

    for root in (j for j, parent in enumerate(skeleton.parents) if parent < 0):
        emit(root, 0)
    values = motion.values.copy()
    _, _, position_columns = skeleton._position_columns
    values[:, position_columns] *= UNIT_SCALES[motion.units] / UNIT_SCALES[units]
    lines += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {_NUMBER_FORMAT % motion.frame_time}"]
    buffer = io.StringIO()
    buffer.write("\n".join(lines) + "\n")
    np.savetxt(buffer, values, fmt=_NUMBER_FORMAT, delimiter=" ")
    payload = buffer.getvalue().encode("utf-8")
    if Path(path).name.endswith(".gz"):
        payload = gzip.compress(payload, mtime=0)
    with atomic_write(path, "wb") as handle:
        handle.write(payload)
