"""A lab study as values: who was measured, which trials, on which model, with which settings.

`load_study` reads a study from a folder, recognising three layouts, or from a TOML file that names everything
itself; `biomotion.analysis.batch` runs it. Nothing here computes biomechanics: a `Study` is paths plus settings,
so that the batch can hash its inputs, resume, and ship trials to other processes or machines.

Layouts (detected in this order; `detect_layout`):

- **Fukuchi** (``fukuchi-running/SOURCE.md``): ``c3d/<subject>static.c3d`` and ``c3d/<subject><trial>.c3d``
  (markers in mm, exact zeros as gaps, force plates in the file), a subject table in the folder (``participantInfo
  .csv`` or any table whose schema `biomotion.io.tables.table_schema` knows), and per subject ``<subject>/`` with an
  OpenSim ScaleTool setup (``*scaleSetup*.xml``) and IK setups (``*<token>*ikSetup*.xml``, the token being the trial
  name with its leading lowercase word removed: ``runT35`` -> ``T35``). The generic model is the file the scale
  setup names, looked up by name under the folder. Settings from the source's processing chain: markers
  low-passed at 10 Hz, mtp and subtalar welded (locked at 0).
- **OpenCap / AddBiomechanics** (``opencap/SOURCE.md``): ``<subject>/MarkerData/*.trc``, force plates in
  ``<subject>/ID/<trial>_grf.mot``, IK setups ``<subject>/IK/<trial>_ik_setup.xml``, models in ``<subject>/Models``
  (a ScaleTool setup there scales its generic model; otherwise the scaled model the IK setups name is used as it
  is). The static trial is the one whose name starts with ``static``. The folder may be the subject folder itself.
- **Motus** (``movement-screen-183/SOURCE.md``): ``Kinematic_Data/<PPID>/Generated_C3D_files/*.c3d`` with
  ``Calib1.c3d`` the static trial, and ``Participants Info/Subject Log.xlsx`` (possibly one folder deeper). The
  layout holds no model: the model (and a ScaleTool setup) must come from the caller (``model=``,
  ``scale_setup=``; ``biomotion batch --model --scale-setup``), and a marker map usually too.

A **TOML config** lists it all (paths relative to the config's folder)::

    [study]
    name = "my study"
    layout = "fukuchi"            # optional: start from a detected folder (``folder``, default the config's)
    model = "models/generic.osim" # generic model (scaled per subject) or a scaled one (no static trial)
    scale_setup = "setups/scale.xml"
    marker_filter_hz = 10
    cutoff_hz = 6
    forces = "auto"               # auto | measured | inferred | learned
    muscles = "gait2392_subject01"
    locked = ["mtp_angle_r", "mtp_angle_l"]
    plates = { 1 = "right", 2 = "left", 3 = "none" }
    marker_map = { "RASI" = "R.ASIS" }

    [[subject]]
    name = "S01"
    mass = 62.0                   # kg; default the subject table's, else the scale setup's
    static = "S01/static.trc"
    [[subject.trial]]
    name = "walk1"
    markers = "S01/walk1.trc"
    forces = "S01/walk1_grf.mot"  # a C3D holds its own plates
    setup = "S01/walk1_ik_setup.xml"
    time_range = [0.5, 2.5]
    plates = "1=right,2=left"

Contract: `load_study` returns a `Study` whose every path exists (a missing file is a `ConfigError` naming it and
the key or layout that asked for it) and whose settings are checked; it reads only the folder or config and the
subject table.
"""

from __future__ import annotations

import dataclasses
import difflib
import fnmatch
import hashlib
import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from biomotion.errors import ConfigError, DataFormatError

LAYOUTS = ("fukuchi", "opencap", "motus")
FORCE_SOURCES = ("auto", "measured", "inferred", "learned")
SIDES = {"right": "calcn_r", "r": "calcn_r", "left": "calcn_l", "l": "calcn_l", "none": None, "off": None}
MARKER_SUFFIXES = (".c3d", ".trc")
#: the Fukuchi source's processing chain (fukuchi-running/SOURCE.md, "Processing chain" 1 and 3)
FUKUCHI_FILTER_HZ = 10.0
FUKUCHI_LOCKED = ("mtp_angle_r", "mtp_angle_l", "subtalar_angle_r", "subtalar_angle_l")


# --- settings -----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StudySettings:
    """How every trial of a study is processed (the same for all, so the batch can hash them once).

    Attributes:
        marker_filter_hz: zero-lag low-pass of the markers before IK (None: as recorded).
        cutoff_hz: low-pass of the coordinates before differentiation (OpenSim's ID tool; 0 to skip).
        forces: ground reaction for the torques: ``measured`` (the plates; a trial without plates fails),
            ``inferred`` (from the kinematics alone, PhysPT's contact model), ``learned`` (the learned
            ground-reaction model, given to the batch by its caller), ``auto`` (the plates when the trial has them,
            else learned when given, else inferred).
        muscles: muscle path functions (a ``.safetensors`` file or a shipped name) for static optimization; None:
            no static optimization (the report says so).
        locked: coordinates held at 0 (welded joints, as the Fukuchi chain welds mtp and subtalar).
        plates: plate channel -> body (``calcn_r``, ``calcn_l`` ...) or None (ignored); see `parse_plates`.
            Channels not named are assigned to the feet automatically.
        marker_map: data marker name -> model marker name, applied before anything else.
        viewer: write each trial's viewer page.
    """

    marker_filter_hz: float | None = None
    cutoff_hz: float = 6.0
    forces: str = "auto"
    muscles: str | None = None
    locked: tuple[str, ...] = ()
    plates: tuple[tuple[str, str | None], ...] = ()
    marker_map: tuple[tuple[str, str], ...] = ()
    viewer: bool = True

    def __post_init__(self) -> None:
        if self.forces not in FORCE_SOURCES:
            raise ConfigError(f"forces must be one of {', '.join(FORCE_SOURCES)}, got {self.forces!r}")
        if self.marker_filter_hz is not None and not self.marker_filter_hz > 0:
            raise ConfigError(f"marker_filter_hz must be positive, got {self.marker_filter_hz}")
        if not self.cutoff_hz >= 0:
            raise ConfigError(f"cutoff_hz must be >= 0, got {self.cutoff_hz}")

    def as_dict(self) -> dict[str, Any]:
        """JSON-able form (what the record and the resume hash hold)."""
        out = dataclasses.asdict(self)
        out["plates"] = dict(self.plates)
        out["marker_map"] = dict(self.marker_map)
        out["locked"] = list(self.locked)
        return out


def parse_plates(spec: str | Mapping[Any, Any] | None, where: str = "plates") -> tuple[tuple[str, str | None], ...]:
    """A plate override: ``"1=right,2=left,3=none"`` or a mapping ``{1: "right", ...}``, as (channel, body) pairs.

    A channel is a plate's number (1-based, in file order) or its channel name; a side is ``right``/``r``,
    ``left``/``l``, ``none`` (the plate is ignored), or a body name of the model (``calcn_r``, ``toes_l`` ...).
    """
    if spec is None or spec == "":
        return ()
    if isinstance(spec, str):
        items = []
        for part in spec.split(","):
            if "=" not in part:
                raise ConfigError(f"{where}: {part.strip()!r} is not CHANNEL=SIDE (e.g. 1=right,2=left,3=none)")
            key, value = part.split("=", 1)
            items.append((key.strip(), value.strip()))
    elif isinstance(spec, Mapping):
        items = [(str(k).strip(), str(v).strip()) for k, v in spec.items()]
    else:
        raise ConfigError(f"{where}: expected 'CHANNEL=SIDE,...' or a table, got {type(spec).__name__}")
    out = []
    for key, value in items:
        if not key:
            raise ConfigError(f"{where}: an empty plate name in {spec!r}")
        side = value.lower()
        out.append((key, SIDES[side] if side in SIDES else value))
    return tuple(out)


def plate_bodies(names: Iterable[str], plates: Iterable[tuple[str, str | None]]) -> dict[str, str | None]:
    """The override for each of a trial's plate channels (``names``, file order) that ``plates`` names: channel ->
    body, or None where the plate is ignored. A key matches a channel by name or, when it is a whole number k, the
    k-th channel. A key that matches no channel is a `ConfigError` listing the channels."""
    names = list(names)
    out: dict[str, str | None] = {}
    for key, body in plates:
        if key in names:
            out[key] = body
        elif key.isdigit() and 1 <= int(key) <= len(names):
            out[names[int(key) - 1]] = body
        else:
            raise ConfigError(f"plate override names {key!r}, but the trial's plates are: {', '.join(names)}")
    return out


def parse_marker_map(spec: str | Path | Mapping[str, str] | None) -> tuple[tuple[str, str], ...]:
    """A marker-name map, data name -> model name: a mapping, ``"RASI=R.ASIS,LASI=L.ASIS"``, or a file (``.toml``
    with a ``[marker_map]`` table or top-level keys, ``.csv``/``.tsv``/``.txt`` with two columns ``data,model``)."""
    if spec is None or spec == "":
        return ()
    if isinstance(spec, Mapping):
        return tuple((str(k), str(v)) for k, v in spec.items())
    path = Path(spec)
    if path.suffix.lower() in (".toml", ".csv", ".tsv", ".txt") and path.exists():
        if path.suffix.lower() == ".toml":
            table = _read_toml(path)
            table = table.get("marker_map", table)
            if not all(isinstance(v, str) for v in table.values()):
                raise ConfigError(f"{path}: a marker map maps names to names")
            return tuple(table.items())
        pairs = []
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            fields_ = [f.strip() for f in re.split(r"[,\t;]", line) if f.strip()]
            if not fields_ or line.lstrip().startswith("#"):
                continue
            if len(fields_) != 2:
                raise DataFormatError(path, f"a marker map line holds two names, found {len(fields_)}", line=number)
            if number == 1 and [f.lower() for f in fields_] == ["data", "model"]:
                continue
            pairs.append((fields_[0], fields_[1]))
        return tuple(pairs)
    if isinstance(spec, Path) or "=" not in str(spec):
        raise ConfigError(f"marker map {spec}: no such file, and not NAME=NAME,... either")
    pairs = []
    for part in str(spec).split(","):
        if "=" not in part:
            raise ConfigError(f"marker map: {part.strip()!r} is not DATA=MODEL")
        data, model = part.split("=", 1)
        pairs.append((data.strip(), model.strip()))
    return tuple(pairs)


def closest_names(names: Iterable[str], candidates: Iterable[str], count: int = 2) -> dict[str, list[str]]:
    """For each name, the closest of ``candidates`` (case-insensitive, dots and underscores ignored): what a
    marker-name mismatch report shows next to each unmatched name."""
    pool = list(candidates)
    keyed = {re.sub(r"[._\s-]", "", c.lower()): c for c in pool}
    out = {}
    for name in names:
        key = re.sub(r"[._\s-]", "", name.lower())
        found = difflib.get_close_matches(key, list(keyed), n=count, cutoff=0.5)
        out[name] = [keyed[f] for f in found]
    return out


# --- the study ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrialSpec:
    """One dynamic trial: its marker file, its force file when the plates are not in it, its IK setup (marker
    weights, coordinate tasks, time range), an explicit time range, and a per-trial plate override."""

    name: str
    markers: Path
    forces: Path | None = None
    setup: Path | None = None
    time_range: tuple[float, float] | None = None
    plates: tuple[tuple[str, str | None], ...] = ()

    def files(self) -> dict[str, Path]:
        """The trial's own input files by role (for hashing and the record)."""
        out = {"markers": self.markers}
        if self.forces is not None:
            out["forces"] = self.forces
        if self.setup is not None:
            out["setup"] = self.setup
        return out


@dataclass(frozen=True)
class SubjectSpec:
    """One subject: the static trial and how to scale (``model`` is the generic model when ``scale_setup`` is
    given, else the subject's model used as it is), body mass and height (kg, m; None: the setup's or the
    model's), muscle paths (overrides the study's), and the dynamic trials."""

    name: str
    model: Path
    trials: tuple[TrialSpec, ...]
    static: Path | None = None
    scale_setup: Path | None = None
    mass: float | None = None
    height: float | None = None
    muscles: str | None = None

    def files(self) -> dict[str, Path]:
        out = {"model": self.model}
        if self.static is not None:
            out["static"] = self.static
        if self.scale_setup is not None:
            out["scale_setup"] = self.scale_setup
        muscles = Path(self.muscles) if self.muscles else None
        if muscles is not None and muscles.is_file():
            out["muscles"] = muscles
        return out


@dataclass(frozen=True)
class Study:
    """A study: where it came from (``source``: the folder or config), its layout (``fukuchi``, ``opencap``,
    ``motus`` or ``config``), its subjects and the settings every trial shares."""

    name: str
    source: Path
    layout: str
    subjects: tuple[SubjectSpec, ...]
    settings: StudySettings = field(default_factory=StudySettings)

    @property
    def n_trials(self) -> int:
        return sum(len(s.trials) for s in self.subjects)

    def select(self, subjects: Iterable[str] | None = None, trials: Iterable[str] | None = None) -> Study:
        """The study restricted to ``subjects`` (names) and ``trials`` (shell patterns on trial names, e.g.
        ``runT35`` or ``walk*``); a name that matches nothing is a `ConfigError` listing what there is."""
        chosen = list(self.subjects)
        if subjects:
            wanted = list(subjects)
            known = {s.name for s in chosen}
            unknown = [w for w in wanted if w not in known]
            if unknown:
                raise ConfigError(f"no subject {', '.join(unknown)} in {self.source}; subjects: {', '.join(known)}")
            chosen = [s for s in chosen if s.name in wanted]
        if trials:
            patterns = list(trials)
            chosen = [
                dataclasses.replace(
                    s, trials=tuple(t for t in s.trials if any(fnmatch.fnmatchcase(t.name, p) for p in patterns))
                )
                for s in chosen
            ]
            if not any(s.trials for s in chosen):
                raise ConfigError(f"no trial matches {', '.join(patterns)} in {self.source}")
        return dataclasses.replace(self, subjects=tuple(chosen))

    def with_settings(self, **changes: Any) -> Study:
        return dataclasses.replace(self, settings=dataclasses.replace(self.settings, **changes))


def file_sha256(path: Path, cache: dict[Path, str] | None = None) -> str:
    """SHA-256 of a file's bytes (memoised in ``cache``)."""
    path = Path(path)
    if cache is not None and path in cache:
        return cache[path]
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    value = digest.hexdigest()
    if cache is not None:
        cache[path] = value
    return value


def settings_hash(*parts: Any) -> str:
    """SHA-256 of JSON-able parts (sorted keys): the settings half of a resume key."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


# --- reading ------------------------------------------------------------------------------------------------------


def load_study(
    source: str | Path,
    *,
    model: str | Path | None = None,
    scale_setup: str | Path | None = None,
    **settings: Any,
) -> Study:
    """The study in ``source``: a TOML config, or a folder in one of `LAYOUTS` (see the module docstring).

    ``model`` and ``scale_setup`` give every subject that generic model and setup (required for the Motus layout,
    which holds no model); ``settings`` override `StudySettings` fields (``plates``, ``marker_map`` in any form
    `parse_plates` / `parse_marker_map` take).
    """
    source = Path(source)
    if not source.exists():
        raise ConfigError(f"{source}: no such study folder or config")
    if source.is_file():
        if source.suffix.lower() != ".toml":
            raise ConfigError(f"{source}: a study is a folder or a .toml config")
        study = _from_config(source)
    else:
        study = _from_folder(source)
    if model is not None or scale_setup is not None:
        study = _with_model(study, model, scale_setup)
    if settings:
        settings = dict(settings)
        if "plates" in settings:
            settings["plates"] = parse_plates(settings["plates"])
        if "marker_map" in settings:
            settings["marker_map"] = parse_marker_map(settings["marker_map"])
        if "locked" in settings:
            settings["locked"] = tuple(settings["locked"])
        study = study.with_settings(**settings)
    _check_files(study)
    return study


def _with_model(study: Study, model: str | Path | None, scale_setup: str | Path | None) -> Study:
    subjects = []
    for subject in study.subjects:
        changes: dict[str, Any] = {}
        if model is not None:
            changes["model"] = Path(model)
        if scale_setup is not None:
            changes["scale_setup"] = Path(scale_setup)
        subjects.append(dataclasses.replace(subject, **changes))
    return dataclasses.replace(study, subjects=tuple(subjects))


def _check_files(study: Study) -> None:
    if not study.subjects:
        raise ConfigError(f"{study.source}: the study has no subject")
    for subject in study.subjects:
        if subject.model == Path(_NO_MODEL):
            raise ConfigError(
                f"{study.source}: the {study.layout} layout holds no model for {subject.name}: give the generic "
                "model and its ScaleTool setup (--model, --scale-setup; `model`, `scale_setup` in a config)"
            )
        for role, path in subject.files().items():
            if not Path(path).exists():
                raise ConfigError(f"{study.source}: subject {subject.name}: its {role} {path} does not exist")
        if subject.static is not None and subject.static.suffix.lower() not in MARKER_SUFFIXES:
            raise ConfigError(f"{subject.static}: a static trial is a marker file (.c3d or .trc)")
        for trial in subject.trials:
            for role, path in trial.files().items():
                if not Path(path).exists():
                    raise ConfigError(f"{study.source}: {subject.name}/{trial.name}: its {role} {path} does not exist")


def detect_layout(folder: Path) -> str | None:
    """Which of `LAYOUTS` a folder has, or None."""
    folder = Path(folder)
    if (folder / "c3d").is_dir() and any((folder / "c3d").glob("*static.c3d")):
        return "fukuchi"
    if (folder / "Kinematic_Data").is_dir():
        return "motus"
    if (folder / "MarkerData").is_dir() or any(p.is_dir() for p in folder.glob("*/MarkerData")):
        return "opencap"
    return None


def _from_folder(folder: Path, layout: str | None = None) -> Study:
    layout = layout or detect_layout(folder)
    if layout is None:
        raise ConfigError(
            f"{folder}: not a study layout biomotion knows (Fukuchi: c3d/<subject>static.c3d; OpenCap: "
            "<subject>/MarkerData/*.trc; Motus: Kinematic_Data/<PPID>/Generated_C3D_files): give a TOML config "
            "(`biomotion batch --help`)"
        )
    reader = {"fukuchi": _fukuchi, "opencap": _opencap, "motus": _motus}.get(layout)
    if reader is None:
        raise ConfigError(f"unknown layout {layout!r}; known: {', '.join(LAYOUTS)}")
    return reader(folder)


def _profiles(folder: Path, names: Iterable[str] = ()) -> dict[str, Any]:
    """Subjects of the first table in ``folder`` (or the named files) whose schema is known; {} when none."""
    from biomotion.io.tables import read_subject_table, table_schema

    candidates = [folder / n for n in names] + sorted(
        p for p in folder.glob("*") if p.suffix.lower() in (".csv", ".tsv", ".xlsx") and p.is_file()
    )
    for path in candidates:
        if path.is_file() and table_schema(path) is not None:
            return read_subject_table(path)
    return {}


def _find_model(folder: Path, file_name: str) -> Path | None:
    """A model file named ``file_name`` (a setup's raw path, Windows separators allowed) under ``folder``."""
    name = Path(file_name.replace("\\", "/")).name
    if not name:
        return None
    found = sorted(folder.rglob(name))
    return found[0] if found else None


def _fukuchi(folder: Path) -> Study:
    from biomotion.io.setup import read_scale_setup

    c3d = folder / "c3d"
    profiles = _profiles(folder, ["participantInfo.csv"])
    statics = {p.name[: -len("static.c3d")]: p for p in sorted(c3d.glob("*static.c3d"))}
    subjects = []
    for name, static in statics.items():
        trials = []
        for path in sorted(c3d.glob(f"{name}*.c3d")):
            trial = path.stem[len(name) :]
            if path == static or not trial or trial[0].isdigit():  # RBDS01x files are other subjects'
                continue
            trials.append(TrialSpec(trial, path, setup=_ik_setup(folder / name, trial)))
        setups = sorted((folder / name).glob("*scaleSetup*.xml")) if (folder / name).is_dir() else []
        scale_setup = setups[0] if setups else None
        model = None
        if scale_setup is not None:
            model = _find_model(folder, read_scale_setup(scale_setup).model_file)
        if model is None:  # the caller gives it (load_study's model=, --model)
            model = Path(_NO_MODEL)
        profile = profiles.get(name)
        subjects.append(
            SubjectSpec(
                name,
                model,
                tuple(trials),
                static=static,
                scale_setup=scale_setup,
                mass=None if profile is None else profile.mass,
                height=None if profile is None else profile.height,
            )
        )
    settings = StudySettings(marker_filter_hz=FUKUCHI_FILTER_HZ, locked=FUKUCHI_LOCKED)
    return Study(folder.name, folder, "fukuchi", tuple(subjects), settings)


def _ik_setup(folder: Path, trial: str) -> Path | None:
    """The IK setup in a subject folder for a trial: a ``*ikSetup*``/``*ik_setup*`` file naming the trial, or its
    token (the name without a leading lowercase word: ``runT35`` -> ``T35``)."""
    if not folder.is_dir():
        return None
    token = re.sub(r"^[a-z]+(?=[A-Z0-9])", "", trial)
    setups = sorted(p for p in folder.glob("*.xml") if re.search(r"ik_?setup", p.name, re.IGNORECASE))
    for key in (trial, token):
        for path in setups:
            if re.search(rf"(^|[_.-]){re.escape(key)}([_.-]|$)", path.stem):
                return path
    return None


_NO_MODEL = "<no model>"


def _opencap(folder: Path) -> Study:
    from biomotion.io.setup import read_ik_setup, read_scale_setup

    roots = [folder] if (folder / "MarkerData").is_dir() else sorted(p.parent for p in folder.glob("*/MarkerData"))
    subjects = []
    for root in roots:
        markers = sorted((root / "MarkerData").glob("*.trc"))
        static = next((p for p in markers if p.stem.lower().startswith("static")), None)
        trials = []
        model_from_ik = None
        for path in markers:
            if path == static:
                continue
            setup = root / "IK" / f"{path.stem}_ik_setup.xml"
            grf = root / "ID" / f"{path.stem}_grf.mot"
            trials.append(
                TrialSpec(
                    path.stem,
                    path,
                    forces=grf if grf.exists() else None,
                    setup=setup if setup.exists() else None,
                )
            )
            if model_from_ik is None and setup.exists():
                raw = read_ik_setup(setup).model_file
                candidate = root / raw.replace("\\", "/")
                model_from_ik = candidate if candidate.exists() else _find_model(root, raw)
        setups = [p for p in sorted((root / "Models").glob("*.xml")) if _is_scale_setup(p)]
        scale_setup, model, mass, height = None, model_from_ik, None, None
        if setups:
            setup = read_scale_setup(setups[0])
            generic = root / setup.model_file.replace("\\", "/")
            generic = generic if generic.exists() else _find_model(root, setup.model_file)
            if generic is not None:
                scale_setup, model = setups[0], generic
                mass = setup.mass if setup.mass > 0 else None
                height = setup.height if setup.height > 0 else None
        subjects.append(
            SubjectSpec(
                root.name,
                model or Path(_NO_MODEL),
                tuple(trials),
                static=static,
                scale_setup=scale_setup,
                mass=mass,
                height=height,
            )
        )
    return Study(folder.name, folder, "opencap", tuple(subjects), StudySettings())


def _is_scale_setup(path: Path) -> bool:
    with open(path, "rb") as handle:
        return b"<ScaleTool" in handle.read(4096)


def _motus(folder: Path) -> Study:
    logs = (
        sorted((folder / "Participants Info").rglob("Subject Log.xlsx"))
        if (folder / "Participants Info").is_dir()
        else []
    )
    profiles = _profiles(logs[0].parent, [logs[0].name]) if logs else {}  # some zips unpack one folder deeper
    subjects = []
    for subject in sorted((folder / "Kinematic_Data").iterdir(), key=lambda p: (len(p.name), p.name)):
        trials_folder = subject / "Generated_C3D_files"
        if not trials_folder.is_dir():
            continue
        files = sorted(trials_folder.glob("*.c3d"))
        static = next((p for p in files if p.stem.lower().startswith("calib")), None)
        trials = tuple(TrialSpec(p.stem, p) for p in files if p != static)
        profile = profiles.get(subject.name)
        subjects.append(
            SubjectSpec(
                subject.name,
                Path(_NO_MODEL),
                trials,
                static=static,
                mass=None if profile is None else profile.mass,
                height=None if profile is None else profile.height,
            )
        )
    return Study(folder.name, folder, "motus", tuple(subjects), StudySettings())


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except tomllib.TOMLDecodeError as error:
        raise DataFormatError(path, f"not valid TOML: {error}") from None


_STUDY_KEYS = {
    "name",
    "layout",
    "folder",
    "model",
    "scale_setup",
    "marker_filter_hz",
    "cutoff_hz",
    "forces",
    "muscles",
    "locked",
    "plates",
    "marker_map",
    "viewer",
}
_SUBJECT_KEYS = {"name", "model", "scale_setup", "static", "mass", "height", "muscles", "trial"}
_TRIAL_KEYS = {"name", "markers", "forces", "setup", "time_range", "plates"}


def _unknown(table: Mapping[str, Any], known: set[str], where: str, path: Path) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        hints = closest_names(unknown, known, 1)
        named = ", ".join(f"{u!r}" + (f" (did you mean {hints[u][0]!r}?)" if hints[u] else "") for u in unknown)
        raise ConfigError(f"{path}: unknown {where} key {named}; known: {', '.join(sorted(known))}")


def _from_config(path: Path) -> Study:
    config = _read_toml(path)
    _unknown(config, {"study", "subject"}, "top-level", path)
    head = config.get("study", {})
    _unknown(head, _STUDY_KEYS, "[study]", path)
    base = path.parent

    def resolve(value: Any, key: str) -> Path | None:
        if value is None:
            return None
        if not isinstance(value, str):
            raise ConfigError(f"{path}: {key} must be a path (a string), got {value!r}")
        return (base / value).resolve() if not Path(value).is_absolute() else Path(value)

    if "layout" in head:
        study = _from_folder(resolve(head.get("folder", "."), "folder"), head["layout"])
    else:
        study = Study(path.stem, path, "config", ())
    settings = {k: head[k] for k in ("marker_filter_hz", "cutoff_hz", "forces", "muscles", "viewer") if k in head}
    if "locked" in head:
        settings["locked"] = tuple(head["locked"])
    if "plates" in head:
        settings["plates"] = parse_plates(head["plates"], f"{path}: [study] plates")
    if "marker_map" in head:
        mapping = head["marker_map"]
        settings["marker_map"] = parse_marker_map(
            resolve(mapping, "marker_map") if isinstance(mapping, str) else mapping
        )
    muscles = settings.get("muscles")
    if isinstance(muscles, str) and (base / muscles).exists():
        settings["muscles"] = str((base / muscles).resolve())
    try:
        study = study.with_settings(**settings)
    except TypeError as error:
        raise ConfigError(f"{path}: [study]: {error}") from None
    if "model" in head or "scale_setup" in head:
        study = _with_model(study, resolve(head.get("model"), "model"), resolve(head.get("scale_setup"), "scale_setup"))
    default_model = resolve(head.get("model"), "model")
    default_setup = resolve(head.get("scale_setup"), "scale_setup")
    subjects = list(study.subjects)
    for entry in config.get("subject", []):
        _unknown(entry, _SUBJECT_KEYS, "[[subject]]", path)
        if "name" not in entry:
            raise ConfigError(f"{path}: a [[subject]] has no name")
        trials = []
        for trial in entry.get("trial", []):
            _unknown(trial, _TRIAL_KEYS, "[[subject.trial]]", path)
            if "markers" not in trial:
                raise ConfigError(f"{path}: subject {entry['name']}: a trial has no markers file")
            markers = resolve(trial["markers"], "markers")
            time_range = trial.get("time_range")
            if time_range is not None and (len(time_range) != 2 or time_range[0] > time_range[1]):
                raise ConfigError(f"{path}: {entry['name']}: time_range must be [start, end], got {time_range}")
            trials.append(
                TrialSpec(
                    str(trial.get("name", markers.stem)),
                    markers,
                    forces=resolve(trial.get("forces"), "forces"),
                    setup=resolve(trial.get("setup"), "setup"),
                    time_range=None if time_range is None else (float(time_range[0]), float(time_range[1])),
                    plates=parse_plates(trial.get("plates"), f"{path}: {entry['name']} plates"),
                )
            )
        model = resolve(entry.get("model"), "model") or default_model
        if model is None:
            raise ConfigError(f"{path}: subject {entry['name']} has no model (give [study] model or its own)")
        muscles = entry.get("muscles")
        if isinstance(muscles, str) and (base / muscles).exists():
            muscles = str((base / muscles).resolve())
        subject = SubjectSpec(
            str(entry["name"]),
            model,
            tuple(trials),
            static=resolve(entry.get("static"), "static"),
            scale_setup=resolve(entry.get("scale_setup"), "scale_setup") or default_setup,
            mass=entry.get("mass"),
            height=entry.get("height"),
            muscles=muscles,
        )
        existing = [k for k, s in enumerate(subjects) if s.name == subject.name]
        if existing:
            subjects[existing[0]] = subject
        else:
            subjects.append(subject)
    name = str(head.get("name", study.name if study.layout != "config" else path.stem))
    layout = study.layout if study.layout != "config" else "config"
    return dataclasses.replace(study, name=name, source=path, layout=layout, subjects=tuple(subjects))
