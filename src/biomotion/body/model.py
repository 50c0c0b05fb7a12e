"""`BodyModel`: the tensors of an OpenSim model that kinematics and dynamics need, built from a `ModelSpec`.

As in Pinocchio (Carpentier et al. 2019, SII) the model is constant data and every algorithm is a function of
(model, state); nothing here changes after construction (scaling returns a new model). Conventions follow
OpenSim 4 / Simbody (Seth et al. 2018; Sherman et al. 2011):

- bodies are in BodySet order; ``parent[b]`` is the parent body index or -1 for ground; ``joint_order`` lists the
  joints parents-first (topological order) for the recursive algorithms;
- coordinates are in CoordinateSet order (each joint's coordinates in JointSet order), which is
  ``model.getCoordinateSet()``'s order in OpenSim;
- a joint connects frame F (fixed on the parent body: ``parent_rotation``, ``parent_translation``) to frame M
  (fixed on the child body: ``child_rotation``, ``child_translation``); its motion X_FM(q) is the CustomJoint
  spatial transform: rotations about the (normalised) rotation axes applied in order as body-fixed rotations,
  then translation along the translation axes expressed in F, each axis amount a function of one coordinate;
- offset frame orientations are body-fixed X-Y-Z Euler angles, as OpenSim's PhysicalOffsetFrame;
- inertias are about the centre of mass, in the body frame.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import torch

from biomotion.body.functions import Constant, Function, build_function
from biomotion.body.spatial import body_fixed_xyz
from biomotion.errors import ModelError
from biomotion.io import osim


@dataclass(frozen=True)
class Axis:
    """One non-trivial transform axis: amount = ``scale * function(q[coordinate])`` (rad or m) along ``axis``."""

    rotation: bool
    axis: torch.Tensor  # [3], unit
    function: Function
    coordinate: int | None  # None: the function is a constant
    scale: torch.Tensor  # [], OpenSim's MultiplierFunction scale applied by scaling
    slot: int  # which TransformAxis: 0-2 rotation1-3, 3-5 translation1-3

    def amount(self, q: torch.Tensor) -> torch.Tensor:
        """[...] amount at coordinates ``q`` [..., n_q]."""
        return self.scale * self.function(self._argument(q))

    def derivatives(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """[...] amount and its first and second derivatives with respect to its coordinate."""
        f, d1, d2 = self.function.derivatives(self._argument(q))
        return self.scale * f, self.scale * d1, self.scale * d2

    def _argument(self, q: torch.Tensor) -> torch.Tensor:
        return q[..., self.coordinate] if self.coordinate is not None else q.new_zeros(q.shape[:-1])


@dataclass(frozen=True)
class JointModel:
    name: str
    type: str
    parent: int  # body index, -1 = ground
    child: int  # body index
    parent_rotation: torch.Tensor  # [3, 3] R_PF: frame F in the parent body
    parent_translation: torch.Tensor  # [3]    p_PF
    child_rotation: torch.Tensor  # [3, 3] R_BM: frame M in the child body
    child_translation: torch.Tensor  # [3]    p_BM
    coordinates: tuple[int, ...]
    axes: tuple[Axis, ...]  # rotations (in order) first, then translations


@dataclass(frozen=True)
class Coupler:
    """``q[dependent] = scale_factor * function(q[independent])`` (OpenSim's CoordinateCouplerConstraint)."""

    name: str
    dependent: int
    independent: int
    function: Function
    scale_factor: float


@dataclass(frozen=True)
class BodyModel:
    """An OpenSim model as tensors (see the module docstring for conventions). ``spec`` is the parsed file as
    loaded; after scaling, the tensors (and ``body_scales``) hold the scaled values and ``spec`` does not."""

    name: str
    spec: osim.ModelSpec
    body_names: tuple[str, ...]
    parent: tuple[int, ...]
    masses: torch.Tensor  # [B]
    coms: torch.Tensor  # [B, 3] in the body frame
    inertias: torch.Tensor  # [B, 3, 3] about the COM, body frame
    joints: tuple[JointModel, ...]  # JointSet order
    joint_order: tuple[int, ...]  # indices into joints, parents first
    coordinate_names: tuple[str, ...]
    coordinate_joint: tuple[int, ...]  # joint index of each coordinate
    motion_types: tuple[str, ...]
    ranges: torch.Tensor  # [n_q, 2]
    defaults: torch.Tensor  # [n_q]
    clamped: torch.Tensor  # [n_q] bool
    locked: torch.Tensor  # [n_q] bool
    couplers: tuple[Coupler, ...]  # dependency order
    marker_names: tuple[str, ...]
    marker_bodies: torch.Tensor  # [M] long, -1 = ground
    marker_offsets: torch.Tensor  # [M, 3] in the body frame
    gravity: torch.Tensor  # [3]
    body_scales: torch.Tensor  # [B, 3] scale factors applied since loading (for meshes); ones when unscaled

    # ---- construction ------------------------------------------------------------------------------------------
    @classmethod
    def from_osim(cls, path: str | Path, dtype: torch.dtype = torch.float64) -> BodyModel:
        """Load an OpenSim 4 model file."""
        return cls.from_spec(osim.read_osim(path), dtype)

    @classmethod
    def from_spec(cls, spec: osim.ModelSpec, dtype: torch.dtype = torch.float64) -> BodyModel:
        return _build(spec).to(dtype)

    # ---- look-ups ----------------------------------------------------------------------------------------------
    @property
    def n_q(self) -> int:
        return len(self.coordinate_names)

    @property
    def n_bodies(self) -> int:
        return len(self.body_names)

    @property
    def dtype(self) -> torch.dtype:
        return self.masses.dtype

    @property
    def total_mass(self) -> torch.Tensor:
        return self.masses.sum()

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def body_index(self, name: str) -> int:
        try:
            return self.body_names.index(name)
        except ValueError:
            raise ModelError(f"model {self.name!r} has no body {name!r}") from None

    def coordinate_index(self, name: str) -> int:
        try:
            return self.coordinate_names.index(name)
        except ValueError:
            raise ModelError(f"model {self.name!r} has no coordinate {name!r}") from None

    def marker_index(self, name: str) -> int:
        try:
            return self.marker_names.index(name)
        except ValueError:
            raise ModelError(f"model {self.name!r} has no marker {name!r}") from None

    def default_q(self) -> torch.Tensor:
        return self.defaults.clone()

    def frame_in_body(self, path: str) -> tuple[int, torch.Tensor, torch.Tensor]:
        """(body index or -1 for ground, R [3, 3], p [3]) of a frame path of the spec, relative to its body,
        with the body's scale factors applied to the translation."""
        body, rotation, translation = _FrameResolver(self.spec).resolve(path)
        translation = translation.to(self.dtype)
        if body >= 0:
            translation = translation * self.body_scales[body]
        return body, rotation.to(self.dtype), translation

    # ---- conversion --------------------------------------------------------------------------------------------
    def to(self, dtype: torch.dtype) -> BodyModel:
        """The same model with every floating tensor in ``dtype``."""
        return _map_tensors(self, dtype)


def _map_tensors(obj, dtype: torch.dtype):
    if isinstance(obj, torch.Tensor):
        return obj.to(dtype) if obj.is_floating_point() else obj
    if isinstance(obj, tuple):
        return tuple(_map_tensors(o, dtype) for o in obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, osim.ModelSpec) and not isinstance(obj, type):
        return dataclasses.replace(
            obj, **{f.name: _map_tensors(getattr(obj, f.name), dtype) for f in dataclasses.fields(obj) if f.init}
        )
    if hasattr(obj, "to") and callable(obj) and not isinstance(obj, torch.Tensor):  # torch functions
        return obj.to(dtype)
    return obj


# ---- building -------------------------------------------------------------------------------------------------


class _FrameResolver:
    def __init__(self, spec: osim.ModelSpec) -> None:
        self.spec = spec
        self.bodies = {b.path: i for i, b in enumerate(spec.bodies)}
        self.offsets = {f.path: f for f in spec.frames}

    def resolve(self, path: str, depth: int = 0) -> tuple[int, torch.Tensor, torch.Tensor]:
        if path == osim.GROUND:
            return -1, torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
        if path in self.bodies:
            return self.bodies[path], torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
        if path not in self.offsets or depth > 32:
            raise ModelError(
                f"{self.spec.path}: frame {path!r} is not a body, ground or offset frame (or its offset chain loops)"
            )
        frame = self.offsets[path]
        body, r_parent, p_parent = self.resolve(frame.parent, depth + 1)
        r_local = body_fixed_xyz(torch.tensor(frame.orientation, dtype=torch.float64))
        p_local = torch.tensor(frame.translation, dtype=torch.float64)
        return body, r_parent @ r_local, p_parent + r_parent @ p_local


def _inertia_matrix(i: osim.Inertia) -> list[list[float]]:
    return [[i.xx, i.xy, i.xz], [i.xy, i.yy, i.yz], [i.xz, i.yz, i.zz]]


def _axes(spec: osim.ModelSpec, joint: osim.JointSpec, coordinate_index: dict[str, int]) -> tuple[Axis, ...]:
    axes = []
    for slot, t in enumerate(joint.transform):
        function = build_function(t.function)
        if isinstance(function, Constant) and function.value == 0.0:
            continue  # no motion along this axis
        axis = torch.tensor(t.axis, dtype=torch.float64)
        axes.append(
            Axis(
                t.name.startswith("rotation"),
                axis / torch.linalg.vector_norm(axis),
                function,
                coordinate_index[t.coordinates[0]] if t.coordinates else None,
                torch.tensor(1.0, dtype=torch.float64),
                slot,
            )
        )
    return tuple(axes)


def _topological(spec: osim.ModelSpec, parents: list[int], children: list[int]) -> tuple[int, ...]:
    order, placed = [], {-1}
    remaining = list(range(len(spec.joints)))
    while remaining:
        ready = [j for j in remaining if parents[j] in placed]
        if not ready:
            names = [spec.joints[j].name for j in remaining]
            raise ModelError(f"{spec.path}: joints {names} do not connect to ground (a loop or a reversed joint)")
        for j in ready:
            order.append(j)
            placed.add(children[j])
            remaining.remove(j)
    return tuple(order)


def _coupler_order(spec: osim.ModelSpec, couplers: list[Coupler]) -> tuple[Coupler, ...]:
    ordered, done, pending = [], set(), list(couplers)
    dependents = {c.dependent for c in couplers}
    while pending:
        ready = [c for c in pending if c.independent not in dependents or c.independent in done]
        if not ready:
            raise ModelError(f"{spec.path}: coordinate couplers form a cycle")
        for c in ready:
            ordered.append(c)
            done.add(c.dependent)
            pending.remove(c)
    return tuple(ordered)


def _build(spec: osim.ModelSpec) -> BodyModel:
    frames = _FrameResolver(spec)
    coordinate_index = {c.name: i for i, c in enumerate(spec.coordinates)}
    joint_of_child: dict[int, str] = {}
    joints, parents, children = [], [], []
    for joint in spec.joints:
        parent, r_pf, p_pf = frames.resolve(joint.parent_frame)
        child, r_bm, p_bm = frames.resolve(joint.child_frame)
        if child < 0:
            raise ModelError(
                f"{spec.path}: joint {joint.name!r} has ground as its child (reversed joints are not supported)"
            )
        if child in joint_of_child:
            raise ModelError(
                f"{spec.path}: body {spec.bodies[child].name!r} is the child of joints "
                f"{joint_of_child[child]!r} and {joint.name!r} (kinematic loops are not supported)"
            )
        if child == parent:
            raise ModelError(f"{spec.path}: joint {joint.name!r} connects body {spec.bodies[child].name!r} to itself")
        joint_of_child[child] = joint.name
        joints.append(
            JointModel(
                joint.name,
                joint.type,
                parent,
                child,
                r_pf,
                p_pf,
                r_bm,
                p_bm,
                tuple(coordinate_index[c] for c in joint.coordinates),
                _axes(spec, joint, coordinate_index),
            )
        )
        parents.append(parent)
        children.append(child)
    loose = [b.name for i, b in enumerate(spec.bodies) if i not in joint_of_child]
    if loose:
        raise ModelError(f"{spec.path}: bodies {loose} have no joint to a parent")
    order = _topological(spec, parents, children)
    parent_of_body = [-1] * len(spec.bodies)
    for joint in joints:
        parent_of_body[joint.child] = joint.parent

    couplers = [
        Coupler(
            c.name,
            coordinate_index[c.dependent],
            coordinate_index[c.independent[0]],
            build_function(c.function),
            c.scale_factor,
        )
        for c in spec.couplers
    ]
    marker_bodies, marker_offsets = [], []
    for marker in spec.markers:
        body, rotation, translation = frames.resolve(marker.frame)
        marker_bodies.append(body)
        marker_offsets.append(translation + rotation @ torch.tensor(marker.location, dtype=torch.float64))
    joint_index = {j.name: i for i, j in enumerate(spec.joints)}
    f64 = torch.float64
    return BodyModel(
        name=spec.name,
        spec=spec,
        body_names=tuple(b.name for b in spec.bodies),
        parent=tuple(parent_of_body),
        masses=torch.tensor([b.mass for b in spec.bodies], dtype=f64),
        coms=torch.tensor([b.mass_center for b in spec.bodies], dtype=f64).reshape(-1, 3),
        inertias=torch.tensor([_inertia_matrix(b.inertia) for b in spec.bodies], dtype=f64).reshape(-1, 3, 3),
        joints=tuple(joints),
        joint_order=order,
        coordinate_names=tuple(c.name for c in spec.coordinates),
        coordinate_joint=tuple(joint_index[c.joint] for c in spec.coordinates),
        motion_types=tuple(c.motion_type for c in spec.coordinates),
        ranges=torch.tensor([c.range for c in spec.coordinates], dtype=f64).reshape(-1, 2),
        defaults=torch.tensor([c.default_value for c in spec.coordinates], dtype=f64),
        clamped=torch.tensor([c.clamped for c in spec.coordinates], dtype=torch.bool),
        locked=torch.tensor([c.locked for c in spec.coordinates], dtype=torch.bool),
        couplers=_coupler_order(spec, couplers),
        marker_names=tuple(m.name for m in spec.markers),
        marker_bodies=torch.tensor(marker_bodies, dtype=torch.long),
        marker_offsets=torch.stack(marker_offsets) if marker_offsets else torch.zeros(0, 3, dtype=f64),
        gravity=torch.tensor(spec.gravity, dtype=f64),
        body_scales=torch.ones(len(spec.bodies), 3, dtype=f64),
    )
