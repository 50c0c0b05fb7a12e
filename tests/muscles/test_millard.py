"""Millard 2012 curves against OpenSim 4.6 (the oracle); the Millard muscles' force per unit activation is
checked in test_properties.py."""

import numpy as np
import pytest
import torch

from biomotion.errors import ModelError
from biomotion.muscles.millard import (
    ACTIVE_DEFAULTS,
    VELOCITY_DEFAULTS,
    active_force_length_curve,
    corner_points,
    force_velocity_curve,
)

#: (min, transition, max, shallow slope, minimum value): Rajagopal 2016's curve and OpenSim's default one
ACTIVE = [(0.25, 0.77, 1.9, 0.75, 0.0), tuple(ACTIVE_DEFAULTS.values())]
VELOCITY = [tuple(VELOCITY_DEFAULTS.values()), (0.05, 0.3, 4.0, 0.02, 0.1, 1.6, 0.3, 0.5)]


def _parameters(rows, keys):
    return {k: torch.tensor([row[i] for row in rows], dtype=torch.float64) for i, k in enumerate(keys)}


def test_corner_meets_its_end_points_with_their_slopes():
    x, y = corner_points(0.0, 0.0, 0.0, 1.0, 1.0, 3.0, 0.5)
    assert (float(x[0]), float(y[0]), float(x[5]), float(y[5])) == (0.0, 0.0, 1.0, 1.0)
    assert float((y[1] - y[0]) / (x[1] - x[0])) == pytest.approx(0.0)
    assert float((y[5] - y[4]) / (x[5] - x[4])) == pytest.approx(3.0)


def test_curves_are_monotone_where_they_should_be_and_extend_linearly():
    fv = force_velocity_curve(_parameters(VELOCITY, VELOCITY_DEFAULTS))
    v = torch.linspace(-1.5, 1.5, 3001, dtype=torch.float64)[:, None].expand(-1, 2)
    values = fv(v)
    assert bool((values.diff(dim=0) >= -1e-12).all())
    assert values[-1, 1] == pytest.approx(1.6 + 0.02 * 0.5)  # fmax + eccentric slope at vmax x 0.5
    afl = active_force_length_curve(_parameters(ACTIVE, ACTIVE_DEFAULTS))
    assert afl(torch.tensor([[0.0, 0.0]], dtype=torch.float64)).tolist() == [[0.0, 0.1]]  # the floor


def test_curves_match_opensim():
    opensim = pytest.importorskip("opensim")
    opensim.Logger.setLevelString("error")
    afl = active_force_length_curve(_parameters(ACTIVE, ACTIVE_DEFAULTS))
    lengths = np.linspace(0.0, 2.2, 1101)
    ours = afl(torch.tensor(np.stack([lengths, lengths], 1))).numpy()
    for k, row in enumerate(ACTIVE):
        curve = opensim.ActiveForceLengthCurve(*row)
        reference = np.array([curve.calcValue(float(x)) for x in lengths])
        np.testing.assert_allclose(ours[:, k], reference, atol=1e-8)  # measured 4e-9
    fv = force_velocity_curve(_parameters(VELOCITY, VELOCITY_DEFAULTS))
    speeds = np.linspace(-1.3, 1.3, 1301)
    ours = fv(torch.tensor(np.stack([speeds, speeds], 1))).numpy()
    for k, row in enumerate(VELOCITY):
        curve = opensim.ForceVelocityCurve(*row)
        reference = np.array([curve.calcValue(float(v)) for v in speeds])
        np.testing.assert_allclose(ours[:, k], reference, atol=1e-8)


def test_bad_curve_parameters_are_refused():
    bad = _parameters([(0.8, 0.7, 1.9, 0.75, 0.0)], ACTIVE_DEFAULTS)  # transition below the minimum
    with pytest.raises(ModelError, match="active force-length"):
        active_force_length_curve(bad)


def test_gradient_flows_through_the_curve_inversion():
    fv = force_velocity_curve(_parameters(VELOCITY[:1], VELOCITY_DEFAULTS))
    v = torch.tensor([[-0.4], [0.2]], dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(fv(v).sum(), v)
    step = 1e-6
    numeric = (fv(v.detach() + step) - fv(v.detach() - step)) / (2 * step)
    np.testing.assert_allclose(grad.numpy(), numeric.numpy(), rtol=1e-6)


def test_passive_curve_matches_opensim_and_refuses_other_strains():
    opensim = pytest.importorskip("opensim")
    opensim.Logger.setLevelString("error")
    from biomotion.muscles.millard import passive_force_length_curve

    reference_curve = opensim.FiberForceLengthCurve()  # the defaults every Rajagopal muscle uses
    curve = passive_force_length_curve(
        {
            "strain_at_zero_force": torch.zeros(1, dtype=torch.float64),
            "strain_at_one_norm_force": torch.full((1,), 0.7, dtype=torch.float64),
        }
    )
    lengths = np.linspace(0.8, 2.0, 601)
    reference = np.array([reference_curve.calcValue(float(x)) for x in lengths])
    np.testing.assert_allclose(curve(torch.tensor(lengths)[:, None])[:, 0].numpy(), reference, atol=1e-10)
    with pytest.raises(ModelError, match="default strains"):
        passive_force_length_curve(
            {
                "strain_at_zero_force": torch.zeros(1, dtype=torch.float64),
                "strain_at_one_norm_force": torch.full((1,), 0.5, dtype=torch.float64),
            }
        )
