"""``biomotion batch`` and ``biomotion check`` from the command line: exit statuses, what they print, the marker-name
mismatch reported with the closest model names, the plate override."""

import json

import numpy as np

from biomotion.cli import main
from biomotion.io.mot import read_motion, write_motion
from biomotion.io.trc import read_trc
from tests.conftest import data_path

GAIT = "opensim-models/Pipelines/Gait2392_Simbody"


def _config(folder, trials: str) -> str:
    gait = data_path(GAIT)
    config = folder / "study.toml"
    config.write_text(
        f"""
[study]
viewer = false
[[subject]]
name = "s01"
model = "{gait}/OutputReference/subject01_simbody.osim"
{trials}
"""
    )
    return str(config)


def test_batch_command_runs_a_study_on_a_process_pool(tmp_path, capsys):
    gait = data_path(GAIT)
    config = _config(
        tmp_path,
        f"""[[subject.trial]]
name = "walk1"
markers = "{gait}/subject01_walk1.trc"
forces = "{gait}/subject01_walk1_grf.mot"
setup = "{gait}/subject01_Setup_IK.xml"
""",
    )
    out = tmp_path / "out"
    argv = ["batch", config, "--out", str(out), "--workers", "2", "--no-progress", "--plates", "1=right,2=left"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "s01/walk1" in printed and "plates ground_force->calcn_r, 1_ground_force->calcn_l" in printed
    assert (out / "report.html").is_file() and (out / "s01" / "walk1" / "torques.sto").is_file()
    outcome = json.loads((out / "s01" / "walk1" / "outcome.json").read_text())
    assert outcome["figures"]["plates"]["ground_force"] == {"mode": "given", "body": "calcn_r"}
    # an existing output needs --resume or --overwrite: one line, exit status 2
    assert main(argv) == 2
    assert "--resume" in capsys.readouterr().err
    assert main([*argv, "--resume"]) == 0
    assert "2 resumed" in capsys.readouterr().out  # the subject (no static: the model as given) and the trial


def test_unmatched_marker_names_fail_the_trial_with_the_closest_model_names(tmp_path, capsys):
    """Another lab's names (here every data marker prefixed): the trial fails, naming what did not match and the
    model markers closest to it; the marker map fixes it."""
    gait = data_path(GAIT)
    markers = read_trc(f"{gait}/subject01_walk1.trc").slice(0.5, 0.8)
    renamed = markers.rename({n: f"LAB_{n}" for n in markers.names})
    from biomotion.io.trc import write_trc

    write_trc(tmp_path / "walk.trc", renamed)
    config = _config(tmp_path, f'[[subject.trial]]\nname = "walk"\nmarkers = "{tmp_path / "walk.trc"}"\n')
    assert main(["batch", config, "--out", str(tmp_path / "out"), "--workers", "1", "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "fail s01/walk" in printed and "give a marker map" in printed
    assert "LAB_R.ASIS (closest: R.ASIS" in printed
    mapping = ",".join(f"LAB_{n}={n}" for n in markers.names)
    argv = ["batch", config, "--out", str(tmp_path / "mapped"), "--workers", "1", "--no-progress"]
    assert main([*argv, "--marker-map", mapping]) == 0
    assert "0 errors" in capsys.readouterr().out  # the trial ran (its verdict is another matter)


def test_check_command_exit_status_and_json(tmp_path, capsys):
    subject4 = data_path("opencap/Subject4")
    model = str(subject4 / "Models/optimized_scale_and_markers.osim")
    motion = read_motion(subject4 / "IK/walking1_ik.mot")
    assert main(["check", str(subject4 / "IK/walking1_ik.mot"), "--model", model]) == 0
    assert capsys.readouterr().out.split(":")[0] in ("ok", "warn")
    values = motion.values.copy()
    values[:, motion.index("pelvis_tx")] += 1.0 * (motion.times - motion.times[0])
    sliding = write_motion(tmp_path / "sliding.mot", motion.with_values(values))
    assert main(["check", str(sliding), "--model", model, "--json"]) == 1
    verdict = json.loads(capsys.readouterr().out)
    assert verdict["verdict"] == "fail" and verdict["reasons"][0]["rule"] == "foot_sliding"
    assert np.isfinite(verdict["frames"])
    assert main(["check", str(tmp_path / "missing.mot"), "--model", model]) == 2


def test_analyze_plate_override_and_the_printed_assignment(tmp_path, capsys):
    subject4 = data_path("opencap/Subject4")
    argv = [
        "analyze",
        str(subject4 / "IK/DJ1_ik.mot"),
        "--model",
        str(subject4 / "Models/optimized_scale_and_markers.osim"),
        "--grf",
        str(subject4 / "ID/DJ1_grf.mot"),
        "--no-figures",
    ]
    assert main([*argv, "--out", str(tmp_path / "auto")]) == 0
    printed = capsys.readouterr().out
    # opencap/SOURCE.md: plate 1 is the right foot, plate 2 the left, plate 3 empty
    assert "ground_force_1 -> right 100%" in printed and "ground_force_2 -> left 100%" in printed
    assert "ground_force_3: never loaded" in printed
    assert main([*argv, "--plates", "1=right,2=left,3=none", "--out", str(tmp_path / "given")]) == 0
    assert "ground_force_1 -> calcn_r (given); ground_force_2 -> calcn_l (given)" in capsys.readouterr().out
    summary = json.loads((tmp_path / "given" / "summary.json").read_text())
    assert summary["plates"]["ground_force_2"] == {"mode": "given", "body": "calcn_l"}
    assert main([*argv, "--plates", "1=upside", "--out", str(tmp_path / "bad")]) == 2
