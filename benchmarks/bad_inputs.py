"""The bad-input corpus (`tests/bad_inputs/cases.py`): every case run as ``python -m biomotion ...`` in a subprocess
with a timeout, and classified as a clean error, a silent wrong result, a traceback or a hang
(`tests/bad_inputs/runner.py` says how). Writes ``docs/results/bad_inputs.json`` (the counts, every case's record,
the command and the versions) and ``docs/results/bad_inputs.md`` (a table).

    python benchmarks/bad_inputs.py [--data-root ../shared/data] [--quick] [--only ID ...] [--timeout 60]
        [--json docs/results/bad_inputs.json] [--md docs/results/bad_inputs.md]

``--quick`` runs only the fast subset (the cases the test suite runs). Each case writes its inputs and outputs in
its own temporary folder, made from copies of the data root's files (which is never written). Argument errors
(answered by the parser, before anything heavy is imported) are timed: each must answer in under a second.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tqdm import tqdm  # noqa: E402

from biomotion.io.atomic import atomic_write  # noqa: E402
from tests.bad_inputs.cases import CASES  # noqa: E402
from tests.bad_inputs.runner import CLASSES, TIMEOUT, Outcome, run_subprocess  # noqa: E402

ARGUMENT_BAR_S = 1.0


def shorten(argument: str, root: Path, data: Path) -> str:
    """An argument as the report shows it: temporary and data paths abbreviated, very long ones cut."""
    text = argument.replace(str(root), "$TMP").replace(str(data), "$DATA").replace(str(REPO), "$REPO")
    return text if len(text) <= 120 else f"{text[:60]}...({len(text)} characters)"


def versions() -> dict[str, str]:
    import numpy
    import torch

    import biomotion

    return {
        "biomotion": biomotion.__version__,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": numpy.__version__,
        "platform": platform.platform(),
    }


def record(outcome: Outcome, root: Path, data: Path) -> dict:
    case = outcome.case
    return {
        "id": case.id,
        "covers": case.covers,
        "what": case.what,
        "expect": case.expect,
        "argv": [shorten(a, root, data) for a in outcome.argv],
        "exit": outcome.returncode,
        "seconds": round(outcome.seconds, 3),
        "stderr_first_line": shorten(outcome.first_error_line, root, data)[:300],
        "class": outcome.verdict,
        "reason": outcome.reason,
        "argument_error": case.argument,
        "fast": case.fast,
        **({"interrupt_tries": outcome.tries} if outcome.tries else {}),
    }


def markdown(report: dict) -> str:
    lines = [
        "# Bad-input corpus",
        "",
        f"Produced by `{report['command']}` on {report['date']} (biomotion {report['versions']['biomotion']}, "
        f"Python {report['versions']['python']}, torch {report['versions']['torch']}; "
        f"timeout {report['timeout_s']:g} s per case). Each case runs `python -m biomotion ...` as a subprocess on "
        "inputs copied from the data root and corrupted in a temporary folder (`tests/bad_inputs/cases.py`).",
        "",
        f"**{report['bad_inputs_cases']} cases: {report['bad_inputs_clean']} clean, {report['bad_inputs_silent']} "
        f"silent, {report['bad_inputs_traceback']} traceback, {report['bad_inputs_hang']} hang.** Argument errors "
        + (
            f"answer in at most {report['argument_error_max_s']:.2f} s (bar: {ARGUMENT_BAR_S:g} s)."
            if report["argument_error_max_s"] is not None
            else "(no argument-error case in this run)."
        ),
        "",
        "clean: one `error:` line naming the file or argument, exit 2 (or, for the valid requests marked ok, the "
        "right output; for interrupted runs, exit 130 and nothing left behind); silent: a wrong result without "
        "an error; traceback: exit 1, a traceback, or an error that is not one line naming its input; hang: no "
        "answer within the timeout.",
        "",
        "| case | covers | expect | exit | s | class | first stderr line |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in report["cases"]:
        first = row["stderr_first_line"].replace("|", "\\|")
        if len(first) > 160:
            first = first[:157] + "..."
        lines.append(
            f"| {row['id']} | {row['covers']} | {row['expect']} | {row['exit']} | {row['seconds']:.2f} | "
            f"{row['class']} | {first} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-root", type=Path, default=Path("../shared/data"))
    parser.add_argument("--quick", action="store_true", help="only the fast subset")
    parser.add_argument("--only", nargs="+", metavar="ID", help="only these cases")
    parser.add_argument("--timeout", type=float, default=TIMEOUT, help="seconds per case (default: %(default)s)")
    parser.add_argument("--json", type=Path, default=REPO / "docs/results/bad_inputs.json")
    parser.add_argument("--md", type=Path, default=REPO / "docs/results/bad_inputs.md")
    args = parser.parse_args(argv)
    data = args.data_root.resolve()
    if not data.is_dir():
        parser.error(f"{args.data_root}: no data root there")
    cases = [c for c in CASES if (not args.quick or c.fast) and (not args.only or c.id in args.only)]
    outcomes = []
    with tempfile.TemporaryDirectory(prefix="bad_inputs.") as scratch:
        root = Path(scratch)
        for case in tqdm(cases, desc="bad inputs", unit="case"):
            outcome = run_subprocess(case, root, data, args.timeout)
            outcomes.append(record(outcome, root, data))
            if outcome.verdict != "clean":
                tqdm.write(f"{case.id}: {outcome.verdict}: {outcome.reason}")
    counts = {verdict: sum(o["class"] == verdict for o in outcomes) for verdict in CLASSES}
    timed = [o["seconds"] for o in outcomes if o["argument_error"]]
    report = {
        "bad_inputs_cases": len(outcomes),
        **{f"bad_inputs_{verdict}": n for verdict, n in counts.items()},
        "argument_error_max_s": round(max(timed), 3) if timed else None,
        "argument_error_under_1s": all(s < ARGUMENT_BAR_S for s in timed),
        "timeout_s": args.timeout,
        "quick": args.quick,
        "command": "python benchmarks/bad_inputs.py " + " ".join(shlex.quote(a) for a in (sys.argv[1:] or [])),
        "date": time.strftime("%Y-%m-%d"),
        "versions": versions(),
        "cpu_count": os.cpu_count(),
        "cases": outcomes,
    }
    report["command"] = report["command"].rstrip()
    for path, text in ((args.json, json.dumps(report, indent=1) + "\n"), (args.md, markdown(report))):
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path) as handle:
            handle.write(text)
    print(
        f"{len(outcomes)} cases: "
        + ", ".join(f"{n} {verdict}" for verdict, n in counts.items())
        + f"; argument errors in at most {report['argument_error_max_s']} s -> {args.json}, {args.md}"
    )
    return 0 if counts["clean"] == len(outcomes) and report["argument_error_under_1s"] else 1


if __name__ == "__main__":
    sys.exit(main())
