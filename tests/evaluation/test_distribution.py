"""The distribution-metric hook: clips in canonical order, the repeated figures and the report's Markdown (the
scoring itself on a trained evaluator: tests/training/test_train_evaluator.py)."""

from __future__ import annotations

import numpy as np
import pytest

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.errors import BiomotionError
from biomotion.evaluation import distribution as ED
from biomotion.motion import Motion


def test_text_clip_puts_coordinates_in_canonical_order_and_combines_masks():
    names = tuple(reversed(CANONICAL_COORDINATES))
    values = np.tile(np.arange(39, dtype=float)[::-1], (5, 1))  # column j holds the canonical index of its name
    own = np.ones(39, bool)
    own[0] = False  # the last canonical coordinate is absent from the motion
    motion = Motion(times=np.arange(5) / 30.0, names=names, values=values, mask=own)
    other = np.ones(39, bool)
    other[1] = False
    clip = ED.text_clip(motion, "walk", mask=other)
    np.testing.assert_array_equal(clip.values[0], np.arange(39))
    assert clip.mask.tolist() == [i not in (1, 38) for i in range(39)]
    assert clip.rate == pytest.approx(30.0)
    with pytest.raises(BiomotionError, match="lacks canonical coordinates"):
        ED.text_clip(Motion(times=np.arange(5) / 30.0, names=names[:5], values=values[:, :5]), "walk")


def test_repeated_figures_keep_counts_and_average_the_rest():
    out = ED._repeated(lambda seed: {"a": float(seed), "n": 7, "m": None}, 3)
    assert out == {"a": {"mean": 1.0, "std": pytest.approx(np.std([0, 1, 2]))}, "n": 7, "m": None}
    assert ED._repeated(lambda seed: 2.0, 2) == {"mean": 2.0, "std": 0.0}


def test_markdown_shows_the_real_figures_and_pgbig_beside_them():
    figures = {key: {"mean": 0.5, "std": 0.01} for key, _ in ED._ROWS} | {"r_precision_pool": 32, "texts": 40}
    report = {
        "command": "python -m biomotion.evaluation.distribution",
        "evaluator": {"weights": "evaluator.safetensors", "sha256": "0" * 64, "trained_on": "x", "train_clips": 3},
        "held_out": {"splits": ["val", "test"], "clips": 9, "subjects": 2, "clips_per_source": {"s": 9}},
        "repeats": 2,
        "real_held_out": figures,
        "fid_real_halves": {"mean": 0.04, "std": 0.01},
        "pgbig": None,
    }
    report["held_out"]["distinct_texts"] = 4
    text = ED.markdown(report)
    assert "| R-precision top-1 ↑ | 0.500 ± 0.010 |" in text and "PG-BIG" not in text
    report["pgbig"] = {
        "generator_sources": ["fukuchi"],
        "targets": 5,
        "subjects": 2,
        "samples_per_target": 2,
        "max_seconds": 6.0,
        "real": figures,
        "generated": figures,
        "fid_real_halves": {"mean": 0.1, "std": 0.0},
        "fid_generated_to_real": 0.3,
        "fid_generated_to_real_one_sample_per_clip": {"mean": 0.5, "std": 0.1},
    }
    text = ED.markdown(report)
    assert "| FID to the real clips, all samples (10 vs 5) ↓ | – | 0.300 |" in text
    assert "| FID to the real clips, one sample per clip (5 vs 5) ↓ | – | 0.500 ± 0.100 |" in text
    assert "| FID between two halves of the real clips (2 vs 2) | 0.100 ± 0.000 | – |" in text
