"""The torch OpenSim functions against OpenSim 4.6's own Function objects (values and first two derivatives),
on random knots and on every transform-axis function of the Rajagopal model."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.body.functions import build_function
from biomotion.io import osim as spec
from tests.body.oracle import osim
from tests.conftest import data_path

TOLERANCE = 1e-9


def _opensim_function(tmp_path, tag: str, x, y):
    path = tmp_path / f"{tag}.xml"
    path.write_text(
        f'<?xml version="1.0"?><OpenSimDocument Version="40000"><{tag} name="f">'
        f"<x>{' '.join(map(repr, x))}</x><y>{' '.join(map(repr, y))}</y></{tag}></OpenSimDocument>"
    )
    return osim.Function.safeDownCast(osim.OpenSimObject.makeObjectFromFile(str(path)))


def _opensim_values(function, xs, order: int = 0) -> np.ndarray:
    if order == 0:
        return np.array([function.calcValue(osim.Vector(1, float(v))) for v in xs])
    return np.array([function.calcDerivative(osim.StdVectorInt([0] * order), osim.Vector(1, float(v))) for v in xs])


@pytest.mark.parametrize(
    "tag, cls",
    [
        ("SimmSpline", spec.SimmSpline),
        ("NaturalCubicSpline", spec.NaturalCubicSpline),
        ("PiecewiseLinearFunction", spec.PiecewiseLinearFunction),
    ],
)
@pytest.mark.parametrize("knots", [2, 3, 4, 5, 13])
def test_splines_match_opensim(tmp_path, tag: str, cls, knots: int) -> None:
    rng = np.random.default_rng(knots)
    x = np.sort(rng.uniform(-1.0, 2.0, knots))
    y = rng.normal(size=knots)
    between = np.linspace(x[0] - 0.7, x[-1] + 0.7, 301)  # inside and outside the knots
    xs = np.concatenate([between, x])
    ours = build_function(cls(tuple(x), tuple(y)))
    reference = _opensim_function(tmp_path, tag, x.tolist(), y.tolist())
    value, slope, curvature = ours.derivatives(torch.tensor(xs))
    assert np.abs(value.numpy() - _opensim_values(reference, xs)).max() <= TOLERANCE
    assert np.abs(ours(torch.tensor(xs)).numpy() - value.numpy()).max() == 0.0
    n = between.size  # derivatives are compared off the knots, where a piecewise-linear slope is undefined
    assert np.abs(slope.numpy()[:n] - _opensim_values(reference, between, 1)).max() <= TOLERANCE
    assert np.abs(curvature.numpy()[:n] - _opensim_values(reference, between, 2)).max() <= TOLERANCE


def test_polynomial_linear_constant_multiplier_match_opensim() -> None:
    xs = np.linspace(-2.0, 2.0, 41)
    cases = [
        (spec.PolynomialFunction((0.5, -1.0, 2.0, 3.0)), osim.PolynomialFunction(osim.Vector([0.5, -1.0, 2.0, 3.0]))),
        (spec.LinearFunction(-2.5, 0.3), osim.LinearFunction(-2.5, 0.3)),
        (spec.ConstantFunction(0.7), osim.Constant(0.7)),
    ]
    for ours_spec, reference in cases:
        ours = build_function(ours_spec)
        for order in range(3):
            assert (
                np.abs(ours.derivatives(torch.tensor(xs))[order].numpy() - _opensim_values(reference, xs, order)).max()
                <= TOLERANCE
            )
    multiplied = build_function(spec.MultiplierFunction(spec.PolynomialFunction((1.0, 0.0, -1.0)), 1.5))
    assert torch.allclose(multiplied(torch.tensor(xs)), 1.5 * (torch.tensor(xs) ** 2 - 1.0), atol=1e-15, rtol=0)


def test_every_rajagopal_transform_function_matches_opensim() -> None:
    path = data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")
    model = osim.Model(str(path))
    parsed = {j.name: j for j in spec.read_osim(path).joints}
    xs = np.linspace(-0.5, 2.6, 63)
    checked = 0
    for i in range(model.getJointSet().getSize()):
        joint = osim.CustomJoint.safeDownCast(model.getJointSet().get(i))
        if joint is None:
            continue
        transform = joint.getSpatialTransform()
        for k in range(6):
            axis = transform.getTransformAxis(k)
            if axis.getCoordinateNamesInArray().getSize() == 0:
                continue
            ours = build_function(parsed[joint.getName()].transform[k].function)
            for order in range(3):
                assert (
                    np.abs(
                        ours.derivatives(torch.tensor(xs))[order].numpy()
                        - _opensim_values(axis.getFunction(), xs, order)
                    ).max()
                    <= TOLERANCE
                )
            checked += 1
    assert checked >= 30


def test_autograd_and_float32() -> None:
    ours = build_function(spec.SimmSpline((0.0, 0.5, 1.0, 1.5, 2.0), (0.0, 0.3, 0.2, -0.1, 0.4)))
    x = torch.linspace(-0.2, 2.2, 25, dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(ours(x).sum(), x)
    assert torch.allclose(grad, ours.derivatives(x.detach())[1], atol=1e-12, rtol=0)
    assert ours(x.detach().float()).dtype == torch.float32
    assert torch.allclose(ours(x.detach().float()).double(), ours(x.detach()), atol=1e-6, rtol=0)
