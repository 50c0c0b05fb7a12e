"""The distribution metrics (FID, R-precision, diversity, multimodality) against their closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from biomotion.errors import DataFormatError
from biomotion.metrics import distribution as D
from biomotion.metrics.base import DESCRIPTION


def test_fid_of_a_set_with_itself_is_zero():
    x = np.random.default_rng(0).normal(size=(200, 8))
    assert D.fid(x, x) == pytest.approx(0.0, abs=1e-6)


def test_fid_of_a_shifted_set_is_the_squared_shift():
    """Same covariance, means apart by delta: the trace term vanishes and FID = ||delta||^2 exactly."""
    x = np.random.default_rng(1).normal(size=(500, 6))
    delta = np.array([0.3, -1.0, 0.0, 2.0, 0.5, -0.2])
    assert D.fid(x, x + delta) == pytest.approx(float(delta @ delta), rel=1e-6)


def test_frechet_distance_matches_the_closed_form_of_diagonal_gaussians():
    """||mu1 - mu2||^2 + sum_i (sqrt(a_i) - sqrt(b_i))^2 for diagonal covariances a, b."""
    mu1, mu2 = np.array([0.0, 1.0, -2.0]), np.array([1.0, 1.0, 0.0])
    a, b = np.array([1.0, 4.0, 0.25]), np.array([9.0, 1.0, 0.25])
    expected = float((mu1 - mu2) @ (mu1 - mu2) + ((np.sqrt(a) - np.sqrt(b)) ** 2).sum())
    assert D.frechet_distance(mu1, np.diag(a), mu2, np.diag(b)) == pytest.approx(expected, rel=1e-9)


def test_fid_of_samples_approaches_the_gaussian_closed_form():
    """Samples of N(0, I) and N(mu, 4 I) in 4 dims: FID -> ||mu||^2 + 4 (2 - 1)^2 as the samples grow."""
    rng = np.random.default_rng(2)
    mu = np.array([1.0, 0.0, -1.0, 0.5])
    value = D.fid(rng.normal(size=(40000, 4)), mu + 2.0 * rng.normal(size=(40000, 4)))
    assert value == pytest.approx(mu @ mu + 4.0, rel=0.03)


def test_fid_grows_with_the_mean_shift():
    x = np.random.default_rng(3).normal(size=(300, 5))
    values = [D.fid(x, x + s) for s in (0.0, 0.5, 1.0, 2.0)]
    assert values == sorted(values) and values[-1] == pytest.approx(4 * 5, rel=1e-6)


def test_fid_with_fewer_samples_than_dims_is_finite():
    rng = np.random.default_rng(4)
    assert math.isfinite(D.fid(rng.normal(size=(5, 16)), rng.normal(size=(6, 16))))


def test_fid_refuses_sets_of_different_widths_or_a_single_sample():
    with pytest.raises(DataFormatError):
        D.fid(np.zeros((4, 3)), np.zeros((4, 2)))
    with pytest.raises(DataFormatError):
        D.fid(np.zeros((1, 3)), np.zeros((4, 3)))


def test_r_precision_of_perfectly_matched_embeddings_is_one():
    rng = np.random.default_rng(5)
    texts = rng.normal(size=(100, 16))
    hits, pool = D.r_precision_hits(texts, texts)
    assert pool == 32 and hits.shape == (100, 3) and np.all(hits == 1.0)


def test_r_precision_with_repeated_texts_never_draws_the_own_text_as_a_distractor():
    """Ten motions of each of 40 texts, each embedded exactly on its text: all hits, although a random draw of
    other *clips* would often pick a clip of the same text."""
    rng = np.random.default_rng(6)
    table = rng.normal(size=(40, 8))
    names = np.repeat(np.arange(40), 10)
    hits, pool = D.r_precision_hits(table[names], table[names], names.tolist())
    assert pool == 32 and np.all(hits == 1.0)


def test_r_precision_of_unrelated_embeddings_is_chance():
    """Independent motion and text embeddings: top-k is k / 32."""
    rng = np.random.default_rng(7)
    hits, _ = D.r_precision_hits(rng.normal(size=(4000, 8)), rng.normal(size=(4000, 8)))
    assert hits.mean(0) == pytest.approx(np.array([1, 2, 3]) / 32, abs=0.015)


def test_r_precision_pool_shrinks_to_the_distinct_texts_and_ties_count_against():
    texts = np.eye(3)
    hits, pool = D.r_precision_hits(texts, texts)
    assert pool == 3 and np.all(hits == 1.0)
    midway = np.array([[0.5, 0.5, 0.0]])  # as near text 0 as text 1: a tie is no hit at top-1
    hits, _ = D.r_precision_hits(np.vstack([midway, texts[1:]]), texts, top_k=(1, 2))
    assert hits[0].tolist() == [0.0, 1.0]


def test_diversity_is_the_mean_random_pair_distance():
    x = np.zeros((4, 2))
    assert np.all(D.diversity_distances(x) == 0.0)
    two = np.array([[0.0, 0.0], [3.0, 4.0]])
    distances = D.diversity_distances(two, seed=0)
    assert len(distances) == 2 and set(distances.tolist()) <= {0.0, 5.0}
    many = np.random.default_rng(8).normal(size=(1000, 3))
    assert len(D.diversity_distances(many)) == 300


def test_diversity_of_gaussian_embeddings_matches_its_expectation():
    """Pairs of N(0, I_d) points are N(0, 2 I_d) apart: mean distance sqrt(2) * sqrt(2) Gamma((d+1)/2) / Gamma(d/2)."""
    d = 3
    x = np.random.default_rng(9).normal(size=(20000, d))
    expected = math.sqrt(2) * math.sqrt(2) * math.gamma((d + 1) / 2) / math.gamma(d / 2)
    assert D.diversity_distances(x, pairs=20000).mean() == pytest.approx(expected, rel=0.02)


def test_multimodality_averages_within_prompt_distances():
    x = np.array([[0.0, 0.0], [3.0, 4.0], [1.0, 1.0], [1.0, 1.0], [9.0, 9.0]])
    per_prompt = D.multimodality_per_prompt(x, ["a", "a", "b", "b", "c"])
    assert per_prompt.tolist() == [5.0, 0.0]  # "c" has one motion: left out


def test_metric_objects_describe_themselves():
    metrics = D.distribution_metrics()
    assert [m.name for m in metrics] == [
        "fid",
        "r_precision_top1",
        "r_precision_top2",
        "r_precision_top3",
        "diversity_evaluator",
        "multimodality",
    ]
    for metric in metrics:
        assert all(
            getattr(metric, field) not in ("", None)
            for field in DESCRIPTION
            if field not in ("higher_is_better", "display_unit")
        )
    assert [m.higher_is_better for m in metrics] == [False, True, True, True, None, True]


def test_metric_objects_score_like_the_functions():
    rng = np.random.default_rng(10)
    x, y = rng.normal(size=(50, 4)), rng.normal(size=(60, 4)) + 1.0
    fid, top1, top2, top3, diversity, multimodality = D.distribution_metrics()
    assert float(fid.score(x, y)[0]) == pytest.approx(D.fid(x, y))
    assert torch.equal(top3.score(x, x), torch.ones(50, dtype=torch.float64))
    assert float(diversity.score(x).mean()) == pytest.approx(D.diversity_distances(x).mean())
    assert multimodality.score(x, ["p"] * 50).shape == (1,)
    with pytest.raises(DataFormatError):
        D.RPrecision(top_k=32)


def test_set_figures_and_half_split_fid():
    rng = np.random.default_rng(11)
    table = rng.normal(size=(40, 8))
    names = np.repeat(np.arange(40), 4)
    figures = D.set_figures(table[names], table[names], names.tolist())
    assert figures["r_precision_top1"] == 1.0 and figures["matching_score"] == 0.0
    assert figures["motions"] == 160 and figures["texts"] == 40 and figures["multimodality"] == 0.0
    assert D.half_split_fid(rng.normal(size=(4000, 3))) == pytest.approx(0.0, abs=0.02)


def test_the_registry_lists_the_distribution_metrics():
    from biomotion.metrics.registry import DISTRIBUTION

    assert [m.name for m in DISTRIBUTION] == [m.name for m in D.distribution_metrics()]
