"""The bad-input corpus (`tests/bad_inputs/cases.py`) in the suite: every fast case, run in this process through
`biomotion.cli.main`, must be handled cleanly (one ``error:`` line naming the file or argument with exit status 2,
or the right output); an interrupted run is checked as a subprocess. ``python benchmarks/bad_inputs.py`` runs the
whole corpus, slow cases included, each as a subprocess with a timeout."""

import json
import subprocess
import sys

import pytest

from tests.bad_inputs.cases import CASES
from tests.bad_inputs.runner import run_in_process, run_subprocess

FAST = [case for case in CASES if case.fast]


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return tmp_path_factory.mktemp("bad_inputs")


def test_the_corpus_covers_the_issue():
    """At least 60 cases; every reader and verb; the cases the issue lists by name."""
    assert len(CASES) >= 60 and len({case.id for case in CASES}) == len(CASES)
    covered = " ".join(case.covers for case in CASES)
    readers = (".mot", ".sto", ".trc", ".c3d", ".bvh", ".bvh.gz", ".osim", "IK setup", "Scale setup", ".csv", ".xlsx")
    readers += (".yaml", ".json", ".csv motion", ".vtp", "safetensors")
    verbs = ("analyze", "generate", "scale", "retarget", "convert", "inspect", "view", "eval", "validate")
    verbs += ("data build", "data augment", "data sources")
    verbs += tuple(f"train {m}" for m in ("tokenizer", "generator", "surrogate", "labels", "paths", "segments"))
    assert [r for r in readers if r not in covered] == [] and [v for v in verbs if f"verb {v}" not in covered] == []
    ids = {case.id for case in CASES}
    for listed in (
        "grf-shorter-than-motion",
        "trc-row-missing-value",
        "profile-unknown-key",
        "generate-nonsense-action",
        "generate-out-exists",
        "generate-records-what-made-it",
        "mot-nan-analyze",
        "generate-out-is-a-file",
        "generate-out-unwritable",
        "generate-seconds-nan",
        "generate-seconds-inf",
        "generate-seconds-100000",
        "ik-setup-path-5000-chars",
        "convert-into-existing-folder",
        "osim-entity-bomb",
        "osim-external-entity",
        "generate-same-seed",
        "generate-interrupted",
        "analyze-interrupted",
    ):
        assert listed in ids, listed
    assert {case.expect for case in CASES} == {"clean", "ok", "interrupt"}


@pytest.mark.parametrize("case", FAST, ids=lambda case: case.id)
def test_a_bad_input_is_handled_cleanly(case, root, data_root, monkeypatch):
    monkeypatch.setenv("BIOMOTION_DATA_ROOT", str(data_root))
    outcome = run_in_process(case, root, data_root)
    assert outcome.verdict == "clean", (
        f"{case.id} ({case.what}): {outcome.verdict}: {outcome.reason}\nstderr: {outcome.stderr[-1500:]}"
    )


def test_an_interrupted_analysis_leaves_nothing_behind(root, data_root):
    """SIGINT once `analyze` is writing: exit status 130, no --out, no scratch folder beside it."""
    case = next(case for case in CASES if case.id == "analyze-interrupted")
    outcome = run_subprocess(case, root, data_root, timeout=120)
    assert outcome.verdict == "clean", f"{outcome.verdict}: {outcome.reason}\nstderr: {outcome.stderr[-1500:]}"


def test_argument_errors_answer_before_the_library_loads():
    """A wrong argument is answered by the parser alone, before torch is imported (what makes it answer in well
    under a second: `benchmarks/bad_inputs.py` times it), on one line."""
    script = (
        "import sys, io, contextlib\n"
        "from biomotion.cli import main\n"
        "err = io.StringIO()\n"
        "with contextlib.redirect_stderr(err):\n"
        "    code = main(['generate', '--seconds', 'nan', '--out', 'x'])\n"
        "print(json.dumps([code, 'torch' in sys.modules, err.getvalue()]))\n"
    )
    result = subprocess.run([sys.executable, "-c", "import json\n" + script], capture_output=True, text=True)
    code, torch_loaded, message = json.loads(result.stdout)
    assert (code, torch_loaded) == (2, False), result.stdout + result.stderr
    assert message.startswith("error: argument --seconds") and message.count("\n") == 1
