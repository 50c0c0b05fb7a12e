"""ScaleSet application against OpenSim 4.6's Model.scale on the Fukuchi runners' scale sets applied to the
generic Denton 2023 model (and the Uhlrich 2022 one), with and without preserving the mass distribution."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.body.kinematics import forward_kinematics, marker_positions
from biomotion.body.model import BodyModel
from biomotion.body.scaling.bodies import scale_factors, scale_model, scale_model_from_file
from biomotion.io.osim import read_scale_set
from tests.body.oracle import osim, random_poses
from tests.conftest import DATA_ROOT, data_path

DENTON = "fukuchi-running/generic-models/Denton2023_LowerLimb_Fukuchi2017.osim"
UHLRICH = "fukuchi-running/generic-models/Uhlrich2022_LowerLimb_Fukuchi2017.osim"
SCALE_SET = "fukuchi-running/RBDS001/RBDS001_scaleSet_simple.xml"
RUNNER_MASS = 62.0  # kg, RBDS001 in participantInfo.csv


def _opensim_scaled(source, scale_set, preserve: bool, mass: float, tmp_path) -> BodyModel:
    model = osim.Model(str(source))
    state = model.initSystem()
    assert model.scale(state, osim.ScaleSet(str(scale_set)), preserve, mass)
    out = tmp_path / f"scaled_{preserve}.osim"
    model.printToXML(str(out))
    return BodyModel.from_osim(out)


def _assert_same(ours: BodyModel, reference: BodyModel) -> None:
    assert (ours.masses - reference.masses).abs().max() <= 1e-9
    assert (ours.coms - reference.coms).abs().max() <= 1e-12
    assert (ours.inertias - reference.inertias).abs().max() <= 1e-12
    q = torch.tensor(random_poses(ours, np.random.default_rng(0), 3))
    a, b = forward_kinematics(ours, q), forward_kinematics(reference, q)
    assert (a.positions - b.positions).abs().max() <= 1e-9
    assert (marker_positions(ours, q) - marker_positions(reference, q)).abs().max() <= 1e-9


@pytest.mark.parametrize("generic", [DENTON, UHLRICH])
@pytest.mark.parametrize("preserve", [True, False])
def test_scale_set_matches_opensim(generic: str, preserve: bool, tmp_path) -> None:
    source, scale_set = data_path(generic), data_path(SCALE_SET)
    ours = scale_model_from_file(BodyModel.from_osim(source), scale_set, RUNNER_MASS, preserve)
    _assert_same(ours, _opensim_scaled(source, scale_set, preserve, RUNNER_MASS, tmp_path))
    assert abs(float(ours.total_mass) - RUNNER_MASS) <= 1e-9


def test_every_runner_scale_set_matches_opensim(tmp_path) -> None:
    source = data_path(DENTON)
    generic = BodyModel.from_osim(source)
    scale_sets = sorted(DATA_ROOT.glob("fukuchi-running/*/*_scaleSet_simple.xml"))
    assert scale_sets
    for scale_set in scale_sets:
        _assert_same(
            scale_model_from_file(generic, scale_set, 70.0), _opensim_scaled(source, scale_set, True, 70.0, tmp_path)
        )


def test_products_of_inertia_scale_like_opensim(tmp_path) -> None:
    """No generic model has products of inertia, so give every body some and compare again."""
    model = osim.Model(str(data_path(DENTON)))
    bodies = model.getBodySet()
    for i in range(bodies.getSize()):
        moments = bodies.get(i).getInertia().getMoments()
        xx, yy, zz = (moments.get(k) for k in range(3))
        bodies.get(i).setInertia(osim.Inertia(xx, yy, zz, 0.1 * xx, -0.05 * yy, 0.02 * zz))
    source = tmp_path / "products.osim"
    model.printToXML(str(source))
    scale_set = data_path(SCALE_SET)
    for preserve in (True, False):
        ours = scale_model_from_file(BodyModel.from_osim(source), scale_set, None, preserve)
        _assert_same(ours, _opensim_scaled(source, scale_set, preserve, -1.0, tmp_path))


def test_scaling_is_differentiable_in_the_factors() -> None:
    model = BodyModel.from_osim(data_path(DENTON))
    base = scale_factors(model, read_scale_set(data_path(SCALE_SET)))
    q = torch.tensor(random_poses(model, np.random.default_rng(1), 1))

    def markers(factors: torch.Tensor) -> torch.Tensor:
        return marker_positions(scale_model(model, factors, RUNNER_MASS), q)

    assert torch.autograd.gradcheck(markers, (base.clone().requires_grad_(),))
    inertia = lambda f: scale_model(model, f, RUNNER_MASS).inertias  # noqa: E731
    assert torch.autograd.gradcheck(inertia, (base.clone().requires_grad_(),))


def test_unscaled_bodies_and_shapes() -> None:
    model = BodyModel.from_osim(data_path(DENTON))
    factors = scale_factors(model, {"femur_r": [1.1, 1.2, 1.1]})
    assert torch.equal(factors[model.body_index("pelvis")], torch.ones(3, dtype=torch.float64))
    scaled = scale_model(model, factors)
    assert torch.equal(scaled.body_scales, factors) and torch.allclose(scaled.total_mass, model.total_mass)
    from biomotion.errors import ModelError

    with pytest.raises(ModelError):
        scale_model(model, torch.ones(3, 3, dtype=torch.float64))
    with pytest.raises(ModelError, match="no body"):
        scale_factors(model, {"humerus_r": [1.0, 1.0, 1.0]})
