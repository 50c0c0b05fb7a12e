"""Uniform scaling of the generic Rajagopal 2016 model to a person's height and mass: the scaled model's standing
height (forward kinematics, 1 mm) and total mass (1e-6 relative), the written .osim read back by our reader and by
OpenSim 4.6."""

from __future__ import annotations

import re

import pytest
import torch

from biomotion.body.kinematics import forward_kinematics, marker_positions
from biomotion.body.model import BodyModel
from biomotion.body.scaling.stature import RAJAGOPAL_2016_HEIGHT, scale_to_person, scale_to_profile, standing_height
from biomotion.errors import ConfigError
from biomotion.profile import Profile
from tests.conftest import data_path

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
HEIGHT_TOLERANCE = 1e-3  # m
MASS_TOLERANCE = 1e-6  # relative

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def generic_path():
    return data_path(RAJAGOPAL)


def _poses(model: BodyModel, count: int = 4) -> torch.Tensor:
    generator = torch.Generator().manual_seed(0)
    return model.default_q() + 0.3 * torch.randn(count, model.n_q, dtype=torch.float64, generator=generator)


def _assert_same_model(ours: BodyModel, written: BodyModel) -> None:
    assert torch.allclose(ours.masses, written.masses, rtol=1e-12, atol=0)
    assert torch.allclose(ours.inertias, written.inertias, rtol=1e-12, atol=1e-15)
    assert torch.allclose(ours.coms, written.coms, rtol=1e-12, atol=1e-15)
    q = _poses(ours)
    assert (forward_kinematics(ours, q).positions - forward_kinematics(written, q).positions).abs().max() < 1e-12
    assert (marker_positions(ours, q) - marker_positions(written, q)).abs().max() < 1e-12


def test_generic_rajagopal_height_is_the_stated_one(generic_path):
    measured = standing_height(BodyModel.from_osim(generic_path))
    assert measured.height == pytest.approx(RAJAGOPAL_2016_HEIGHT, abs=1e-12)
    assert "torso" in measured.reference and measured.bottom < -0.9  # feet below the pelvis origin


@pytest.mark.parametrize("height, mass", [(1.82, 68.0), (1.55, 92.5)])
def test_scaled_height_and_mass(generic_path, tmp_path, height, mass):
    generic = BodyModel.from_osim(generic_path)
    scaled = scale_to_profile(generic_path, height, mass, tmp_path / "scaled.osim")
    assert abs(standing_height(scaled).height - height) < HEIGHT_TOLERANCE
    assert abs(float(scaled.total_mass) / mass - 1) < MASS_TOLERANCE
    ratio = generic.masses / generic.total_mass
    assert torch.allclose(scaled.masses / scaled.total_mass, ratio, rtol=1e-12)  # distribution preserved
    written = BodyModel.from_osim(tmp_path / "scaled.osim")
    _assert_same_model(scaled, written)
    assert abs(float(written.total_mass) / mass - 1) < MASS_TOLERANCE


def test_missing_height_or_mass_leaves_that_aspect(generic_path, tmp_path):
    generic = BodyModel.from_osim(generic_path)
    mass_only = scale_to_profile(generic_path, None, 60.0, tmp_path / "mass_only.osim")
    assert abs(standing_height(mass_only).height - RAJAGOPAL_2016_HEIGHT) < 1e-12
    assert abs(float(mass_only.total_mass) / 60.0 - 1) < MASS_TOLERANCE
    height_only = scale_to_person(generic_path, Profile(height=1.9), tmp_path / "height_only.osim")
    assert abs(standing_height(height_only).height - 1.9) < HEIGHT_TOLERANCE
    assert torch.allclose(height_only.masses, generic.masses, rtol=1e-12)
    _assert_same_model(height_only, BodyModel.from_osim(tmp_path / "height_only.osim"))
    with pytest.raises(ConfigError, match="SI units"):
        scale_to_profile(generic_path, 182.0, None, tmp_path / "cm.osim")


def test_head_marker_is_measured_and_survives_the_file(generic_path, tmp_path):
    """A model with a head-top marker is measured by it, so the written file measures the same height again."""
    text = generic_path.read_text()
    marker = (
        '<Marker name="HEAD"><socket_parent_frame>/bodyset/torso</socket_parent_frame>'
        "<location>-0.03 0.66 0</location><fixed>false</fixed></Marker>"
    )
    text, count = re.subn(r"(<MarkerSet name=\"markerset\">\s*<objects>)", r"\1" + marker, text)
    assert count == 1
    with_head = tmp_path / "with_head.osim"
    with_head.write_text(text)
    generic_height = standing_height(BodyModel.from_osim(with_head))
    assert generic_height.reference == "marker HEAD" and 1.6 < generic_height.height < 1.7
    scaled = scale_to_profile(with_head, 1.75, 70.0, tmp_path / "scaled.osim")
    assert abs(standing_height(scaled).height - 1.75) < HEIGHT_TOLERANCE
    assert abs(standing_height(BodyModel.from_osim(tmp_path / "scaled.osim")).height - 1.75) < HEIGHT_TOLERANCE


def test_opensim_loads_the_scaled_model(generic_path, tmp_path):
    osim = pytest.importorskip("opensim", reason="the opensim package (validate extra) checks the written file")
    osim.Logger.setLevelString("error")
    scale_to_profile(generic_path, 1.82, 68.0, tmp_path / "scaled.osim")
    model = osim.Model(str(tmp_path / "scaled.osim"))
    state = model.initSystem()
    assert abs(model.getTotalMass(state) / 68.0 - 1) < MASS_TOLERANCE
    ours = BodyModel.from_osim(tmp_path / "scaled.osim")
    bodies = model.getBodySet()
    assert [bodies.get(i).getName() for i in range(bodies.getSize())] == list(ours.body_names)
    masses = torch.tensor([bodies.get(i).getMass() for i in range(bodies.getSize())], dtype=torch.float64)
    assert torch.allclose(masses, ours.masses, rtol=1e-12)
    model.realizePosition(state)  # default pose: body origins agree
    theirs = torch.tensor(
        [[bodies.get(i).getTransformInGround(state).p().get(k) for k in range(3)] for i in range(bodies.getSize())],
        dtype=torch.float64,
    )
    assert (forward_kinematics(ours, ours.default_q()).positions - theirs).abs().max() < 1e-9
