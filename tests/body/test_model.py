"""BodyModel construction: coordinate order and properties, inertial data and topology against OpenSim 4.6."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from biomotion.body.model import BodyModel
from biomotion.errors import ModelError
from tests.body.oracle import Oracle
from tests.conftest import data_path

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
RUNNER = "fukuchi-running/RBDS001/RBDS001_simple.osim"


@pytest.mark.parametrize("relative", [RAJAGOPAL, RUNNER])
def test_coordinates_and_bodies_match_opensim(relative: str) -> None:
    path = data_path(relative)
    model, oracle = BodyModel.from_osim(path), Oracle(path)
    assert list(model.coordinate_names) == oracle.coordinate_names
    for i, name in enumerate(model.coordinate_names):
        c = oracle.model.getCoordinateSet().get(name)
        assert float(model.defaults[i]) == c.getDefaultValue()
        assert model.ranges[i].tolist() == [c.getRangeMin(), c.getRangeMax()]
        assert bool(model.locked[i]) == c.getDefaultLocked() and bool(model.clamped[i]) == c.getDefaultClamped()
        expected = {1: "rotational", 2: "translational", 3: "coupled"}[int(c.getMotionType())]
        assert model.motion_types[i] == expected, name
    bodies = oracle.model.getBodySet()
    assert list(model.body_names) == [bodies.get(b).getName() for b in range(bodies.getSize())]
    for b in range(bodies.getSize()):
        body = bodies.get(b)
        assert float(model.masses[b]) == body.getMass()
        assert model.coms[b].tolist() == [body.getMassCenter().get(i) for i in range(3)]
        moments, products = body.getInertia().getMoments(), body.getInertia().getProducts()
        inertia = model.inertias[b]
        assert inertia.diagonal().tolist() == [moments.get(i) for i in range(3)]
        assert [float(inertia[0, 1]), float(inertia[0, 2]), float(inertia[1, 2])] == [products.get(i) for i in range(3)]
    assert abs(float(model.total_mass) - oracle.model.getTotalMass(oracle.state)) <= 1e-12


def test_rajagopal_facts() -> None:
    model = BodyModel.from_osim(data_path(RAJAGOPAL))
    assert (model.n_bodies, model.n_q, len(model.marker_names)) == (22, 39, 66)
    assert abs(float(model.total_mass) - 75.337) < 1e-3
    assert [(model.coordinate_names[c.dependent], model.coordinate_names[c.independent]) for c in model.couplers] == [
        ("knee_angle_r_beta", "knee_angle_r"),
        ("knee_angle_l_beta", "knee_angle_l"),
    ]
    locked = {model.coordinate_names[i] for i in torch.nonzero(model.locked).flatten().tolist()}
    assert locked == {f"{c}_{s}" for c in ("subtalar_angle", "mtp_angle", "wrist_flex", "wrist_dev") for s in "rl"}
    seen = {-1}
    for j in model.joint_order:  # parents before children
        assert model.joints[j].parent in seen
        seen.add(model.joints[j].child)
    assert model.parent[model.body_index("tibia_r")] == model.body_index("femur_r")
    assert float(model.default_q()[model.coordinate_index("pelvis_ty")]) == pytest.approx(0.94)


def test_dtype_conversion() -> None:
    model = BodyModel.from_osim(data_path(RUNNER))
    single = model.to(torch.float32)
    assert single.dtype == torch.float32 and single.joints[0].parent_rotation.dtype == torch.float32
    assert single.marker_bodies.dtype == torch.long and single.locked.dtype == torch.bool
    assert single.to(torch.float64).masses.dtype == torch.float64


def test_frames_resolve_to_bodies() -> None:
    model = BodyModel.from_osim(data_path(RAJAGOPAL))
    body, rotation, translation = model.frame_in_body("/jointset/walker_knee_r/femur_r_offset")
    assert body == model.body_index("femur_r")
    assert torch.allclose(rotation @ rotation.T, torch.eye(3, dtype=torch.float64), atol=1e-14)
    assert translation.tolist() == pytest.approx([-0.00809, -0.40796, -0.00275])


def test_topology_errors() -> None:
    model = BodyModel.from_osim(data_path(RUNNER))
    spec = model.spec
    hip = next(j for j in spec.joints if j.name == "hip_r")
    knee = next(j for j in spec.joints if j.name == "knee_r")
    two_parents = dataclasses.replace(
        spec, joints=spec.joints + (dataclasses.replace(hip, name="extra", coordinates=(), transform=()),)
    )
    with pytest.raises(ModelError, match="child of joints"):
        BodyModel.from_spec(two_parents)
    loop = dataclasses.replace(
        spec,
        joints=tuple(
            dataclasses.replace(j, parent_frame=knee.child_frame) if j.name == "hip_r" else j for j in spec.joints
        ),
    )
    with pytest.raises(ModelError, match="connect to ground"):
        BodyModel.from_spec(loop)
    orphan = dataclasses.replace(
        spec,
        joints=tuple(j for j in spec.joints if j.name != "knee_r"),
        coordinates=tuple(c for c in spec.coordinates if c.joint != "knee_r"),
    )
    with pytest.raises(ModelError, match="no joint"):
        BodyModel.from_spec(orphan)
