"""Control targets for PG-BIG generation through guidance: a spec read from YAML and its differentiable loss.

FlexMotion Sec. 3.3 controls a diffusion model's joints, torques, contact forces and activations with a trained
control branch; PG-BIG (Sec. 3.3) already refines its sampled latents by gradient descent on biomechanical losses,
so the same kind of targets can be met there by one more guidance term. This module holds that term.

A spec (``examples/control/*.yaml``) is a list of targets::

    targets:
      - quantity: grf_vertical   # grf_vertical (body weights), joint_angle (needs coordinate), com_height (m),
        kind: max                # joint_position (needs body), joint_torque (needs coordinate)
        value: 2.2               # max: upper bound over the window; min: lower bound; value: equal at times;
        window: [0.0, 2.0]       # path: a body origin through points; omitted window: the whole clip
        weight: 1000             # multiplies the target's loss inside the guidance sum (default 1000)
      - quantity: joint_angle
        coordinate: knee_angle_r # a canonical coordinate (`biomotion.body.canonical.CANONICAL_COORDINATES`)
        kind: value
        times: [0.5, 1.0]        # s; kind value only
        value: 40                # degrees for rotational coordinates, m for pelvis translations
      - quantity: joint_position
        body: hand_r             # a canonical body (`biomotion.body.canonical.CANONICAL_BODIES`): its origin
        kind: path               # path: points [t (s), x, y, z (m)]; value: value [x, y, z] at times
        path: [[0.0, 0.3, 1.2, 0.25], [0.5, 0.5, 1.3, 0.25]]
      - quantity: joint_torque
        coordinate: knee_angle_r # the coordinate's inverse-dynamics moment, N·m/kg, OpenSim's sign: a knee
        kind: min                # extension moment is negative, so "extension moment at most 1.5" is min -1.5
        value: -1.5
      - quantity: muscle_activation
        muscle: glmed1_r         # a muscle of the shipped surrogate (Rajagopal 2016 names)
        kind: max                # max, min over a window; value at times
        value: 0.4               # activation, 0-1

Quantities, evaluated on the guided clip's `Kinematics` (canonical body size, y up, ground at y = 0):

- ``grf_vertical``: the whole-body Newton estimate of the total vertical ground reaction, m (g + a_COM,y), in
  body weights, i.e. 1 + a_COM,y / g, with a_COM,y the central second difference of the COM height. It is the
  sum of both feet's vertical force whatever the contact pattern, and needs no contact solve; it is evaluated at
  the canonical size (a person of another height, moving the same, scaled, has a_COM scaled by the height ratio).
- ``joint_angle``: the named coordinate of q (rad, or m for translations).
- ``com_height``: the COM's height above the floor (m).
- ``joint_position``: the origin of a named body of the canonical model in ground (m; a body's origin is its
  joint centre with its parent: ``hand_r`` the wrist, ``calcn_r`` the subtalar joint, ``pelvis`` the pelvis
  frame), by the differentiable forward kinematics the guidance uses for the COM
  (`biomotion.body.kinematics.forward_kinematics`), at the canonical size and in the generated clip's frame
  (the clip starts with the pelvis over the origin, the floor at y = 0): OmniControl's spatial joint control
  (Xie et al. 2024, Sec. 3) of a body origin rather than an SMPL joint.
- ``joint_torque``: the named coordinate's generalized force by inverse dynamics (`joint_moments`), in N·m per kg
  of the canonical model. Velocities and accelerations are central differences of the guided coordinates. The
  ground's loads: the total force the ground must supply is the pelvis translations' generalized force of
  inverse dynamics without loads (Newton's law for the whole body, differentiable), shared among the foot contact
  points in the proportions of the vertical forces the analysis's contact solve gives them
  (`biomotion.body.contact.infer_ground_reaction`, PhysPT Eq. 4-5; recomputed at every guidance step, without
  gradient) and applied at the points' current positions in the differentiable recursive Newton-Euler pass
  (`biomotion.body.dynamics.inverse_dynamics`). The approximation: the shares (which foot, where under it) are
  held fixed within a step, so the gradient sees the force's size and the lever arms but not a shift of load
  between points; and the analysis the bound is measured with filters the coordinates at 6 Hz first, the
  guidance does not, so its peaks are the higher ones.
- ``muscle_activation``: the named muscle's activation (0-1) as the muscle surrogate predicts it from the guided
  coordinates (`biomotion.muscles.surrogate.MuscleSurrogate`, the network PG-BIG's guidance already runs every
  step for its activation bounds, Sec. 3.3 and A.7): FlexMotion's activation control (Sec. 3.3) done through
  guidance. The loss takes the activations [B, T, M] and their muscle names from its caller
  (`biomotion.guidance.refine.Guide.terms`); the spec is read before any surrogate is loaded, so a muscle's name
  is checked against the surrogate's names when they are known (`Control.check_muscles`). What the bound acts on
  is the surrogate's estimate of static optimization, not static optimization itself.

Losses, each a per-clip [B] tensor, weighted per target and summed: a bound is a squared hinge on a smooth maximum
(minimum) over the window, relu(tau logsumexp(x / tau) - cap)^2, so the gradient reaches the frames near the peak
and the smooth maximum, never below the true one, errs on the safe side; ``value`` is the mean squared difference
at the given times (nearest frame), and ``path`` and a joint position's ``value`` the mean squared distance
(m^2) between the body origin and the points at their times (nearest frame).

Validation raises `biomotion.errors.ConfigError` with one line naming the file and the target (``FILE: target N
(quantity): ...``): unknown quantity, kind, coordinate or body (with the closest body names), a bad window, time
or point, an activation outside 0-1, bounds that contradict each other (a min above a max of the same quantity over
overlapping windows), once the clip length is known (`Control.check`) windows or times outside the clip, and once
the surrogate is known (`Control.check_muscles`) an unknown muscle (with the closest names) or muscle targets with
no surrogate to compute activations.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from biomotion.body.model import BodyModel
from biomotion.errors import ConfigError

QUANTITIES = ("grf_vertical", "joint_angle", "com_height", "joint_position", "joint_torque", "muscle_activation")
KINDS = ("max", "min", "value", "path")
#: the kinds each quantity takes
QUANTITY_KINDS = {
    "grf_vertical": ("max", "min", "value"),
    "joint_angle": ("max", "min", "value"),
    "com_height": ("max", "min", "value"),
    "joint_position": ("path", "value"),
    "joint_torque": ("max", "min"),
    "muscle_activation": ("max", "min", "value"),
}
GRAVITY = 9.81
DEFAULT_WEIGHT = 1000.0
#: smooth-max sharpness per quantity, in its unit (body weights, rad, m, N·m/kg, activation)
SHARPNESS = {
    "grf_vertical": 0.05,
    "joint_angle": 0.02,
    "com_height": 0.005,
    "joint_torque": 0.02,
    "muscle_activation": 0.01,
}
_KEYS = {"quantity", "kind", "value", "window", "times", "weight", "coordinate", "body", "path", "muscle"}


@dataclass(frozen=True)
class Target:
    """One target: ``quantity`` and ``kind`` (see the module), ``value`` in SI / body weights / N·m/kg (a joint
    angle already in rad; NaN for a joint position, whose points are in ``points``), ``window`` (start, end) in s
    or None for the whole clip, ``times`` in s (kinds value and path), ``weight``, ``coordinate`` (joint_angle,
    joint_torque), ``body`` and ``points`` [(x, y, z) m per time] (joint_position), ``muscle``
    (muscle_activation: a surrogate muscle's name, checked by `Control.check_muscles`)."""

    quantity: str
    kind: str
    value: float
    window: tuple[float, float] | None = None
    times: tuple[float, ...] = ()
    weight: float = DEFAULT_WEIGHT
    coordinate: str | None = None
    body: str | None = None
    points: tuple[tuple[float, float, float], ...] = ()
    muscle: str | None = None

    def describe(self) -> str:
        """The quantity and what it names (coordinate, body or muscle), as error messages show a target."""
        named = next((x for x in (self.coordinate, self.body, self.muscle) if x is not None), None)
        return self.quantity if named is None else f"{self.quantity} {named}"


@dataclass(frozen=True)
class Control:
    """A validated list of targets (`Target`), with the file it came from (for error messages)."""

    targets: tuple[Target, ...]
    source: str = "control"

    @classmethod
    def load(cls, path: str | Path) -> Control:
        """Read and validate a spec file (module docstring); ConfigError on anything it cannot use."""
        import yaml

        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"{path}: --control is not a file")
        try:
            data = yaml.safe_load(path.read_text())
        except yaml.YAMLError as error:
            raise ConfigError(f"{path}: not valid YAML ({str(error).splitlines()[0]})") from None
        return cls.from_dict(data, str(path))

    @classmethod
    def from_dict(cls, data, source: str = "control") -> Control:
        """Validate a parsed spec (``{"targets": [...]}``)."""
        if not isinstance(data, dict) or not isinstance(data.get("targets"), list) or not data["targets"]:
            raise ConfigError(f"{source}: a control spec needs a non-empty list 'targets'")
        targets = []
        for n, raw in enumerate(data["targets"], 1):
            where = f"{source}: target {n}"
            if not isinstance(raw, dict):
                raise ConfigError(f"{where}: expected a mapping of quantity, kind, value, ...")
            quantity = raw.get("quantity")
            where = f"{where} ({quantity})"
            unknown = sorted(set(raw) - _KEYS)
            if unknown:
                raise ConfigError(f"{where}: unknown key(s) {', '.join(map(str, unknown))}; known: {sorted(_KEYS)}")
            if quantity not in QUANTITIES:
                raise ConfigError(f"{where}: unknown quantity; choose one of {', '.join(QUANTITIES)}")
            kind = raw.get("kind")
            if kind not in KINDS:
                raise ConfigError(f"{where}: unknown kind {kind!r}; choose one of {', '.join(KINDS)}")
            if kind not in QUANTITY_KINDS[quantity]:
                raise ConfigError(
                    f"{where}: kind {kind} does not apply to {quantity}; choose {' or '.join(QUANTITY_KINDS[quantity])}"
                )
            coordinate = _coordinate(raw.get("coordinate"), quantity, where)
            body = _body(raw.get("body"), quantity, where)
            muscle = _muscle(raw.get("muscle"), quantity, where)
            weight = _number(raw.get("weight", DEFAULT_WEIGHT), f"{where}: weight")
            if weight < 0:
                raise ConfigError(f"{where}: weight must not be negative, got {weight:g}")
            if quantity == "joint_position":
                times, points = _points(raw, kind, where)
                targets.append(Target(quantity, kind, math.nan, None, times, weight, None, body, points))
                continue
            if raw.get("path") is not None:
                raise ConfigError(f"{where}: a path applies to joint_position only")
            value = _number(raw.get("value"), f"{where}: value")
            if quantity == "joint_angle" and not coordinate.startswith("pelvis_t"):
                value = math.radians(value)
            if quantity == "muscle_activation" and not 0.0 <= value <= 1.0:
                raise ConfigError(f"{where}: an activation lies in 0-1, got {value:g}")
            window, times = None, ()
            if kind == "value":
                if raw.get("window") is not None:
                    raise ConfigError(f"{where}: kind value takes times, not a window")
                times = _times(raw.get("times"), where)
            else:
                if raw.get("times") is not None:
                    raise ConfigError(f"{where}: kind {kind} takes a window, not times")
                given = raw.get("window")
                if given is not None:
                    if not isinstance(given, list) or len(given) != 2:
                        raise ConfigError(f"{where}: window must be [start, end] in s")
                    window = (_number(given[0], f"{where}: window"), _number(given[1], f"{where}: window"))
                    if window[0] < 0 or window[1] <= window[0]:
                        raise ConfigError(
                            f"{where}: window [{window[0]:g}, {window[1]:g}] s must have 0 <= start < end"
                        )
            targets.append(Target(quantity, kind, value, window, times, weight, coordinate, muscle=muscle))
        _check_consistent(targets, source)
        return cls(tuple(targets), source)

    def check(self, seconds: float) -> None:
        """ConfigError when a window or time lies outside a clip of ``seconds``."""
        for n, t in enumerate(self.targets, 1):
            late = max(t.times) if t.times else (t.window[1] if t.window is not None else 0.0)
            if late > seconds + 1e-9:
                raise ConfigError(
                    f"{self.source}: target {n} ({t.describe()}): {'time' if t.times else 'window'} ends at "
                    f"{late:g} s, outside the {seconds:g} s clip"
                )

    def check_muscles(self, names: Sequence[str] | None) -> None:
        """ConfigError when a muscle_activation target names a muscle not in ``names`` (the muscle surrogate's,
        `biomotion.muscles.surrogate.MuscleSurrogate.names`; the message gives the closest ones), or when there is
        any muscle_activation target and ``names`` is None: nothing will compute activations (guidance off, or no
        surrogate loaded). The generation pipeline calls it before generating."""
        from biomotion.analysis.study import closest_names

        for n, t in enumerate(self.targets, 1):
            if t.quantity != "muscle_activation":
                continue
            where = f"{self.source}: target {n} ({t.describe()})"
            if names is None:
                raise ConfigError(
                    f"{where}: muscle activations come from the muscle surrogate inside guidance, and this "
                    "generation has none (guidance off or no surrogate loaded)"
                )
            if t.muscle not in names:
                close = closest_names([t.muscle], names, 3)[t.muscle]
                hint = f"closest: {', '.join(close)}; " if close else ""
                raise ConfigError(
                    f"{where}: unknown muscle {t.muscle!r} ({hint}the surrogate's {len(names)} muscles are the "
                    f"Rajagopal 2016 ones, e.g. {', '.join(names[:3])})"
                )

    def loss(
        self,
        q: torch.Tensor,
        com: torch.Tensor,
        rate: float,
        frames: int | None = None,
        body: BodyModel | None = None,
        *,
        activations: torch.Tensor | None = None,
        muscles: Sequence[str] | None = None,
    ) -> torch.Tensor:
        """The weighted sum [B] of every target's loss on clips q [B, T, 39] and COM [B, T, 3] (canonical, on the
        floor) at ``rate`` Hz; ``frames``: the clip's length (T when None; later frames are ignored); ``body``:
        the canonical `BodyModel` the clips were posed with, needed by joint_position and joint_torque targets;
        ``activations`` [B, T, M] (0-1, frame for frame with q) and their ``muscles`` names: the surrogate's
        prediction on q, needed by muscle_activation targets (FlexMotion Sec. 3.3's activation control)."""
        from biomotion.body.canonical import CANONICAL_COORDINATES

        frames = q.shape[1] if frames is None else min(frames, q.shape[1])
        q = q[:, :frames]
        needs_body = {t.quantity for t in self.targets} & {"joint_position", "joint_torque"}
        if needs_body and body is None:
            raise ValueError(f"{self.source}: {', '.join(sorted(needs_body))} targets need the body model")
        if any(t.quantity == "muscle_activation" for t in self.targets):
            if activations is None or muscles is None:
                raise ValueError(f"{self.source}: muscle_activation targets need the activations and their names")
            missing = sorted({t.muscle for t in self.targets if t.muscle is not None} - set(muscles))
            if missing:
                raise ValueError(f"{self.source}: no activations for {', '.join(missing)}")
        positions = moments = None
        total = torch.zeros(q.shape[0], dtype=q.dtype)
        for t in self.targets:
            if t.quantity == "joint_position":
                if positions is None:
                    positions = body_origins(body, q)
                total = total + t.weight * _path_loss(t, positions[:, :, body.body_index(t.body)], rate)
                continue
            if t.quantity == "grf_vertical":
                y = com[:, :frames, 1]
                accel = (y[:, 2:] - 2 * y[:, 1:-1] + y[:, :-2]) * rate**2
                series = torch.nn.functional.pad(1.0 + accel / GRAVITY, (1, 1), mode="replicate")
            elif t.quantity == "com_height":
                series = com[:, :frames, 1]
            elif t.quantity == "joint_torque":
                if moments is None:
                    moments = joint_moments(body, q, rate)
                series = moments[:, :, CANONICAL_COORDINATES.index(t.coordinate)]
            elif t.quantity == "muscle_activation":
                series = activations[:, :frames, list(muscles).index(t.muscle)]
            else:
                series = q[:, :, CANONICAL_COORDINATES.index(t.coordinate)]
            total = total + t.weight * _target_loss(t, series, rate)
        return total


def body_origins(body: BodyModel, q: torch.Tensor) -> torch.Tensor:
    """[..., T, n_bodies, 3] origin of every body in ground for coordinates q [..., T, n_q] (differentiable)."""
    from biomotion.body.kinematics import forward_kinematics

    return forward_kinematics(body, q.reshape(-1, q.shape[-1])).positions.view(*q.shape[:-1], -1, 3)


def joint_moments(body: BodyModel, q: torch.Tensor, rate: float) -> torch.Tensor:
    """[B, T, n_q] generalized forces per kg of ``body`` (N·m/kg, N/kg) for clips q [B, T, n_q] at ``rate`` Hz,
    with the ground's loads shared among the foot contact points as the analysis's contact solve shares them
    (module docstring, ``joint_torque``)."""
    from biomotion.body.contact import foot_points, infer_ground_reaction, root_coordinates
    from biomotion.body.dynamics import ExternalLoad, inverse_dynamics
    from biomotion.body.kinematics import forward_kinematics, points_in_ground

    step = 1.0 / rate
    qd = torch.gradient(q, spacing=step, dim=1)[0]
    qdd = torch.gradient(qd, spacing=step, dim=1)[0]
    solver = body.to(torch.float64)
    feet = foot_points(body)
    names = [body.body_names[int(i)] for i in feet.bodies]
    translations = [c for c in root_coordinates(body) if body.motion_types[c] == "translational"]
    out = []
    for b in range(q.shape[0]):
        with torch.no_grad():
            solved = infer_ground_reaction(solver, *(x[b].detach().double() for x in (q, qd, qdd)))
            vertical = solved.point_forces[..., 1]  # [T, K]
            share = (vertical / vertical.sum(-1, keepdim=True).clamp(min=1e-6)).to(q.dtype)
        needed = inverse_dynamics(body, q[b], qd[b], qdd[b])[:, translations]  # [T, 3] force the ground supplies
        points = points_in_ground(forward_kinematics(body, q[b]), feet.bodies, feet.offsets.to(q.dtype))
        loads = [ExternalLoad(name, share[:, k, None] * needed, points[:, k]) for k, name in enumerate(names)]
        out.append(inverse_dynamics(body, q[b], qd[b], qdd[b], loads))
    return torch.stack(out) / body.total_mass.to(q.dtype)


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def _coordinate(coordinate, quantity: str, where: str) -> str | None:
    """The validated coordinate of a joint_angle or joint_torque target (None for the other quantities)."""
    from biomotion.body.canonical import CANONICAL_COORDINATES, COUPLED_COORDINATES

    if quantity not in ("joint_angle", "joint_torque"):
        if coordinate is not None:
            raise ConfigError(f"{where}: a coordinate applies to joint_angle and joint_torque only")
        return None
    if coordinate not in CANONICAL_COORDINATES:
        raise ConfigError(
            f"{where}: unknown coordinate {coordinate!r}; the canonical ones are {', '.join(CANONICAL_COORDINATES)}"
        )
    if quantity == "joint_torque" and (coordinate.startswith("pelvis_") or coordinate in COUPLED_COORDINATES):
        raise ConfigError(
            f"{where}: {coordinate} has no joint moment (the pelvis is the unactuated floating base, a _beta "
            "coordinate follows its knee); choose a joint coordinate"
        )
    return coordinate


def _body(body, quantity: str, where: str) -> str | None:
    """The validated body of a joint_position target (None for the other quantities); an unknown name gets the
    closest canonical ones."""
    from biomotion.analysis.study import closest_names
    from biomotion.body.canonical import CANONICAL_BODIES

    if quantity != "joint_position":
        if body is not None:
            raise ConfigError(f"{where}: a body applies to joint_position only")
        return None
    if body not in CANONICAL_BODIES:
        close = closest_names([str(body)], CANONICAL_BODIES, 3)[str(body)] if isinstance(body, str) else []
        hint = f"closest: {', '.join(close)}; " if close else ""
        raise ConfigError(
            f"{where}: unknown body {body!r} ({hint}the canonical ones are {', '.join(CANONICAL_BODIES)})"
        )
    return body


def _muscle(muscle, quantity: str, where: str) -> str | None:
    """The muscle of a muscle_activation target (None for the other quantities); its name is checked against the
    surrogate's later (`Control.check_muscles`), since the spec loads before the surrogate."""
    if quantity != "muscle_activation":
        if muscle is not None:
            raise ConfigError(f"{where}: a muscle applies to muscle_activation only")
        return None
    if not isinstance(muscle, str) or not muscle:
        raise ConfigError(f"{where}: muscle_activation needs 'muscle', a muscle name of the surrogate (e.g. glmed1_r)")
    return muscle


def _times(given, where: str) -> tuple[float, ...]:
    if not isinstance(given, list) or not given:
        raise ConfigError(f"{where}: kind value needs a non-empty list 'times' (s)")
    times = tuple(_number(t, f"{where}: times") for t in given)
    if min(times) < 0:
        raise ConfigError(f"{where}: times must not be negative, got {min(times):g} s")
    return times


def _points(raw: dict, kind: str, where: str) -> tuple[tuple[float, ...], tuple[tuple[float, float, float], ...]]:
    """Times (s) and points (x, y, z in m) of a joint_position target: ``path`` [[t, x, y, z], ...] (kind path)
    or ``value`` [x, y, z] at ``times`` (kind value)."""
    if raw.get("window") is not None:
        raise ConfigError(
            f"{where}: a joint_position target takes {'a path' if kind == 'path' else 'times'}, no window"
        )
    if kind == "path":
        if raw.get("times") is not None or raw.get("value") is not None:
            raise ConfigError(f"{where}: kind path takes its times and points from 'path' alone")
        path = raw.get("path")
        if not isinstance(path, list) or not path:
            raise ConfigError(f"{where}: kind path needs a non-empty list 'path' of [t, x, y, z] (s, m)")
        rows = []
        for k, row in enumerate(path, 1):
            if not isinstance(row, list) or len(row) != 4:
                raise ConfigError(f"{where}: path point {k} must be [t, x, y, z] (s, m), got {row!r}")
            rows.append(tuple(_number(x, f"{where}: path point {k}") for x in row))
        times = tuple(r[0] for r in rows)
        if min(times) < 0:
            raise ConfigError(f"{where}: path times must not be negative, got {min(times):g} s")
        return times, tuple(r[1:] for r in rows)
    if raw.get("path") is not None:
        raise ConfigError(f"{where}: kind value takes 'value' [x, y, z] and 'times', not a path")
    value = raw.get("value")
    if not isinstance(value, list) or len(value) != 3:
        raise ConfigError(f"{where}: a joint position's value must be [x, y, z] (m), got {value!r}")
    point = tuple(_number(x, f"{where}: value") for x in value)
    times = _times(raw.get("times"), where)
    return times, (point,) * len(times)


def _check_consistent(targets: list[Target], source: str) -> None:
    """ConfigError for a min bound above a max bound of the same quantity over overlapping windows."""
    for i, low in enumerate(targets, 1):
        for j, high in enumerate(targets, 1):
            if low.kind != "min" or high.kind != "max" or low.describe() != high.describe():
                continue
            a, b = low.window or (0.0, math.inf), high.window or (0.0, math.inf)
            if max(a[0], b[0]) < min(a[1], b[1]) and low.value > high.value:
                raise ConfigError(
                    f"{source}: target {i} ({low.describe()}): its lower bound {low.value:g} is above target "
                    f"{j}'s upper bound {high.value:g} over overlapping windows"
                )


def _target_loss(t: Target, series: torch.Tensor, rate: float) -> torch.Tensor:
    """[B] loss of one target on its quantity's series [B, T] (module docstring)."""
    last = series.shape[1] - 1
    if t.kind == "value":
        index = torch.tensor([min(round(s * rate), last) for s in t.times])
        return (series[:, index] - t.value).pow(2).mean(-1)
    start, end = (0, last) if t.window is None else (round(t.window[0] * rate), min(round(t.window[1] * rate), last))
    x = series[:, start : end + 1]
    tau = SHARPNESS[t.quantity]
    if t.kind == "max":
        return torch.relu(tau * torch.logsumexp(x / tau, -1) - t.value).pow(2)
    return torch.relu(t.value + tau * torch.logsumexp(-x / tau, -1)).pow(2)


def _path_loss(t: Target, positions: torch.Tensor, rate: float) -> torch.Tensor:
    """[B] mean squared distance (m^2) between a body origin [B, T, 3] and a joint_position target's points at
    their times (nearest frame)."""
    last = positions.shape[1] - 1
    index = torch.tensor([min(round(s * rate), last) for s in t.times])
    points = torch.tensor(t.points, dtype=positions.dtype)
    return (positions[:, index] - points).pow(2).sum(-1).mean(-1)
