"""Bound targets checked the way the outputs are measured, and tightened for another round of guidance.

Guidance meets a control spec's bounds (`biomotion.guidance.control`) on its own differentiable estimates: vertical
GRF from Newton's law on the unfiltered COM, joint moments by inverse dynamics of the unfiltered coordinates. What
the user reads (``grf.mot``, ``torques.sto``) and what `biomotion eval control` scores is the analysis of the final
coordinates (`biomotion.analysis.chain.analyze`: 6 Hz low-pass, spline derivatives, the contact model's ground
reaction), after foot planting and the coordinate-space fit have moved the legs. The two can disagree by more than
a bound's margin, so a bound met in guidance can be missed in the files.

The remedy is a feedback loop on the measured value, as a controller closes a loop on its sensor: measure each
``max``/``min`` bound on the vertical GRF or a joint moment by the analysis, and where one is missed, guide again
from the same sample with that bound moved by what it missed plus a margin (``offset``, cumulative over rounds).
The spec's own values are what is measured against; only the guidance's internal target moves.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch

from biomotion.guidance.control import Control, Target

#: bound quantities that the analysis recomputes from the final coordinates (muscle activations are the
#: surrogate's on the final motion, joint angles and COM height are read directly, so they need no loop)
MEASURED_QUANTITIES = ("grf_vertical", "joint_torque")


def measured_bounds(control: Control) -> list[int]:
    """Indices of the targets that are bounds (``max``/``min``) on a quantity in `MEASURED_QUANTITIES`."""
    return [i for i, t in enumerate(control.targets) if t.kind in ("max", "min") and t.quantity in MEASURED_QUANTITIES]


def _window(target: Target, rate: float, frames: int) -> slice:
    """The frames of the target's window, rounded as the guidance's loss rounds them."""
    last = frames - 1
    if target.window is None:
        return slice(0, frames)
    return slice(round(target.window[0] * rate), min(round(target.window[1] * rate), last) + 1)


def analysed_series(result, quantity: str, coordinate: str | None = None) -> np.ndarray:
    """[T] the series a bound on ``quantity`` is judged on in an analysis (`biomotion.analysis.chain.Analysis`):
    ``grf_vertical``, the inferred vertical ground reaction summed over the feet, in body weights; ``joint_torque``,
    ``coordinate``'s generalized force per kg of the analysed model (N·m/kg, OpenSim's sign)."""
    if quantity == "grf_vertical":
        return result.inferred.force[:, :, 1].sum(1) / result.body_weight
    if quantity == "joint_torque":
        model = result.model
        return result.torques[:, model.coordinate_index(coordinate)] / float(model.total_mass)
    raise ValueError(f"the analysis judges no bound on {quantity}")


def measured_excess(body, q: torch.Tensor, rate: float, control: Control, indices: Sequence[int]) -> np.ndarray:
    """[B, len(indices)] by how much each clip of q [B, T, 39] (canonical coordinates, on the floor) misses each
    bound, as the analysis measures it: the measured extreme over the window minus the bound for ``max``, the bound
    minus the extreme for ``min`` (body weights, N·m/kg; <= 0 where met). ``body``: the canonical `BodyModel`."""
    from biomotion.analysis.chain import analyze
    from biomotion.body.canonical import CANONICAL_COORDINATES
    from biomotion.motion import Motion

    model = body.to(torch.float64)
    out = np.zeros((q.shape[0], len(indices)))
    for b, clip in enumerate(q.detach().double().numpy()):
        result = analyze(Motion(times=np.arange(len(clip)) / rate, values=clip, names=CANONICAL_COORDINATES), model)
        for j, i in enumerate(indices):
            target = control.targets[i]
            series = analysed_series(result, target.quantity, target.coordinate)
            x = series[_window(target, rate, len(series))]
            out[b, j] = x.max() - target.value if target.kind == "max" else target.value - x.min()
    return out


def tightened(control: Control, indices: Sequence[int], offsets: Sequence[float]) -> Control:
    """The spec with bound ``indices[j]`` moved inwards by ``offsets[j]`` (a ``max`` lowered, a ``min`` raised)."""
    targets = list(control.targets)
    for i, offset in zip(indices, offsets):
        t = targets[i]
        targets[i] = dataclasses.replace(t, value=t.value - offset if t.kind == "max" else t.value + offset)
    return dataclasses.replace(control, targets=tuple(targets))
