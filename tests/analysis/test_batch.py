"""A whole study in one call: a 2-subject study end to end (OpenSim files per trial, the report in Chromium, the
record), a corrupted trial reported while the rest go on, the swapped-marker trial flagged by the a-priori rules,
resume, and Ray giving the local executor's numbers."""

import json
import shutil

import numpy as np
import pytest

from biomotion.analysis.batch import OUTCOME, RECORD, REPORT, batch
from biomotion.analysis.study import load_study
from biomotion.errors import ConfigError
from biomotion.io.mot import read_storage
from tests.conftest import data_path

GAIT = "opensim-models/Pipelines/Gait2392_Simbody"
FUKUCHI = "fukuchi-running"


def write_config(folder, *, corrupted: bool = True, window=(12.0, 13.2)) -> "Path":  # noqa: F821
    """Two subjects: gait2392's subject01 (its scaled model as given, walk1 with plates, IK setup and shipped muscle
    paths) and Fukuchi's RBDS001 (scaled from its static C3D by its setup; 3.5 m/s running, a short window, and a
    truncated copy of its 2.5 m/s C3D)."""
    gait, fukuchi = data_path(GAIT), data_path(FUKUCHI)
    folder.mkdir(parents=True, exist_ok=True)
    trials = f"""
[[subject.trial]]
name = "runT35"
markers = "{fukuchi}/c3d/RBDS001runT35.c3d"
setup = "{fukuchi}/RBDS001/RBDS001_T35_ikSetup.xml"
time_range = [{window[0]}, {window[1]}]
"""
    if corrupted:
        broken = folder / "RBDS001runT25_truncated.c3d"
        data = (fukuchi / "c3d" / "RBDS001runT25.c3d").read_bytes()
        broken.write_bytes(data[: len(data) // 3])
        trials += f"""
[[subject.trial]]
name = "broken"
markers = "{broken}"
"""
    config = folder / "study.toml"
    config.write_text(
        f"""
[study]
name = "two subjects"
marker_filter_hz = 10

[[subject]]
name = "gait2392"
model = "{gait}/OutputReference/subject01_simbody.osim"
muscles = "gait2392_subject01"
[[subject.trial]]
name = "walk1"
markers = "{gait}/subject01_walk1.trc"
forces = "{gait}/subject01_walk1_grf.mot"
setup = "{gait}/subject01_Setup_IK.xml"

[[subject]]
name = "RBDS001"
model = "{fukuchi}/generic-models/Denton2023_LowerLimb_Fukuchi2017.osim"
scale_setup = "{fukuchi}/RBDS001/RBDS001_scaleSetup_simple.xml"
static = "{fukuchi}/c3d/RBDS001static.c3d"
mass = 62.0
{trials}"""
    )
    return config


@pytest.fixture(scope="module")
def study_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("study")
    config = write_config(folder)
    result = batch(config, folder / "out", workers=1, progress=False)
    return config, result


def _outcome(result, subject, name):
    return next(o for o in result.outcomes if o.subject == subject and o.name == name)


def test_two_subject_study_end_to_end(study_run):
    _, result = study_run
    out = result.out
    trials = [o for o in result.outcomes if o.kind == "trial"]
    assert [(o.subject, o.name) for o in trials] == [
        ("gait2392", "walk1"),
        ("RBDS001", "runT35"),
        ("RBDS001", "broken"),
    ]
    walk = _outcome(result, "gait2392", "walk1")
    assert walk.status == "done"
    folder = out / "gait2392" / "walk1"
    # OpenSim formats: the model, coordinates, torques, ground reactions with their ExternalLoads, activations
    for name in (
        "gait2392.osim",
        "walk1_ik.mot",
        "torques.sto",
        "grf_measured_by_foot.mot",
        "grf_measured_loads.xml",
        "com_zmp.sto",
        "activations.sto",
        "viewer.html",
    ):
        assert (folder / name).is_file(), name
    torques = read_storage(folder / "torques.sto")
    assert "knee_angle_r_moment" in torques.labels and np.isfinite(torques.data).all()
    assert "frames balanced" in walk.figures["static_optimization"]
    # the automatic plate assignment: gait2392's first plate under the right foot, the second under the left
    plates = walk.figures["plates"]
    assert plates["ground_force"]["right"] > 0.9 and plates["1_ground_force"]["left"] > 0.9
    viewer = (folder / "viewer.html").read_text()
    assert r"GRF right foot \u2190 plate ground_force" in viewer  # the legend names the plates (JSON-escaped arrow)
    assert '<script src="../../plotly.min.js">' in viewer and (out / "plotly.min.js").is_file()
    scaled = _outcome(result, "RBDS001", "RBDS001static")
    assert scaled.status == "done" and (out / "RBDS001" / "RBDS001.osim").is_file()
    assert scaled.figures["mass_kg"] == pytest.approx(62.0)
    assert set(scaled.figures["scale_factors"]) >= {"pelvis", "femur_r", "tibia_l"}
    assert scaled.figures["static_marker_rms_m"] < 0.05


def test_the_swapped_metatarsal_markers_fail_by_the_a_priori_rules(study_run):
    """fukuchi-running/SOURCE.md: RBDS001's 3.5 m/s C3D has R.MT1 and R.MT5 swapped."""
    _, result = study_run
    run = _outcome(result, "RBDS001", "runT35")
    assert run.verdict["verdict"] == "fail"
    rules = {r["rule"]: r for r in run.verdict["reasons"]}
    assert rules["markers"]["verdict"] == "fail"
    worst = [w["marker"] for w in rules["markers"]["figures"]["worst_markers"][:2]]
    assert sorted(worst) == ["R.MT1", "R.MT5"]
    assert rules["marker_labels"]["figures"]["swaps"][0]["markers"] == ["R.MT1", "R.MT5"]


def test_a_corrupted_trial_is_reported_and_the_rest_processed(study_run):
    _, result = study_run
    broken = _outcome(result, "RBDS001", "broken")
    assert broken.status == "error" and broken.error_kind == "input" and broken.verdict["verdict"] == "fail"
    assert "RBDS001runT25_truncated.c3d" in broken.error
    assert json.loads((result.out / "RBDS001" / "broken" / OUTCOME).read_text())["status"] == "error"
    assert _outcome(result, "RBDS001", "runT35").status == "done"


def test_record_holds_versions_settings_inputs_and_timings(study_run):
    config, result = study_run
    record = json.loads((result.out / RECORD).read_text())
    assert record["biomotion"] and record["versions"]["torch"] and record["settings"]["marker_filter_hz"] == 10
    inputs = record["inputs_sha256"]
    assert any(path.endswith("subject01_walk1.trc") for path in inputs)
    assert all(len(digest) == 64 for digest in inputs.values())
    assert record["trial_verdicts"]["fail"] >= 2 and record["seconds"] > 0
    assert all(row["seconds"] for row in record["trials"])


def test_report_is_one_offline_page_with_every_trial(study_run):
    _, result = study_run
    text = (result.out / REPORT).read_text()
    assert "<script src=" not in text  # plotly.js inline: the page is self-contained
    for subject, name in (("gait2392", "walk1"), ("RBDS001", "runT35"), ("RBDS001", "broken")):
        assert f'<td class="">{name}</td>' in text and subject in text
    assert text.count('<tr id="trial-') == 3


def test_report_opens_in_chromium(study_run):
    from biomotion.viz.browser import Page, find_chromium

    if find_chromium() is None:
        pytest.skip("headless Chromium not installed (Debian package `chromium`)")
    _, result = study_run
    with Page(1200, 800) as page:
        page.open(result.out / REPORT)
        assert page.evaluate("window.report.ready") is True
        assert page.evaluate("document.querySelectorAll('#trials tbody tr').length") == 3
        page.evaluate("document.querySelector('details[data-subject=\"RBDS001\"]').open = true")
        page.evaluate("window.report.draw('RBDS001')")
        assert page.evaluate("document.querySelectorAll('.plot .main-svg').length") >= 3  # plots drawn
        page.evaluate("document.querySelectorAll('#trials th')[2].click()")  # sort by verdict
        assert page.errors == []
        assert [url for url in page.requests if not url.startswith("file://")] == []  # nothing fetched


def test_resume_skips_what_hashes_the_same(study_run, tmp_path):
    config, first = study_run
    out = tmp_path / "out"
    shutil.copytree(first.out, out)
    again = batch(config, out, workers=1, progress=False, resume=True)
    assert all(o.skipped for o in again.outcomes if o.status == "done")
    assert again.counts() == first.counts() | {"skipped": again.counts()["skipped"]}
    with pytest.raises(ConfigError, match="--resume"):
        batch(config, out, workers=1, progress=False)
    changed = batch(load_study(config, cutoff_hz=8.0), out, workers=1, progress=False, resume=True)
    assert not any(o.skipped for o in changed.outcomes if o.kind == "trial" and o.status == "done")
    assert all(o.skipped for o in changed.outcomes if o.kind == "static" and o.status == "done")


def _numbers(folder):
    """Every number of the .sto/.mot files under a batch folder, by file."""
    return {
        path.relative_to(folder): read_storage(path).data
        for path in sorted(folder.rglob("*"))
        if path.suffix in (".sto", ".mot")
    }


def test_ray_gives_the_local_executors_numbers(tmp_path):
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'biomotion[distributed]')")
    config = write_config(tmp_path, corrupted=False, window=(12.0, 12.8))
    study = load_study(config, viewer=False)
    local = batch(study, tmp_path / "local", workers=1, progress=False, report=False)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        remote = batch(study, tmp_path / "ray", executor="ray", progress=False, report=False)
    finally:
        ray.shutdown()
    assert [o.verdict for o in local.outcomes] == [o.verdict for o in remote.outcomes]
    ours, theirs = _numbers(tmp_path / "local"), _numbers(tmp_path / "ray")
    assert ours.keys() == theirs.keys() and len(ours) >= 10
    assert max(float(np.abs(ours[k] - theirs[k]).max()) for k in ours) <= 1e-9
