"""Records name paths relative to the working folder or under ~, never by a machine's absolute path."""

import os
import shlex
from pathlib import Path

from biomotion.cli._common import command_line
from biomotion.io.paths import portable


def test_working_folder_and_home_leave_the_text():
    cwd, home = os.getcwd(), str(Path.home())
    assert portable(f"{cwd}/checkpoints/refiner.safetensors") == "checkpoints/refiner.safetensors"
    assert portable(cwd) == "."
    assert portable(f"--cache={home}/.cache/biomotion/x") == "--cache=~/.cache/biomotion/x"
    assert portable("../shared/data") == "../shared/data"


def test_recorded_command_runs_as_written_in_a_shell():
    home = str(Path.home())
    line = command_line(["train", "refiner", "--cache", f"{home}/.cache/b m", "--out", f"{os.getcwd()}/out"])
    assert line == "biomotion train refiner --cache ~/'.cache/b m' --out out"
    # the shell's word splitting gives back one argument per path, with ~ outside the quotes to expand
    assert shlex.split(line)[4] == "~/.cache/b m"
