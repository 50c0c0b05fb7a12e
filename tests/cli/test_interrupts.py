"""Ctrl-C is never lost: a run that a library's exception handling would carry on past still stops, leaves no
output and exits 130 (`biomotion.cli._common.remembering_interrupts`)."""

import os
import signal

import pytest

from biomotion.cli._common import fresh_folder, interrupted, remembering_interrupts


def _ctrl_c_swallowed_by_an_optional_import() -> None:
    """What a C extension's import does with a SIGINT that lands while it initialises, and an optional import
    around it: the KeyboardInterrupt becomes ImportError, which is caught."""
    try:
        try:
            os.kill(os.getpid(), signal.SIGINT)
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None
    except ImportError:
        pass


def test_a_swallowed_ctrl_c_still_discards_the_run(tmp_path):
    out = tmp_path / "out"
    with remembering_interrupts():
        with pytest.raises(KeyboardInterrupt):
            with fresh_folder(out, overwrite=False) as scratch:
                (scratch / "half.mot").write_text("written before the interrupt")
                _ctrl_c_swallowed_by_an_optional_import()
        assert interrupted()
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []  # no scratch folder left either


def test_a_run_without_ctrl_c_moves_into_place(tmp_path):
    out = tmp_path / "out"
    with remembering_interrupts():
        with fresh_folder(out, overwrite=False) as scratch:
            (scratch / "done.mot").write_text("whole")
        assert not interrupted()
    assert (out / "done.mot").read_text() == "whole"


def test_the_previous_sigint_handler_comes_back():
    before = signal.getsignal(signal.SIGINT)
    with remembering_interrupts():
        pass
    assert signal.getsignal(signal.SIGINT) is before
