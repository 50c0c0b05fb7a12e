"""The bad-input corpus as data: one `Case` per wrong thing a user can give a reader or a verb.

Each case names the command line (``argv`` of ``biomotion``), what it must do (``expect``), what it covers (the
reader and the verb) and, where the input has to be made, a ``make(tmp, data)`` that writes it into the case's own
temporary folder: real files are copied *from* the data root into that folder and the copy is corrupted there (the
data root is read-only input and is never written). In ``argv`` and ``names``, ``{t}`` is that temporary folder,
``{d}`` the data root and ``{r}`` the repository.

Expectations:

- ``clean``: exit status 2 and one ``error: ...`` line on stderr (``warning:``/``note:`` lines may come before it)
  that contains ``names`` (the file or the argument at fault);
- ``ok``: a valid (if unusual) request that must succeed, exit status 0, and ``check(tmp, stdout, stderr)`` finds
  the output right (it returns what is wrong, or None);
- ``interrupt``: the command is sent SIGINT once it has started writing (``out`` is its output folder); it must
  exit with status 130 and leave neither ``out`` nor a ``*.partial`` scratch folder beside it.

``argument`` marks the cases the argument parser answers (timed: each must answer in under a second); ``fast``
the cases that answer within a few seconds, which the test suite runs (`tests/test_bad_inputs.py`).
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

# real files the corpus starts from (relative to the data root)
GAIT = "opensim-models/Pipelines/Gait2392_Simbody"
IK_MOT = f"{GAIT}/subject01_walk1_ik.mot"  # 211 frames, 0.5-4 s, 60 Hz, degrees
GRF_MOT = f"{GAIT}/subject01_walk1_grf.mot"  # 0-2.5 s, 600 Hz: shorter than the motion
MODEL = f"{GAIT}/OutputReference/subject01_simbody.osim"
TRC = f"{GAIT}/subject01_walk1.trc"  # 151 frames, 41 markers, mm
IK_SETUP = f"{GAIT}/subject01_Setup_IK.xml"
SCALE_SETUP = f"{GAIT}/subject01_Setup_Scale.xml"
STO = f"{GAIT}/subject01_walk1_RRA_Kinematics_q.sto"
C3D_STATIC = "fukuchi-running/c3d/RBDS001static.c3d"  # markers in mm, one force plate
BVH_GZ = "bandai-namco/dataset-1/dataset-1_dash_normal_001.bvh.gz"  # 20 frames at 30 fps
RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
VTP = "opensim-models/Geometry/r_patella.vtp"
SUBJECTS = "fukuchi-running/participantInfo.csv"
ANSUR_MEN = "anthropometry/ANSUR_II_MALE_Public.csv"
PROFILE = "examples/runner_52_acl.yaml"  # in the repository

Maker = Callable[[Path, Path], None]
Check = Callable[[Path, str, str], "str | None"]


@dataclass(frozen=True)
class Case:
    """One bad input: see the module docstring."""

    id: str
    argv: tuple[str, ...]
    expect: str  # "clean" | "ok" | "interrupt"
    covers: str  # the reader and the verb, e.g. "reader .mot; verb analyze"
    what: str
    names: str = ""  # clean: text the error line must hold (the file or the argument)
    make: Maker | None = None
    check: Check | None = None
    out: str = ""  # interrupt: the output folder
    fast: bool = True
    argument: bool = False


# --- making the inputs: copies of real files, corrupted in the case's folder -------------------------------------


def _data_text(data: Path, relative: str) -> str:
    path = data / relative
    if path.name.endswith(".gz"):
        with gzip.open(path, "rt", encoding="utf-8") as handle:
            return handle.read()
    return path.read_text(encoding="utf-8", errors="replace")


def copy(relative: str, name: str) -> Maker:
    """The data file copied as ``name``."""
    return lambda t, d: shutil.copyfile(d / relative, t / name) and None


def write(name: str, content: str | bytes) -> Maker:
    """A file ``name`` holding ``content``."""

    def make(t: Path, d: Path) -> None:
        path = t / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content if isinstance(content, bytes) else content.encode())

    return make


def edited(relative: str, name: str, edit: Callable[[str], str]) -> Maker:
    """The data file's text, changed by ``edit``, written as ``name``."""

    def make(t: Path, d: Path) -> None:
        (t / name).write_text(edit(_data_text(d, relative)), encoding="utf-8")

    return make


def cut(relative: str, name: str, fraction: float) -> Maker:
    """The first ``fraction`` of the data file's bytes (a download or a disk that stopped)."""

    def make(t: Path, d: Path) -> None:
        raw = (d / relative).read_bytes()
        (t / name).write_bytes(raw[: int(len(raw) * fraction)])

    return make


def both(*makers: Maker) -> Maker:
    def make(t: Path, d: Path) -> None:
        for maker in makers:
            maker(t, d)

    return make


def folder(name: str) -> Maker:
    return lambda t, d: (t / name).mkdir(parents=True, exist_ok=True)


def unwritable(t: Path) -> str:
    """A path that cannot be written: under a read-only folder, or, where permissions do not bind (root), under a
    file."""
    if os.geteuid() == 0:
        (t / "afile").write_text("a file, not a folder\n")
        return str(t / "afile" / "out")
    locked = t / "locked"
    locked.mkdir(exist_ok=True)
    locked.chmod(0o555)
    return str(locked / "out")


def lines(edit: Callable[[list[str]], list[str]]) -> Callable[[str], str]:
    """A text edit made on the list of lines."""
    return lambda text: "\n".join(edit(text.splitlines())) + "\n"


def mot_rows(text: str) -> tuple[list[str], int]:
    """(lines, index of the first data row) of a storage file."""
    rows = text.splitlines()
    end = next(i for i, line in enumerate(rows) if line.strip().lower() == "endheader")
    return rows, end + 2


def mot_cell(row: int, column: int, value: str) -> Callable[[str], str]:
    """Data row ``row``, column ``column`` (0 = time) replaced by ``value``."""

    def edit(text: str) -> str:
        rows, first = mot_rows(text)
        cells = rows[first + row].split()
        cells[column] = value
        rows[first + row] = "\t".join(cells)
        return "\n".join(rows) + "\n"

    return edit


def mot_keep(rows_kept: int) -> Callable[[str], str]:
    def edit(text: str) -> str:
        rows, first = mot_rows(text)
        return "\n".join(rows[: first + rows_kept]) + "\n"

    return edit


def mot_shift_time(seconds: float) -> Callable[[str], str]:
    def edit(text: str) -> str:
        rows, first = mot_rows(text)
        for k in range(first, len(rows)):
            cells = rows[k].split()
            if cells:
                cells[0] = repr(float(cells[0]) + seconds)
                rows[k] = "\t".join(cells)
        return "\n".join(rows) + "\n"

    return edit


def trc_row(row: int, edit_fields: Callable[[list[str]], list[str]]) -> Callable[[str], str]:
    """TRC data row ``row`` (0-based) with its tab-separated fields changed."""

    def edit(text: str) -> str:
        rows = text.splitlines()
        fields = rows[6 + row].split("\t")
        rows[6 + row] = "\t".join(edit_fields(fields))
        return "\n".join(rows) + "\n"

    return edit


def trc_header(key: str, value: str) -> Callable[[str], str]:
    def edit(text: str) -> str:
        rows = text.splitlines()
        keys, values = rows[1].split("\t"), rows[2].split("\t")
        values[keys.index(key)] = value
        rows[2] = "\t".join(values)
        return "\n".join(rows) + "\n"

    return edit


def bvh_text(edit: Callable[[str], str], name: str, *, compress: bool = False) -> Maker:
    def make(t: Path, d: Path) -> None:
        text = edit(_data_text(d, BVH_GZ))
        if compress:
            (t / name).write_bytes(gzip.compress(text.encode()))
        else:
            (t / name).write_text(text)

    return make


def c3d_without_point_units(name: str) -> Maker:
    """The static C3D with its POINT:UNITS parameter renamed (the file then does not say its length unit)."""

    def make(t: Path, d: Path) -> None:
        raw = bytearray((d / C3D_STATIC).read_bytes())
        start = 512 * (raw[0] - 1)
        group = next(
            256 - raw[k + 1]
            for k in range(start + 4, len(raw) - 7)
            if raw[k] in (5, 251) and raw[k + 1] > 127 and raw[k + 2 : k + 7] == b"POINT"
        )
        k = next(
            k
            for k in range(start + 4, len(raw) - 7)
            if raw[k] in (5, 251) and raw[k + 1] == group and raw[k + 2 : k + 7] == b"UNITS"
        )
        raw[k + 2 : k + 7] = b"UNITX"
        (t / name).write_bytes(bytes(raw))

    return make


def c3d_header_frames(name: str, last_frame: int) -> Maker:
    """The static C3D with the header's last frame changed (the header then disagrees with the data)."""

    def make(t: Path, d: Path) -> None:
        raw = bytearray((d / C3D_STATIC).read_bytes())
        raw[8:10] = struct.pack("<H", last_frame)
        (t / name).write_bytes(bytes(raw))

    return make


BILLION_LAUGHS = (
    '<?xml version="1.0"?>\n<!DOCTYPE lolz [\n <!ENTITY lol "lol">\n'
    + "".join(f' <!ENTITY lol{k} "{("&lol" + (str(k - 1) if k > 1 else "") + ";") * 10}">\n' for k in range(1, 10))
    + ']>\n<OpenSimDocument Version="40000"><Model name="&lol9;"/></OpenSimDocument>\n'
)
EXTERNAL_ENTITY = (
    '<?xml version="1.0"?>\n<!DOCTYPE x [<!ENTITY secret SYSTEM "file:///etc/passwd">]>\n'
    '<OpenSimDocument Version="40000"><Model name="&secret;"/></OpenSimDocument>\n'
)


def _alias_bomb(leaf: str = "{location: knee, diagnosis: sprain}") -> str:
    """A YAML "billion laughs": nine levels of ten aliases, a billion leaves once expanded (the parser builds it
    as shared references in microseconds; whoever walks, prints or dumps it expands it)."""
    value = leaf
    for k in range(9):
        value = f"[&l{k} {value}" + f", *l{k}" * 9 + "]"
    return value


def profile_bomb(t: Path, d: Path) -> None:
    (t / "bomb.yaml").write_text(f"age: 30\ninjuries: {_alias_bomb()}\n")


def xlsx_table(name: str, rows: list[list]) -> Maker:
    def make(t: Path, d: Path) -> None:
        import openpyxl

        book = openpyxl.Workbook()
        sheet = book.active
        for row in rows:
            sheet.append(row)
        book.save(t / name)

    return make


def checkpoints_with(name: str, damage: Callable[[bytes], bytes]) -> Maker:
    """A copy of the shipped lab bundle in ``{t}/ckpt`` with ``name`` damaged."""

    def make(t: Path, d: Path) -> None:
        repo = Path(__file__).resolve().parents[2] / "checkpoints"
        (t / "ckpt").mkdir()
        for file in repo.glob("*.safetensors"):
            data = file.read_bytes()
            (t / "ckpt" / file.name).write_bytes(damage(data) if file.name == name else data)

    return make


def cache_with(manifest: str | None, clips: bytes | None) -> Maker:
    """A folder laid out like a dataset cache, with the given manifest.json text and clips.safetensors bytes."""

    def make(t: Path, d: Path) -> None:
        (t / "cache").mkdir()
        if manifest is not None:
            (t / "cache" / "manifest.json").write_text(manifest)
        if clips is not None:
            (t / "cache" / "clips.safetensors").write_bytes(clips)

    return make


def tokenizer_config(edit: Callable[[str], str]) -> Maker:
    def make(t: Path, d: Path) -> None:
        repo = Path(__file__).resolve().parents[2]
        (t / "config.yaml").write_text(edit((repo / "configs" / "tokenizer.yaml").read_text()))

    return make


def data_root_with(relative: str, maker: Callable[[bytes], bytes]) -> Maker:
    """A data root in ``{t}/datadir`` holding only ``relative``, damaged by ``maker``."""

    def make(t: Path, d: Path) -> None:
        path = t / "datadir" / relative
        path.parent.mkdir(parents=True)
        path.write_bytes(maker((d / relative).read_bytes()))

    return make


def rename_columns(text: str) -> str:
    """Every coordinate column of a storage file renamed (``q1``, ``q2`` ...): names no model has."""
    rows, first = mot_rows(text)
    labels = rows[first - 1].split()
    rows[first - 1] = "\t".join([labels[0], *(f"q{k}" for k in range(1, len(labels)))])
    return "\n".join(rows) + "\n"


def drop_last_label(text: str) -> str:
    rows, first = mot_rows(text)
    rows[first - 1] = "\t".join(rows[first - 1].split()[:-1])
    return "\n".join(rows) + "\n"


def bvh_value(text: str, frame: int, channel: int, value: str) -> str:
    """Channel ``channel`` of frame ``frame`` of a BVH's MOTION block set to ``value``."""
    rows = text.splitlines()
    first = next(k for k, row in enumerate(rows) if row.startswith("Frame Time")) + 1
    cells = rows[first + frame].split()
    cells[channel] = value
    rows[first + frame] = " ".join(cells)
    return "\n".join(rows) + "\n"


def set_time_range(text: str, value: str) -> str:
    start = text.index("<time_range>") + len("<time_range>")
    return text[:start] + value + text[text.index("</time_range>", start) :]


def first_weight(text: str, value: str) -> str:
    start = text.index("<weight>") + len("<weight>")
    return text[:start] + value + text[text.index("</weight>", start) :]


def shipped_paths() -> bytes:
    """The shipped gait2392 muscle-path functions (a valid file to damage)."""
    return (
        Path(__file__).resolve().parents[2] / "src/biomotion/muscles/paths/gait2392_subject01.safetensors"
    ).read_bytes()


def garbage(size: int = 4096, seed: int = 7) -> bytes:
    import random

    rng = random.Random(seed)
    return bytes(rng.randrange(256) for _ in range(size))


# --- checks of the runs that must succeed ------------------------------------------------------------------------


def storage_rows(path: Path) -> list[list[float]]:
    rows, first = mot_rows(path.read_text())
    return [[float(x) for x in row.split()] for row in rows[first:] if row.strip()]


def check_trimmed(t: Path, stdout: str, stderr: str) -> str | None:
    """--forces-trim: only the frames the force file covers (0.5-2.5 s of the 0.5-4 s motion: 121 frames)."""
    summary = json.loads((t / "out" / "summary.json").read_text())
    rows = storage_rows(t / "out" / "torques.sto")
    times = [row[0] for row in rows]
    if len(rows) != 121 or summary.get("frames") not in (None, 121):
        return f"{len(rows)} torque rows, summary frames {summary.get('frames')}; expected 121"
    if min(times) < 0.5 - 1e-9 or max(times) > 2.5 + 1e-9:
        return f"torques span {min(times)}-{max(times)} s, outside the forces' 0-2.5 s"
    if "warning:" not in stderr or "2.500" not in stderr:
        return "no warning that the motion was trimmed to the forces"
    return None


def check_sources(t: Path, stdout: str, stderr: str) -> str | None:
    listed = [line for line in stdout.splitlines() if line.strip()]
    if not listed or any(" absent " not in line for line in listed):
        return "an empty data root must list every source as absent"
    return None


def check_c3d_round_trip(t: Path, stdout: str, stderr: str) -> str | None:
    import numpy as np

    from biomotion.io.c3d import read_c3d_markers
    from biomotion.io.trc import read_trc

    source, written = read_trc(t / "in.trc"), read_c3d_markers(t / "out.c3d")
    if source.names != written.names or source.positions.shape != written.positions.shape:
        return f"{len(written.names)} markers x {written.n_frames} frames written for {len(source.names)} x " + str(
            source.n_frames
        )
    error = np.nanmax(np.abs(source.positions - written.positions))
    if not error < 1e-4:
        return f"markers moved by {error} m in the round trip"
    return None


def check_overwrite(t: Path, stdout: str, stderr: str) -> str | None:
    out = t / "out"
    if (out / "stale.txt").exists():
        return "--overwrite kept a file of the earlier run"
    if not (out / "torques.sto").is_file():
        return "no torques.sto written"
    if any(p.name.endswith(".partial") for p in t.iterdir()):
        return "a scratch folder was left beside --out"
    return None


VERSION_KEYS = ("biomotion", "torch", "python")


def check_generate_record(t: Path, stdout: str, stderr: str) -> str | None:
    """metrics.json says what made it: inputs, the profile used (every field), the action text and what it was
    understood as, the seed and the versions."""
    metrics = json.loads((t / "out" / "metrics.json").read_text())
    request = metrics.get("request", {})
    problems = []
    profile = request.get("profile") or {}
    for field, value in (("age", 52), ("sex", "M"), ("height", 1.76), ("mass", 74.0), ("sport", "running")):
        if profile.get(field) != value:
            problems.append(f"profile.{field} = {profile.get(field)!r}, not {value!r}")
    if not profile.get("injuries"):
        problems.append("profile.injuries missing")
    inputs = request.get("inputs", {})
    if not str(inputs.get("profile", "")).endswith("runner_52_acl.yaml"):
        problems.append(f"inputs.profile = {inputs.get('profile')!r}")
    if request.get("text") != "run at 3.5 m/s":
        problems.append(f"text = {request.get('text')!r}")
    if (request.get("action") or {}).get("action") != "run" or request["action"].get("speed") != 3.5:
        problems.append(f"action understood = {request.get('action')!r}")
    if request.get("seed") != 5:
        problems.append(f"seed = {request.get('seed')!r}")
    versions = request.get("versions") or metrics.get("versions") or {}
    problems += [f"versions.{key} missing" for key in VERSION_KEYS if not versions.get(key)]
    return "; ".join(problems) or None


def check_same_seed(t: Path, stdout: str, stderr: str) -> str | None:
    """The same request and seed again (a second process): motion.mot byte-identical."""
    import subprocess
    import sys

    argv = [a.replace(str(t / "out"), str(t / "again")) for a in json.loads((t / "argv.json").read_text())]
    again = subprocess.run([sys.executable, "-m", "biomotion", *argv], capture_output=True, text=True, timeout=120)
    if again.returncode != 0:
        return f"the second run failed: {again.stderr.strip()[-300:]}"
    first, second = (t / "out" / "motion.mot").read_bytes(), (t / "again" / "motion.mot").read_bytes()
    return None if first == second else "two runs with seed 3 wrote different motion.mot"


# the lightest request that runs the whole command: an action named exactly (no sentence encoder to load), the
# shortest clip, no guidance, no figures; 7 s of CPU, which a 60 s timeout must also cover on a loaded machine (the
# guided path's seed and record are checked by tests/generation/test_generate_cli.py)
GENERATE = ("generate", "--action", "run at 3.5 m/s", "--seconds", "0.5", "--no-figures", "--no-guidance")
GENERATE += ("--data-root", "{d}")


# --- the corpus --------------------------------------------------------------------------------------------------

MODEL_ARGS = ("--model", f"{{d}}/{MODEL}")
ANALYZE_IK = ("analyze", f"{{d}}/{IK_MOT}", *MODEL_ARGS, "--no-figures")
PROFILE_ARGS = ("--profile", f"{{r}}/{PROFILE}")

CASES: list[Case] = [
    # ----- .mot / .sto (coordinates, forces, activations) -----
    Case(
        "mot-row-cut-short",
        ("inspect", "{t}/cut.mot"),
        "clean",
        "reader .mot; verb inspect",
        "the last row of an IK result cut in the middle (a copy that stopped)",
        "cut.mot:",
        make=edited(IK_MOT, "cut.mot", lambda text: text.rstrip()[:-40] + "\n"),
    ),
    Case(
        "mot-fewer-rows-than-header",
        ("analyze", "{t}/short.mot", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .mot; verb analyze",
        "nRows=211 but only 100 rows (truncated at a line boundary)",
        "short.mot",
        make=edited(IK_MOT, "short.mot", mot_keep(100)),
    ),
    Case(
        "mot-nan-analyze",
        ("analyze", "{t}/nan.mot", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .mot; verb analyze",
        "NaN in a knee angle of a .mot given to analyze",
        "nan.mot:",
        make=edited(IK_MOT, "nan.mot", mot_cell(50, 10, "NaN")),
    ),
    Case(
        "mot-inf",
        ("inspect", "{t}/inf.mot"),
        "clean",
        "reader .mot; verb inspect",
        "an infinite value",
        "inf.mot:",
        make=edited(IK_MOT, "inf.mot", mot_cell(3, 4, "-inf")),
    ),
    Case(
        "mot-huge-value-analyze",
        ("analyze", "{t}/huge.mot", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .mot; verb analyze",
        "a hip angle of 1e300 degrees (a corrupted number): torques would overflow",
        "huge.mot",
        make=edited(IK_MOT, "huge.mot", mot_cell(40, 7, "1e300")),
        fast=False,
    ),
    Case(
        "mot-time-goes-back",
        ("inspect", "{t}/back.mot"),
        "clean",
        "reader .mot; verb inspect",
        "a time that goes backwards (rows pasted out of order)",
        "back.mot:",
        make=edited(IK_MOT, "back.mot", mot_cell(20, 0, "0.1")),
    ),
    Case(
        "mot-empty",
        ("inspect", "{t}/empty.mot"),
        "clean",
        "reader .mot; verb inspect",
        "an empty file",
        "empty.mot",
        make=write("empty.mot", ""),
    ),
    Case(
        "mot-binary-garbage",
        ("inspect", "{t}/garbage.mot"),
        "clean",
        "reader .mot; verb inspect",
        "random bytes named .mot",
        "garbage.mot",
        make=write("garbage.mot", garbage()),
    ),
    Case(
        "mot-degrees-declared-radians",
        ("analyze", "{t}/liar.mot", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .mot; verb analyze",
        "wrong units: the header says inDegrees=no, the values are degrees (60-degree knee read as 60 rad)",
        "liar.mot",
        make=edited(IK_MOT, "liar.mot", lambda text: text.replace("inDegrees=yes", "inDegrees=no")),
        fast=False,
    ),
    Case(
        "mot-columns-name-no-coordinate",
        ("analyze", "{t}/renamed.mot", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .mot; verb analyze",
        "a coordinates file whose columns name none of the model's coordinates (the wrong model)",
        "renamed.mot",
        make=edited(IK_MOT, "renamed.mot", lambda text: rename_columns(text)),
    ),
    Case(
        "sto-label-missing",
        ("inspect", "{t}/labels.sto"),
        "clean",
        "reader .sto; verb inspect",
        "a .sto whose label line lost a column name (values no longer line up)",
        "labels.sto:",
        make=edited(STO, "labels.sto", drop_last_label),
    ),
    Case(
        "sto-coordinates-as-grf",
        ("analyze", f"{{d}}/{IK_MOT}", *MODEL_ARGS, "--grf", f"{{d}}/{STO}", "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .sto; verb analyze",
        "--grf given a coordinates file (no force columns)",
        "subject01_walk1_RRA_Kinematics_q.sto",
    ),
    # ----- ground reaction against the motion: lengths and rates -----
    Case(
        "grf-shorter-than-motion",
        ("analyze", f"{{d}}/{IK_MOT}", *MODEL_ARGS, "--grf", f"{{d}}/{GRF_MOT}", "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .mot (forces); verb analyze",
        "a GRF file (0-2.5 s) shorter than the motion (0.5-4 s): refused unless --forces-trim",
        "--forces-trim",
    ),
    Case(
        "grf-shorter-trimmed",
        (
            "analyze",
            f"{{d}}/{IK_MOT}",
            *MODEL_ARGS,
            "--grf",
            f"{{d}}/{GRF_MOT}",
            "--forces-trim",
            "--out",
            "{t}/out",
            "--no-figures",
        ),
        "ok",
        "reader .mot (forces); verb analyze",
        "the same with --forces-trim: only the 121 frames the forces cover, and a warning saying so",
        check=check_trimmed,
        fast=False,
    ),
    Case(
        "grf-no-overlap",
        (
            "analyze",
            f"{{d}}/{IK_MOT}",
            *MODEL_ARGS,
            "--grf",
            "{t}/later.mot",
            "--forces-trim",
            "--out",
            "{t}/out",
            "--no-figures",
        ),
        "clean",
        "reader .mot (forces); verb analyze",
        "mismatched clocks: forces recorded 100 s later than the motion (no overlap even with --forces-trim)",
        "later.mot",
        make=edited(GRF_MOT, "later.mot", mot_shift_time(100.0)),
    ),
    Case(
        "grf-nan",
        ("analyze", f"{{d}}/{IK_MOT}", *MODEL_ARGS, "--grf", "{t}/nan_grf.mot", "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .mot (forces); verb analyze",
        "NaN in a vertical force",
        "nan_grf.mot:",
        make=edited(GRF_MOT, "nan_grf.mot", mot_cell(100, 2, "nan")),
    ),
    # ----- .trc markers -----
    Case(
        "trc-row-missing-value",
        ("inspect", "{t}/missing.trc"),
        "clean",
        "reader .trc; verb inspect",
        "a TRC row missing a value (every later value would shift into the wrong marker)",
        "missing.trc:",
        make=edited(TRC, "missing.trc", trc_row(10, lambda fields: fields[:7] + fields[8:])),
    ),
    Case(
        "trc-row-missing-value-convert",
        ("convert", "{t}/missing.trc", "{t}/out.c3d"),
        "clean",
        "reader .trc; verb convert",
        "the same row given to convert",
        "missing.trc:",
        make=edited(TRC, "missing.trc", trc_row(80, lambda fields: fields[:50] + fields[51:])),
    ),
    Case(
        "trc-truncated",
        ("inspect", "{t}/half.trc"),
        "clean",
        "reader .trc; verb inspect",
        "the first half of the file",
        "half.trc",
        make=cut(TRC, "half.trc", 0.5),
    ),
    Case(
        "trc-empty",
        ("inspect", "{t}/empty.trc"),
        "clean",
        "reader .trc; verb inspect",
        "an empty file",
        "empty.trc",
        make=write("empty.trc", ""),
    ),
    Case(
        "trc-unknown-units",
        ("inspect", "{t}/units.trc"),
        "clean",
        "reader .trc; verb inspect",
        "Units 'furlongs'",
        "units.trc",
        make=edited(TRC, "units.trc", trc_header("Units", "furlongs")),
    ),
    Case(
        "trc-rate-zero",
        ("inspect", "{t}/rate.trc"),
        "clean",
        "reader .trc; verb inspect",
        "DataRate 0",
        "rate.trc",
        make=edited(TRC, "rate.trc", trc_header("DataRate", "0")),
    ),
    Case(
        "trc-rate-disagrees-with-times",
        ("inspect", "{t}/clock.trc"),
        "clean",
        "reader .trc; verb inspect",
        "mismatched rates: DataRate 200 Hz, Time column at 60 Hz",
        "clock.trc",
        make=edited(TRC, "clock.trc", trc_header("DataRate", "200.00")),
    ),
    Case(
        "trc-mm-declared-m",
        ("analyze", "{t}/metres.trc", "--setup", f"{{d}}/{IK_SETUP}", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .trc; verb analyze",
        "wrong units: millimetres declared as metres (the subject would be 1.8 km tall)",
        "metres.trc",
        make=edited(TRC, "metres.trc", trc_header("Units", "m")),
        fast=False,
    ),
    Case(
        "trc-inf",
        ("inspect", "{t}/inf.trc"),
        "clean",
        "reader .trc; verb inspect",
        "an infinite coordinate",
        "inf.trc:",
        make=edited(TRC, "inf.trc", trc_row(5, lambda fields: fields[:4] + ["inf"] + fields[5:])),
    ),
    # ----- .c3d -----
    Case(
        "c3d-truncated",
        ("inspect", "{t}/half.c3d"),
        "clean",
        "reader .c3d; verb inspect",
        "the first 60 % of a static trial",
        "half.c3d",
        make=cut(C3D_STATIC, "half.c3d", 0.6),
    ),
    Case(
        "c3d-garbage",
        ("inspect", "{t}/garbage.c3d"),
        "clean",
        "reader .c3d; verb inspect",
        "random bytes named .c3d",
        "garbage.c3d",
        make=write("garbage.c3d", garbage(8192)),
    ),
    Case(
        "c3d-empty",
        ("inspect", "{t}/empty.c3d"),
        "clean",
        "reader .c3d; verb inspect",
        "an empty file",
        "empty.c3d",
        make=write("empty.c3d", b""),
    ),
    Case(
        "c3d-no-point-units",
        ("inspect", "{t}/nounits.c3d"),
        "clean",
        "reader .c3d; verb inspect",
        "wrong units: no POINT:UNITS (mm or m cannot be told)",
        "POINT:UNITS",
        make=c3d_without_point_units("nounits.c3d"),
    ),
    Case(
        "c3d-header-more-frames",
        ("convert", "{t}/frames.c3d", "{t}/out.trc"),
        "clean",
        "reader .c3d; verb convert",
        "the header declares more frames than the data holds",
        "frames.c3d",
        make=c3d_header_frames("frames.c3d", 400),
    ),
    Case(
        "c3d-as-model",
        ("analyze", f"{{d}}/{IK_MOT}", "--model", f"{{d}}/{C3D_STATIC}", "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .osim; verb analyze",
        "a C3D file given as --model",
        "RBDS001static.c3d",
    ),
    # ----- .bvh / .bvh.gz -----
    Case(
        "bvh-truncated",
        ("inspect", "{t}/cut.bvh"),
        "clean",
        "reader .bvh; verb inspect",
        "a BVH cut in the middle of its frames",
        "cut.bvh",
        make=bvh_text(lambda text: text[: int(len(text) * 0.7)], "cut.bvh"),
    ),
    Case(
        "bvh-gz-truncated",
        ("inspect", "{t}/cut.bvh.gz"),
        "clean",
        "reader .bvh.gz; verb inspect",
        "a gzip stream cut short",
        "cut.bvh.gz",
        make=cut(BVH_GZ, "cut.bvh.gz", 0.5),
    ),
    Case(
        "bvh-gz-not-gzip",
        ("inspect", "{t}/plain.bvh.gz"),
        "clean",
        "reader .bvh.gz; verb inspect",
        "plain text named .bvh.gz",
        "plain.bvh.gz",
        make=bvh_text(lambda text: text, "plain.bvh.gz"),
    ),
    Case(
        "bvh-more-frames-declared",
        ("inspect", "{t}/frames.bvh.gz"),
        "clean",
        "reader .bvh.gz; verb inspect",
        "Frames: 2000 for 20 rows",
        "frames.bvh.gz",
        make=bvh_text(lambda text: text.replace("Frames:\t20", "Frames:\t2000"), "frames.bvh.gz", compress=True),
    ),
    Case(
        "bvh-frame-time-zero",
        ("inspect", "{t}/rate.bvh"),
        "clean",
        "reader .bvh; verb inspect",
        "Frame Time: 0",
        "rate.bvh",
        make=bvh_text(lambda text: text.replace("Frame Time:\t0.0333333", "Frame Time:\t0"), "rate.bvh"),
    ),
    Case(
        "bvh-empty",
        ("inspect", "{t}/empty.bvh"),
        "clean",
        "reader .bvh; verb inspect",
        "an empty file",
        "empty.bvh",
        make=write("empty.bvh", ""),
    ),
    Case(
        "bvh-unclosed-hierarchy",
        ("inspect", "{t}/braces.bvh"),
        "clean",
        "reader .bvh; verb inspect",
        "a HIERARCHY with a closing brace missing",
        "braces.bvh",
        make=bvh_text(lambda text: text.replace("}\nMOTION", "\nMOTION", 1), "braces.bvh"),
    ),
    Case(
        "bvh-nan-channel",
        ("retarget", "{t}/nan.bvh", "--model", f"{{d}}/{RAJAGOPAL}", "--out", "{t}/out", "--quiet"),
        "clean",
        "reader .bvh; verb retarget",
        "a NaN rotation in a skeleton given to retarget",
        "nan.bvh",
        make=bvh_text(lambda text: bvh_value(text, 5, 7, "nan"), "nan.bvh"),
    ),
    # ----- .osim models and the XML reader -----
    Case(
        "osim-entity-bomb",
        ("inspect", "{t}/bomb.osim"),
        "clean",
        "reader .osim (XML); verb inspect",
        "an XML model with nested entity expansion (billion laughs)",
        "bomb.osim",
        make=write("bomb.osim", BILLION_LAUGHS),
    ),
    Case(
        "osim-external-entity",
        ("inspect", "{t}/xxe.osim"),
        "clean",
        "reader .osim (XML); verb inspect",
        "an external entity naming /etc/passwd (must not be resolved)",
        "xxe.osim",
        make=write("xxe.osim", EXTERNAL_ENTITY),
    ),
    Case(
        "osim-truncated",
        ("analyze", f"{{d}}/{IK_MOT}", "--model", "{t}/cut.osim", "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .osim; verb analyze",
        "a model file cut in half",
        "cut.osim",
        make=cut(MODEL, "cut.osim", 0.5),
    ),
    Case(
        "osim-not-a-model",
        ("inspect", "{t}/other.osim"),
        "clean",
        "reader .osim; verb inspect",
        "well-formed XML that is not an OpenSim model",
        "other.osim",
        make=write("other.osim", '<?xml version="1.0"?>\n<html><body>hello</body></html>\n'),
    ),
    Case(
        "osim-empty",
        ("inspect", "{t}/empty.osim"),
        "clean",
        "reader .osim; verb inspect",
        "an empty file",
        "empty.osim",
        make=write("empty.osim", ""),
    ),
    Case(
        "osim-model-is-a-folder",
        ("analyze", f"{{d}}/{IK_MOT}", "--model", "{t}/models", "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader .osim; verb analyze",
        "a folder where the model file belongs",
        "models",
        make=folder("models"),
    ),
    # ----- OpenSim setups (.xml) -----
    Case(
        "ik-setup-entity-bomb",
        ("analyze", f"{{d}}/{TRC}", "--setup", "{t}/bomb.xml", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader IK setup .xml; verb analyze",
        "an IK setup with nested entity expansion",
        "bomb.xml",
        make=write("bomb.xml", BILLION_LAUGHS.replace("OpenSimDocument", "OpenSimDocument")),
    ),
    Case(
        "ik-setup-path-5000-chars",
        ("analyze", f"{{d}}/{TRC}", "--setup", "{t}/" + "s" * 5000 + ".xml", *MODEL_ARGS, "--out", "{t}/out"),
        "clean",
        "reader IK setup .xml; verb analyze",
        "a setup path of 5000 characters",
        "sssssssss",
    ),
    Case(
        "ik-setup-truncated",
        ("analyze", f"{{d}}/{TRC}", "--setup", "{t}/cut.xml", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader IK setup .xml; verb analyze",
        "an IK setup cut in half",
        "cut.xml",
        make=cut(IK_SETUP, "cut.xml", 0.5),
    ),
    Case(
        "ik-setup-reversed-time-range",
        ("analyze", f"{{d}}/{TRC}", "--setup", "{t}/range.xml", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader IK setup .xml; verb analyze",
        "a time range that ends before it starts",
        "range.xml",
        make=edited(IK_SETUP, "range.xml", lambda text: set_time_range(text, "2.5 0.6")),
    ),
    Case(
        "ik-setup-nan-weight",
        ("analyze", f"{{d}}/{TRC}", "--setup", "{t}/weight.xml", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader IK setup .xml; verb analyze",
        "a marker weight of NaN",
        "weight.xml",
        make=edited(IK_SETUP, "weight.xml", lambda text: first_weight(text, "nan")),
    ),
    Case(
        "ik-setup-is-a-folder",
        ("analyze", f"{{d}}/{TRC}", "--setup", "{t}/setup", *MODEL_ARGS, "--out", "{t}/out", "--no-figures"),
        "clean",
        "reader IK setup .xml; verb analyze",
        "a folder where the setup file belongs",
        "setup",
        make=folder("setup"),
    ),
    Case(
        "scale-setup-truncated",
        ("scale", "{t}/cut.xml", "--out", "{t}/out"),
        "clean",
        "reader Scale setup .xml; verb scale",
        "a ScaleTool setup cut in half",
        "cut.xml",
        make=cut(SCALE_SETUP, "cut.xml", 0.5),
    ),
    Case(
        "scale-setup-entity-bomb",
        ("scale", "{t}/bomb.xml", "--out", "{t}/out"),
        "clean",
        "reader Scale setup .xml; verb scale",
        "a ScaleTool setup with nested entity expansion",
        "bomb.xml",
        make=write("bomb.xml", BILLION_LAUGHS),
    ),
    Case(
        "scale-setup-static-missing",
        ("scale", "{t}/setup.xml", "--out", "{t}/out"),
        "clean",
        "reader Scale setup .xml; verb scale",
        "a setup copied away from the files it names (its generic model and static trial not found)",
        "setup.xml",
        make=copy(SCALE_SETUP, "setup.xml"),
    ),
    # ----- subject tables (.csv, .xlsx) -----
    Case(
        "table-row-extra-cell",
        ("generate", "--subject-table", "{t}/people.csv", "--subject-id", "s1", "--action", "walk", "--out", "{t}/o"),
        "clean",
        "reader subject table .csv; verb generate",
        "a row with one cell more than the header (a comma in a value)",
        "people.csv:3",
        make=write("people.csv", "subject_id,sex,age_years,height_m,mass_kg\ns0,F,40,1.6,60\ns1,M,52,1,76,74\n"),
    ),
    Case(
        "table-unknown-subject",
        ("scale", "--subject-table", f"{{d}}/{SUBJECTS}", "--subject-id", "RBDS999", "--model", f"{{d}}/{RAJAGOPAL}")
        + ("--out", "{t}/out"),
        "clean",
        "reader subject table .csv; verb scale",
        "a subject id the table does not hold",
        "RBDS999",
    ),
    Case(
        "table-height-in-cm",
        ("scale", "--subject-table", "{t}/people.xlsx", "--subject-id", "s1", "--model", f"{{d}}/{RAJAGOPAL}")
        + ("--out", "{t}/out"),
        "clean",
        "reader subject table .xlsx; verb scale",
        "wrong units: height_m holding centimetres (176)",
        "people.xlsx",
        make=xlsx_table(
            "people.xlsx", [["subject_id", "sex", "age_years", "height_m", "mass_kg"], ["s1", "M", 52, 176, 74]]
        ),
    ),
    Case(
        "xlsx-not-a-workbook",
        ("inspect", "{t}/people.xlsx"),
        "clean",
        "reader subject table .xlsx; verb inspect",
        "a text file named .xlsx",
        "people.xlsx",
        make=write("people.xlsx", "subject_id,mass_kg\ns1,70\n"),
    ),
    Case(
        "xlsx-not-a-workbook-generate",
        ("generate", "--subject-table", "{t}/people.xlsx", "--subject-id", "s1", "--action", "walk", "--out", "{t}/o"),
        "clean",
        "reader subject table .xlsx; verb generate",
        "a corrupted workbook as --subject-table",
        "people.xlsx",
        make=write("people.xlsx", garbage(2048)),
    ),
    Case(
        "table-empty",
        ("generate", "--subject-table", "{t}/people.csv", "--subject-id", "s1", "--action", "walk", "--out", "{t}/o"),
        "clean",
        "reader subject table .csv; verb generate",
        "an empty table",
        "people.csv",
        make=write("people.csv", ""),
    ),
    # ----- profiles (.yaml, .json) -----
    Case(
        "profile-unknown-key",
        ("generate", "--profile", "{t}/p.yaml", "--action", "walk", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb generate",
        "unknown key in a profile (agee: 30)",
        "agee",
        make=write("p.yaml", "agee: 30\nsex: F\n"),
    ),
    Case(
        "profile-json-malformed",
        ("generate", "--profile", "{t}/p.json", "--action", "walk", "--out", "{t}/out"),
        "clean",
        "reader profile .json; verb generate",
        "a JSON profile with a missing brace",
        "p.json",
        make=write("p.json", '{"age": 30, "sex": "F", "injuries": [{"location": "knee"}\n'),
    ),
    Case(
        "profile-not-a-mapping",
        ("scale", "--profile", "{t}/p.yaml", "--model", f"{{d}}/{RAJAGOPAL}", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb scale",
        "a profile that is a list",
        "p.yaml",
        make=write("p.yaml", "- age: 30\n- sex: F\n"),
    ),
    Case(
        "profile-negative-mass",
        ("generate", "--profile", "{t}/p.yaml", "--action", "walk", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb generate",
        "mass: -70",
        "mass",
        make=write("p.yaml", "mass: -70\nheight: 1.7\n"),
    ),
    Case(
        "profile-nan-height",
        ("scale", "--profile", "{t}/p.yaml", "--model", f"{{d}}/{RAJAGOPAL}", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb scale",
        "height: .nan",
        "height",
        make=write("p.yaml", "height: .nan\nmass: 70\n"),
    ),
    Case(
        "profile-height-in-cm",
        ("scale", "--profile", "{t}/p.yaml", "--model", f"{{d}}/{RAJAGOPAL}", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb scale",
        "wrong units: height 176 (cm for m)",
        "height",
        make=write("p.yaml", "height: 176\nmass: 70\n"),
    ),
    Case(
        "profile-yaml-alias-bomb",
        ("generate", "--profile", "{t}/bomb.yaml", "--action", "walk", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb generate",
        "a YAML alias bomb: a billion injuries once expanded",
        "bomb.yaml",
        make=profile_bomb,
    ),
    Case(
        "profile-extra-alias-bomb",
        ("generate", "--profile", "{t}/bomb.yaml", "--action", "walk", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb generate",
        "a YAML alias bomb under extra (kept as given, and written into metrics.json)",
        "extra",
        make=lambda t, d: (t / "bomb.yaml").write_text("age: 30\nextra:\n  shoes: " + _alias_bomb() + "\n"),
    ),
    Case(
        "profile-sport-a-list",
        ("scale", "--profile", "{t}/p.yaml", "--model", f"{{d}}/{RAJAGOPAL}", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb scale",
        "a text field given a list",
        "sport",
        make=write("p.yaml", "height: 1.7\nsport: [running, cycling]\n"),
    ),
    Case(
        "profile-empty",
        ("generate", "--profile", "{t}/p.yaml", "--action", "walk", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb generate",
        "an empty profile file",
        "p.yaml",
        make=write("p.yaml", ""),
    ),
    Case(
        "profile-is-a-folder",
        ("generate", "--profile", "{t}/p.yaml", "--action", "walk", "--out", "{t}/out"),
        "clean",
        "reader profile .yaml; verb generate",
        "a folder named like a profile",
        "p.yaml",
        make=folder("p.yaml"),
    ),
    # ----- .csv motion -----
    Case(
        "csv-motion-nan",
        ("convert", "{t}/nan.csv", "{t}/out.mot"),
        "clean",
        "reader .csv motion; verb convert",
        "a NaN cell in a coordinates CSV",
        "nan.csv",
        make=write("nan.csv", "time,hip_flexion_r,knee_angle_r\n0,0.1,0.2\n0.01,nan,0.2\n0.02,0.1,0.2\n"),
    ),
    Case(
        "csv-motion-text-cell",
        ("inspect", "{t}/text.csv"),
        "clean",
        "reader .csv motion; verb inspect",
        "a word where a number belongs",
        "text.csv",
        make=write("text.csv", "time,hip_flexion_r,knee_angle_r\n0,0.1,0.2\n0.01,0.1,oops\n0.02,0.1,0.2\n"),
    ),
    Case(
        "csv-motion-empty",
        ("convert", "{t}/empty.csv", "{t}/out.mot"),
        "clean",
        "reader .csv motion; verb convert",
        "an empty CSV",
        "empty.csv",
        make=write("empty.csv", ""),
    ),
    # ----- .vtp meshes -----
    Case(
        "vtp-truncated",
        ("view", "{t}/m/ik.mot", "--model", "{t}/m/model.osim", "--out", "{t}/view.html"),
        "clean",
        "reader .vtp; verb view",
        "a bone mesh cut in half beside the model",
        "pelvis.vtp",
        make=both(
            folder("m/Geometry"),
            copy(IK_MOT, "m/ik.mot"),
            copy(MODEL, "m/model.osim"),
            cut(VTP, "m/Geometry/pelvis.vtp", 0.5),
        ),
    ),
    Case(
        "vtp-entity-bomb",
        ("view", "{t}/m/ik.mot", "--model", "{t}/m/model.osim", "--out", "{t}/view.html"),
        "clean",
        "reader .vtp; verb view",
        "a bone mesh with nested entity expansion",
        "pelvis.vtp",
        make=both(
            folder("m/Geometry"),
            copy(IK_MOT, "m/ik.mot"),
            copy(MODEL, "m/model.osim"),
            write("m/Geometry/pelvis.vtp", BILLION_LAUGHS),
        ),
    ),
    # ----- safetensors checkpoints -----
    Case(
        "checkpoint-truncated",
        ("generate", "--action", "walk", "--checkpoints", "{t}/ckpt", "--out", "{t}/out", "--data-root", "{d}"),
        "clean",
        "reader safetensors (--checkpoints); verb generate",
        "generator.safetensors cut in half",
        "generator.safetensors",
        make=checkpoints_with("generator.safetensors", lambda data: data[: len(data) // 2]),
        fast=False,
    ),
    Case(
        "checkpoint-garbage-tokenizer",
        ("generate", "--action", "walk", "--checkpoints", "{t}/ckpt", "--out", "{t}/out", "--data-root", "{d}"),
        "clean",
        "reader safetensors (--checkpoints); verb generate",
        "tokenizer.safetensors overwritten with random bytes",
        "tokenizer.safetensors",
        make=checkpoints_with("tokenizer.safetensors", lambda data: garbage(4096)),
        fast=False,
    ),
    Case(
        "checkpoint-empty-folder",
        ("generate", "--action", "walk", "--checkpoints", "{t}/ckpt", "--out", "{t}/out", "--data-root", "{d}"),
        "clean",
        "reader safetensors (--checkpoints); verb generate",
        "--checkpoints an empty folder",
        "ckpt",
        make=folder("ckpt"),
        fast=False,
    ),
    Case(
        "checkpoint-is-a-file",
        ("generate", "--action", "walk", "--checkpoints", "{t}/ckpt", "--out", "{t}/out", "--data-root", "{d}"),
        "clean",
        "reader safetensors (--checkpoints); verb generate",
        "--checkpoints a file where a folder belongs",
        "ckpt",
        make=write("ckpt", "not a folder\n"),
        fast=False,
    ),
    Case(
        "muscle-paths-truncated",
        ("analyze", f"{{d}}/{IK_MOT}", *MODEL_ARGS, "--muscles", "{t}/paths.safetensors", "--out", "{t}/out"),
        "clean",
        "reader safetensors (muscle paths); verb analyze",
        "--muscles a path-function file cut short",
        "paths.safetensors",
        make=lambda t, d: (t / "paths.safetensors").write_bytes(shipped_paths()[:1000]) and None,
    ),
    # ----- generate: arguments, actions, outputs -----
    *[
        Case(
            f"generate-seconds-{label}",
            ("generate", "--action", "walk", "--seconds", value, "--out", "{t}/out"),
            "clean",
            "verb generate (arguments)",
            f"--seconds {value}",
            "--seconds",
            argument=True,
        )
        for label, value in (("nan", "nan"), ("inf", "inf"), ("100000", "100000"), ("negative", "-3"), ("zero", "0"))
    ],
    Case(
        "generate-samples-zero",
        ("generate", "--action", "walk", "--samples", "0", "--out", "{t}/out"),
        "clean",
        "verb generate (arguments)",
        "--samples 0",
        "--samples",
        argument=True,
    ),
    Case(
        "generate-seed-negative",
        ("generate", "--action", "walk", "--seed", "-1", "--out", "{t}/out"),
        "clean",
        "verb generate (arguments)",
        "--seed -1",
        "--seed",
        argument=True,
    ),
    Case(
        "generate-seed-huge",
        ("generate", "--action", "walk", "--seed", "1" + "0" * 40, "--out", "{t}/out"),
        "clean",
        "verb generate (arguments)",
        "--seed 10^40 (beyond 64 bits)",
        "--seed",
        argument=True,
    ),
    Case(
        "generate-nonsense-action",
        ("generate", "--action", "asdfgh", "--seconds", "1", "--out", "{t}/out", "--data-root", "{d}"),
        "clean",
        "verb generate (action text)",
        'a nonsense action ("asdfgh"): refused with the closest known ones',
        "asdfgh",
        fast=False,
    ),
    Case(
        "generate-no-action",
        ("generate", "--out", "{t}/out"),
        "clean",
        "verb generate (arguments)",
        "no --action",
        "--action",
    ),
    Case(
        "generate-out-is-a-file",
        ("generate", "--action", "walk", "--out", "{t}/out"),
        "clean",
        "verb generate (outputs)",
        "--out names an existing file",
        "out",
        make=write("out", "a file\n"),
    ),
    Case(
        "generate-out-unwritable",
        ("generate", "--action", "walk", "--out", "{unwritable}"),
        "clean",
        "verb generate (outputs)",
        "--out where nothing can be written (a read-only folder, or under a file when run as root)",
        "out",
    ),
    Case(
        "generate-out-exists",
        ("generate", "--action", "walk", "--out", "{t}/out"),
        "clean",
        "verb generate (outputs)",
        "re-running into an existing output folder: refused unless --overwrite",
        "--overwrite",
        make=write("out/motion.mot", "an earlier run\n"),
    ),
    Case(
        "generate-reference-nan",
        ("generate", "--action", "walk", "--reference", "{t}/ref.mot", "--out", "{t}/out", "--data-root", "{d}"),
        "clean",
        "reader .mot (reference); verb generate",
        "a reference clip with a NaN",
        "ref.mot",
        make=edited(IK_MOT, "ref.mot", mot_cell(30, 10, "nan")),
    ),
    Case(
        "generate-reference-action-count",
        ("generate", "--action", "walk", "--reference", f"{{d}}/{IK_MOT}", "--reference-action", "walk")
        + ("--reference-action", "run", "--out", "{t}/out"),
        "clean",
        "verb generate (arguments)",
        "two --reference-action for one --reference",
        "--reference-action",
    ),
    Case(
        "generate-smooth-without-guidance",
        ("generate", "--action", "walk", "--no-guidance", "--smooth", "6", "--out", "{t}/out", "--data-root", "{d}"),
        "clean",
        "verb generate (arguments)",
        "--smooth with --no-guidance (it would have no effect)",
        "--smooth",
    ),
    Case(
        "generate-records-what-made-it",
        (*GENERATE, *PROFILE_ARGS, "--seed", "5", "--out", "{t}/out"),
        "ok",
        "verb generate (metrics.json)",
        "metrics.json records the inputs, the profile used (all fields), the action text and what it was "
        "understood as, the seed and the versions",
        check=check_generate_record,
        fast=False,
    ),
    Case(
        "generate-same-seed",
        (*GENERATE, "--seed", "3", "--out", "{t}/out"),
        "ok",
        "verb generate (reproducibility)",
        "two runs with the same seed: byte-identical motion.mot",
        check=check_same_seed,
        fast=False,
    ),
    Case(
        "generate-interrupted",  # guided and 3 s long: still computing when the signal comes
        (
            "generate",
            "--action",
            "run at 3.5 m/s",
            "--seconds",
            "3",
            "--no-figures",
            "--data-root",
            "{d}",
            "--out",
            "{t}/out",
        ),
        "interrupt",
        "verb generate (interrupted run)",
        "SIGINT while generating: exit 130, no --out, no scratch folder left",
        out="{t}/out",
        fast=False,
    ),
    # ----- analyze: outputs and arguments -----
    Case(
        "analyze-trial-is-a-folder",
        ("analyze", "{t}/trial", *MODEL_ARGS, "--out", "{t}/out"),
        "clean",
        "verb analyze (inputs)",
        "a folder where the trial file belongs",
        "trial",
        make=folder("trial"),
    ),
    Case(
        "analyze-out-exists",
        (*ANALYZE_IK, "--out", "{t}/out"),
        "clean",
        "verb analyze (outputs)",
        "re-running into an existing output folder: refused unless --overwrite",
        "--overwrite",
        make=write("out/torques.sto", "an earlier run\n"),
    ),
    Case(
        "analyze-overwrite",
        (*ANALYZE_IK, "--out", "{t}/out", "--overwrite"),
        "ok",
        "verb analyze (outputs)",
        "--overwrite replaces the earlier run whole (no stale file kept)",
        make=write("out/stale.txt", "an earlier run\n"),
        check=check_overwrite,
        fast=False,
    ),
    Case(
        "analyze-out-is-a-file",
        (*ANALYZE_IK, "--out", "{t}/out"),
        "clean",
        "verb analyze (outputs)",
        "--out names a file",
        "out",
        make=write("out", "a file\n"),
    ),
    Case(
        "analyze-out-unwritable",
        (*ANALYZE_IK, "--out", "{unwritable}"),
        "clean",
        "verb analyze (outputs)",
        "--out not writable",
        "out",
    ),
    Case(
        "analyze-cutoff-negative",
        (*ANALYZE_IK, "--cutoff", "-6", "--out", "{t}/out"),
        "clean",
        "verb analyze (arguments)",
        "--cutoff -6",
        "--cutoff",
        argument=True,
    ),
    Case(
        "analyze-cutoff-nan",
        (*ANALYZE_IK, "--cutoff", "nan", "--out", "{t}/out"),
        "clean",
        "verb analyze (arguments)",
        "--cutoff nan",
        "--cutoff",
        argument=True,
    ),
    Case(
        "analyze-missing-arguments",
        ("analyze",),
        "clean",
        "verb analyze (arguments)",
        "no arguments",
        "trial",
        argument=True,
    ),
    Case(
        "analyze-interrupted",
        ("analyze", f"{{d}}/{IK_MOT}", *MODEL_ARGS, "--out", "{t}/out"),
        "interrupt",
        "verb analyze (interrupted run)",
        "SIGINT while analysing: exit 130, no --out, no scratch folder left",
        out="{t}/out",
        fast=False,
    ),
    # ----- scale -----
    Case(
        "scale-mass-zero",
        ("scale", f"{{d}}/{SCALE_SETUP}", "--mass", "0", "--out", "{t}/out"),
        "clean",
        "verb scale (arguments)",
        "--mass 0",
        "--mass",
        argument=True,
    ),
    Case(
        "scale-name-with-slash",
        ("scale", f"{{d}}/{SCALE_SETUP}", "--name", "../escape", "--out", "{t}/out"),
        "clean",
        "verb scale (arguments)",
        "--name holding a path separator",
        "--name",
    ),
    Case(
        "scale-nothing-to-scale",
        ("scale", "--out", "{t}/out"),
        "clean",
        "verb scale (arguments)",
        "neither a setup nor a person",
        "--profile",
    ),
    # ----- retarget -----
    Case(
        "retarget-empty-folder",
        ("retarget", "{t}/trials", "--model", f"{{d}}/{RAJAGOPAL}", "--out", "{t}/out", "--quiet"),
        "clean",
        "verb retarget (inputs)",
        "a folder with no motion files",
        "trials",
        make=folder("trials"),
    ),
    Case(
        "retarget-truncated-bvh",
        ("retarget", "{t}/cut.bvh", "--model", f"{{d}}/{RAJAGOPAL}", "--out", "{t}/out", "--quiet"),
        "clean",
        "reader .bvh; verb retarget",
        "a single BVH cut in its frames",
        "cut.bvh",
        make=bvh_text(lambda text: text[: int(len(text) * 0.7)], "cut.bvh"),
    ),
    Case(
        "retarget-filter-nan",
        ("retarget", f"{{d}}/{BVH_GZ}", "--model", f"{{d}}/{RAJAGOPAL}", "--filter", "nan", "--out", "{t}/out"),
        "clean",
        "verb retarget (arguments)",
        "--filter nan",
        "--filter",
        argument=True,
    ),
    # ----- convert -----
    Case(
        "convert-into-existing-folder",
        ("convert", f"{{d}}/{IK_MOT}", "{t}/outdir"),
        "clean",
        "verb convert (outputs)",
        "OUTPUT names an existing folder",
        "outdir",
        make=folder("outdir"),
    ),
    Case(
        "convert-output-exists",
        ("convert", f"{{d}}/{IK_MOT}", "{t}/out.csv"),
        "clean",
        "verb convert (outputs)",
        "OUTPUT exists: refused unless --overwrite",
        "--overwrite",
        make=write("out.csv", "earlier\n"),
    ),
    Case(
        "convert-unsupported-suffix",
        ("convert", f"{{d}}/{IK_MOT}", "{t}/out.xyz"),
        "clean",
        "verb convert (outputs)",
        "an output format nobody knows",
        ".xyz",
    ),
    Case(
        "convert-unwritable",
        ("convert", f"{{d}}/{IK_MOT}", "{unwritable}.csv"),
        "clean",
        "verb convert (outputs)",
        "OUTPUT not writable",
        "out.csv",
    ),
    Case(
        "convert-onto-itself",
        ("convert", "{t}/in.mot", "{t}/in.mot", "--overwrite"),
        "clean",
        "verb convert (outputs)",
        "OUTPUT is INPUT",
        "in.mot",
        make=copy(IK_MOT, "in.mot"),
    ),
    Case(
        "convert-trc-to-c3d",
        ("convert", "{t}/in.trc", "{t}/out.c3d"),
        "ok",
        "reader .trc, writer .c3d; verb convert",
        "a valid conversion: the markers read back from the C3D equal the TRC's",
        make=copy(TRC, "in.trc"),
        check=check_c3d_round_trip,
    ),
    # ----- inspect -----
    Case(
        "inspect-folder",
        ("inspect", "{t}"),
        "clean",
        "verb inspect (inputs)",
        "a folder where a file belongs",
        "a folder",
    ),
    Case(
        "inspect-missing",
        ("inspect", "{t}/nothing.mot"),
        "clean",
        "verb inspect (inputs)",
        "a file that does not exist",
        "nothing.mot",
    ),
    Case(
        "inspect-unknown-suffix",
        ("inspect", "{t}/notes.docx"),
        "clean",
        "verb inspect (inputs)",
        "a format biomotion does not read",
        "notes.docx",
        make=write("notes.docx", "hello\n"),
    ),
    # ----- view -----
    Case(
        "view-out-is-a-folder",
        ("view", f"{{d}}/{BVH_GZ}", "--out", "{t}/page"),
        "clean",
        "verb view (outputs)",
        "--out names a folder",
        "page",
        make=folder("page"),
    ),
    Case(
        "view-coordinates-without-model",
        ("view", f"{{d}}/{IK_MOT}", "--out", "{t}/view.html"),
        "clean",
        "verb view (inputs)",
        "coordinates without the --model they belong to",
        "--model",
    ),
    Case(
        "view-activations-truncated",
        ("view", f"{{d}}/{IK_MOT}", *MODEL_ARGS, "--activations", "{t}/act.sto", "--out", "{t}/view.html"),
        "clean",
        "reader .sto (activations); verb view",
        "an activations file cut in a row",
        "act.sto",
        make=write(
            "act.sto", "activations\nendheader\ntime\tsoleus_r\tgasmed_r\n0.5\t0.1\t0.2\n0.6\t0.1\n0.7\t0.1\t0.2\n"
        ),
    ),
    # ----- eval -----
    Case(
        "eval-pred-missing",
        ("eval", "--pred", "{t}/none", "--data-root", "{d}"),
        "clean",
        "verb eval (inputs)",
        "--pred a path that does not exist",
        "none",
    ),
    Case(
        "eval-pred-garbage",
        ("eval", "--pred", "{t}/pred", "--data-root", "{d}"),
        "clean",
        "reader .mot; verb eval",
        "a prediction folder holding a corrupted .mot",
        "bad.mot",
        make=both(folder("pred"), write("pred/bad.mot", garbage(1000))),
    ),
    Case(
        "eval-pred-empty-folder",
        ("eval", "--pred", "{t}/pred", "--data-root", "{d}"),
        "clean",
        "verb eval (inputs)",
        "a prediction folder with nothing to score",
        "pred",
        make=folder("pred"),
    ),
    Case(
        "eval-generation-without-json",
        ("eval", "generation", "--data-root", "{d}"),
        "clean",
        "verb eval (arguments)",
        "eval generation without --json",
        "--json",
    ),
    Case(
        "eval-max-seconds-nan",
        ("eval", "generation", "--max-seconds", "nan", "--json", "{t}/e.json"),
        "clean",
        "verb eval (arguments)",
        "--max-seconds nan",
        "--max-seconds",
        argument=True,
    ),
    # ----- validate -----
    Case(
        "validate-data-root-is-a-file",
        ("validate", "kinematics", "--data-root", "{t}/datadir", "--json", "{t}/k.json"),
        "clean",
        "verb validate (inputs)",
        "--data-root names a file",
        "datadir",
        make=write("datadir", "a file\n"),
    ),
    Case(
        "validate-json-is-a-folder",
        ("validate", "kinematics", "--data-root", "{d}", "--json", "{t}/k"),
        "clean",
        "verb validate (outputs)",
        "--json names a folder",
        "k",
        make=folder("k"),
    ),
    Case(
        "validate-unknown-check",
        ("validate", "everything", "--json", "{t}/k.json"),
        "clean",
        "verb validate (arguments)",
        "a check that does not exist",
        "everything",
        argument=True,
    ),
    # ----- data build | augment | sources -----
    Case(
        "data-build-root-missing",
        ("data", "build", "--data-root", "{t}/nowhere", "--out", "{t}/cache", "--quiet"),
        "clean",
        "verb data build (inputs)",
        "a data root that does not exist",
        "nowhere",
    ),
    Case(
        "data-build-rate-zero",
        ("data", "build", "--rate", "0", "--out", "{t}/cache"),
        "clean",
        "verb data build (arguments)",
        "--rate 0",
        "--rate",
        argument=True,
    ),
    Case(
        "data-build-unknown-source",
        ("data", "build", "--data-root", "{d}", "--source", "nosuch", "--out", "{t}/cache", "--quiet"),
        "clean",
        "verb data build (arguments)",
        "--source naming no registered source",
        "nosuch",
    ),
    Case(
        "data-build-out-exists",
        ("data", "build", "--data-root", "{d}", "--out", "{t}/cache", "--quiet"),
        "clean",
        "verb data build (outputs)",
        "--out an existing, non-empty folder",
        "--overwrite",
        make=write("cache/manifest.json", "{}\n"),
    ),
    Case(
        "data-augment-not-a-cache",
        ("data", "augment", "--cache", "{t}/cache", "--out", "{t}/aug", "--quiet"),
        "clean",
        "reader dataset cache; verb data augment",
        "--cache an empty folder",
        "cache",
        make=folder("cache"),
    ),
    Case(
        "data-augment-corrupt-manifest",
        ("data", "augment", "--cache", "{t}/cache", "--out", "{t}/aug", "--quiet"),
        "clean",
        "reader dataset cache; verb data augment",
        "a cache whose manifest.json is cut short",
        "manifest.json",
        make=cache_with('{"clips": [{"source": "opencap", ', b""),
    ),
    Case(
        "data-augment-truncated-clips",
        ("data", "augment", "--cache", "{t}/cache", "--out", "{t}/aug", "--quiet"),
        "clean",
        "reader dataset cache (safetensors); verb data augment",
        "a cache whose clips.safetensors is cut short",
        "clips.safetensors",
        make=cache_with(
            json.dumps({"clips": [], "rate_hz": 30.0, "coordinates": ["pelvis_tx"], "format": "x"}), garbage(600)
        ),
    ),
    Case(
        "data-augment-cache-is-a-file",
        ("data", "augment", "--cache", "{t}/cache", "--out", "{t}/aug", "--quiet"),
        "clean",
        "reader dataset cache; verb data augment",
        "--cache names a file",
        "cache",
        make=write("cache", "a file\n"),
    ),
    Case(
        "data-augment-time-warp-zero",
        ("data", "augment", "--cache", "{t}/cache", "--out", "{t}/aug", "--time-warp", "0"),
        "clean",
        "verb data augment (arguments)",
        "--time-warp 0",
        "--time-warp",
        argument=True,
    ),
    Case(
        "data-sources-empty-root",
        ("data", "sources", "--data-root", "{t}"),
        "ok",
        "verb data sources",
        "a data root holding none of the sources: every source listed as absent",
        check=check_sources,
    ),
    Case(
        "data-sources-root-is-a-file",
        ("data", "sources", "--data-root", "{t}/datadir"),
        "clean",
        "verb data sources (inputs)",
        "--data-root names a file",
        "datadir",
        make=write("datadir", "a file\n"),
    ),
    # ----- train tokenizer | generator | surrogate | labels | paths | segments -----
    Case(
        "train-config-missing",
        ("train", "tokenizer", "--config", "{t}/none.yaml", "--cache", "{t}/cache", "--out", "{t}/w.safetensors"),
        "clean",
        "verb train tokenizer (config)",
        "--config a file that does not exist",
        "none.yaml",
    ),
    Case(
        "train-config-bad-yaml",
        ("train", "tokenizer", "--config", "{t}/config.yaml", "--cache", "{t}/cache", "--out", "{t}/w.safetensors"),
        "clean",
        "verb train tokenizer (config)",
        "a config with broken indentation",
        "config.yaml",
        make=tokenizer_config(lambda text: text + "\n  model:\n width: [1, 2\n"),
    ),
    Case(
        "train-config-a-list",
        ("train", "generator", "--config", "{t}/config.yaml", "--cache", "{t}/cache", "--out", "{t}/w.safetensors")
        + ("--tokenizer", "{r}/checkpoints/tokenizer.safetensors"),
        "clean",
        "verb train generator (config)",
        "a config that is a list, not a mapping",
        "config.yaml",
        make=write("config.yaml", "- model\n- data\n"),
    ),
    Case(
        "train-config-unknown-key",
        ("train", "tokenizer", "--config", "{t}/config.yaml", "--cache", "{t}/cache", "--out", "{t}/w.safetensors"),
        "clean",
        "verb train tokenizer (config)",
        "an unknown setting in the model section (a typo)",
        "widht",
        make=tokenizer_config(lambda text: text.replace("model:\n", "model:\n  widht: 512\n", 1)),
    ),
    Case(
        "train-config-missing-section",
        ("train", "surrogate", "--config", "{t}/config.yaml", "--cache", "{t}/cache", "--out", "{t}/w.safetensors"),
        "clean",
        "verb train surrogate (config)",
        "a config without its train section",
        "config.yaml",
        make=write("config.yaml", "model: {}\n"),
    ),
    Case(
        "train-tokenizer-cache-corrupt",
        ("train", "tokenizer", "--config", "{r}/configs/tokenizer.yaml", "--cache", "{t}/cache")
        + ("--out", "{t}/w.safetensors"),
        "clean",
        "reader dataset cache; verb train tokenizer",
        "a cache whose manifest.json is not JSON",
        "manifest.json",
        make=cache_with("not json at all", garbage(100)),
    ),
    Case(
        "train-generator-tokenizer-garbage",
        ("train", "generator", "--config", "{r}/configs/generator.yaml", "--cache", "{t}/cache")
        + ("--tokenizer", "{t}/tok.safetensors", "--out", "{t}/w.safetensors"),
        "clean",
        "reader safetensors (--tokenizer); verb train generator",
        "--tokenizer a file of random bytes",
        "tok.safetensors",
        make=both(write("tok.safetensors", garbage(2000)), cache_with("{}", b"")),
    ),
    Case(
        "train-surrogate-labels-garbage",
        ("train", "surrogate", "--config", "{r}/configs/surrogate.yaml", "--cache", "{t}/cache")
        + ("--labels", "{t}/labels.safetensors", "--out", "{t}/w.safetensors"),
        "clean",
        "reader safetensors (--labels); verb train surrogate",
        "--labels a file of random bytes",
        "labels.safetensors",
        make=both(write("labels.safetensors", garbage(2000)), cache_with("{}", b"")),
    ),
    Case(
        "train-iterations-zero",
        ("train", "tokenizer", "--config", "{r}/configs/tokenizer.yaml", "--cache", "{t}/c", "--iterations", "0")
        + ("--out", "{t}/w.safetensors"),
        "clean",
        "verb train tokenizer (arguments)",
        "--iterations 0",
        "--iterations",
        argument=True,
    ),
    Case(
        "train-labels-not-a-cache",
        ("train", "labels", "--cache", "{t}/cache", "--quiet"),
        "clean",
        "reader dataset cache; verb train labels",
        "--cache an empty folder",
        "cache",
        make=folder("cache"),
    ),
    Case(
        "train-paths-model-bomb",
        ("train", "paths", "--model", "{t}/bomb.osim", "--out", "{t}/paths.safetensors"),
        "clean",
        "reader .osim (XML); verb train paths",
        "a model with nested entity expansion",
        "bomb.osim",
        make=write("bomb.osim", BILLION_LAUGHS),
    ),
    Case(
        "train-paths-bad-range",
        ("train", "paths", "--model", f"{{d}}/{RAJAGOPAL}", "--range", "knee_angle_r=1", "--out", "{t}/p.safetensors"),
        "clean",
        "verb train paths (arguments)",
        "--range without LO:HI",
        "knee_angle_r=1",
    ),
    Case(
        "train-paths-samples-few",
        ("train", "paths", "--model", f"{{d}}/{RAJAGOPAL}", "--samples", "5", "--out", "{t}/p.safetensors"),
        "clean",
        "verb train paths (arguments)",
        "--samples 5",
        "--samples",
        argument=True,
    ),
    Case(
        "train-segments-no-anthropometry",
        ("train", "segments", "--data-root", "{t}", "--out", "{t}/segments.json"),
        "clean",
        "reader ANSUR II .csv; verb train segments",
        "a data root without anthropometry/",
        "ANSUR_II_MALE_Public.csv",
    ),
    Case(
        "train-segments-ansur-truncated",
        ("train", "segments", "--data-root", "{t}/datadir", "--out", "{t}/segments.json"),
        "clean",
        "reader ANSUR II .csv; verb train segments",
        "the ANSUR II table cut in the middle of a row",
        "ANSUR_II_MALE_Public.csv",
        make=data_root_with(ANSUR_MEN, lambda data: data[: len(data) // 3]),
    ),
    # ----- check | refine | batch -----
    Case(
        "check-nan-motion",
        ("check", "{t}/nan.mot", *MODEL_ARGS),
        "clean",
        "reader .mot; verb check",
        "a motion with a NaN given to check",
        "nan.mot:",
        make=edited(IK_MOT, "nan.mot", mot_cell(12, 8, "nan")),
    ),
    Case(
        "check-motion-is-a-folder",
        ("check", "{t}/motion", *MODEL_ARGS),
        "clean",
        "verb check (inputs)",
        "a folder where the motion file belongs",
        "motion",
        make=folder("motion"),
    ),
    Case(
        "refine-garbage",
        ("refine", "{t}/garbage.mot", "--out", "{t}/out", "--data-root", "{d}"),
        "clean",
        "reader .mot; verb refine",
        "random bytes named .mot given to refine",
        "garbage.mot",
        make=write("garbage.mot", garbage()),
    ),
    Case(
        "refine-mass-nan",
        ("refine", f"{{d}}/{IK_MOT}", "--mass", "nan", "--out", "{t}/out"),
        "clean",
        "verb refine (arguments)",
        "--mass nan",
        "--mass",
        argument=True,
    ),
    Case(
        "batch-study-missing",
        ("batch", "{t}/nowhere", "--out", "{t}/out", "--no-progress"),
        "clean",
        "verb batch (inputs)",
        "a study folder that does not exist",
        "nowhere",
    ),
    Case(
        "batch-workers-zero",
        ("batch", "{t}", "--workers", "0", "--out", "{t}/out"),
        "clean",
        "verb batch (arguments)",
        "--workers 0",
        "--workers",
        argument=True,
    ),
    Case(
        "eval-shape-no-runners",
        ("eval", "shape", "--data-root", "{t}", "--adapter", "none", "--json", "{t}/shape.json"),
        "clean",
        "verb eval shape (inputs)",
        "a data root without a runner to pair",
        "no pair of runners",
    ),
    Case(
        "eval-refine-garbage-weights",
        ("eval", "refine", "--refiner", "{t}/refiner.safetensors", "--json", "{t}/refine.json", "--data-root", "{d}"),
        "clean",
        "reader .safetensors; verb eval refine",
        "random bytes named .safetensors given as the refiner",
        "refiner.safetensors",
        make=write("refiner.safetensors", garbage()),
    ),
    Case(
        "analyze-learned-garbage-weights",
        (
            "analyze",
            f"{{d}}/{IK_MOT}",
            "--model",
            f"{{d}}/{MODEL}",
            "--forces",
            "learned",
            "--forces-model",
            "{t}/forces.safetensors",
            "--out",
            "{t}/out",
            "--no-figures",
        ),
        "clean",
        "reader .safetensors; verb analyze --forces learned",
        "random bytes named .safetensors given as the learned-forces weights",
        "forces.safetensors",
        make=write("forces.safetensors", garbage()),
    ),
    Case(
        "train-evaluator-config-missing",
        ("train", "evaluator", "--config", "{t}/nope.yaml", "--cache", "{t}", "--out", "{t}/e.safetensors"),
        "clean",
        "verb train evaluator (inputs)",
        "a config file that does not exist",
        "nope.yaml",
    ),
    Case(
        "train-shape-adapter-config-missing",
        (
            "train",
            "shape-adapter",
            "--config",
            "{t}/nope.yaml",
            "--cache",
            "{t}",
            "--out",
            "{t}/a.safetensors",
            "--data-root",
            "{d}",
        ),
        "clean",
        "verb train shape-adapter (inputs)",
        "a config file that does not exist",
        "nope.yaml",
    ),
    # ----- the command line itself -----
    Case(
        "unknown-verb",
        ("frobnicate",),
        "clean",
        "command line",
        "a verb that does not exist",
        "frobnicate",
        argument=True,
    ),
    Case(
        "unknown-option",
        ("inspect", f"{{d}}/{IK_MOT}", "--colour"),
        "clean",
        "command line",
        "an option the verb does not have",
        "--colour",
        argument=True,
    ),
]
