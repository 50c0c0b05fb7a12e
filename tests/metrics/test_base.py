"""The update()/compute() protocol, masks and finite differences shared by every metric."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from biomotion.errors import DataFormatError
from biomotion.metrics.base import column_mask, difference, masked_mean, pair_mask
from biomotion.metrics.contact import Penetration


def test_update_compute_reset_and_nan_sequences():
    metric = Penetration()
    batch = torch.zeros(3, 4, 1, 3)
    batch[0, :, 0, 1] = -0.01
    batch[1, :, 0, 1] = -0.03
    valid = torch.tensor([[True] * 4, [True] * 4, [False] * 4])  # the third clip is all padding: undefined
    values = metric.update(batch, valid)
    assert values.shape == (3,) and math.isnan(values[2].item())
    metric.update(np.zeros((4, 1, 3)))  # numpy input, one clip without batch dims
    result = metric.compute()
    assert result.count == 3 and result.values.shape == (4,)
    assert result.mean == pytest.approx(0.04 / 3) and float(result) == result.mean
    assert result.std == pytest.approx(np.std([0.01, 0.03, 0.0]))
    assert result.name == "penetration" and result.unit == "m"
    metric.reset()
    assert metric.compute().count == 0 and math.isnan(metric.compute().mean)


def test_masks_and_differences():
    valid = torch.tensor([True, True, False, True, True, True])
    assert pair_mask(valid).tolist() == [True, False, False, True, True]
    assert pair_mask(valid, 2).tolist() == [False, False, False, True]
    x = torch.tensor([1.0, 2.0, 3.0, 4.0])
    assert masked_mean(x, torch.tensor([True, False, True, False]), -1).item() == 2.0
    assert math.isnan(masked_mean(x, torch.zeros(4, dtype=torch.bool), -1).item())
    per_clip = column_mask(torch.tensor([[True, False], [False, True]]), (2, 5, 2), 1)
    assert per_clip.shape == (2, 4, 2) and per_clip[0, :, 0].all() and not per_clip[0, :, 1].any()
    per_frame = torch.ones(5, 2, dtype=torch.bool)
    per_frame[2, 1] = False
    assert column_mask(per_frame, (5, 2), 1)[:, 1].tolist() == [True, False, False, True]
    t = torch.arange(5, dtype=torch.float64) / 10
    assert difference((t**2)[:, None], 10.0, 2).flatten().tolist() == pytest.approx([2.0] * 3)
    with pytest.raises(DataFormatError, match="rate"):
        difference(t[:, None], 0.0)
    with pytest.raises(DataFormatError, match="frames"):
        difference(t[:2, None], 10.0, 2)
    with pytest.raises(DataFormatError, match="valid"):
        Penetration().score(torch.zeros(4, 1, 3), torch.ones(3, dtype=torch.bool))
