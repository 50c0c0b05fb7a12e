"""`Scene`: what the viewer draws, frame by frame, whatever the motion came from.

A scene is a clock (``times`` [T]) and things that move on it, all in OpenSim's ground frame (y up, metres):

- rigid bodies, each a pose per frame (rotation ``R`` [T, 3, 3], origin ``p`` [T, 3]) carrying meshes and capsules
  given in the body's own frame, so a vertex ``v`` is drawn at ``R @ v + p``;
- point sets (markers, joint centres) [T, K, 3] with optional links between points; NaN hides a point;
- arrows (ground reaction forces from the centre of pressure), COM and ZMP points, a support polygon per frame;
- muscle activations [T, M] in [0, 1].

Builders make scenes from `Markers`, from BVH clips, from a `GroundReaction` and from coordinates moving a body
model (forward kinematics gives each body's pose, the model's ``.vtp`` meshes its shape). Anything on another
clock is linearly interpolated onto the scene's; frames outside the source's time span are NaN (hidden).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from biomotion.errors import DataFormatError
from biomotion.motion import GroundReaction, Markers, Motion

if TYPE_CHECKING:  # the body model needs torch, which only `model_scene` imports
    from biomotion.body.model import BodyModel
    from biomotion.io.bvh import BVHMotion

FORCE_SCALE = 1e-3
"""Metres of arrow per newton: body weight (~700 N) draws as a 0.7 m arrow."""

FORCE_THRESHOLD = 20.0
"""Newtons below which a ground reaction is not drawn (its centre of pressure is meaningless)."""


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh: ``vertices`` [V, 3] (metres, in the frame of the body that carries it), ``triangles``
    [F, 3] vertex indices, counter-clockwise seen from outside."""

    vertices: np.ndarray
    triangles: np.ndarray

    def __post_init__(self) -> None:
        vertices = np.asarray(self.vertices, dtype=float)
        triangles = np.asarray(self.triangles, dtype=np.int64)
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "triangles", triangles)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.all(np.isfinite(vertices)):
            raise DataFormatError(None, f"mesh vertices must be finite [V, 3], got shape {vertices.shape}")
        if triangles.ndim != 2 or triangles.shape[1] != 3:
            raise DataFormatError(None, f"mesh triangles must be [F, 3], got shape {triangles.shape}")
        if triangles.size and (triangles.min() < 0 or triangles.max() >= len(vertices)):
            raise DataFormatError(None, f"mesh triangle index out of range [0, {len(vertices)})")

    def scaled(self, factors: Sequence[float]) -> Mesh:
        """The mesh stretched by ``factors`` (x, y, z) in its frame (OpenSim's ``scale_factors``)."""
        return Mesh(self.vertices * np.asarray(factors, dtype=float), self.triangles)

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> Mesh:
        """The mesh moved into a parent frame: ``R @ v + p`` (e.g. from an offset frame into its body)."""
        return Mesh(
            self.vertices @ np.asarray(rotation, dtype=float).T + np.asarray(translation, dtype=float), self.triangles
        )


@dataclass(frozen=True, eq=False)
class Capsule:
    """A cylinder with hemispherical ends around the segment ``start``-``end`` (body frame, metres)."""

    start: np.ndarray
    end: np.ndarray
    radius: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", np.asarray(self.start, dtype=float).reshape(3))
        object.__setattr__(self, "end", np.asarray(self.end, dtype=float).reshape(3))
        if not self.radius > 0:
            raise DataFormatError(None, f"capsule radius must be positive, got {self.radius}")

    def mesh(self, sides: int = 10, rings: int = 3) -> Mesh:
        """Triangles of the capsule surface: ``sides`` around the axis, ``rings`` per hemispherical cap."""
        axis = self.end - self.start
        length = float(np.linalg.norm(axis))
        w = axis / length if length > 0 else np.array([0.0, 1.0, 0.0])
        helper = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        u = np.cross(w, helper)
        u /= np.linalg.norm(u)
        v = np.cross(w, u)
        # latitude from the start pole (-pi/2) to the end pole (+pi/2); the equator is doubled to make the cylinder
        latitude = np.concatenate(
            [np.linspace(-np.pi / 2, 0, rings + 1)[1:], np.linspace(0, np.pi / 2, rings + 1)[:-1]]
        )
        along = np.where(np.arange(latitude.size) < rings, 0.0, length)
        angle = 2 * np.pi * np.arange(sides) / sides
        ring_points = (
            np.cos(latitude)[:, None, None] * (np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * v)
            + np.sin(latitude)[:, None, None] * w
        ) * self.radius + along[:, None, None] * w
        body = ring_points.reshape(-1, 3) + self.start
        poles = np.stack([self.start - self.radius * w, self.end + self.radius * w])
        vertices = np.concatenate([body, poles])
        n_rings, south, north = latitude.size, len(body), len(body) + 1
        r, s = np.meshgrid(np.arange(n_rings - 1), np.arange(sides), indexing="ij")
        a, b = r * sides + s, r * sides + (s + 1) % sides
        c, d = a + sides, b + sides
        quads = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
        first, last = np.arange(sides), (n_rings - 1) * sides + np.arange(sides)
        caps = np.concatenate(
            [
                np.stack([np.full(sides, south), (first + 1) % sides, first], -1),
                np.stack([np.full(sides, north), last, (n_rings - 1) * sides + (first + 1) % sides], -1),
            ]
        )
        return Mesh(vertices, np.concatenate([quads, caps]))


@dataclass(frozen=True, eq=False)
class Body:
    """A rigid body: pose per frame (``rotations`` [T, 3, 3], ``positions`` [T, 3]; NaN position = hidden) and
    the shapes it carries, in its own frame."""

    name: str
    rotations: np.ndarray
    positions: np.ndarray
    meshes: tuple[Mesh, ...] = ()
    capsules: tuple[Capsule, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "rotations", np.asarray(self.rotations, dtype=float))
        object.__setattr__(self, "positions", np.asarray(self.positions, dtype=float))
        object.__setattr__(self, "meshes", tuple(self.meshes))
        object.__setattr__(self, "capsules", tuple(self.capsules))
        frames = self.positions.shape[0] if self.positions.ndim == 2 else -1
        if self.positions.shape != (frames, 3) or self.rotations.shape != (frames, 3, 3):
            raise DataFormatError(
                None,
                f"body {self.name!r}: rotations {self.rotations.shape} and positions "
                f"{self.positions.shape} must be [T, 3, 3] and [T, 3]",
                field=self.name,
            )

    def surface(self) -> Mesh:
        """All meshes and tessellated capsules of the body as one mesh (body frame)."""
        parts = list(self.meshes) + [capsule.mesh() for capsule in self.capsules]
        if not parts:
            return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
        offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
        return Mesh(
            np.concatenate([p.vertices for p in parts]),
            np.concatenate([p.triangles + o for p, o in zip(parts, offsets)]),
        )


@dataclass(frozen=True, eq=False)
class PointSet:
    """Points over time (``positions`` [T, K, 3], NaN = hidden), with optional ``links`` [L, 2] drawn as lines."""

    name: str
    positions: np.ndarray
    labels: tuple[str, ...] = ()
    links: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))

    def __post_init__(self) -> None:
        positions = np.asarray(self.positions, dtype=float)
        links = np.asarray(self.links, dtype=np.int64).reshape(-1, 2)
        object.__setattr__(self, "positions", positions)
        object.__setattr__(self, "links", links)
        object.__setattr__(self, "labels", tuple(self.labels))
        if positions.ndim != 3 or positions.shape[2] != 3:
            raise DataFormatError(
                None, f"points {self.name!r} must be [T, K, 3], got {positions.shape}", field=self.name
            )
        if self.labels and len(self.labels) != positions.shape[1]:
            raise DataFormatError(None, f"{len(self.labels)} labels for {positions.shape[1]} points", field=self.name)
        if links.size and (links.min() < 0 or links.max() >= positions.shape[1]):
            raise DataFormatError(None, f"link index out of range [0, {positions.shape[1]})", field=self.name)


@dataclass(frozen=True, eq=False)
class ArrowSet:
    """Arrows from ``origins`` [T, A, 3] along ``vectors`` [T, A, 3], both in metres as drawn; NaN = hidden."""

    name: str
    origins: np.ndarray
    vectors: np.ndarray
    labels: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "origins", np.asarray(self.origins, dtype=float))
        object.__setattr__(self, "vectors", np.asarray(self.vectors, dtype=float))
        object.__setattr__(self, "labels", tuple(self.labels))
        if self.origins.ndim != 3 or self.origins.shape[2] != 3 or self.vectors.shape != self.origins.shape:
            raise DataFormatError(
                None,
                f"arrows {self.name!r}: origins {self.origins.shape} and vectors "
                f"{self.vectors.shape} must both be [T, A, 3]",
                field=self.name,
            )


@dataclass(frozen=True, eq=False)
class Activations:
    """Muscle activations [T, M] (0 = at rest, 1 = fully active), one column per name in ``names``."""

    names: tuple[str, ...]
    values: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "values", np.asarray(self.values, dtype=float))
        if self.values.ndim != 2 or self.values.shape[1] != len(self.names):
            raise DataFormatError(None, f"activations {self.values.shape} do not match {len(self.names)} muscles")


@dataclass(frozen=True, eq=False)
class Scene:
    """Everything the viewer draws for one motion, on the clock ``times`` [T] (seconds, increasing).

    ``com`` and ``zmp`` are [T, 3]; ``support`` is [T, P, 3], one polygon per frame, vertices in order around it,
    rows of NaN after the last vertex of a frame whose polygon has fewer than P.
    """

    times: np.ndarray
    name: str = "motion"
    bodies: tuple[Body, ...] = ()
    points: tuple[PointSet, ...] = ()
    arrows: tuple[ArrowSet, ...] = ()
    com: np.ndarray | None = None
    zmp: np.ndarray | None = None
    support: np.ndarray | None = None
    activations: Activations | None = None

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=float)
        object.__setattr__(self, "times", times)
        for name in ("bodies", "points", "arrows"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if times.ndim != 1 or times.size == 0 or not np.all(np.isfinite(times)):
            raise DataFormatError(None, f"scene {self.name!r}: times must be finite [T], T >= 1")
        if np.any(np.diff(times) <= 0):
            frame = int(np.flatnonzero(np.diff(times) <= 0)[0]) + 1
            raise DataFormatError(None, f"scene {self.name!r}: time does not increase", frame=frame)
        timed = [(f"body {b.name!r}", b.positions) for b in self.bodies]
        timed += [(f"points {p.name!r}", p.positions) for p in self.points]
        timed += [(f"arrows {a.name!r}", a.origins) for a in self.arrows]
        for name in ("com", "zmp", "support"):
            array = getattr(self, name)
            if array is not None:
                array = np.asarray(array, dtype=float)
                object.__setattr__(self, name, array)
                shape_ok = (
                    array.shape == (times.size, 3) if name != "support" else (array.ndim == 3 and array.shape[2] == 3)
                )
                if not shape_ok:
                    raise DataFormatError(None, f"scene {self.name!r}: {name} has shape {array.shape}", field=name)
                timed.append((name, array))
        if self.activations is not None:
            timed.append(("activations", self.activations.values))
        for what, array in timed:
            if array.shape[0] != times.size:
                raise DataFormatError(
                    None, f"scene {self.name!r}: {what} has {array.shape[0]} frames, the clock has {times.size}"
                )

    @property
    def n_frames(self) -> int:
        return int(self.times.size)

    def with_points(
        self, markers: Markers, *, links: np.ndarray | Sequence[tuple[int, int]] = (), name: str = "markers"
    ) -> Scene:
        """Add marker trajectories (resampled onto the scene clock)."""
        positions = on_clock(markers.times, markers.positions, self.times)
        return replace(self, points=self.points + (PointSet(name, positions, markers.names, np.asarray(links)),))

    def with_ground_reaction(
        self,
        forces: GroundReaction,
        *,
        scale: float = FORCE_SCALE,
        threshold: float = FORCE_THRESHOLD,
        name: str = "GRF",
    ) -> Scene:
        """Add one arrow per force channel, from its centre of pressure, ``scale`` metres per newton.

        A channel is hidden in frames where its force is below ``threshold`` N or its CoP is undefined (NaN).
        """
        force = on_clock(forces.times, forces.force, self.times)
        cop = on_clock(forces.times, forces.cop, self.times)
        hidden = (
            (np.linalg.norm(force, axis=-1) < threshold)
            | ~np.isfinite(cop).all(axis=-1)
            | ~np.isfinite(force).all(axis=-1)
        )
        cop[hidden] = np.nan
        arrows = ArrowSet(name, cop, np.where(hidden[..., None], np.nan, force * scale), forces.names)
        return replace(self, arrows=self.arrows + (arrows,))

    def with_balance(
        self,
        times: np.ndarray,
        *,
        com: np.ndarray | None = None,
        zmp: np.ndarray | None = None,
        support: np.ndarray | None = None,
    ) -> Scene:
        """Add the centre of mass [N, 3], zero-moment point [N, 3] and support polygons [N, P, 3] given at
        ``times`` [N] (support polygons are taken from the nearest earlier sample, not interpolated)."""
        changes = {}
        if com is not None:
            changes["com"] = on_clock(times, com, self.times)
        if zmp is not None:
            changes["zmp"] = on_clock(times, zmp, self.times)
        if support is not None:
            support = np.asarray(support, dtype=float)
            index = np.searchsorted(np.asarray(times, dtype=float), self.times + 1e-9, side="right") - 1
            outside = (index < 0) | (self.times > times[-1] + 1e-9)
            picked = support[np.clip(index, 0, len(times) - 1)].copy()
            picked[outside] = np.nan
            changes["support"] = picked
        return replace(self, **changes)

    def with_activations(self, times: np.ndarray, names: Sequence[str], values: np.ndarray) -> Scene:
        """Add muscle activations [N, M] given at ``times`` [N]."""
        return replace(self, activations=Activations(tuple(names), on_clock(times, values, self.times)))

    def frame_of(self, times: np.ndarray) -> np.ndarray:
        """Index of the scene frame nearest to each of ``times`` (clamped to the clip)."""
        right = np.clip(np.searchsorted(self.times, times), 0, self.n_frames - 1)
        left = np.clip(right - 1, 0, self.n_frames - 1)
        return np.where(np.abs(self.times[left] - times) <= np.abs(self.times[right] - times), left, right)


def on_clock(source_times: np.ndarray, values: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``values`` [N, ...] sampled at ``source_times`` [N], linearly interpolated at ``times`` [T] along axis 0.

    Frames outside the source's span are NaN. A NaN sample hides the frames interpolated from it, except a frame
    that falls on a sample time, which takes that sample as it is.
    """
    source_times = np.asarray(source_times, dtype=float)
    values = np.asarray(values, dtype=float)
    times = np.asarray(times, dtype=float)
    if source_times.shape == times.shape and np.allclose(source_times, times, rtol=0, atol=1e-9):
        return values.copy()
    tolerance = 1e-9
    left = np.clip(np.searchsorted(source_times, times + tolerance, side="right") - 1, 0, source_times.size - 1)
    right = np.minimum(left + 1, source_times.size - 1)
    span = source_times[right] - source_times[left]
    offset = times - source_times[left]
    weight = np.divide(offset, span, out=np.zeros_like(offset), where=(span > 0) & (offset > tolerance))
    w = weight.reshape((-1,) + (1,) * (values.ndim - 1))
    before, after = values[left], values[right]
    out = np.where(w == 0, before, before + w * (after - before))
    outside = (times < source_times[0] - tolerance) | (times > source_times[-1] + tolerance)
    out[outside] = np.nan
    return out


def parent_links(parents: Sequence[int]) -> np.ndarray:
    """Links [L, 2] (parent, child) of a skeleton given each joint's parent index (-1 for a root)."""
    return np.array([(p, j) for j, p in enumerate(parents) if p >= 0], dtype=np.int64).reshape(-1, 2)


def markers_scene(
    markers: Markers, *, links: np.ndarray | Sequence[tuple[int, int]] = (), name: str = "markers"
) -> Scene:
    """A scene on the markers' clock showing them as points (C3D, TRC, joint positions of any skeleton)."""
    return Scene(markers.times, name=name).with_points(markers, links=links, name=name)


BONE_MAX_LENGTH = 0.75
"""Metres: a parent-child offset longer than this places a figure in the room rather than being a bone."""


def bvh_scene(clip: BVHMotion, *, name: str = "bvh", radius_ratio: float = 0.08) -> Scene:
    """A scene of a BVH clip: one body per joint carrying capsules to its children,
    plus the joints at the ends of those bones as points.

    A child is drawn as a bone (a capsule of radius ``radius_ratio`` x its length, within 1.5-4 cm) when its offset
    from the parent is constant through the clip and between 1 mm and `BONE_MAX_LENGTH`; offsets that move (the
    root translation of `Hips` below a `joint_Root`) or are long place the figure in the room.
    """
    skeleton = clip.skeleton
    rotations, positions = clip.global_transforms()
    translations = clip.local_translations()
    rigid = np.ptp(translations, axis=0).max(axis=1) < 1e-3
    lengths = np.linalg.norm(translations[0], axis=1)
    bone = rigid & (lengths > 1e-3) & (lengths < BONE_MAX_LENGTH) & (np.asarray(skeleton.parents) >= 0)
    bodies = []
    for j, joint in enumerate(skeleton.names):
        children = [c for c, p in enumerate(skeleton.parents) if p == j and bone[c]]
        if children:
            capsules = tuple(
                Capsule(np.zeros(3), translations[0, c], float(np.clip(radius_ratio * lengths[c], 0.015, 0.04)))
                for c in children
            )
            bodies.append(Body(joint, rotations[:, j], positions[:, j], capsules=capsules))
    drawn = {skeleton.index(b.name) for b in bodies} | set(np.flatnonzero(bone).tolist())
    joints = sorted(j for j in drawn if not skeleton.end_sites[j])
    points = PointSet("joints", positions[:, joints], tuple(skeleton.names[j] for j in joints))
    return Scene(clip.times, name=name, bodies=tuple(bodies), points=(points,))


def geometry_folders(model_path: str | Path) -> list[Path]:
    """Where OpenSim looks for a model's mesh files: the model's folder, its ``Geometry`` subfolder, and the
    ``Geometry`` folders one and two levels up (the layout of opensim-models, whose Rajagopal model shares
    ``opensim-models/Geometry``)."""
    folder = Path(model_path).resolve().parent
    return [folder, folder / "Geometry", folder.parent / "Geometry", folder.parent.parent / "Geometry"]


def model_scene(model: BodyModel, motion: Motion, *, folders: Sequence[str | Path] = (), name: str = "motion") -> Scene:
    """A scene of ``motion`` (coordinates) moving ``model``: body poses by forward kinematics, each body's meshes
    (``.vtp`` files found in ``folders``, scaled by their ``scale_factors``; other mesh formats are not read), and
    capsules from the body's joint to its children's joints for bodies with no mesh found; the model's markers as
    points.

    Coordinates the motion lacks (or masks) take the model's defaults; coupled coordinates follow their couplers.
    """
    import torch

    from biomotion.body.kinematics import apply_couplers, forward_kinematics, marker_positions
    from biomotion.io.vtp import read_vtp

    selected = motion.select(model.coordinate_names)
    q = torch.where(torch.as_tensor(selected.mask), torch.as_tensor(selected.values, dtype=model.dtype), model.defaults)
    q = apply_couplers(model, q)
    poses = forward_kinematics(model, q)
    rotations, positions = poses.rotations.detach().numpy(), poses.positions.detach().numpy()
    bodies = []
    for b, spec in enumerate(model.spec.bodies):
        meshes = []
        for mesh in (m for m in spec.meshes if m.mesh_file.lower().endswith(".vtp")):
            found = next((Path(f) / mesh.mesh_file for f in folders if (Path(f) / mesh.mesh_file).is_file()), None)
            if found is not None:
                _, rotation, translation = model.frame_in_body(mesh.frame)
                meshes.append(
                    Mesh(*read_vtp(found))
                    .scaled(mesh.scale_factors)
                    .transformed(rotation.detach().numpy(), translation.detach().numpy())
                )
        capsules = () if meshes else _skeleton_capsules(model, b)
        bodies.append(Body(spec.name, rotations[:, b], positions[:, b], tuple(meshes), capsules))
    points = ()
    if model.marker_names:
        markers = marker_positions(model, q, poses).detach().numpy()
        points = (PointSet("model markers", markers, model.marker_names),)
    return Scene(motion.times, name=name, bodies=tuple(bodies), points=points)


def _skeleton_capsules(model: BodyModel, body: int, radius_ratio: float = 0.1) -> tuple[Capsule, ...]:
    """Capsules from where ``body`` hangs on its parent to where each child hangs on it (body frame); a small
    sphere for a body without children."""
    own = next((j for j in model.joints if j.child == body), None)
    start = np.zeros(3) if own is None else own.child_translation.detach().numpy()
    ends = [j.parent_translation.detach().numpy() for j in model.joints if j.parent == body]
    capsules = tuple(
        Capsule(start, end, float(np.clip(radius_ratio * np.linalg.norm(end - start), 0.015, 0.05)))
        for end in ends
        if np.linalg.norm(end - start) > 1e-3
    )
    return capsules or (Capsule(start, start, 0.025),)
