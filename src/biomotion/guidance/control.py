"""Control targets for PG-BIG generation through guidance: a spec read from YAML and its differentiable loss.

FlexMotion Sec. 3.3 controls a diffusion model's joints, torques, contact forces and activations with a trained
control branch; PG-BIG (Sec. 3.3) already refines its sampled latents by gradient descent on biomechanical losses,
so the same kind of targets can be met there by one more guidance term. This module holds that term.

A spec (``examples/control/*.yaml``) is a list of targets::

    targets:
      - quantity: grf_vertical   # grf_vertical (body weights), joint_angle (needs coordinate), com_height (m)
        kind: max                # max: upper bound over the window; min: lower bound; value: equal at times
        value: 2.2
        window: [0.0, 2.0]       # s from the clip's start; omitted: the whole clip (max and min only)
        weight: 1000             # multiplies the target's loss inside the guidance sum (default 1000)
      - quantity: joint_angle
        coordinate: knee_angle_r # a canonical coordinate (`biomotion.body.canonical.CANONICAL_COORDINATES`)
        kind: value
        times: [0.5, 1.0]        # s; kind value only
        value: 40                # degrees for rotational coordinates, m for pelvis translations

Quantities, evaluated on the guided clip's `Kinematics` (canonical body size, y up, ground at y = 0):

- ``grf_vertical``: the whole-body Newton estimate of the total vertical ground reaction, m (g + a_COM,y), in
  body weights, i.e. 1 + a_COM,y / g, with a_COM,y the central second difference of the COM height. It is the
  sum of both feet's vertical force whatever the contact pattern, and needs no contact solve; it is evaluated at
  the canonical size (a person of another height, moving the same, scaled, has a_COM scaled by the height ratio).
- ``joint_angle``: the named coordinate of q (rad, or m for translations).
- ``com_height``: the COM's height above the floor (m).

Losses, each a per-clip [B] tensor, weighted per target and summed: a bound is a squared hinge on a smooth maximum
(minimum) over the window, relu(tau logsumexp(x / tau) - cap)^2, so the gradient reaches the frames near the peak
and the smooth maximum, never below the true one, errs on the safe side; ``value`` is the mean squared difference
at the given times (nearest frame). Joint torques, muscle activations and joint positions (the issue's other
quantities) are not supported here.

Validation raises `biomotion.errors.ConfigError` with one line naming the file and the target (``FILE: target N
(quantity): ...``): unknown quantity, kind or coordinate, a bad window or time, bounds that contradict each other
(a min above a max of the same quantity over overlapping windows) and, once the clip length is known
(`Control.check`), windows or times outside the clip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch

from biomotion.errors import ConfigError

QUANTITIES = ("grf_vertical", "joint_angle", "com_height")
KINDS = ("max", "min", "value")
GRAVITY = 9.81
DEFAULT_WEIGHT = 1000.0
#: smooth-max sharpness per quantity, in its unit (body weights, rad, m)
SHARPNESS = {"grf_vertical": 0.05, "joint_angle": 0.02, "com_height": 0.005}
_KEYS = {"quantity", "kind", "value", "window", "times", "weight", "coordinate"}


@dataclass(frozen=True)
class Target:
    """One target: ``quantity`` and ``kind`` (see the module), ``value`` in SI / body weights (a joint angle
    already in rad), ``window`` (start, end) in s or None for the whole clip, ``times`` in s (kind value),
    ``weight``, and ``coordinate`` (joint_angle)."""

    quantity: str
    kind: str
    value: float
    window: tuple[float, float] | None = None
    times: tuple[float, ...] = ()
    weight: float = DEFAULT_WEIGHT
    coordinate: str | None = None

    def describe(self) -> str:
        return self.quantity if self.coordinate is None else f"{self.quantity} {self.coordinate}"


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
        from biomotion.body.canonical import CANONICAL_COORDINATES

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
            coordinate = raw.get("coordinate")
            if quantity == "joint_angle":
                if coordinate not in CANONICAL_COORDINATES:
                    raise ConfigError(
                        f"{where}: unknown coordinate {coordinate!r}; the canonical ones are "
                        f"{', '.join(CANONICAL_COORDINATES)}"
                    )
            elif coordinate is not None:
                raise ConfigError(f"{where}: a coordinate applies to joint_angle only")
            value = _number(raw.get("value"), f"{where}: value")
            weight = _number(raw.get("weight", DEFAULT_WEIGHT), f"{where}: weight")
            if weight < 0:
                raise ConfigError(f"{where}: weight must not be negative, got {weight:g}")
            if quantity == "joint_angle" and not coordinate.startswith("pelvis_t"):
                value = math.radians(value)
            window, times = None, ()
            if kind == "value":
                if raw.get("window") is not None:
                    raise ConfigError(f"{where}: kind value takes times, not a window")
                given = raw.get("times")
                if not isinstance(given, list) or not given:
                    raise ConfigError(f"{where}: kind value needs a non-empty list 'times' (s)")
                times = tuple(_number(t, f"{where}: times") for t in given)
                if min(times) < 0:
                    raise ConfigError(f"{where}: times must not be negative, got {min(times):g} s")
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
            targets.append(Target(quantity, kind, value, window, times, weight, coordinate))
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

    def loss(self, q: torch.Tensor, com: torch.Tensor, rate: float, frames: int | None = None) -> torch.Tensor:
        """The weighted sum [B] of every target's loss on clips q [B, T, 39] and COM [B, T, 3] (canonical, on the
        floor) at ``rate`` Hz; ``frames``: the clip's length (T when None; later frames are ignored)."""
        from biomotion.body.canonical import CANONICAL_COORDINATES

        frames = q.shape[1] if frames is None else min(frames, q.shape[1])
        total = torch.zeros(q.shape[0], dtype=q.dtype)
        for t in self.targets:
            if t.quantity == "grf_vertical":
                y = com[:, :frames, 1]
                accel = (y[:, 2:] - 2 * y[:, 1:-1] + y[:, :-2]) * rate**2
                series = torch.nn.functional.pad(1.0 + accel / GRAVITY, (1, 1), mode="replicate")
            elif t.quantity == "com_height":
                series = com[:, :frames, 1]
            else:
                series = q[:, :frames, CANONICAL_COORDINATES.index(t.coordinate)]
            total = total + t.weight * _target_loss(t, series, rate)
        return total


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where} must be a finite number, got {value!r}")
    return float(value)


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
