"""The registry of the metrics that apply to a set of clips, and of the paired metrics of a predicted set against a
reference set: `Metric` objects with the adapters that feed them from a `ClipSet`.

Each entry is a `ClipSetMetric`: a configured metric of a family module and the adapter that turns a `ClipSet`
(or a pair of them) into that metric's ``score`` arguments. Name, label, unit, direction, paper, equation and
display are the metric's own: `record` and every report read them from the object, so nothing here restates them.

Per-set metrics (`metrics`, one value per clip; docs/metrics.md gives every definition and its paper): the contact
family on the sole points with the absolute ground and PG-BIG's clip-median ground, jerk of the joint centres,
energy consistency of the whole-body COM as a point mass (and, with ``physics=True`` on coordinate clips, of the
full-body energy of the body model, with the ZMP-inside-support share), joint-range violations against the model's
ranges (coordinate clips) and motion entropy of the body-point heights; `DIVERSITY`, the pairwise diversity of the
clips, is scored per set. Paired metrics (`paired_metrics`, clips paired by name, else in order): MJE and P-MJE
(PhysPT Sec. 4), ACCL and VEL, and PG-BIG's fidelity (DTW, pelvis-relative) with its Gaussian W2 variant.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import torch

from biomotion.errors import BiomotionError
from biomotion.metrics.base import DESCRIPTION, Metric, Tensor, pair_mask, summarize
from biomotion.metrics.clip_set import ClipSet
from biomotion.metrics.contact import Floating, FootContactVelocity, Penetration, SkateRatio
from biomotion.metrics.distribution import distribution_metrics
from biomotion.metrics.fidelity import Diversity, Fidelity, GaussianFidelity, MotionEntropy
from biomotion.metrics.plausibility import JointRangeViolation
from biomotion.metrics.reconstruction import JointError, ProcrustesJointError
from biomotion.metrics.smoothness import (
    AccelerationError,
    EnergyConsistency,
    JerkIndex,
    VelocityError,
    mechanical_energy,
)
from biomotion.metrics.stability import ZMPInsideSupport


class ClipSetMetric(Metric):
    """A registered metric fed from clip sets: ``score(clips)`` for a per-set metric ([N], one value per clip) or
    ``score(pred, ref, both)`` for a paired one is ``metric.score(*inputs(...))``. The description (`DESCRIPTION`:
    name, label, unit, direction, paper, equation, display) is the wrapped metric's, copied at registration, which
    fails for a metric that does not declare its direction."""

    def __init__(self, metric: Metric, inputs: Callable[..., tuple]) -> None:
        super().__init__()
        self.metric, self.inputs = metric, inputs
        for field in DESCRIPTION:
            setattr(self, field, getattr(metric, field))

    def score(self, *clips) -> Tensor:
        return self.metric.score(*self.inputs(*clips))


def _feet(s: ClipSet) -> tuple:
    return s.feet, s.valid


def _feet_rate(s: ClipSet) -> tuple:
    return s.feet, s.rate, s.valid


def _com_energy(s: ClipSet) -> tuple:
    """Point-mass energy of the whole-body COM, one value per frame pair."""
    return mechanical_energy(s.com[..., None, :], [s.total_mass], s.rate), pair_mask(s.valid)


def _joint_ranges(model) -> ClipSetMetric:
    translation = torch.tensor([n.endswith(("_tx", "_ty", "_tz")) for n in model.coordinate_names])
    metric = JointRangeViolation(low=model.ranges[:, 0], high=model.ranges[:, 1])
    return ClipSetMetric(metric, lambda s: (s.q, s.mask & ~translation, s.valid))


def _body_energy(model) -> Callable[[ClipSet], tuple]:
    """Full-body energy of the body model (kinetic with segment rotation plus potential) per valid frame."""
    from biomotion.body.balance import mechanical_energy as body_energy
    from biomotion.body.kinematics import torch_threads

    def inputs(s: ClipSet) -> tuple:
        with torch_threads(1), torch.no_grad():
            kinetic, potential = body_energy(model, s.q[s.valid], s.qd[s.valid])
        energy = s.q.new_zeros(s.valid.shape)
        energy[s.valid] = kinetic + potential
        return energy, s.valid

    return inputs


def _zmp(model) -> Callable[[ClipSet], tuple]:
    """The body model's ZMP per valid frame (NaN elsewhere) with the sole points."""
    from biomotion.body.balance import zero_moment_point
    from biomotion.body.kinematics import torch_threads

    def inputs(s: ClipSet) -> tuple:
        with torch_threads(1), torch.no_grad():
            zmp_valid = zero_moment_point(model, s.q[s.valid], s.qd[s.valid], s.qdd[s.valid])
        zmp = s.q.new_full((*s.valid.shape, 3), float("nan"))
        zmp[s.valid] = zmp_valid
        return zmp, s.feet, s.valid

    return inputs


def metrics(kind: str, model=None, *, physics: bool = False) -> list[ClipSetMetric]:
    """The per-clip metrics that apply to a set of ``kind`` ("coordinates" or "bvh"), in report order; coordinate
    clips need the body ``model`` (joint ranges, and with ``physics`` full-body energy and ZMP)."""
    entries = [
        ClipSetMetric(Penetration(), _feet),
        ClipSetMetric(Penetration(ground="clip_median"), _feet),
        ClipSetMetric(Floating(), _feet_rate),
        ClipSetMetric(Floating(ground="clip_median"), _feet_rate),
        ClipSetMetric(SkateRatio(), _feet_rate),
        ClipSetMetric(FootContactVelocity(), _feet_rate),
        ClipSetMetric(JerkIndex(squared=False), lambda s: (s.points, s.rate, s.valid)),
        ClipSetMetric(EnergyConsistency(std=True, energy="com"), _com_energy),
        ClipSetMetric(MotionEntropy(), lambda s: (s.points[..., 1], s.valid)),
    ]
    if kind == "coordinates":
        if model is None:
            raise BiomotionError("coordinate clips need the body model to check joint ranges")
        extra = [_joint_ranges(model)]
        if physics:
            extra = [
                ClipSetMetric(EnergyConsistency(std=True, energy="body"), _body_energy(model)),
                ClipSetMetric(ZMPInsideSupport(), _zmp(model)),
                *extra,
            ]
        entries[8:8] = extra
    return entries


def diversity_features(s: ClipSet) -> torch.Tensor:
    """[N, 4 J] per-clip features for the diversity, invariant to place and heading: mean and std over valid frames
    of each body point's height and of its horizontal distance from the pelvis (m)."""
    relative = s.points - s.points[..., s.root : s.root + 1, :]
    per_frame = torch.cat([s.points[..., 1], relative[..., [0, 2]].norm(dim=-1)], -1)  # [N, T, 2 J]
    frames = s.valid[..., None].to(per_frame.dtype)
    count = frames.sum(1)
    mean = (per_frame * frames).sum(1) / count
    std = (((per_frame - mean[:, None]) ** 2 * frames).sum(1) / count).sqrt()
    return torch.cat([mean, std], -1)


DIVERSITY = Diversity(unit="m")
"""The diversity of a set: ``DIVERSITY.score(diversity_features(clips))`` gives the distances of all clip pairs."""


DISTRIBUTION = tuple(distribution_metrics())
"""The distribution metrics (FID, R-precision top-1/2/3, diversity, multimodality; `biomotion.metrics.distribution`):
scored on the motion-text evaluator's embeddings of whole sets by `biomotion.evaluation.distribution`, not from a
`ClipSet`."""


def paired_metrics(root: int = 0) -> list[ClipSetMetric]:
    """Metrics of a predicted clip against its reference clip: ``score(pred, ref, both)`` with pred and ref padded
    to one length and ``both`` the frames valid in both; ``root`` is the pelvis among the points."""
    return [
        ClipSetMetric(JointError(root=root), lambda p, r, v: (p.points, r.points, v)),
        ClipSetMetric(ProcrustesJointError(), lambda p, r, v: (p.points, r.points, v)),
        ClipSetMetric(AccelerationError(), lambda p, r, v: (p.points, r.points, p.rate, v)),
        ClipSetMetric(VelocityError(), lambda p, r, v: (p.points, r.points, p.rate, v)),
        ClipSetMetric(Fidelity(root=root), lambda p, r, v: (p.points, r.points, p.valid, r.valid)),
        ClipSetMetric(
            GaussianFidelity(unit="m"), lambda p, r, v: (_relative_flat(p), _relative_flat(r), p.valid, r.valid)
        ),
    ]


def every_metric(kind: str, model=None, *, physics: bool = False) -> list[Metric]:
    """Everything the registry scores on clips of ``kind``: the per-clip metrics, the diversity and the paired
    metrics, in report order."""
    return [*metrics(kind, model, physics=physics), DIVERSITY, *paired_metrics()]


def _relative_flat(s: ClipSet) -> torch.Tensor:
    return (s.points - s.points[..., s.root : s.root + 1, :]).flatten(-2)


def record(metric: Metric, values: torch.Tensor) -> dict:
    """The JSON record of per-clip ``values`` (SI) of ``metric``: its label, printed unit and direction mark, and
    mean, std, count and values in the printed unit (``display_scale`` times SI; None where undefined)."""
    unit = metric.display_unit or metric.unit
    result = summarize(metric.name, unit, values.detach().to(torch.float64) * metric.display_scale)
    return {
        "label": metric.label,
        "unit": unit,
        "better": metric.arrow,
        "mean": _num(result.mean),
        "std": _num(result.std),
        "count": result.count,
        "values": [_num(v) for v in result.values.tolist()],
    }


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def set_record(metric: Metric, values: torch.Tensor) -> dict:
    """`record` of a set-level metric (the diversity): without per-pair values."""
    return {k: v for k, v in record(metric, values).items() if k != "values"}


def score_set(clips: ClipSet, model=None, *, physics: bool = False) -> dict[str, torch.Tensor]:
    """Per-clip values [N] (SI units) of every metric that applies to ``clips``, keyed by metric name."""
    return {metric.name: metric.score(clips) for metric in metrics(clips.kind, model, physics=physics)}


def summarize_set(
    clips: ClipSet,
    model=None,
    *,
    physics: bool = False,
    selection: Sequence[int] | None = None,
    scores: dict[str, torch.Tensor] | None = None,
) -> dict:
    """Records (`record`) of every per-clip metric and of the diversity, over all clips or the ``selection``; pass
    ``scores`` from `score_set` to summarize groups without rescoring."""
    registered = metrics(clips.kind, model, physics=physics)
    scores = score_set(clips, model, physics=physics) if scores is None else scores
    index = torch.arange(len(clips)) if selection is None else torch.as_tensor(list(selection), dtype=torch.long)
    records = {metric.name: record(metric, scores[metric.name][index]) for metric in registered}
    features = diversity_features(clips)[index]
    distances = DIVERSITY.score(features) if len(index) > 1 else torch.full((1,), float("nan"))
    records[DIVERSITY.name] = set_record(DIVERSITY, distances)
    return records


def _pad_time(s: ClipSet, length: int) -> ClipSet:
    extra = length - s.valid.shape[1]
    if extra == 0:
        return s

    def pad(x: torch.Tensor | None) -> torch.Tensor | None:
        if x is None:
            return None
        return torch.cat([x, x.new_zeros(x.shape[0], extra, *x.shape[2:])], 1)

    return replace(
        s,
        valid=pad(s.valid),
        points=pad(s.points),
        feet=pad(s.feet),
        com=pad(s.com),
        q=pad(s.q),
        qd=pad(s.qd),
        qdd=pad(s.qdd),
    )


def _take(s: ClipSet, index: Sequence[int]) -> ClipSet:
    i = torch.as_tensor(list(index), dtype=torch.long)
    pick = lambda x: None if x is None else x[i]
    return replace(
        s,
        names=tuple(s.names[k] for k in i),
        groups=tuple(s.groups[k] for k in i),
        valid=s.valid[i],
        points=s.points[i],
        feet=s.feet[i],
        com=s.com[i],
        q=pick(s.q),
        mask=pick(s.mask),
        qd=pick(s.qd),
        qdd=pick(s.qdd),
    )


def pair_clips(pred: ClipSet, ref: ClipSet) -> list[tuple[int, int]]:
    """(pred, ref) index pairs: by clip name where any name matches, else in order when the counts agree."""
    names = {n: j for j, n in enumerate(ref.names)}
    by_name = [(i, names[n]) for i, n in enumerate(pred.names) if n in names]
    if by_name:
        return by_name
    if len(pred) != len(ref):
        raise BiomotionError(
            f"cannot pair {len(pred)} predicted with {len(ref)} reference clips: no clip name "
            "matches and the counts differ"
        )
    return [(i, i) for i in range(len(pred))]


def score_pairs(pred: ClipSet, ref: ClipSet) -> tuple[list[tuple[int, int]], dict]:
    """Pairs and records of the paired metrics (frames compared up to the shorter clip of each pair)."""
    if pred.kind != ref.kind or pred.points.shape[-2] != ref.points.shape[-2]:
        raise BiomotionError(
            f"pred ({pred.kind}, {pred.points.shape[-2]} points) and ref ({ref.kind}, "
            f"{ref.points.shape[-2]} points) have different skeletons"
        )
    if abs(pred.rate - ref.rate) > 1e-9:
        raise BiomotionError(f"pred at {pred.rate} Hz and ref at {ref.rate} Hz")
    pairs = pair_clips(pred, ref)
    p, r = _take(pred, [a for a, _ in pairs]), _take(ref, [b for _, b in pairs])
    length = max(p.valid.shape[1], r.valid.shape[1])
    p, r = _pad_time(p, length), _pad_time(r, length)
    both = p.valid & r.valid
    return pairs, {metric.name: record(metric, metric.score(p, r, both)) for metric in paired_metrics(p.root)}
