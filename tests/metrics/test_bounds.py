"""PercentileBounds: masked percentiles against numpy, JSON round trip, malformed files."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from biomotion.errors import DataFormatError
from biomotion.metrics.bounds import PercentileBounds, bound_excess


def test_masked_percentiles_match_numpy_per_column():
    rng = np.random.default_rng(3)
    values = rng.normal(size=(4, 50, 3)) * [1.0, 2.0, 3.0]
    column_mask = np.array([[True, True, False]] * 2 + [[True, True, True]] * 2)  # [clips, n]: col 2 absent twice
    frame_valid = np.ones((4, 50), dtype=bool)
    frame_valid[1, 40:] = False  # padding of clip 1
    mask = column_mask[:, None, :] & frame_valid[..., None]
    bounds = PercentileBounds.from_samples(
        torch.from_numpy(values), ("a", "b", "c"), mask=torch.from_numpy(mask), quantity="test", unit="rad/s"
    )
    for j in range(3):
        kept = values[..., j][mask[..., j]]
        assert bounds.low[j] == pytest.approx(np.percentile(kept, 5), abs=1e-12)
        assert bounds.high[j] == pytest.approx(np.percentile(kept, 95), abs=1e-12)
        assert bounds.counts[j] == kept.size
    assert bounds.counts.tolist() == [190, 190, 100]


def test_round_trip_and_unbounded_columns(tmp_path):
    values = np.array([[0.0, np.nan], [1.0, np.nan], [2.0, np.nan], [3.0, np.nan], [4.0, np.nan]])
    bounds = PercentileBounds.from_samples(values, ("knee", "elbow"), percentiles=(25, 75), unit="rad")
    assert bounds.low[0] == 1.0 and bounds.high[0] == 3.0 and np.isnan(bounds.low[1])
    path = tmp_path / "bounds.json"
    bounds.save(path)
    document = json.loads(path.read_text())
    assert document["columns"][1] == {"name": "elbow", "low": None, "high": None, "count": 0}
    loaded = PercentileBounds.load(path)
    assert loaded.names == ("knee", "elbow") and loaded.percentiles == (25.0, 75.0) and loaded.unit == "rad"
    np.testing.assert_array_equal(loaded.low, bounds.low)
    np.testing.assert_array_equal(loaded.high, bounds.high)
    x = torch.tensor([[0.5, 100.0], [3.5, -100.0], [2.0, 0.0]])
    assert loaded.excess(x).tolist() == [[0.5, 0.0], [0.5, 0.0], [0.0, 0.0]]  # the NaN column does not bound
    assert loaded.select(["elbow", "knee"]).names == ("elbow", "knee")
    with pytest.raises(DataFormatError, match="hip"):
        loaded.select(["hip"])


def test_malformed_bounds_are_rejected(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{"format": "biomotion-percentile-bounds/1",\n "columns": [')
    with pytest.raises(DataFormatError, match=r"bad\.json:2"):
        PercentileBounds.load(path)
    path.write_text(json.dumps({"format": "other"}))
    with pytest.raises(DataFormatError, match="format"):
        PercentileBounds.load(path)
    path.write_text(
        json.dumps(
            {
                "format": "biomotion-percentile-bounds/1",
                "percentiles": [5, 95],
                "columns": [{"name": "a", "low": 2.0, "high": 1.0}],
            }
        )
    )
    with pytest.raises(DataFormatError, match="field 'a'"):
        PercentileBounds.load(path)
    with pytest.raises(DataFormatError, match="names"):
        PercentileBounds.from_samples(np.zeros((3, 2)), ("only-one",))


def test_bound_excess_is_the_table_1_hinge():
    x = torch.tensor([-2.0, 0.0, 0.5, 3.0], requires_grad=True)
    excess = bound_excess(x, torch.tensor(-1.0), torch.tensor(1.0))
    assert excess.tolist() == [1.0, 0.0, 0.0, 2.0]
    excess.sum().backward()
    assert x.grad.tolist() == [-1.0, 0.0, 0.0, 1.0]
