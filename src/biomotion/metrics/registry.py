"""The metrics that apply to a set of clips, and the paired metrics of a predicted set against a reference set.

Per-set metrics (docs/metrics.md gives every definition and its paper): the contact family on the sole points with
the absolute ground and PG-BIG's clip-median ground, jerk of the joint centres, energy consistency of the
whole-body COM as a point mass (and, with ``physics=True`` on coordinate clips, of the full-body energy of the
body model, with the ZMP-inside-support share), joint-range violations against the model's ranges (coordinate
clips), motion entropy of the body-point heights and the pairwise diversity of the clips.
Paired metrics (clips paired by name, else in order): MJE and P-MJE (PhysPT Sec. 4), ACCL and VEL, and PG-BIG's
fidelity (DTW, pelvis-relative) with its Gaussian W2 variant.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import torch

from biomotion.errors import BiomotionError
from biomotion.metrics.base import pair_mask, summarize
from biomotion.metrics.clip_set import ClipSet
from biomotion.metrics.contact import FootContactVelocity, Floating, Penetration, SkateRatio
from biomotion.metrics.fidelity import Fidelity, GaussianFidelity, MotionEntropy, pairwise_diversity
from biomotion.metrics.plausibility import JointRangeViolation
from biomotion.metrics.reconstruction import JointError, ProcrustesJointError
from biomotion.metrics.smoothness import (AccelerationError, EnergyConsistency, JerkIndex, VelocityError,
                                          mechanical_energy)
from biomotion.metrics.stability import ZMPInsideSupport


@dataclass(frozen=True)
class MetricSpec:
    """How one metric is computed from a `ClipSet` (per clip, [N]) and printed (unit, scale, better direction)."""

    key: str
    label: str
    unit: str
    scale: float
    better: str  # "↓" lower, "↑" higher, "→" closer to the reference
    score: Callable[..., torch.Tensor]


def _feet(s: ClipSet) -> tuple[torch.Tensor, torch.Tensor]:
    return s.feet, s.valid


def _com_energy(s: ClipSet) -> torch.Tensor:
    energy = mechanical_energy(s.com[..., None, :], [s.total_mass], s.rate)
    return EnergyConsistency(std=True).score(energy, pair_mask(s.valid))


def _joint_ranges(model) -> Callable[[ClipSet], torch.Tensor]:
    translation = torch.tensor([n.endswith(("_tx", "_ty", "_tz")) for n in model.coordinate_names])
    metric = JointRangeViolation(low=model.ranges[:, 0], high=model.ranges[:, 1])
    return lambda s: metric.score(s.q, s.mask & ~translation, s.valid)


def _body_energy(model) -> Callable[[ClipSet], torch.Tensor]:
    from biomotion.body.balance import mechanical_energy as body_energy
    from biomotion.body.kinematics import torch_threads

    def score(s: ClipSet) -> torch.Tensor:
        with torch_threads(1), torch.no_grad():
            kinetic, potential = body_energy(model, s.q[s.valid], s.qd[s.valid])
        energy = s.q.new_zeros(s.valid.shape)
        energy[s.valid] = kinetic + potential
        return EnergyConsistency(std=True).score(energy, s.valid)
    return score


def _zmp_share(model) -> Callable[[ClipSet], torch.Tensor]:
    from biomotion.body.balance import zero_moment_point
    from biomotion.body.kinematics import torch_threads

    def score(s: ClipSet) -> torch.Tensor:
        with torch_threads(1), torch.no_grad():
            zmp_valid = zero_moment_point(model, s.q[s.valid], s.qd[s.valid], s.qdd[s.valid])
        zmp = s.q.new_full((*s.valid.shape, 3), float("nan"))
        zmp[s.valid] = zmp_valid
        return ZMPInsideSupport().score(zmp, s.feet, s.valid)
    return score


def set_metrics(kind: str, model=None, *, physics: bool = False) -> list[MetricSpec]:
    """The per-clip metrics that apply to a set of ``kind`` ("coordinates" or "bvh")."""
    specs = [
        MetricSpec("penetration", "Penetration", "cm", 100.0, "↓", lambda s: Penetration().score(*_feet(s))),
        MetricSpec("penetration_median", "Penetration (clip median)", "cm", 100.0, "↓",
                   lambda s: Penetration(ground="clip_median").score(*_feet(s))),
        MetricSpec("floating", "Floating", "cm", 100.0, "↓",
                   lambda s: Floating().score(s.feet, s.rate, s.valid)),
        MetricSpec("floating_median", "Floating (clip median)", "cm", 100.0, "↓",
                   lambda s: Floating(ground="clip_median").score(s.feet, s.rate, s.valid)),
        MetricSpec("skate_ratio", "Skate", "%", 100.0, "↓", lambda s: SkateRatio().score(s.feet, s.rate, s.valid)),
        MetricSpec("foot_contact_velocity", "Foot contact vel.", "m/s", 1.0, "↓",
                   lambda s: FootContactVelocity().score(s.feet, s.rate, s.valid)),
        MetricSpec("jerk", "Jerk", "m/s³", 1.0, "↓",
                   lambda s: JerkIndex(squared=False).score(s.points, s.rate, s.valid)),
        MetricSpec("energy_com", "Energy std (COM)", "J", 1.0, "↓", _com_energy),
        MetricSpec("entropy", "Entropy", "nat", 1.0, "→", lambda s: MotionEntropy().score(s.points[..., 1], s.valid)),
    ]
    if kind == "coordinates":
        if model is None:
            raise BiomotionError("coordinate clips need the body model to check joint ranges")
        specs.insert(8, MetricSpec("joint_range", "Out of range", "%", 100.0, "↓", _joint_ranges(model)))
        if physics:
            specs.insert(8, MetricSpec("energy_body", "Energy std (body)", "J", 1.0, "↓", _body_energy(model)))
            specs.insert(9, MetricSpec("zmp_in_support", "ZMP in support", "%", 100.0, "↑", _zmp_share(model)))
    return specs


def diversity_features(s: ClipSet) -> torch.Tensor:
    """[N, 4 J] per-clip features for the diversity, invariant to place and heading: mean and std over valid frames
    of each body point's height and of its horizontal distance from the pelvis (m)."""
    relative = s.points - s.points[..., s.root: s.root + 1, :]
    per_frame = torch.cat([s.points[..., 1], relative[..., [0, 2]].norm(dim=-1)], -1)       # [N, T, 2 J]
    frames = s.valid[..., None].to(per_frame.dtype)
    count = frames.sum(1)
    mean = (per_frame * frames).sum(1) / count
    std = (((per_frame - mean[:, None]) ** 2 * frames).sum(1) / count).sqrt()
    return torch.cat([mean, std], -1)


DIVERSITY = MetricSpec("diversity", "Diversity", "cm", 100.0, "→", diversity_features)  # scored per set, not per clip


def paired_metrics() -> list[MetricSpec]:
    """Metrics of a predicted clip against its reference clip; ``score`` takes (pred, ref) padded to one length."""
    return [
        MetricSpec("mje", "MJE", "mm", 1000.0, "↓",
                   lambda p, r, v: JointError(root=p.root).score(p.points, r.points, v)),
        MetricSpec("p_mje", "P-MJE", "mm", 1000.0, "↓",
                   lambda p, r, v: ProcrustesJointError().score(p.points, r.points, v)),
        MetricSpec("accl", "ACCL", "m/s²", 1.0, "↓",
                   lambda p, r, v: AccelerationError().score(p.points, r.points, p.rate, v)),
        MetricSpec("vel", "VEL", "m/s", 1.0, "↓", lambda p, r, v: VelocityError().score(p.points, r.points, p.rate, v)),
        MetricSpec("fidelity", "Fidelity (DTW)", "cm", 100.0, "↓",
                   lambda p, r, v: Fidelity(root=p.root).score(p.points, r.points, p.valid, r.valid)),
        MetricSpec("gaussian_w2", "Fidelity (W2)", "cm", 100.0, "↓",
                   lambda p, r, v: GaussianFidelity().score(_relative_flat(p), _relative_flat(r), p.valid, r.valid)),
    ]


def _relative_flat(s: ClipSet) -> torch.Tensor:
    return (s.points - s.points[..., s.root: s.root + 1, :]).flatten(-2)


def record(spec: MetricSpec, values: torch.Tensor) -> dict:
    result = summarize(spec.key, spec.unit, values.detach().to(torch.float64) * spec.scale)
    return {"label": spec.label, "unit": spec.unit, "better": spec.better, "mean": _num(result.mean),
            "std": _num(result.std), "count": result.count, "values": [_num(v) for v in result.values.tolist()]}


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def score_set(clips: ClipSet, model=None, *, physics: bool = False) -> dict[str, torch.Tensor]:
    """Per-clip values [N] (SI units) of every metric that applies to ``clips``, keyed by metric key."""
    return {spec.key: spec.score(clips) for spec in set_metrics(clips.kind, model, physics=physics)}


def summarize_set(clips: ClipSet, model=None, *, physics: bool = False,
                  selection: Sequence[int] | None = None, scores: dict[str, torch.Tensor] | None = None) -> dict:
    """Records (label, unit in print units, mean, std, count, per-clip values) of every metric and the diversity,
    over all clips or the ``selection``; pass ``scores`` from `score_set` to summarize groups without rescoring."""
    specs = set_metrics(clips.kind, model, physics=physics)
    scores = score_set(clips, model, physics=physics) if scores is None else scores
    index = torch.arange(len(clips)) if selection is None else torch.as_tensor(list(selection), dtype=torch.long)
    records = {spec.key: record(spec, scores[spec.key][index]) for spec in specs}
    features = diversity_features(clips)[index]
    distances = pairwise_diversity(features) if len(index) > 1 else torch.full((1,), float("nan"))
    records[DIVERSITY.key] = {k: v for k, v in record(DIVERSITY, distances).items() if k != "values"}
    return records


def _pad_time(s: ClipSet, length: int) -> ClipSet:
    extra = length - s.valid.shape[1]
    if extra == 0:
        return s

    def pad(x: torch.Tensor | None) -> torch.Tensor | None:
        if x is None:
            return None
        return torch.cat([x, x.new_zeros(x.shape[0], extra, *x.shape[2:])], 1)
    return replace(s, valid=pad(s.valid), points=pad(s.points), feet=pad(s.feet), com=pad(s.com), q=pad(s.q),
                   qd=pad(s.qd), qdd=pad(s.qdd))


def _take(s: ClipSet, index: Sequence[int]) -> ClipSet:
    i = torch.as_tensor(list(index), dtype=torch.long)
    pick = (lambda x: None if x is None else x[i])
    return replace(s, names=tuple(s.names[k] for k in i), groups=tuple(s.groups[k] for k in i), valid=s.valid[i],
                   points=s.points[i], feet=s.feet[i], com=s.com[i], q=pick(s.q), mask=pick(s.mask), qd=pick(s.qd),
                   qdd=pick(s.qdd))


def pair_clips(pred: ClipSet, ref: ClipSet) -> list[tuple[int, int]]:
    """(pred, ref) index pairs: by clip name where any name matches, else in order when the counts agree."""
    names = {n: j for j, n in enumerate(ref.names)}
    by_name = [(i, names[n]) for i, n in enumerate(pred.names) if n in names]
    if by_name:
        return by_name
    if len(pred) != len(ref):
        raise BiomotionError(f"cannot pair {len(pred)} predicted with {len(ref)} reference clips: no clip name "
                             "matches and the counts differ")
    return [(i, i) for i in range(len(pred))]


def score_pairs(pred: ClipSet, ref: ClipSet) -> tuple[list[tuple[int, int]], dict]:
    """Pairs and records of the paired metrics (frames compared up to the shorter clip of each pair)."""
    if pred.kind != ref.kind or pred.points.shape[-2] != ref.points.shape[-2]:
        raise BiomotionError(f"pred ({pred.kind}, {pred.points.shape[-2]} points) and ref ({ref.kind}, "
                             f"{ref.points.shape[-2]} points) have different skeletons")
    if abs(pred.rate - ref.rate) > 1e-9:
        raise BiomotionError(f"pred at {pred.rate} Hz and ref at {ref.rate} Hz")
    pairs = pair_clips(pred, ref)
    p, r = _take(pred, [a for a, _ in pairs]), _take(ref, [b for _, b in pairs])
    length = max(p.valid.shape[1], r.valid.shape[1])
    p, r = _pad_time(p, length), _pad_time(r, length)
    both = p.valid & r.valid
    return pairs, {spec.key: record(spec, spec.score(p, r, both)) for spec in paired_metrics()}
