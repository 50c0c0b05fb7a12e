"""The field's distribution metrics of text-to-motion generation, on the embeddings of a motion-text evaluator:
FID, R-precision (top-1/2/3), diversity and multimodality (Guo et al. 2022, "Generating Diverse and Natural 3D
Human Motions from Text", CVPR, Sec. 5 "Evaluation metrics"; FlexMotion Sec. 4 "Evaluation Metrics" and Tables
1-3 report R-precision, FID and DIV with the same definitions).

Every function takes embeddings already computed (``[N, D]`` per-motion vectors from the evaluator's motion
encoder, ``[N, D]`` per-text vectors from its text encoder), so the formulas are tested here without any network
(`biomotion.models.motion_text_evaluator` makes the embeddings, `biomotion.evaluation.distribution` feeds them).

- FID (Heusel et al. 2017, Eq. 6): the Fréchet distance between the Gaussians fitted to two embedding sets,
  ``||mu_1 - mu_2||^2 + tr(S_1 + S_2 - 2 (S_1 S_2)^(1/2))``, with `scipy.linalg.sqrtm` as the reference code
  (pytorch-fid, T2M's ``calculate_frechet_distance``) computes it: a tiny diagonal offset where the product is
  singular and the real part of the root.
- R-precision (T2M): each motion is ranked against a pool of its own text and 31 other texts by Euclidean distance
  of the embeddings; top-k is the share of motions whose own text is among the k nearest. The action and style
  labels of the datasets repeat (many clips share "walk, happy"), so the 31 others are drawn among the *distinct*
  texts other than the motion's own (T2M draws random clips of HumanML3D, whose captions almost never repeat);
  where fewer than 31 other texts exist the pool is all of them, and the pool size is reported.
- Diversity (T2M): the mean Euclidean distance between ``S_d`` random pairs of motion embeddings (two independent
  draws without replacement of ``min(S_d, N)`` motions, T2M's S_d = 300).
- Multimodality (T2M): for each prompt with at least two motions, the mean distance between ``S_l`` random pairs
  of distinct motions generated for it (T2M: S_l = 10), averaged over prompts.

Distances are in embedding units (the evaluator's unit-length embeddings: 0 to 2), so the figures compare
generators scored by the *same* evaluator, never with published numbers of another evaluator.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np
import torch

from biomotion.errors import DataFormatError
from biomotion.metrics.base import Metric, MetricResult, Tensor, summarize

R_PRECISION_POOL = 32
"""Texts a motion is ranked against in R-precision: its own and 31 others (T2M)."""
DIVERSITY_PAIRS = 300
"""Random pairs of the diversity (T2M's S_d)."""
MULTIMODALITY_PAIRS = 10
"""Random pairs per prompt of the multimodality (T2M's S_l)."""
TOP_K = (1, 2, 3)


def _embeddings(x, name: str) -> np.ndarray:
    array = np.asarray(x.detach().cpu().numpy() if isinstance(x, Tensor) else x, dtype=np.float64)
    if array.ndim != 2 or array.shape[0] == 0:
        raise DataFormatError(None, f"needs embeddings [N, D] with N >= 1, got shape {array.shape}", field=name)
    if not np.all(np.isfinite(array)):
        raise DataFormatError(None, "non-finite embedding values", field=name)
    return array


def gaussian(embeddings) -> tuple[np.ndarray, np.ndarray]:
    """Mean [D] and covariance [D, D] (unbiased, ``numpy.cov``) of embeddings [N, D], N >= 2."""
    x = _embeddings(embeddings, "embeddings")
    if x.shape[0] < 2:
        raise DataFormatError(None, f"a covariance needs at least 2 embeddings, got {x.shape[0]}", field="embeddings")
    return x.mean(0), np.atleast_2d(np.cov(x, rowvar=False))


def frechet_distance(mu1, sigma1, mu2, sigma2, eps: float = 1e-6) -> float:
    """Fréchet distance between N(mu1, sigma1) and N(mu2, sigma2) (Heusel et al. 2017, Eq. 6; Dowson & Landau 1982):
    ``||mu1 - mu2||^2 + tr(sigma1) + tr(sigma2) - 2 tr((sigma1 sigma2)^(1/2))``.

    The matrix square root is `scipy.linalg.sqrtm`; where the product is singular (fewer samples than dims) it is
    taken of ``(sigma1 + eps I)(sigma2 + eps I)``, and a complex root from rounding keeps its real part, as the
    reference implementations do. Rounding can make the result slightly negative: it is clipped at 0."""
    from scipy import linalg

    mu1, mu2 = np.atleast_1d(np.asarray(mu1, np.float64)), np.atleast_1d(np.asarray(mu2, np.float64))
    sigma1, sigma2 = np.atleast_2d(np.asarray(sigma1, np.float64)), np.atleast_2d(np.asarray(sigma2, np.float64))
    if mu1.shape != mu2.shape or sigma1.shape != sigma2.shape or sigma1.shape != (mu1.size, mu1.size):
        raise DataFormatError(
            None,
            f"Gaussians of different sizes: means {mu1.shape}, {mu2.shape}; covariances {sigma1.shape}, {sigma2.shape}",
            field="sigma",
        )
    diff = mu1 - mu2
    covmean = linalg.sqrtm(sigma1 @ sigma2)
    if not np.all(np.isfinite(covmean)):
        offset = np.eye(mu1.size) * eps
        covmean = linalg.sqrtm((sigma1 + offset) @ (sigma2 + offset))
    covmean = np.real(covmean)
    value = diff @ diff + np.trace(sigma1) + np.trace(sigma2) - 2.0 * np.trace(covmean)
    return max(float(value), 0.0)


def fid(embeddings_1, embeddings_2) -> float:
    """FID between two embedding sets [N1, D] and [N2, D] (`frechet_distance` of their fitted Gaussians)."""
    return frechet_distance(*gaussian(embeddings_1), *gaussian(embeddings_2))


def _groups(groups: Sequence[Hashable] | None, n: int, name: str) -> np.ndarray:
    """Integer group ids [n] (equal ids = equal prompt); None makes every item its own group."""
    if groups is None:
        return np.arange(n)
    groups = list(groups)
    if len(groups) != n:
        raise DataFormatError(None, f"{len(groups)} groups for {n} embeddings", field=name)
    ids: dict[Hashable, int] = {}
    return np.array([ids.setdefault(g, len(ids)) for g in groups], dtype=np.int64)


def r_precision_hits(
    motion_embeddings,
    text_embeddings,
    texts: Sequence[Hashable] | None = None,
    *,
    pool: int = R_PRECISION_POOL,
    top_k: Sequence[int] = TOP_K,
    seed: int = 0,
) -> tuple[np.ndarray, int]:
    """Per-motion R-precision hits [N, len(top_k)] (1.0 where the motion's own text is among its k nearest texts of
    the pool) and the pool size used (T2M Sec. 5; module docstring for the pool).

    ``motion_embeddings`` [N, D] and ``text_embeddings`` [N, D] are paired row by row; ``texts`` [N] names each
    row's text (rows with equal names have the same text; None: every row its own text). Each motion's pool is its
    own text and ``pool - 1`` distinct other texts drawn with ``seed``; ties in distance count against the motion
    (its text must be strictly nearer than the k-th other)."""
    motions = _embeddings(motion_embeddings, "motion_embeddings")
    text_rows = _embeddings(text_embeddings, "text_embeddings")
    if motions.shape != text_rows.shape:
        raise DataFormatError(
            None, f"motion {motions.shape} and text {text_rows.shape} embeddings differ", field="text_embeddings"
        )
    ids = _groups(texts, len(motions), "texts")
    unique, first = np.unique(ids, return_index=True)
    table = text_rows[first]  # one embedding per distinct text, indexed by position in ``unique``
    position = np.searchsorted(unique, ids)
    if len(unique) < 2:
        raise DataFormatError(None, "R-precision needs at least 2 distinct texts", field="texts")
    others = min(pool - 1, len(unique) - 1)
    rng = np.random.default_rng(seed)
    k = np.asarray(list(top_k))
    hits = np.zeros((len(motions), len(k)))
    for i, own in enumerate(position):
        candidates = np.delete(np.arange(len(unique)), own)
        chosen = rng.choice(candidates, size=others, replace=False)
        own_distance = np.linalg.norm(motions[i] - table[own])
        other_distance = np.linalg.norm(motions[i] - table[chosen], axis=-1)
        rank = int(np.sum(other_distance <= own_distance))  # 0: the own text is the nearest
        hits[i] = rank < k
    return hits, others + 1


def diversity_distances(embeddings, pairs: int = DIVERSITY_PAIRS, seed: int = 0) -> np.ndarray:
    """T2M diversity: distances [min(pairs, N)] between the embeddings of two independent random orderings of
    ``min(pairs, N)`` motions (draws without replacement); their mean is the diversity."""
    x = _embeddings(embeddings, "embeddings")
    if len(x) < 2:
        raise DataFormatError(None, f"diversity needs at least 2 motions, got {len(x)}", field="embeddings")
    rng = np.random.default_rng(seed)
    count = min(pairs, len(x))
    first, second = rng.choice(len(x), count, replace=False), rng.choice(len(x), count, replace=False)
    return np.linalg.norm(x[first] - x[second], axis=-1)


def multimodality_per_prompt(
    embeddings, prompts: Sequence[Hashable], pairs: int = MULTIMODALITY_PAIRS, seed: int = 0
) -> np.ndarray:
    """T2M multimodality per prompt [P]: for each prompt (in order of first appearance) with at least two motions,
    the mean distance of ``pairs`` random pairs of distinct motions of that prompt (both members of a pair drawn
    uniformly, redrawn until they differ); prompts with one motion are left out. Their mean is the multimodality."""
    x = _embeddings(embeddings, "embeddings")
    ids = _groups(prompts, len(x), "prompts")
    rng = np.random.default_rng(seed)
    values = []
    for group in dict.fromkeys(ids.tolist()):
        members = np.flatnonzero(ids == group)
        if len(members) < 2:
            continue
        first = rng.integers(len(members), size=pairs)
        second = (first + rng.integers(1, len(members), size=pairs)) % len(members)  # uniform over the others
        values.append(np.linalg.norm(x[members[first]] - x[members[second]], axis=-1).mean())
    return np.asarray(values, dtype=np.float64)


class FrechetInceptionDistance(Metric):
    """FID between generated and real motion embeddings (T2M Sec. 5; FlexMotion Tables 1-3 "FID"). A set metric:
    ``score(generated [N1, D], real [N2, D])`` is one value [1]."""

    name, label, unit = "fid", "FID", "embedding units²"
    higher_is_better = False
    paper = "Heusel et al. 2017 Eq. 6; T2M (Guo et al. 2022) Sec. 5; FlexMotion Tables 1-3"
    equation = "||mu_g - mu_r||^2 + tr(S_g + S_r - 2 (S_g S_r)^(1/2)) of the embedding Gaussians"

    def score(self, generated, real) -> Tensor:
        return torch.tensor([fid(generated, real)], dtype=torch.float64)


class RPrecision(Metric):
    """R-precision top-k (T2M Sec. 5 top-1/2/3; FlexMotion Tables 1-3 "R-Precision"): ``score(motions [N, D], texts
    [N, D], names)`` gives per-motion hits [N] (1 where the own text ranks within the top k of its pool of 32)."""

    higher_is_better = True
    unit = "1"
    paper = "T2M (Guo et al. 2022) Sec. 5; FlexMotion Tables 1-3"

    def __init__(self, top_k: int = 1, pool: int = R_PRECISION_POOL, seed: int = 0) -> None:
        super().__init__()
        if top_k < 1 or top_k >= pool:
            raise DataFormatError(None, f"top_k must be in 1 .. {pool - 1}, got {top_k}", field="top_k")
        self.top_k, self.pool, self.seed = top_k, pool, seed
        self.name, self.label = f"r_precision_top{top_k}", f"R-precision top-{top_k}"
        self.equation = (
            f"share of motions whose own text is among the {top_k} nearest (Euclidean) of itself and "
            f"{pool - 1} distinct other texts"
        )

    def score(self, motion_embeddings, text_embeddings, texts=None) -> Tensor:
        hits, _ = r_precision_hits(
            motion_embeddings, text_embeddings, texts, pool=self.pool, top_k=(self.top_k,), seed=self.seed
        )
        return torch.from_numpy(hits[:, 0])


class EmbeddingDiversity(Metric):
    """T2M diversity of a set of motion embeddings (FlexMotion Tables 1-3 "DIV", closer to the real data's is
    better): ``score(embeddings [N, D])`` gives the ``min(300, N)`` random-pair distances."""

    name, label, unit = "diversity_evaluator", "Diversity (evaluator)", "embedding units"
    higher_is_better = None
    paper = 'T2M (Guo et al. 2022) Sec. 5 (S_d = 300); FlexMotion Tables 1-3 "DIV"'
    equation = "mean over S_d random pairs (i, j) of ||f_i - f_j||, f the evaluator's motion embeddings"

    def __init__(self, pairs: int = DIVERSITY_PAIRS, seed: int = 0) -> None:
        super().__init__()
        self.pairs, self.seed = pairs, seed

    def score(self, embeddings) -> Tensor:
        return torch.from_numpy(diversity_distances(embeddings, self.pairs, self.seed))


class Multimodality(Metric):
    """T2M multimodality (T2M "MModality"; FlexMotion does not report it; higher: more varied motions per prompt):
    ``score(embeddings [N, D], prompts [N])`` gives one value per prompt with two motions or more."""

    name, label, unit = "multimodality", "Multimodality", "embedding units"
    higher_is_better = True
    paper = "T2M (Guo et al. 2022) Sec. 5 (S_l = 10)"
    equation = "mean over prompts of the mean ||f_i - f_j|| over S_l random pairs of motions of the prompt"

    def __init__(self, pairs: int = MULTIMODALITY_PAIRS, seed: int = 0) -> None:
        super().__init__()
        self.pairs, self.seed = pairs, seed

    def score(self, embeddings, prompts) -> Tensor:
        return torch.from_numpy(multimodality_per_prompt(embeddings, prompts, self.pairs, self.seed))


def distribution_metrics(seed: int = 0) -> list[Metric]:
    """The distribution metrics in report order: FID, R-precision top-1/2/3, diversity, multimodality."""
    return [
        FrechetInceptionDistance(),
        *(RPrecision(k, seed=seed) for k in TOP_K),
        EmbeddingDiversity(seed=seed),
        Multimodality(seed=seed),
    ]


def summary(metric: Metric, values: Tensor) -> MetricResult:
    """`MetricResult` of a distribution metric's ``score`` values (mean is the figure the papers print)."""
    return summarize(metric.name, metric.unit, values)


def set_figures(motion_embeddings, text_embeddings, texts: Sequence[Hashable], seed: int = 0) -> dict:
    """The figures of one set of motions with their texts: R-precision top-1/2/3 (with the pool size), the matching
    score (T2M "MM-Dist": mean distance of a motion to its own text), the diversity and the multimodality over the
    set's texts as prompts (None where no text has two motions); counts of motions and distinct texts."""
    motions = _embeddings(motion_embeddings, "motion_embeddings")
    text_rows = _embeddings(text_embeddings, "text_embeddings")
    hits, pool = r_precision_hits(motions, text_rows, texts, seed=seed)
    per_prompt = multimodality_per_prompt(motions, texts, seed=seed)
    figures = {f"r_precision_top{k}": float(hits[:, i].mean()) for i, k in enumerate(TOP_K)}
    return {
        **figures,
        "r_precision_pool": pool,
        "matching_score": float(np.linalg.norm(motions - text_rows, axis=-1).mean()),
        "diversity_evaluator": float(diversity_distances(motions, seed=seed).mean()),
        "multimodality": float(per_prompt.mean()) if len(per_prompt) else None,
        "motions": len(motions),
        "texts": len(set(texts)),
    }


def half_split_fid(embeddings, seed: int = 0) -> float:
    """FID between two random halves of one set of embeddings: the floor a generator's FID against the same real
    set is to be read against (finite samples give a positive FID even between draws of one distribution)."""
    x = _embeddings(embeddings, "embeddings")
    order = np.random.default_rng(seed).permutation(len(x))
    half = len(x) // 2
    return fid(x[order[:half]], x[order[half : 2 * half]])
