"""`Shape` (the HUMOS body identity as an OpenSim scaling): round trips on real scaled models, bad shapes,
and the ANSUR II expectation of a person's build.

Truth: the scaled models of the data sets themselves. A Fukuchi runner's ``_simple.osim`` was written by OpenSim's
ScaleTool from the Denton 2023 generic model with the runner's ``_scaleSet_simple.xml``; OpenCap Subject4's
``optimized_scale_and_markers.osim`` was scaled by AddBiomechanics from ``unscaled_generic.osim`` with its own
per-body masses. The Shape read from the scaled file and applied to the generic model must give the file's joint
frames, centres of mass and masses back to float precision."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from biomotion.body.model import BodyModel
from biomotion.body.scaling.bodies import scale_model
from biomotion.body.scaling.segments import shipped_lines
from biomotion.body.shape import Shape, segment_lengths, shape_of_factors
from biomotion.errors import ConfigError
from biomotion.io.osim import read_scale_set
from tests.conftest import data_path

torch.set_num_threads(1)

DENTON = "fukuchi-running/generic-models/Denton2023_LowerLimb_Fukuchi2017.osim"
RUNNERS = ("RBDS001", "RBDS019")  # a man of 62 kg and the one woman of the set
OPENCAP_GENERIC = "opencap/Subject4/Models/unscaled_generic.osim"
OPENCAP_SCALED = "opencap/Subject4/Models/optimized_scale_and_markers.osim"
RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
EXACT = 1e-12  # m, kg: float64 round-off of products of a few factors


def _same_geometry(rebuilt: BodyModel, scaled: BodyModel, *, inertias: bool = True) -> None:
    """Joint frames (by joint name), centres of mass and masses (by body name) agree to `EXACT`."""
    joints = {j.name: j for j in rebuilt.joints}
    for joint in scaled.joints:
        ours = joints[joint.name]
        assert torch.allclose(ours.parent_translation, joint.parent_translation, rtol=0, atol=EXACT), joint.name
        assert torch.allclose(ours.child_translation, joint.child_translation, rtol=0, atol=EXACT), joint.name
    order = [rebuilt.body_index(b) for b in scaled.body_names]
    assert torch.allclose(rebuilt.coms[order], scaled.coms, rtol=0, atol=EXACT)
    assert torch.allclose(rebuilt.masses[order], scaled.masses, rtol=1e-14, atol=EXACT)
    if inertias:
        assert torch.allclose(rebuilt.inertias[order], scaled.inertias, rtol=1e-12, atol=EXACT)


@pytest.fixture(scope="module")
def denton():
    return BodyModel.from_osim(data_path(DENTON))


@pytest.mark.parametrize("runner", RUNNERS)
def test_fukuchi_round_trip(denton, runner):
    path = data_path(f"fukuchi-running/{runner}/{runner}_simple.osim")
    scaled = BodyModel.from_osim(path)
    shape = Shape.from_model(scaled, denton)
    assert shape.reference == denton.name
    # the factors are the ScaleTool's (the ScaleSet file prints 6 significant digits)
    written = {
        s.segment: s.scales for s in read_scale_set(data_path(f"fukuchi-running/{runner}/{runner}_scaleSet_simple.xml"))
    }
    for body in scaled.body_names:
        np.testing.assert_allclose(shape.scales[body], written[body], rtol=5e-6)
    assert shape.mass == pytest.approx(float(scaled.total_mass), rel=1e-14)
    rebuilt = shape.to_model(denton)
    _same_geometry(rebuilt, scaled)
    # the rebuilt model carries the factors, so reading its shape in memory gives them back unchanged
    again = Shape.from_model(rebuilt)
    for body in scaled.body_names:
        assert again.scales[body] == pytest.approx(shape.scales[body], rel=1e-15)
        assert again.masses[body] == pytest.approx(shape.masses[body], rel=1e-15)
    assert shape.lengths == pytest.approx(segment_lengths(scaled), rel=1e-12)
    assert shape.height is None  # a lower-limb model has no stature


def test_fukuchi_osim_file_round_trip(denton, tmp_path):
    """Shape -> .osim (write_scaled_osim) -> Shape: the same factors and masses; the file's model is the scaled
    one."""
    scaled = BodyModel.from_osim(data_path("fukuchi-running/RBDS001/RBDS001_simple.osim"))
    shape = Shape.from_osim(data_path("fukuchi-running/RBDS001/RBDS001_simple.osim"), data_path(DENTON))
    out = tmp_path / "RBDS001_shape.osim"
    shape.write_osim(data_path(DENTON), out, name="RBDS001_shape")
    back = BodyModel.from_osim(out)
    assert back.name == "RBDS001_shape"
    _same_geometry(back, scaled)
    reread = Shape.from_model(back, denton)
    for body in scaled.body_names:
        np.testing.assert_allclose(reread.scales[body], shape.scales[body], rtol=1e-14)
        assert reread.masses[body] == pytest.approx(shape.masses[body], rel=1e-14)


def test_opencap_subject4_round_trip():
    """AddBiomechanics' own mass distribution and non-uniform factors come back exactly (inertias are its own)."""
    generic = BodyModel.from_osim(data_path(OPENCAP_GENERIC))
    scaled = BodyModel.from_osim(data_path(OPENCAP_SCALED))
    shape = Shape.from_model(scaled, generic)
    assert shape.mass == pytest.approx(62.6, abs=0.05)  # OpenCap SOURCE: 62.6 kg
    ratios = np.array([shape.masses[b] / float(generic.masses[i]) for i, b in enumerate(generic.body_names)])
    assert ratios.max() - ratios.min() > 0.1  # not the generic distribution: the per-body masses matter
    rebuilt = shape.to_model(generic)
    _same_geometry(rebuilt, scaled, inertias=False)
    assert shape.height == pytest.approx(1.68, abs=0.08)  # OpenCap SOURCE: 1.68 m, measured on the model


def test_in_memory_scaling_round_trip():
    generic = BodyModel.from_osim(data_path(RAJAGOPAL))
    rng = np.random.default_rng(0)
    factors = torch.from_numpy(rng.uniform(0.85, 1.2, (generic.n_bodies, 3)))
    scaled = scale_model(generic, factors, mass=68.0)
    for shape in (Shape.from_model(scaled), Shape.from_model(scaled, generic)):
        for i, body in enumerate(generic.body_names):
            np.testing.assert_allclose(shape.scales[body], factors[i].numpy(), rtol=1e-12)
        _same_geometry(shape.to_model(generic), scaled)
    assert Shape.from_model(generic).height == pytest.approx(1.70, abs=1e-9)  # Rajagopal's generic subject


def test_bodies_without_meshes_fall_back_on_their_joint_frames():
    """Without meshes the factors come from the vectors fixed on each body (joint frames, centre of mass): the
    joint frames and centres of mass still come back exactly, and every axis those vectors span has its factor."""
    generic = BodyModel.from_osim(data_path(RAJAGOPAL))
    bare = dataclasses.replace(
        generic,
        spec=dataclasses.replace(
            generic.spec, bodies=tuple(dataclasses.replace(b, meshes=()) for b in generic.spec.bodies)
        ),
    )
    factors = torch.from_numpy(np.random.default_rng(2).uniform(0.85, 1.2, (generic.n_bodies, 3)))
    scaled = BodyModel.from_spec(bare.spec)
    scaled = scale_model(scaled, factors, mass=70.0)
    scaled = dataclasses.replace(scaled, body_scales=torch.ones_like(scaled.body_scales))  # as if read from a file
    shape = Shape.from_model(scaled, bare)
    _same_geometry(shape.to_model(bare), scaled, inertias=False)
    femur = generic.body_index("femur_r")
    np.testing.assert_allclose(shape.scales["femur_r"][1:], factors[femur, 1:].numpy(), rtol=1e-12)  # y, z spanned


def test_height_of_a_scaled_file(tmp_path):
    """A scaled Rajagopal written to a file has no scaling history; measured against its generic model, a uniform
    factor of 1.1 is a stature of 1.1 x 1.70 m."""
    generic = BodyModel.from_osim(data_path(RAJAGOPAL))
    shape = shape_of_factors(generic, {b: (1.1, 1.1, 1.1) for b in generic.body_names}, mass=80.0)
    out = tmp_path / "tall.osim"
    shape.write_osim(data_path(RAJAGOPAL), out)
    back = Shape.from_osim(out, generic)
    assert back.height == pytest.approx(1.87, abs=1e-9)
    assert back.mass == pytest.approx(80.0, rel=1e-12)
    for body in generic.body_names:
        np.testing.assert_allclose(back.scales[body], (1.1, 1.1, 1.1), rtol=1e-12)


def _good(**change) -> dict:
    fields = {
        "reference": "m",
        "scales": {"pelvis": (1.0, 1.0, 1.0), "femur_r": (1.1, 1.1, 1.1)},
        "mass": 10.0,
        "masses": {"pelvis": 6.0, "femur_r": 4.0},
        "height": 1.7,
    }
    return fields | change


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (
            {"scales": {"pelvis": (1.0, 1.0, 1.0), "femur_r": (1.0, -0.9, 1.0)}, "masses": None},
            "Shape.scales['femur_r']",
        ),
        ({"scales": {"pelvis": (1.0, 0.0, 1.0), "femur_r": (1.0, 1.0, 1.0)}, "masses": None}, "Shape.scales['pelvis']"),
        ({"scales": {"pelvis": (1.0, math.nan, 1.0), "femur_r": (1, 1, 1)}, "masses": None}, "Shape.scales['pelvis']"),
        ({"scales": {"pelvis": (1.0, 1.0)}, "masses": None}, "Shape.scales['pelvis']"),
        ({"scales": {}, "masses": None}, "Shape.scales"),
        ({"mass": 0.0, "masses": None}, "Shape.mass"),
        ({"mass": -70.0, "masses": None}, "Shape.mass"),
        ({"mass": math.nan, "masses": None}, "Shape.mass"),
        ({"masses": {"pelvis": 11.0, "femur_r": -1.0}}, "Shape.masses['femur_r']"),
        ({"masses": {"pelvis": 10.0}}, "Shape.masses"),
        ({"mass": 12.0}, "Shape.mass"),
        ({"height": -1.7}, "Shape.height"),
        ({"height": 170.0}, "Shape.height"),
        ({"lengths": {"femur_r": 0.0}}, "Shape.lengths['femur_r']"),
        ({"lengths": {"femur_r": math.inf}}, "Shape.lengths['femur_r']"),
        ({"sex": "x"}, "Shape.sex"),
    ],
)
def test_bad_shapes_get_one_line_errors(change, field):
    with pytest.raises(ConfigError) as error:
        Shape(**_good(**change))
    message = str(error.value)
    assert "\n" not in message
    assert field in message


def test_missing_segments(denton):
    shape = Shape(**_good())
    with pytest.raises(ConfigError, match=r"missing segments") as error:
        shape.to_model(denton)
    assert "\n" not in str(error.value) and "tibia_r" in str(error.value)
    assert Shape(**_good()).as_dict()["masses"] == {"pelvis": 6.0, "femur_r": 4.0}


def test_from_measures_plausible():
    """At the generic subject's height every factor is 1; a taller person has a longer femur and shank; the
    femur of a 1.80 m man is within ANSUR II's spread of Rajagopal's femur scaled by stature."""
    generic = BodyModel.from_osim(data_path(RAJAGOPAL))
    same = Shape.from_measures(1.70, 75.337, generic=generic)
    for body in generic.body_names:
        assert same.scales[body] == pytest.approx((1.0, 1.0, 1.0), rel=1e-6), body
    assert same.mass == pytest.approx(75.337, rel=1e-12)
    short, tall = Shape.from_measures(1.55, 50.0, "female"), Shape.from_measures(1.90, 95.0, "male")
    assert short.sex == "female" and tall.height == 1.90 and short.masses is None
    for body in ("femur_r", "tibia_l", "pelvis", "torso", "humerus_r", "calcn_r"):
        assert tall.scales[body][0] > short.scales[body][0], body
    femur = {}
    for name, shape in (("short", short), ("tall", tall)):
        model = shape.to_model(generic)
        femur[name] = segment_lengths(model)["femur_r"]
        assert float(model.total_mass) == pytest.approx(shape.mass, rel=1e-12)
    assert femur["tall"] > femur["short"] + 0.05  # m: 35 cm of stature, thigh slope 0.275 (ANSUR II men)
    # the thigh line of ANSUR II men (-50.8 mm + 0.2753 x stature): E[L | 1.80 m] / E[L | 1.70 m], a little more
    # than the stature ratio (negative intercept); the shank line too, the foot's (positive intercept) less
    line = shipped_lines()["segments"]
    expected = {
        segment: (line[segment]["intercept_mm"] + line[segment]["slope"] * 1800.0)
        / (line[segment]["intercept_mm"] + line[segment]["slope"] * 1700.0)
        for segment in ("thigh", "shank", "foot")
    }
    shape = Shape.from_measures(1.80, 80.0)
    assert shape.scales["femur_r"][0] == pytest.approx(expected["thigh"], rel=1e-12)
    assert shape.scales["tibia_l"][0] == pytest.approx(expected["shank"], rel=1e-12)
    assert shape.scales["calcn_r"][0] == pytest.approx(expected["foot"], rel=1e-12)
    assert expected["foot"] < 1.80 / 1.70 < expected["thigh"] < 1.08
    assert 0.40 < segment_lengths(Shape.from_measures(1.80, 80.0).to_model(generic))["femur_r"] < 0.47
    with pytest.raises(ConfigError, match="height"):
        Shape.from_measures(180.0, 80.0)
    with pytest.raises(ConfigError, match="Shape.mass"):
        Shape.from_measures(1.8, -80.0)
