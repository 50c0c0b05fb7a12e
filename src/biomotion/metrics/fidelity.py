"""Fidelity to a subject and diversity: PG-BIG's fidelity (joint-centre error to the subject's real motion after
temporal alignment), the per-feature Gaussian W2 variant of its public code, motion entropy and pairwise diversity.

Fidelity pairs a generated motion with the subject's held-out real motion of the same action (the caller makes the
pairs). The two clips need not have the same length or phase, so they are aligned in time first: by dynamic time
warping (``align="dtw"``, default) or by linear time normalisation (``align="linear"``, the "% of cycle"
resampling of gait analysis). Padded batches give per-frame masks ``pred_valid`` / ``ref_valid`` that must be
True on a prefix of each clip (padding at the end).
"""

from __future__ import annotations

import numpy as np
import torch

from biomotion.errors import DataFormatError
from biomotion.metrics.base import Metric, MetricResult, Tensor, as_tensor, frame_mask, masked_mean, summarize

ALIGNMENTS = ("dtw", "linear")
ENTROPY_BINS = 50
"""Histogram bins of the motion entropy (PG-BIG public evaluator)."""


def _lengths(valid: Tensor, name: str) -> Tensor:
    """Number of valid frames per clip, checking that they form a prefix."""
    lengths = valid.sum(-1)
    prefix = torch.arange(valid.shape[-1], device=valid.device) < lengths[..., None]
    if not torch.equal(prefix, valid):
        raise DataFormatError(None, "valid frames must be a prefix of each clip (padding at the end)", field=name)
    if bool((lengths == 0).any()):
        raise DataFormatError(None, "a clip has no valid frame", field=name)
    return lengths


def _joint_weights(joints, shape: torch.Size, dtype, device) -> Tensor:
    """[..., J] float weights of the present joints."""
    if joints is None:
        return torch.ones(shape, dtype=dtype, device=device)
    return torch.broadcast_to(torch.as_tensor(joints, device=device).to(dtype), shape)


def frame_distance(pred: Tensor, ref: Tensor, weights: Tensor) -> Tensor:
    """[B, N, M] mean over present joints of the distance between pred frame i and ref frame j.

    ``pred`` [B, N, J, 3], ``ref`` [B, M, J, 3], ``weights`` [B, J]."""
    distance = torch.cdist(
        pred.transpose(1, 2).contiguous(), ref.transpose(1, 2).contiguous(), compute_mode="donot_use_mm_for_euclid_dist"
    )  # [B, J, N, M]
    return (distance * weights[..., None, None]).sum(1) / weights.sum(-1).clamp(min=1)[..., None, None]


def dtw(cost: Tensor, n: Tensor, m: Tensor) -> tuple[Tensor, Tensor]:
    """Dynamic time warping of a batch of cost matrices ``cost`` [B, N, M] restricted to the first ``n`` [B] rows and
    ``m`` [B] columns; steps (1, 0), (0, 1), (1, 1), both ends matched (Sakoe & Chiba 1978, symmetric form without
    slope weights). Returns the path cost [B] and the number of cells on the path [B] (no gradient).

    The accumulated cost D[i, j] is computed one anti-diagonal s = i + j at a time, each held as a vector over i,
    so a step is three shifted slices, vectorised over the batch and the diagonal. The recursion runs in NumPy:
    its N + M small steps would otherwise pay torch's per-operation threading overhead.
    """
    c = cost.detach().cpu().numpy()
    rows_n, cols_m = n.cpu().numpy(), m.cpu().numpy()
    batch, rows, cols = c.shape
    flat = c.reshape(batch, rows * cols)
    i = np.arange(1, rows + 1)  # D row index of entries 1..N
    before = np.full((batch, rows + 1), np.inf)  # diagonal s - 2
    before[:, 0] = 0.0  # D[0, 0] = 0
    last = np.full((batch, rows + 1), np.inf)  # diagonal s - 1 (s = 1: all inf)
    steps_before, steps_last = np.zeros((batch, rows + 1)), np.zeros((batch, rows + 1))
    total, steps = np.full(batch, np.inf), np.zeros(batch)
    every = np.arange(batch)
    for diagonal in range(2, rows + cols + 1):
        j = diagonal - i
        inside = (j >= 1) & (j <= cols)
        here = np.where(inside, flat[:, np.clip((i - 1) * cols + (j - 1), 0, rows * cols - 1)], np.inf)
        candidates = np.stack([before[:, :-1], last[:, :-1], last[:, 1:]], -1)
        choice = candidates.argmin(-1)
        best = np.take_along_axis(candidates, choice[..., None], -1)[..., 0]
        counts = np.stack([steps_before[:, :-1], steps_last[:, :-1], steps_last[:, 1:]], -1)
        current = np.concatenate([np.full((batch, 1), np.inf), here + best], 1)
        current_steps = np.concatenate(
            [np.zeros((batch, 1)), np.take_along_axis(counts, choice[..., None], -1)[..., 0] + 1], 1
        )
        done = rows_n + cols_m == diagonal
        total = np.where(done, current[every, rows_n], total)
        steps = np.where(done, current_steps[every, rows_n], steps)
        before, last, steps_before, steps_last = last, current, steps_last, current_steps
    return (
        torch.as_tensor(total, dtype=cost.dtype, device=cost.device),
        torch.as_tensor(steps, dtype=cost.dtype, device=cost.device),
    )


def _linear_error(pred: Tensor, ref: Tensor, weights: Tensor, n: Tensor, m: Tensor) -> Tensor:
    """Mean joint error after resampling each pred clip (n frames) linearly onto its ref clip's m frames."""
    cols = ref.shape[1]
    k = torch.arange(cols, device=pred.device, dtype=pred.dtype)
    position = k[None] * ((n - 1).to(pred.dtype) / (m - 1).clamp(min=1).to(pred.dtype))[:, None]  # [B, M]
    lower = position.floor().long().clamp(max=pred.shape[1] - 1)
    upper = (lower + 1).clamp(max=(n - 1)[:, None])
    frac = (position - lower.to(pred.dtype))[..., None, None]
    gather = lambda index: torch.gather(pred, 1, index[..., None, None].expand(-1, -1, *pred.shape[2:]))
    resampled = (1 - frac) * gather(lower) + frac * gather(upper)
    error = torch.linalg.vector_norm(resampled - ref, dim=-1)  # [B, M, J]
    per_frame = (error * weights[:, None]).sum(-1) / weights.sum(-1).clamp(min=1)[:, None]
    return masked_mean(per_frame, k[None] < m[:, None], -1)


def aligned_joint_error(
    pred, ref, *, pred_valid=None, ref_valid=None, joints=None, align: str = "dtw", root: int | None = None
) -> Tensor:
    """PG-BIG Sec. 4.2 "Fidelity": mean joint-centre error (m; Table 2 prints cm) between a generated clip ``pred``
    [..., N, J, 3] and the subject's real clip ``ref`` [..., M, J, 3] of the same action after temporal alignment.

    With ``align="dtw"`` it is the mean per-frame error along the optimal warping path (path cost / path length);
    with ``"linear"``, ``pred`` is resampled onto ``ref``'s frames. ``joints`` [..., J] masks absent joints. With
    ``root``, poses are compared relative to that joint (for clips recorded at different places in the room).
    """
    pred = as_tensor(pred, "pred", min_dims=3, last=3)
    ref = as_tensor(ref, "ref", min_dims=3, last=3).to(pred.dtype)
    if align not in ALIGNMENTS:
        raise DataFormatError(None, f"align must be one of {ALIGNMENTS}, got {align!r}", field="align")
    if pred.shape[-2] != ref.shape[-2]:
        raise DataFormatError(None, f"pred has {pred.shape[-2]} joints, ref {ref.shape[-2]}", field="ref")
    if root is not None:
        pred = pred - pred[..., root : root + 1, :]
        ref = ref - ref[..., root : root + 1, :]
    batch = torch.broadcast_shapes(pred.shape[:-3], ref.shape[:-3])
    n = _lengths(
        frame_mask(pred_valid, batch + pred.shape[-3:-2], pred.device).reshape(-1, pred.shape[-3]), "pred_valid"
    )
    m = _lengths(frame_mask(ref_valid, batch + ref.shape[-3:-2], ref.device).reshape(-1, ref.shape[-3]), "ref_valid")
    pred = pred.expand(*batch, *pred.shape[-3:]).reshape(-1, *pred.shape[-3:])
    ref = ref.expand(*batch, *ref.shape[-3:]).reshape(-1, *ref.shape[-3:])
    weights = _joint_weights(joints, batch + (pred.shape[-2],), pred.dtype, pred.device).reshape(-1, pred.shape[-2])
    if align == "linear":
        return _linear_error(pred, ref, weights, n, m).reshape(batch)
    total, steps = dtw(frame_distance(pred, ref, weights), n, m)
    return (total / steps).reshape(batch)


def gaussian_w2(pred, ref, *, pred_valid=None, ref_valid=None, mask=None) -> Tensor:
    """PG-BIG public code's fidelity variant: per feature, the 2-Wasserstein distance between Gaussians fitted over
    time, ``sqrt((mu_p - mu_r)^2 + (sigma_p - sigma_r)^2)``, averaged over the features present in ``mask`` [..., n]
    (units of the features). ``pred`` [..., N, n], ``ref`` [..., M, n] (e.g. a subject's trials concatenated)."""
    pred = as_tensor(pred, "pred", min_dims=2)
    ref = as_tensor(ref, "ref", min_dims=2).to(pred.dtype)
    if pred.shape[-1] != ref.shape[-1]:
        raise DataFormatError(None, f"pred has {pred.shape[-1]} features, ref {ref.shape[-1]}", field="ref")

    def moments(x: Tensor, valid) -> tuple[Tensor, Tensor]:
        frames = frame_mask(valid, x.shape[:-1], x.device)[..., None]
        mean = masked_mean(x, frames, -2)
        return mean, masked_mean((x - mean[..., None, :]).square(), frames, -2).sqrt()

    mu_p, sigma_p = moments(pred, pred_valid)
    mu_r, sigma_r = moments(ref, ref_valid)
    w2 = ((mu_p - mu_r).square() + (sigma_p - sigma_r).square()).sqrt()
    features = (
        torch.ones_like(w2, dtype=torch.bool)
        if mask is None
        else torch.broadcast_to(torch.as_tensor(mask, device=w2.device).to(torch.bool), w2.shape)
    )
    return masked_mean(w2, features, -1)


def motion_entropy(values, valid=None, *, bins: int = ENTROPY_BINS) -> Tensor:
    """PG-BIG Sec. 4.2 "Motion Entropy" ``H = -sum_k p_k log p_k`` (nats) of the histogram of a sequence's state
    values ``values`` [..., T, F]: every entry of the valid frames, in ``bins`` equal bins spanning the sequence's
    own range (``numpy.histogram``'s rule). The public evaluator histograms the heights of all body points
    (``points[..., 1]``) in 50 bins. A constant sequence has entropy 0; one without valid frames NaN."""
    values = as_tensor(values, "values", min_dims=2)
    if bins < 1:
        raise DataFormatError(None, f"bins must be positive, got {bins}", field="bins")
    valid = frame_mask(valid, values.shape[:-1], values.device)
    flat = values.reshape(*values.shape[:-2], -1)
    keep = valid[..., None].expand(values.shape).reshape(flat.shape)
    inf = torch.tensor(float("inf"), dtype=values.dtype, device=values.device)
    low = torch.where(keep, flat, inf).amin(-1, keepdim=True)
    high = torch.where(keep, flat, -inf).amax(-1, keepdim=True)
    span = torch.where(high > low, high - low, torch.ones_like(high))
    index = ((flat - torch.where(torch.isfinite(low), low, 0.0)) / span * bins).floor().clamp(0, bins - 1).long()
    counts = torch.zeros(*flat.shape[:-1], bins, dtype=values.dtype, device=values.device)
    counts.scatter_add_(-1, torch.where(keep, index, 0), keep.to(values.dtype))
    total = counts.sum(-1, keepdim=True)
    p = counts / total.clamp(min=1)
    entropy = -torch.where(p > 0, p * p.log(), 0.0).sum(-1)
    return torch.where(total.squeeze(-1) > 0, entropy, torch.full_like(entropy, float("nan")))


def pairwise_diversity(features) -> Tensor:
    """[N (N - 1) / 2] Euclidean distances between all pairs of the feature vectors ``features`` [N, D]; their mean
    is the diversity of PG-BIG / FlexMotion ("DIV", Sec. 4 and App.: average pairwise distance between generated
    motions in a feature space; MDM samples random pairs, all pairs are used here)."""
    features = as_tensor(features, "features", min_dims=2)
    features = features.reshape(-1, features.shape[-1])
    i, j = torch.triu_indices(features.shape[0], features.shape[0], 1, device=features.device)
    return torch.linalg.vector_norm(features[i] - features[j], dim=-1)


def _printed_in_cm(metric: Metric, unit: str) -> None:
    """Features given in metres are printed in cm (PG-BIG Table 2); other units as they are."""
    metric.unit = unit
    if unit == "m":
        metric.display_unit, metric.display_scale = "cm", 100.0


class Fidelity(Metric):
    """`aligned_joint_error` per generated clip (PG-BIG Table 2 "Fidelity", printed in cm); ``align="linear"`` is
    named ``fidelity_linear``."""

    name, label, unit, display_unit, display_scale = "fidelity", "Fidelity (DTW)", "m", "cm", 100.0
    higher_is_better = False
    paper = 'PG-BIG Sec. 4.2 "Fidelity", Table 2'

    def __init__(self, align: str = "dtw", root: int | None = None) -> None:
        super().__init__()
        if align not in ALIGNMENTS:
            raise DataFormatError(None, f"align must be one of {ALIGNMENTS}, got {align!r}", field="align")
        self.align, self.root = align, root
        self.equation = (
            "mean joint-centre error ||p_pred - p_ref|| along the optimal DTW path (path cost / path length)"
        )
        if align == "linear":
            self.name, self.label = "fidelity_linear", "Fidelity (linear)"
            self.equation = "mean joint-centre error ||p_pred - p_ref|| with pred resampled linearly onto ref"

    def score(self, pred, ref, pred_valid=None, ref_valid=None, joints=None) -> Tensor:
        return aligned_joint_error(
            pred, ref, pred_valid=pred_valid, ref_valid=ref_valid, joints=joints, align=self.align, root=self.root
        )


class GaussianFidelity(Metric):
    """`gaussian_w2` per generated clip (PG-BIG public code's fidelity) in the ``unit`` of the features (metres
    are printed in cm)."""

    name, label, unit = "gaussian_w2", "Fidelity (W2)", "feature units"
    higher_is_better = False
    paper = 'PG-BIG public code\'s fidelity (pg-big-reference-notes.md, "Evaluation in code")'
    equation = "mean over features of sqrt((mu_p - mu_r)^2 + (sigma_p - sigma_r)^2), moments over time"

    def __init__(self, unit: str = "feature units") -> None:
        super().__init__()
        _printed_in_cm(self, unit)

    def score(self, pred, ref, pred_valid=None, ref_valid=None, mask=None) -> Tensor:
        return gaussian_w2(pred, ref, pred_valid=pred_valid, ref_valid=ref_valid, mask=mask)


class MotionEntropy(Metric):
    """`motion_entropy` per sequence (nats; PG-BIG Table 2 "Entropy", closer to the reference is better)."""

    name, label, unit = "entropy", "Entropy", "nat"
    higher_is_better = None
    paper = 'PG-BIG Sec. 4.2 "Motion Entropy", Table 2 "Entropy"'
    equation = "H = -sum_k p_k log p_k of the histogram (equal bins over the clip's range) of the clip's values"

    def __init__(self, bins: int = ENTROPY_BINS) -> None:
        super().__init__()
        self.bins = bins

    def score(self, values, valid=None) -> Tensor:
        return motion_entropy(values, valid, bins=self.bins)


class Diversity(Metric):
    """Pairwise diversity of a set of motions, in the ``unit`` of the features (metres are printed in cm).

    A set metric: ``score(features [N, D])`` gives one value per pair of motions, the N (N - 1) / 2 distances
    (`pairwise_diversity`), not one per motion; ``update(features [..., D])`` collects feature vectors (one per
    motion) and ``compute()`` gives the mean ± std of the distances over all pairs of everything collected."""

    name, label, unit = "diversity", "Diversity", "feature units"
    higher_is_better = None
    paper = 'FlexMotion Sec. 4 and App. "DIV" (after MDM); all pairs instead of MDM\'s random pairs'
    equation = "mean over pairs i < j of ||f_i - f_j||, f the per-motion feature vectors"

    def __init__(self, unit: str = "feature units") -> None:
        super().__init__()
        _printed_in_cm(self, unit)
        self._features: list[Tensor] = []

    def reset(self) -> None:
        self._features = []

    def score(self, features) -> Tensor:
        return pairwise_diversity(features)

    def update(self, features) -> None:
        features = as_tensor(features, "features", min_dims=1)
        self._features.append(features.detach().reshape(-1, features.shape[-1]).to("cpu", torch.float64))

    def compute(self) -> MetricResult:
        if not self._features:
            return summarize(self.name, self.unit, torch.zeros(0, dtype=torch.float64))
        return summarize(self.name, self.unit, pairwise_diversity(torch.cat(self._features)))
