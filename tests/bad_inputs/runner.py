"""Run one case of the corpus (`biomotion` as a subprocess with a timeout, or in this process through
`biomotion.cli.main`) and judge what it did.

Classes:

- ``clean``: what the case expects: one ``error:`` line naming the file or argument at fault with exit status 2,
  the right output with exit status 0, or an interrupted run that exits with 130 and leaves nothing behind;
- ``silent``: a wrong result without a word: exit status 0 where an error was due, an output that fails its check,
  a refused valid request, or an interrupted run that left a half-written output or a scratch folder;
- ``traceback``: a bug surfaced: exit status 1 (``internal error``), a Python traceback, or an error that is not
  one ``error:`` line naming its file or argument;
- ``hang``: no answer within the timeout.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path

from tests.bad_inputs.cases import Case, unwritable

REPO = Path(__file__).resolve().parents[2]
TIMEOUT = 60.0
CLASSES = ("clean", "silent", "traceback", "hang")
NOTICES = ("warning:", "note:")


@dataclass
class Outcome:
    """What one run of a case did and how it is judged."""

    case: Case
    argv: list[str]
    returncode: int | None
    seconds: float
    stdout: str
    stderr: str
    verdict: str = ""
    reason: str = ""
    #: interrupt cases: one "wait W s: signalled|ended first" per try, in order
    tries: list[str] = field(default_factory=list)

    @property
    def first_error_line(self) -> str:
        shown = [line for line in self.stderr.splitlines() if line.strip() and not line.startswith(NOTICES)]
        return shown[0] if shown else ""


def prepare(case: Case, root: Path, data: Path) -> tuple[Path, list[str]]:
    """The case's own folder under ``root`` with its inputs made, and its argv with the placeholders filled."""
    folder = root / case.id
    folder.mkdir(parents=True)
    if case.make is not None:
        case.make(folder, data)
    argv = [argument.format(**fields(case, folder, data)) for argument in case.argv]
    (folder / "argv.json").write_text(json.dumps(argv))
    return folder, argv


def fields(case: Case, folder: Path, data: Path) -> dict[str, str]:
    values = {"t": str(folder), "d": str(data), "r": str(REPO)}
    if any("{unwritable}" in argument for argument in case.argv):
        values["unwritable"] = unwritable(folder)
    return values


def run_subprocess(case: Case, root: Path, data: Path, timeout: float = TIMEOUT) -> Outcome:
    """``python -m biomotion ARGV`` in the case's folder, ``$BIOMOTION_DATA_ROOT`` set to ``data``. An interrupt
    case whose command had finished its work before the signal reached it (ended before it could be sent, or
    exited 0 with its output complete and in place) tested nothing: it runs again, signalled sooner
    (`INTERRUPT_WAITS`). The last try signals as soon as the scratch folder appears, while the work has only
    begun, so a command that ignores Ctrl-C still fails there."""
    tries = []
    for wait in INTERRUPT_WAITS if case.expect == "interrupt" else (None,):
        shutil.rmtree(root / case.id, ignore_errors=True)
        outcome, signalled = _run_once(case, root, data, timeout, wait)
        if wait is None:
            break
        finished = _finished_first(outcome, root, data)
        tries.append(
            f"wait {wait} s: "
            + ("not signalled (ended first)" if not signalled else f"exit {outcome.returncode}")
            + (", output complete" if finished else "")
        )
        if signalled and not finished:
            break
    outcome.tries = tries
    return outcome


def _finished_first(outcome: Outcome, root: Path, data: Path) -> bool:
    """Whether an interrupted run had already done its work: exit 0 with its output folder in place."""
    folder = root / outcome.case.id
    return outcome.returncode == 0 and Path(outcome.case.out.format(**fields(outcome.case, folder, data))).is_dir()


#: Seconds between the scratch folder appearing and Ctrl-C, one try each: into the work, then sooner for a
#: command that writes fast.
INTERRUPT_WAITS = (0.5, 0.1, 0.0)


def _run_once(case: Case, root: Path, data: Path, timeout: float, wait: float | None) -> tuple[Outcome, bool]:
    folder, argv = prepare(case, root, data)
    env = {**os.environ, "BIOMOTION_DATA_ROOT": str(data)}
    started = time.perf_counter()
    process = subprocess.Popen(
        [sys.executable, "-m", "biomotion", *argv],
        cwd=folder,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_ctrl_c_as_in_a_terminal if wait is not None else None,
    )
    signalled = False
    if wait is not None:
        out = Path(case.out.format(**fields(case, folder, data)))
        signalled = _interrupt_when_writing(process, out, started, timeout, wait)
    try:
        stdout, stderr = process.communicate(timeout=max(timeout - (time.perf_counter() - started), 1.0))
        returncode = process.returncode
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        stdout, stderr = process.communicate()
        returncode = None
    outcome = Outcome(case, argv, returncode, time.perf_counter() - started, stdout, stderr)
    judge(outcome, folder, data)
    return outcome, signalled


def _ctrl_c_as_in_a_terminal() -> None:
    """In the child before it starts: SIGINT to its default action, as a command typed in a terminal has it. A
    runner started in the background of a non-interactive shell (``python benchmarks/bad_inputs.py &``) ignores
    SIGINT, the children inherit that, and Python keeps an ignored SIGINT ignored: Ctrl-C would test nothing."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt_when_writing(process: subprocess.Popen, out: Path, started: float, timeout: float, wait: float) -> bool:
    """SIGINT (Ctrl-C) ``wait`` s after the command has made its scratch output folder (it is then at work), or
    after 20 s; whether the signal was sent (False: the command had already ended)."""
    while process.poll() is None and time.perf_counter() - started < min(20.0, timeout):
        if any(out.parent.glob(f".{out.name}.*.partial")):
            time.sleep(wait)
            break
        time.sleep(0.01)
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        return True
    return False


def run_in_process(case: Case, root: Path, data: Path) -> Outcome:
    """`biomotion.cli.main(argv)` in this process, stdout and stderr captured, in the case's folder."""
    from biomotion.cli import main

    folder, argv = prepare(case, root, data)
    stdout, stderr = io.StringIO(), io.StringIO()
    here = Path.cwd()
    started = time.perf_counter()
    try:
        os.chdir(folder)
        with redirect_stdout(stdout), redirect_stderr(stderr):
            try:
                returncode = main(argv)
            except SystemExit as done:
                returncode = done.code if isinstance(done.code, int) else 1
            except BaseException as error:  # noqa: BLE001 - anything escaping main is a bug to report
                import traceback

                traceback.print_exception(error, file=sys.stderr)
                returncode = 1
    finally:
        os.chdir(here)
    outcome = Outcome(case, argv, returncode, time.perf_counter() - started, stdout.getvalue(), stderr.getvalue())
    judge(outcome, folder, data)
    return outcome


def judge(outcome: Outcome, folder: Path, data: Path) -> None:
    """Set ``outcome.verdict`` (one of `CLASSES`) and ``outcome.reason``."""
    outcome.verdict, outcome.reason = _judge(outcome, folder, data)


def _judge(outcome: Outcome, folder: Path, data: Path) -> tuple[str, str]:
    case, code, stderr = outcome.case, outcome.returncode, outcome.stderr
    if code is None:
        return "hang", f"no answer in {outcome.seconds:.0f} s"
    if "Traceback (most recent call last)" in stderr:
        return "traceback", "a Python traceback on stderr"
    if code == 1 or "internal error" in stderr:
        return "traceback", f"exit {code}: {outcome.first_error_line[:200]}"
    errors = [line for line in stderr.splitlines() if line.strip() and not line.startswith(NOTICES)]
    if case.expect == "interrupt":
        out = Path(case.out.format(**fields(case, folder, data)))
        if code not in (130, -signal.SIGINT):  # ended by the signal itself: what a shell reports as 130 too
            return "silent", f"exit {code} after SIGINT, not 130"
        if out.exists():
            return "silent", f"{out.name} exists after the interrupted run"
        left = [p.name for p in out.parent.glob(f".{out.name}.*.partial")]
        if left:
            return "silent", f"scratch folder left: {left[0]}"
        return "clean", "interrupted: exit 130, nothing left"
    if case.expect == "ok":
        if code != 0:
            return "silent", f"refused a valid request (exit {code}): {outcome.first_error_line[:200]}"
        try:
            problem = case.check(folder, outcome.stdout, stderr) if case.check is not None else None
        except Exception as error:  # noqa: BLE001 - a missing or unreadable output is a wrong result
            problem = f"output unreadable: {type(error).__name__}: {error}"
        return ("silent", problem) if problem else ("clean", "right output")
    if code == 0:
        return "silent", "exit 0 where an error was expected"
    if code != 2:
        return "traceback", f"exit {code}"
    if len(errors) != 1:
        return "traceback", f"{len(errors)} lines on stderr, not one error line"
    if not errors[0].startswith("error:"):
        return "traceback", f"the error line does not start with 'error:': {errors[0][:200]}"
    names = case.names.format(**fields(case, folder, data)) if "{" in case.names else case.names
    if names not in errors[0]:
        return "traceback", f"the error does not name {names!r}"
    return "clean", "one error line naming the input"
