"""Scene values and builders: capsules, BVH bodies against the clip's own forward kinematics, markers, GRF arrows,
balance and activations on the scene clock."""

import numpy as np
import pytest

from biomotion.errors import DataFormatError
from biomotion.io.bvh import read_bvh
from biomotion.io.c3d import read_c3d
from biomotion.io.mot import read_ground_reaction
from biomotion.io.trc import read_trc
from biomotion.viz.scene import (
    FORCE_SCALE,
    Body,
    Capsule,
    Mesh,
    PointSet,
    Scene,
    bvh_scene,
    markers_scene,
    on_clock,
    parent_links,
)
from tests.conftest import data_path

WALK_BVH = "bandai-namco/dataset-1/dataset-1_walk_normal_001.bvh.gz"


def _volume(mesh: Mesh) -> float:
    a, b, c = (mesh.vertices[mesh.triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def test_capsule_surface_is_closed_outward_and_at_the_radius():
    start, end, radius = np.array([0.1, 0.0, -0.2]), np.array([0.1, 0.4, 0.1]), 0.05
    mesh = Capsule(start, end, radius).mesh(sides=10, rings=3)
    edges = np.sort(
        np.concatenate([mesh.triangles[:, [0, 1]], mesh.triangles[:, [1, 2]], mesh.triangles[:, [2, 0]]]), axis=1
    )
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # closed: every edge shared by exactly two triangles
    axis = (end - start) / np.linalg.norm(end - start)
    along = np.clip((mesh.vertices - start) @ axis, 0, np.linalg.norm(end - start))
    distance = np.linalg.norm(mesh.vertices - (start + along[:, None] * axis), axis=1)
    np.testing.assert_allclose(distance, radius, atol=1e-12)  # every vertex on the capsule surface
    length = np.linalg.norm(end - start)
    exact = np.pi * radius**2 * length + 4 / 3 * np.pi * radius**3
    assert 0.85 * exact < _volume(mesh) < exact  # positive = outward normals; inscribed polygon is smaller


def test_bvh_bodies_reproduce_the_clip_joint_positions():
    clip = read_bvh(data_path(WALK_BVH))
    scene = bvh_scene(clip, name="walk")
    positions = clip.global_positions()
    skeleton = clip.skeleton
    names = [b.name for b in scene.bodies]
    assert "joint_Root" not in names and len(names) == 16  # root placement (joint_Root -> Hips) is no bone
    assert scene.n_frames == clip.n_frames and scene.times[1] == pytest.approx(1 / 30, rel=1e-4)
    for body in scene.bodies:
        children = [
            c
            for c, p in enumerate(skeleton.parents)
            if p == skeleton.index(body.name)
            and not skeleton.end_sites[c]
            and np.linalg.norm(skeleton.offsets[c]) < 0.75
        ]
        ends = {tuple(np.round(c.end, 9)) for c in body.capsules}
        assert len(ends) == len(body.capsules)
        for child in children:
            # the capsule end, posed by the body, lands on the child joint in every frame (1e-9 m)
            capsule = next(c for c in body.capsules if np.allclose(c.end, clip.local_translations()[0, child]))
            posed = np.einsum("tij,j->ti", body.rotations, capsule.end) + body.positions
            np.testing.assert_allclose(posed, positions[:, child], atol=1e-9)
    joints = scene.points[0]
    assert "Hips" in joints.labels and "joint_Root" not in joints.labels
    np.testing.assert_allclose(joints.positions[:, joints.labels.index("Head")], positions[:, skeleton.index("Head")])


def test_markers_and_plates_on_their_own_clocks():
    trial = read_c3d(data_path("fukuchi-running/c3d/RBDS002runT35.c3d"))
    scene = markers_scene(trial.markers, name="run").with_ground_reaction(trial.forces)
    assert trial.forces.rate == pytest.approx(2 * trial.markers.rate)  # plates at 300 Hz, markers at 150 Hz
    np.testing.assert_array_equal(scene.points[0].positions, trial.markers.positions)  # NaN gaps kept
    arrows = scene.arrows[0]
    frames = np.flatnonzero(np.isfinite(arrows.origins[:, 0, 0]))
    assert 0.3 < frames.size / scene.n_frames < 0.9  # stance phases only (running: ~35 % contact per foot x 2)
    # scene frame k is plate sample 2k: interpolation returns the sample itself
    force = trial.forces.force[2 * frames, 0]
    np.testing.assert_allclose(arrows.vectors[frames, 0], force * FORCE_SCALE, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(arrows.origins[frames, 0], trial.forces.cop[2 * frames, 0], atol=1e-12)
    hidden = np.flatnonzero(~np.isfinite(arrows.origins[:, 0, 0]))
    light = np.linalg.norm(trial.forces.force[2 * hidden, 0], axis=-1)
    assert np.all((light < 20.0) | ~np.isfinite(trial.forces.cop[2 * hidden, 0, 0]))


def test_opencap_walking_grf_is_shown_only_in_stance():
    markers = read_trc(data_path("opencap/Subject4/MarkerData/walking1.trc"))
    forces = read_ground_reaction(data_path("opencap/Subject4/ID/walking1_grf.mot"))
    scene = markers_scene(markers).with_ground_reaction(forces)
    shown = np.isfinite(scene.arrows[0].origins[..., 0])
    total = np.linalg.norm(forces.force, axis=-1)
    np.testing.assert_array_equal(shown, total >= 20.0)  # same clock, plates 1 and 2 (SOURCE.md)
    peak = np.nanmax(scene.arrows[0].vectors[..., 1]) / FORCE_SCALE
    assert 650 < peak < 800  # SOURCE.md: walking peak vertical GRF per plate 680-760 N


def test_balance_and_activations_follow_the_scene_clock():
    times = np.arange(11) * 0.1
    scene = Scene(times)
    source = np.arange(6) * 0.2
    com = np.stack([source, np.full(6, 0.9), np.zeros(6)], axis=1)
    support = np.full((6, 4, 3), np.nan)
    support[:, :3] = np.array([[0, 0, 0], [0.2, 0, 0], [0.1, 0, 0.1]]) + source[:, None, None] * [1, 0, 0]
    scene = scene.with_balance(source, com=com, zmp=com * [1, 0, 1], support=support)
    np.testing.assert_allclose(scene.com[:, 0], times)  # linear between samples
    np.testing.assert_allclose(scene.zmp[:, 1], 0.0)
    np.testing.assert_allclose(scene.support[3, 0, 0], 0.2)  # t = 0.3 takes the polygon of t = 0.2
    assert np.isnan(scene.support[:, 3]).all()
    scene = scene.with_activations(source[:4], ["soleus_r"], np.array([[0.0], [0.2], [0.4], [0.6]]))
    np.testing.assert_allclose(scene.activations.values[:7, 0], [0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    assert np.isnan(scene.activations.values[7:, 0]).all()  # after the source ends: unknown, not extrapolated


def test_on_clock_and_links():
    values = np.array([[0.0], [np.nan], [2.0], [3.0]])
    out = on_clock(np.array([0.0, 1.0, 2.0, 3.0]), values, np.array([-1.0, 0.5, 2.5, 3.0, 4.0]))
    assert np.isnan(out[0, 0]) and np.isnan(out[1, 0]) and out[2, 0] == 2.5 and out[3, 0] == 3.0
    assert np.isnan(out[4, 0])
    assert parent_links([-1, 0, 1, 0]).tolist() == [[0, 1], [1, 2], [0, 3]]


def test_scene_rejects_arrays_off_the_clock():
    times = np.arange(5) * 0.01
    with pytest.raises(DataFormatError, match="points 'm' has 4 frames"):
        Scene(times, points=(PointSet("m", np.zeros((4, 2, 3))),))
    with pytest.raises(DataFormatError, match="time does not increase"):
        Scene(np.array([0.0, 0.1, 0.1]))
    with pytest.raises(DataFormatError, match="must be \\[T, 3, 3\\]"):
        Body("pelvis", np.zeros((5, 3)), np.zeros((5, 3)))
    with pytest.raises(DataFormatError, match="link index out of range"):
        PointSet("m", np.zeros((5, 2, 3)), links=[(0, 2)])
    with pytest.raises(DataFormatError, match="triangle index out of range"):
        Mesh(np.zeros((3, 3)), [[0, 1, 3]])


def test_model_scene_puts_the_scaled_feet_on_the_floor():
    import torch

    from biomotion.body.kinematics import apply_couplers, forward_kinematics
    from biomotion.body.model import BodyModel
    from biomotion.io.mot import read_motion
    from biomotion.viz.scene import geometry_folders, model_scene

    rajagopal = data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")
    model = BodyModel.from_osim(data_path("SchreiberMoissenet2019/2014001/2014001_scaledModelAdjusted.osim"))
    motion = read_motion(data_path("SchreiberMoissenet2019/2014001/C4_05_ik.mot"))
    scene = model_scene(model, motion, folders=geometry_folders(rajagopal), name="2014001")
    assert [b.name for b in scene.bodies] == list(model.body_names)
    meshes = {b.name: len(b.meshes) for b in scene.bodies}
    assert meshes["pelvis"] == 3 and meshes["tibia_r"] == 1 and meshes["calcn_l"] == 1 and meshes["torso"] == 4
    femur = next(b for b in scene.bodies if b.name == "femur_r")  # femur_r.vtp is not in the data: capsules
    assert femur.meshes == () and len(femur.capsules) == 2  # to the knee and to the patella
    # poses are the body model's forward kinematics of the file's coordinates (couplers applied)
    q = apply_couplers(model, torch.as_tensor(motion.select(model.coordinate_names).values))
    np.testing.assert_allclose(scene.bodies[5].positions, forward_kinematics(model, q).positions[:, 5].numpy())
    # the scaled meshes land where the foot is: lowest foot vertex at the floor (IK lets toes sink a few cm)
    feet = [b for b in scene.bodies if b.name.startswith(("calcn", "toes"))]
    lowest = np.min(
        [
            np.min(
                np.einsum("tij,vj->tvi", b.rotations, b.surface().vertices)[..., 1] + b.positions[:, None, 1], axis=1
            )
            for b in feet
        ],
        axis=0,
    )
    assert np.all((lowest > -0.05) & (lowest < 0.01))
    assert scene.points[0].positions.shape == (motion.n_frames, 62, 3)  # the model's markers
