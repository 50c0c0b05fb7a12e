"""`biomotion scale` and `retarget --static`: OpenSim's ScaleTool run from its setup file, against the scale set
the Fukuchi dataset ships for the same runner (the library underneath is checked against a fresh ScaleTool run in
`tests/ik/test_scaling.py`)."""

import json

import numpy as np
import pytest
import torch

from biomotion.body.kinematics import forward_kinematics
from biomotion.body.model import BodyModel
from biomotion.cli import main
from biomotion.io.mot import read_motion, read_storage
from biomotion.io.osim import read_scale_set
from tests.conftest import data_path

FUKUCHI = "fukuchi-running"
DENTON = f"{FUKUCHI}/generic-models/Denton2023_LowerLimb_Fukuchi2017.osim"
SETUP = f"{FUKUCHI}/RBDS001/RBDS001_scaleSetup_simple.xml"
STATIC = f"{FUKUCHI}/c3d/RBDS001static.c3d"


def test_scale_reproduces_the_runners_shipped_scale_set(tmp_path, capsys):
    """RBDS001's setup, generic model and static trial (10 Hz, as the source's chain filtered it): every body's
    factors against the shipped RBDS001_scaleSet_simple.xml within 1e-4 relative (the file's 6 digits; the issue's
    bar is 3 %), the subject's 62 kg, and the model opens in OpenSim with that mass."""
    code = main(
        [
            "scale",
            str(data_path(SETUP)),
            "--model",
            str(data_path(DENTON)),
            "--static",
            str(data_path(STATIC)),
            "--marker-filter",
            "10",
            "--name",
            "RBDS001",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0 and "11 bodies scaled by 17 measurements, 28 markers placed" in capsys.readouterr().out
    ours = {s.segment: s.scales for s in read_scale_set(tmp_path / "RBDS001_scale_set.xml")}
    shipped = {s.segment: s.scales for s in read_scale_set(data_path(f"{FUKUCHI}/RBDS001/RBDS001_scaleSet_simple.xml"))}
    bodies = set(ours) & set(shipped)  # the shipped set also lists frames (pelvis_offset ...) and the ground
    assert len(bodies) == len(ours) >= 11
    assert max(abs(ours[b][i] / shipped[b][i] - 1) for b in bodies for i in range(3)) < 1e-4
    summary = json.loads((tmp_path / "RBDS001_scale.json").read_text())
    assert summary["mass_kg"] == pytest.approx(62.0) and summary["model"] == "RBDS001.osim"
    assert read_motion(tmp_path / "RBDS001_static_pose.mot").n_frames == 1
    osim = pytest.importorskip("opensim", reason="the opensim package (validate extra) opens the written model")
    model = osim.Model(str(tmp_path / "RBDS001.osim"))
    assert abs(model.getTotalMass(model.initSystem()) - 62.0) < 1e-9


def test_scale_names_what_the_setup_points_to_and_is_missing(tmp_path, capsys):
    """The Fukuchi setups name `..\\model\\Denton2023...`, which the dataset does not ship: the error says which
    option supplies it, and nothing is written."""
    assert main(["scale", str(data_path(SETUP)), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "Denton2023_LowerLimb_Fukuchi2017.osim" in err and "give the generic .osim with --model" in err
    assert not (tmp_path / "out").exists()
    assert (
        main(
            [
                "retarget",
                str(data_path(STATIC)),
                "--model",
                str(data_path(DENTON)),
                "--static",
                str(data_path(STATIC)),
                "--out",
                str(tmp_path / "out"),
            ]
        )
        == 2
    )
    assert "give --scale-setup XML too" in capsys.readouterr().err
    clip = data_path("bandai-namco/dataset-2/dataset-2_walk_normal_016.bvh.gz")
    assert (
        main(
            [
                "retarget",
                str(clip),
                "--model",
                str(data_path(DENTON)),
                "--static",
                str(data_path(STATIC)),
                "--scale-setup",
                str(data_path(SETUP)),
                "--out",
                str(tmp_path / "out"),
            ]
        )
        == 2
    )
    assert "skeletons (BVH, --joint-map) are scaled to their own joint centres" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_retarget_scales_on_the_static_trial_then_solves_on_that_model(tmp_path, capsys):
    """`retarget TRIAL --model GENERIC --static STATIC --scale-setup XML` equals `scale` then `retarget --model
    SCALED`: the same scaled model (bodies within 1e-12 m) and the same coordinates."""
    trial = data_path(f"{FUKUCHI}/c3d/RBDS001runT35.c3d")
    assert (
        main(
            [
                "retarget",
                str(trial),
                "--model",
                str(data_path(DENTON)),
                "--static",
                str(data_path(STATIC)),
                "--scale-setup",
                str(data_path(SETUP)),
                "--filter",
                "10",
                "--out",
                str(tmp_path / "one"),
                "--quiet",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "scale",
                str(data_path(SETUP)),
                "--model",
                str(data_path(DENTON)),
                "--static",
                str(data_path(STATIC)),
                "--marker-filter",
                "10",
                "--out",
                str(tmp_path / "scaled"),
            ]
        )
        == 0
    )
    scaled = tmp_path / "scaled/RBDS001_scaleSetup_simple.osim"
    assert (
        main(
            [
                "retarget",
                str(trial),
                "--model",
                str(scaled),
                "--filter",
                "10",
                "--out",
                str(tmp_path / "two"),
                "--quiet",
            ]
        )
        == 0
    )
    capsys.readouterr()
    one, two = BodyModel.from_osim(tmp_path / "one/RBDS001_scaleSetup_simple.osim"), BodyModel.from_osim(scaled)
    q = two.default_q()[None]
    assert (forward_kinematics(one, q).positions - forward_kinematics(two, q).positions).abs().max() < 1e-12
    first, second = read_motion(tmp_path / "one/RBDS001runT35.mot"), read_motion(tmp_path / "two/RBDS001runT35.mot")
    assert first.n_frames == second.n_frames > 1000
    assert np.abs(first.values - second.values).max() < 1e-9


def test_scale_runs_the_gait2392_tutorial_setup_as_opensim_does(tmp_path, capsys, monkeypatch):
    """gait2392's subject01 setup, which brings its own marker set (GenericModelMaker's marker_set_file, merged
    into the model as OpenSim's Model::updateMarkerSet does) and scales patellae the shipped gait2392 models lack
    (skipped with a warning, as OpenSim skips them), against OpenSim's ScaleTool run fresh on the same setup with
    the same generic model (the setup's gait2392_simbody.osim is not in the data; its thelen2003 sibling is).
    Bars: factors within 1e-5 (OpenSim's 6 written digits; measured 4.6e-6), masses and body positions at random
    poses within 1e-9, the same 39 markers, and our static pose no worse than OpenSim's by the MarkerPlacer's own
    objective (its assembler stops short of the minimum; measured 2.0122e-4 against 2.0129e-4)."""
    osim = pytest.importorskip("opensim", reason="the opensim package (validate extra) is the oracle here")
    from biomotion.ik.markers import evaluate_ik
    from biomotion.ik.scaling import average_frames
    from biomotion.io.mot import read_storage
    from biomotion.io.setup import read_scale_setup
    from biomotion.io.trc import read_trc
    from biomotion.motion import Motion

    osim.Logger.setLevelString("error")
    folder = data_path("opensim-models/Pipelines/Gait2392_Simbody")
    generic = data_path("opensim-models/Models/Gait2392_Simbody/gait2392_thelen2003muscle.osim")
    setup_path = folder / "subject01_Setup_Scale.xml"
    assert main(["scale", str(setup_path), "--model", str(generic), "--out", str(tmp_path / "ours")]) == 0
    assert "which model '3DGaitModel2392' lacks: skipped" in capsys.readouterr().err

    text = setup_path.read_text()
    for old, new in (
        ("gait2392_simbody.osim </model_file>", f"{generic} </model_file>"),
        ("> gait2392_Scale_MarkerSet.xml <", f"> {folder / 'gait2392_Scale_MarkerSet.xml'} <"),
        ("> subject01_static.trc <", f"> {folder / 'subject01_static.trc'} <"),
    ):
        assert old in text
        text = text.replace(old, new)
    (tmp_path / "setup.xml").write_text(text)
    with monkeypatch.context() as patch:
        patch.chdir(tmp_path)  # the setup writes its outputs into the working directory
        assert osim.ScaleTool("setup.xml").run()

    ours = {s.segment: s.scales for s in read_scale_set(tmp_path / "ours/subject01_scale_set.xml")}
    theirs = {s.segment: s.scales for s in read_scale_set(tmp_path / "subject01_scaleSet_applied.xml")}
    bodies = set(ours) & set(theirs)
    assert len(bodies) == len(ours) == 12
    assert max(abs(ours[b][i] / theirs[b][i] - 1) for b in bodies for i in range(3)) < 1e-5
    model, reference = (
        BodyModel.from_osim(tmp_path / "ours/subject01.osim"),
        BodyModel.from_osim(tmp_path / "subject01_simbody.osim"),
    )
    assert sorted(model.marker_names) == sorted(reference.marker_names) and len(model.marker_names) == 39
    loaded = osim.Model(str(tmp_path / "ours/subject01.osim"))  # the added markers in OpenSim 4's layout
    assert loaded.getMarkerSet().getSize() == 39 and abs(loaded.getTotalMass(loaded.initSystem()) - 72.6) < 1e-9
    assert torch.allclose(model.masses, reference.masses, atol=1e-9)
    assert torch.allclose(model.inertias, reference.inertias, atol=1e-9)
    q = model.default_q() + 0.3 * torch.randn(
        5, model.n_q, dtype=torch.float64, generator=torch.Generator().manual_seed(0)
    )
    assert (forward_kinematics(model, q).positions - forward_kinematics(reference, q).positions).abs().max() < 1e-9

    setup = read_scale_setup(setup_path)
    averaged = average_frames(read_trc(folder / "subject01_static.trc").slice(*setup.placer_time_range))
    scaled_only = BodyModel.from_osim(tmp_path / "subject01_scaledOnly.osim")
    table = read_storage(tmp_path / "subject01_static_output.mot")
    joints = [scaled_only.joints[scaled_only.coordinate_joint[c]].name for c in range(scaled_only.n_q)]
    opensim_pose = [
        table.data[0, table.labels.index(f"/jointset/{joints[c]}/{name}/value")]
        for c, name in enumerate(scaled_only.coordinate_names)
    ]
    our_pose = read_motion(tmp_path / "ours/subject01_static_pose.mot").select(scaled_only.coordinate_names)

    def objective(values) -> float:
        pose = Motion(times=averaged.times, names=scaled_only.coordinate_names, values=np.array([values]))
        return float(
            evaluate_ik(
                scaled_only,
                averaged,
                pose,
                weights=setup.placer_tasks.marker_weights,
                coordinate_tasks=setup.placer_tasks.coordinate_tasks,
            ).cost[0]
        )

    assert objective(our_pose.values[0]) <= objective(opensim_pose)


def test_analyze_scales_then_solves_then_analyses_a_runner_from_the_lab_files(tmp_path, capsys):
    """`analyze RUN.c3d --model GENERIC --static STATIC.c3d --scale-setup XML --grf RUN.c3d`: the whole chain in one
    command equals its steps run one by one (`scale`, then `analyze` on the scaled model): the same torques, and
    the scaled model and its summary kept in OUT/ik."""
    trial = str(data_path(f"{FUKUCHI}/c3d/RBDS001runT35.c3d"))  # markers and plates in one file
    common = ["--grf", trial, "--marker-filter", "10", "--no-figures"]
    assert (
        main(
            [
                "analyze",
                trial,
                "--model",
                str(data_path(DENTON)),
                "--static",
                str(data_path(STATIC)),
                "--scale-setup",
                str(data_path(SETUP)),
                "--out",
                str(tmp_path / "one"),
                *common,
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "28 markers placed" in out and "torques from measured ground reaction" in out
    ik = json.loads((tmp_path / "one/summary.json").read_text())["inverse_kinematics"]
    assert ik["model"] == "ik/RBDS001_scaleSetup_simple.osim"
    assert ik["scaling"] == "ik/RBDS001_scaleSetup_simple_scale.json"
    assert (tmp_path / "one/ik/RBDS001_scaleSetup_simple.osim").exists()
    assert (
        main(
            [
                "scale",
                str(data_path(SETUP)),
                "--model",
                str(data_path(DENTON)),
                "--static",
                str(data_path(STATIC)),
                "--marker-filter",
                "10",
                "--out",
                str(tmp_path / "scaled"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "analyze",
                trial,
                "--model",
                str(tmp_path / "scaled/RBDS001_scaleSetup_simple.osim"),
                "--out",
                str(tmp_path / "two"),
                *common,
            ]
        )
        == 0
    )
    one, two = read_storage(tmp_path / "one/torques.sto"), read_storage(tmp_path / "two/torques.sto")
    assert one.labels == two.labels and one.data.shape == two.data.shape and one.data.shape[0] > 1000
    assert np.abs(one.data - two.data).max() < 1e-6
