"""Controlled generation with FlexMotion (FlexMotion Sec. 3.3): a control spec (`biomotion.guidance.control`) turned
into the control module's signal (`biomotion.models.control_net`), DDIM sampling with the module, and the same
coordinate-space stage PG-BIG's control ends with (`biomotion.guidance.control_fit`) for paths and values.

From spec to signal (per frame of the model's window, raw values; the module standardises them):

- ``joint_position`` ``path``: the body origin's channels on every frame from the first to the last path time,
  linearly interpolated between the points (dense); ``value``: the point at its times' frames (sparse).
- ``joint_angle``, ``grf_vertical``, ``muscle_activation`` of kind ``value``: their channel at the given frames
  (a joint angle of ``pelvis_tx``/``pelvis_tz``/``pelvis_rotation`` is frame-dependent and is left to the
  coordinate stage alone).
- Bounds (``max``/``min`` of ``grf_vertical``, ``joint_torque``, ``joint_angle``, ``muscle_activation``): the
  control module takes values, not inequalities, so a bound becomes a value target on the frames where the sample
  breaks it. The uncontrolled sample (same seed) is measured as `biomotion eval control` measures it (vertical GRF
  and joint moments recomputed from the kinematics by `biomotion.analysis.chain.analyze`; activations by the muscle
  surrogate on the coordinates; angles from q); on every frame of the target's window where it breaks the bound,
  and ``dilate`` frames either side, the target is the bound moved ``margin`` x |bound| inside it (for the
  vertical GRF and joint moments: the sample's own generated value scaled by bound / measured, `add_bounds`). The
  controlled sample is measured again; frames that still break the bound are added and the margin doubled, for at
  most ``rounds`` samplings (same seed), and the sampling that breaks the bounds least (`violation`) is kept.
  Moments are converted to FlexMotion's unit (body weights: N·m/kg / g). What this achieves on held-out targets
  (`biomotion eval control --generator flexmotion`): no bound met; the module with an empty signal already moves
  the recomputed peaks by up to 17 % either way (seeds 0-2 of a run and a walk), more than a 10 % cap asks, and
  its directed effect is smaller.
- ``com_height`` targets are refused (`check_spec`): the module has no COM channel.

Frames. FlexMotion generates in the window's own frame (`biomotion.models.refiner.to_local`: mean heading and mean
horizontal pelvis position zero); a spec's positions are in the clip's frame. With position targets the generated
clip is placed (`place`) by the heading turn and horizontal shift (`biomotion.models.refiner.to_world`) and, when
the targets span at least `DRIFT_MIN_SECONDS`, a constant horizontal drift of the pelvis (m/s, zero at the clip's
middle frame) that best bring its constrained body origins onto the target points (`fit_frame`: a grid over the
heading with the shift and drift by least squares, then a few gradient steps through forward kinematics), first
for the uncontrolled sample (which fixes where the targets lie in the model's frame for the signal), then again
for each controlled one. The drift is there because the shipped FlexMotion autoencoder does not hold a window's
forward travel (`biomotion.models.control_net`, last paragraph: 0.61 m mean error on ``pelvis_tx``), so no latent,
controlled or not, sets how far the pelvis has travelled at a given time; the drift sets the travel the targets ask
for and slides the stance feet by as much (the coordinate stage then holds the planted ones). Turning the heading
coordinate is not exactly a turn of the whole body about the vertical (the pelvis's tilt and list come first in
its joint), so a target mapped into the model's frame is approximate by up to centimetres; the coordinate stage
meets the spec in its own frame. Without position targets the clip stays in the model's frame.

Last, the path and value targets are met on the coordinates by `fit_control` (the planted feet are the foot points
within 2 cm of the floor, as after PG-BIG's planting; FlexMotion does no planting of its own).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.errors import ConfigError
from biomotion.guidance.bound_fit import BoundFitConfig
from biomotion.guidance.control import GRAVITY, Control, Target, body_origins
from biomotion.guidance.measured_bounds import analysed_series
from biomotion.models.control_net import CONTROL_DIM, CONTROL_SLICES, ControlNet, position_channels
from biomotion.models.refiner import to_world

CONTROL_WEIGHTS = "control_net.safetensors"
#: coordinates whose value depends on the clip's placement: conditioned through the coordinate stage only
_FRAME_COORDINATES = ("pelvis_tx", "pelvis_tz", "pelvis_rotation")


@dataclass(frozen=True)
class BoundSettings:
    """How bounds become value targets (module docstring)."""

    margin: float = 0.05
    dilate: int = 2
    rounds: int = 3
    bound_fit: BoundFitConfig | None = BoundFitConfig()  # caps still missed: `biomotion.guidance.bound_fit`


@dataclass
class Controlled:
    """A controlled FlexMotion clip: ``decoded`` modalities (``q`` placed in the spec's frame and corrected by the
    coordinate stage; torques, forces and activations as generated), ``uncontrolled`` coordinates [T, 39] (the same
    seed without the module, placed the same way), ``sampled`` coordinates [T, 39] (the module's kept sample,
    placed, before the coordinate stage), ``frame`` (heading, x, z, drift vx, vz) of the placement, ``rounds`` of
    sampling and per-bound ``bounds`` records (peak before and after, met)."""

    decoded: dict[str, torch.Tensor]
    uncontrolled: torch.Tensor
    sampled: torch.Tensor
    frame: torch.Tensor
    rounds: int
    bounds: list[dict] = field(default_factory=list)


def load_control_net(checkpoints: str | Path, model) -> ControlNet:
    """The shipped control module for FlexMotion ``model``; ConfigError when absent."""
    path = Path(checkpoints) / CONTROL_WEIGHTS
    if not path.is_file():
        raise ConfigError(f"{path}: no FlexMotion control weights (`biomotion train control-net`)")
    return ControlNet.load(path, model.config)


def check_spec(spec: Control, seconds: float, muscles) -> None:
    """One-line ConfigError for what FlexMotion's control cannot take: a COM target, a time beyond the clip, an
    unknown muscle."""
    for n, t in enumerate(spec.targets, 1):
        if t.quantity == "com_height":
            raise ConfigError(
                f"{spec.source}: target {n} (com_height): FlexMotion's control module has no COM channel; "
                "use --generator pgbig for COM targets"
            )
    spec.check(seconds)
    spec.check_muscles(list(muscles))


def _frames(t: Target, rate: float, frames: int) -> list[int]:
    return sorted({min(round(s * rate), frames - 1) for s in t.times})


def _window(t: Target, rate: float, frames: int) -> tuple[int, int]:
    if t.window is None:
        return 0, frames - 1
    return round(t.window[0] * rate), min(round(t.window[1] * rate), frames - 1)


def path_points(t: Target, rate: float, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """(frame indices, points [n, 3]) a joint_position target constrains: a path densely (linear between its
    points), a value at its times."""
    times, points = np.asarray(t.times), np.asarray(t.points, dtype=np.float64)
    if t.kind == "path" and len(times) > 1:
        order = np.argsort(times)
        times, points = times[order], points[order]
        index = np.arange(min(round(times[0] * rate), frames - 1), min(round(times[-1] * rate), frames - 1) + 1)
        xyz = np.stack([np.interp(index / rate, times, points[:, k]) for k in range(3)], -1)
        return index, xyz
    index = np.array([min(round(s * rate), frames - 1) for s in times])
    return index, points


_TX, _TZ = CANONICAL_COORDINATES.index("pelvis_tx"), CANONICAL_COORDINATES.index("pelvis_tz")
DRIFT_MIN_SECONDS = 0.5
"""Position targets must span at least this long for the placement to include a drift (module docstring)."""


def _drift_time(frames: torch.Tensor | np.ndarray, rate: float, length: int) -> torch.Tensor:
    """Seconds from the clip's middle frame (the drift's zero) of frame indices."""
    return torch.as_tensor(np.asarray(frames), dtype=torch.float32) / rate - (length - 1) / (2 * rate)


def _turn_points(points: torch.Tensor, frame: torch.Tensor, inverse: bool, time: torch.Tensor | None = None):
    """Points [n, 3] from the model's frame into the spec's (``to_world``'s turn and shift, plus the drift
    ``frame[3:5]`` x ``time`` [n] s from the clip's middle) or back."""
    yaw, x0, z0 = frame[0], frame[1], frame[2]
    if time is not None and len(frame) > 3:
        x0, z0 = x0 + frame[3] * time.to(frame.dtype), z0 + frame[4] * time.to(frame.dtype)
    c, s = torch.cos(yaw), torch.sin(yaw)
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    if inverse:
        x, z = x - x0, z - z0
        return torch.stack([c * x - s * z, y, s * x + c * z], -1)
    return torch.stack([c * x + s * z + x0, y, -s * x + c * z + z0], -1)


def place(q_local: torch.Tensor, frame: torch.Tensor, rate: float) -> torch.Tensor:
    """Clip q_local [T, 39] (model frame) placed by ``frame`` [5] (heading, x, z, drift vx, vz): `to_world` with
    the first three, then the pelvis's horizontal translation moved by the drift x the time from the middle frame."""
    q = to_world(q_local[None], frame[None, :3])[0]
    time = _drift_time(np.arange(len(q)), rate, len(q)).to(q.dtype)
    drift = torch.zeros_like(q)
    drift[:, _TX], drift[:, _TZ] = frame[3] * time, frame[4] * time
    return q + drift


def fit_frame(body, q_local: torch.Tensor, spec: Control, rate: float, frames: int) -> torch.Tensor:
    """[5] (heading, x, z, vx, vz) placing clip q_local [T, 39] (model frame, `place`) so that its constrained body
    origins come closest to the spec's position targets (module docstring); zeros without position targets, no
    drift when they span less than `DRIFT_MIN_SECONDS`."""
    targets = [t for t in spec.targets if t.quantity == "joint_position"]
    frame = torch.zeros(5, dtype=q_local.dtype)
    if not targets:
        return frame
    picks = [(body.body_index(t.body), *path_points(t, rate, frames)) for t in targets]
    with torch.no_grad():
        origins = body_origins(body, q_local[None, :frames])[0]  # [T, bodies, 3]
    local = torch.cat([origins[torch.as_tensor(f), b] for b, f, _ in picks])
    goal = torch.cat([torch.as_tensor(p, dtype=q_local.dtype) for _, _, p in picks])
    time = torch.cat([_drift_time(f, rate, frames) for _, f, _ in picks]).to(q_local.dtype)
    drifts = float(time.max() - time.min()) >= DRIFT_MIN_SECONDS
    spread = float((goal[:, [0, 2]] - goal[:, [0, 2]].mean(0)).norm(dim=-1).max())
    yaws = torch.linspace(-math.pi, math.pi, 73)[:-1] if spread > 0.05 else torch.zeros(1)
    design = torch.stack([torch.ones_like(time), time], -1) if drifts else torch.ones_like(time)[:, None]
    best = None
    for yaw in yaws.to(q_local.dtype):
        turned = _turn_points(local, torch.stack([yaw, yaw * 0, yaw * 0]), False)
        residual = (goal - turned)[:, [0, 2]]  # [n, 2]: x and z, each fitted by shift (+ drift x time)
        coef = torch.linalg.lstsq(design, residual).solution  # [1|2, 2]
        error = float((design @ coef - residual).square().sum())
        if best is None or error < best[0]:
            drift = coef[1] if drifts else torch.zeros(2, dtype=q_local.dtype)
            best = (error, torch.stack([yaw, coef[0, 0], coef[0, 1], drift[0], drift[1]]))
    frame = best[1].clone().requires_grad_(True)
    optimiser = torch.optim.Adam([frame], lr=0.01)
    index = [(b, torch.as_tensor(f)) for b, f, _ in picks]
    keep = torch.tensor([1.0, 1.0, 1.0, float(drifts), float(drifts)], dtype=q_local.dtype)
    for _ in range(30 if spread > 0.05 else 0):
        optimiser.zero_grad()
        placed = body_origins(body, place(q_local[:frames], frame * keep, rate)[None])[0]
        got = torch.cat([placed[f, b] for b, f in index])
        loss = ((got - goal)[:, [0, 2]] ** 2).sum(-1).mean()
        loss.backward()
        optimiser.step()
    return (frame * keep).detach()


def measured(generator, q: torch.Tensor, spec: Control, rate: float) -> dict[str, np.ndarray]:
    """Per frame, the series each bound of ``spec`` is judged on (module docstring): ``grf`` (BW) and moments per
    coordinate name (N·m/kg) from the analysis of the kinematics, activations per muscle from the surrogate,
    angles per coordinate from q. Keys: the target's `Target.describe`."""
    from biomotion.analysis.chain import analyze
    from biomotion.motion import Motion

    bounds = [t for t in spec.targets if t.kind in ("max", "min")]
    out: dict[str, np.ndarray] = {}
    if not bounds:
        return out
    model = generator.refiner.body.to(torch.float64)
    values = q.detach().double().numpy()
    needs_analysis = any(t.quantity in ("grf_vertical", "joint_torque") for t in bounds)
    result = None
    if needs_analysis:
        motion = Motion(times=np.arange(len(values)) / rate, values=values, names=CANONICAL_COORDINATES)
        result = analyze(motion, model)
    activations = None
    if any(t.quantity == "muscle_activation" for t in bounds):
        every = torch.ones(1, q.shape[-1], dtype=torch.bool)
        with torch.no_grad():
            activations = generator.surrogate(q[None].float(), every)[0].numpy()
    names = list(getattr(generator.surrogate, "names", ()))
    for t in bounds:
        if t.quantity in ("grf_vertical", "joint_torque"):
            series = analysed_series(result, t.quantity, t.coordinate)
        elif t.quantity == "muscle_activation":
            series = activations[:, names.index(t.muscle)]
        else:
            series = values[:, CANONICAL_COORDINATES.index(t.coordinate)]
        out[t.describe() + f" {t.kind}"] = np.asarray(series, dtype=np.float64)
    return out


def _channel(t: Target, muscles) -> slice:
    s = CONTROL_SLICES
    if t.quantity == "joint_position":
        return position_channels(t.body)
    if t.quantity == "grf_vertical":
        return s["grf"]
    if t.quantity == "muscle_activation":
        k = s["activations"].start + list(muscles).index(t.muscle)
        return slice(k, k + 1)
    block = "torques" if t.quantity == "joint_torque" else "q"
    k = s[block].start + CANONICAL_COORDINATES.index(t.coordinate)
    return slice(k, k + 1)


def _unit(t: Target) -> float:
    """The spec's unit to the control signal's: joint moments N·m/kg to body weights."""
    return 1.0 / GRAVITY if t.quantity == "joint_torque" else 1.0


def value_signal(spec: Control, frame: torch.Tensor, window: int, frames: int, rate: float, muscles):
    """Raw values and mask [1, window, CONTROL_DIM] of the spec's path and value targets (module docstring),
    positions turned into the model's frame by the inverse of ``frame``."""
    values = torch.zeros(1, window, CONTROL_DIM)
    mask = torch.zeros(1, window, CONTROL_DIM, dtype=torch.bool)
    for t in spec.targets:
        if t.kind not in ("path", "value"):
            continue
        if t.quantity == "joint_angle" and t.coordinate in _FRAME_COORDINATES:
            continue
        channels = _channel(t, muscles)
        if t.quantity == "joint_position":
            index, points = path_points(t, rate, frames)
            time = _drift_time(index, rate, frames)
            local = _turn_points(torch.as_tensor(points, dtype=frame.dtype), frame, True, time)
            values[0, index, channels] = local.float()
            mask[0, index, channels] = True
        else:
            index = _frames(t, rate, frames)
            values[0, index, channels] = t.value * _unit(t)
            mask[0, index, channels] = True
    return values, mask


def generated_series(decoded: dict[str, torch.Tensor], t: Target) -> np.ndarray | None:
    """[W] the sample's own generated modality a vertical-GRF or joint-moment bound acts on, in the control
    signal's unit (body weights); None for other quantities."""
    if t.quantity == "grf_vertical":
        return decoded["forces"][0, :, :, 1].sum(-1).double().numpy()
    if t.quantity == "joint_torque":
        return decoded["torques"][0, :, CANONICAL_COORDINATES.index(t.coordinate)].double().numpy()
    return None


def add_bounds(
    values, mask, spec, series: dict, frames: int, rate: float, muscles, settings, round_: int, decoded=None
) -> int:
    """Put a value target on the frames where ``series`` (`measured`) break the spec's bounds (module docstring);
    returns how many bounds are broken. With the sample's ``decoded`` modalities, a vertical-GRF or joint-moment
    target is the sample's own generated value scaled by bound / measured on that frame (at most 1) and by
    1 - margin: FlexMotion's generated forces and torques disagree with what the analysis recomputes from its
    kinematics (`biomotion.generation.flexmotion.consistency`), so the bound itself, put on the generated channel,
    asked for values far outside the training windows and made the motion worse."""
    broken = 0
    margin = settings.margin * 2**round_
    for t in spec.targets:
        if t.kind not in ("max", "min"):
            continue
        x = series[t.describe() + f" {t.kind}"][:frames]
        start, end = _window(t, rate, frames)
        inside = np.zeros(len(x), dtype=bool)
        inside[start : end + 1] = True
        bad = inside & ((x > t.value) if t.kind == "max" else (x < t.value))
        if not bad.any():
            continue
        broken += 1
        hit = np.flatnonzero(bad)
        spread = np.unique(
            np.clip((hit[:, None] + np.arange(-settings.dilate, settings.dilate + 1)).ravel(), start, end)
        )
        goal = t.value - margin * abs(t.value) if t.kind == "max" else t.value + margin * abs(t.value)
        if t.quantity == "muscle_activation":
            goal = min(max(goal, 0.0), 1.0)
        channels = _channel(t, muscles)
        own = None if decoded is None else generated_series(decoded, t)
        if own is None:
            values[0, spread, channels] = goal * _unit(t)
        else:
            ratio = np.clip(t.value / np.where(np.abs(x[spread]) > 1e-9, x[spread], 1e-9), 0.0, 1.0)
            values[0, spread, channels] = torch.as_tensor(own[spread] * ratio * (1 - margin), dtype=values.dtype)[
                :, None
            ]
        mask[0, spread, channels] = True
    return broken


def violation(spec: Control, series: dict, frames: int, rate: float) -> float:
    """How far a clip's `measured` series break the spec's bounds: the sum over bounds of the peak's excess over
    the bound relative to |bound| (0 when every bound holds)."""
    total = 0.0
    for t in spec.targets:
        if t.kind not in ("max", "min"):
            continue
        start, end = _window(t, rate, frames)
        x = series[t.describe() + f" {t.kind}"][start : end + 1]
        excess = float(x.max()) - t.value if t.kind == "max" else t.value - float(x.min())
        total += max(excess, 0.0) / max(abs(t.value), 1e-6)
    return total


def generate_controlled(
    generator,
    net: ControlNet,
    text: str,
    profile,
    spec: Control,
    *,
    seed: int = 0,
    frames: int | None = None,
    settings: BoundSettings = BoundSettings(),
    sentences: torch.Tensor | None = None,
) -> Controlled:
    """One clip of ``text`` for ``profile`` meeting ``spec`` (module docstring); ``generator`` a
    `biomotion.generation.flexmotion.FlexMotionGenerator`; ``frames`` the clip's length (the window when None)."""
    from biomotion.body.contact import foot_points
    from biomotion.guidance.bound_fit import fit_bounds
    from biomotion.guidance.control_fit import fit_control
    from biomotion.models.motion_text_evaluator import embed_sentences

    model, refiner = generator.model, generator.refiner
    rate, window = model.config.rate, model.config.window
    frames = window if frames is None else min(int(frames), window)
    muscles = list(getattr(generator.surrogate, "names", ()))
    check_spec(spec, frames / rate, muscles)
    sentences = embed_sentences([text.strip()]) if sentences is None else sentences
    every = torch.ones(len(CANONICAL_COORDINATES), dtype=torch.bool)
    body = refiner.body

    def draw(control) -> dict[str, torch.Tensor]:
        decoded = generator.sample([text], [profile], seed=seed, sentences=sentences, control=control)
        decoded["q"] = refiner.full(decoded["q"].float(), every)
        return decoded

    free = draw(None)
    frame = fit_frame(body, free["q"][0], spec, rate, frames)
    uncontrolled = place(free["q"][0, :frames], frame, rate)
    values, mask = value_signal(spec, frame, window, frames, rate, muscles)
    series = measured(generator, uncontrolled, spec, rate)
    before = {k: v.copy() for k, v in series.items()}
    rounds, best, latest = 0, None, free
    while True:
        broken = add_bounds(values, mask, spec, series, frames, rate, muscles, settings, rounds, latest)
        if rounds > 0 and broken == 0:
            break
        if rounds >= settings.rounds:
            break
        decoded = latest = draw(net.bind(values, mask))
        rounds += 1
        frame = fit_frame(body, decoded["q"][0], spec, rate, frames)
        q = place(decoded["q"][0, :frames], frame, rate)
        series = measured(generator, q, spec, rate)
        score = violation(spec, series, frames, rate)
        if best is None or score < best[0]:
            best = (score, decoded, frame, q)
        if not any(t.kind in ("max", "min") for t in spec.targets):
            break
    _, decoded, frame, q = best
    feet = foot_points(body)
    ranges = body.ranges.to(torch.float32)
    rotational = torch.tensor([not n.startswith("pelvis_t") for n in body.coordinate_names])
    lower, upper = ranges[:, 0] + 1e-6, ranges[:, 1] - 1e-6
    fitted = fit_control(body, q[None].float(), spec, rate, feet.bodies, feet.offsets.float(), lower, upper,
                         rotational, frames)  # fmt: skip
    if settings.bound_fit is not None:  # caps the sampling could not meet: the coordinate-space last resort
        damped, _ = fit_bounds(body, fitted, spec, rate, feet.bodies, feet.offsets.float(), feet.feet, lower, upper,
                               frames, settings.bound_fit)  # fmt: skip
        if damped is not fitted:
            fitted = fit_control(body, damped, spec, rate, feet.bodies, feet.offsets.float(), lower, upper,
                                 rotational, frames)  # fmt: skip
    fitted = fitted[0]
    after = measured(generator, fitted, spec, rate)
    bounds = []
    for t in spec.targets:
        if t.kind not in ("max", "min"):
            continue
        key = t.describe() + f" {t.kind}"
        start, end = _window(t, rate, frames)
        pick = np.max if t.kind == "max" else np.min
        peak_before, peak_after = (float(pick(s[key][start : end + 1])) for s in (before, after))
        met = peak_after <= t.value if t.kind == "max" else peak_after >= t.value
        bounds.append({"target": key, "bound": t.value, "uncontrolled": peak_before, "controlled": peak_after,
                       "met": bool(met)})  # fmt: skip
    out = {k: v[:, :frames] for k, v in decoded.items()}
    out["q"] = fitted[None]
    return Controlled(out, uncontrolled, q, frame, rounds, bounds)
