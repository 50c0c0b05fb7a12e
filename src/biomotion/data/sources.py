"""Data sources of the registry: each finds its clips under a data root and loads one as a canonical `Trial`.

A source is a folder of the data root (``fukuchi-running/``, ``opencap/Subject4/`` ...). `Source.discover` lists
what is present — any subjects, so a folder holding other runners or a subset works the same — and `Source.load`
returns the clip mapped onto `CANONICAL_COORDINATES` (mask False for coordinates the source lacks, knee sign made
canonical). Sources that need retargeting (BVH, raw C3D) register themselves through `register_source`.
"""

from __future__ import annotations

import functools
import gzip
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from biomotion.body.canonical import CANONICAL_COORDINATES, KNEE_COORDINATES
from biomotion.errors import ConfigError, DataFormatError
from biomotion.io.mot import read_motion
from biomotion.io.tables import read_subject_table
from biomotion.motion import Motion
from biomotion.profile import Profile
from biomotion.trial import Labels, Trial


@dataclass(frozen=True)
class ClipSpec:
    """One clip a source offers: a stable id, its file, who and what."""

    clip_id: str
    source: str
    path: Path
    subject: str
    labels: Labels
    profile: Profile = field(default_factory=Profile)
    retargeted: bool = False  # solved by IK when loaded (slow: the cache loads such clips in parallel)


@dataclass(frozen=True)
class Source:
    """A registered source: folder under the data root, a discoverer and a loader of canonical motion."""

    name: str
    folder: str
    discover: Callable[[Path], list[ClipSpec]]
    load_motion: Callable[[ClipSpec], Motion]
    description: str = ""
    overground: bool = False  # locomotion speed can be measured from the pelvis path (not on a treadmill)
    treadmill: bool = False  # locomotion on a treadmill at the label's speed (`biomotion.data.placement`)

    def present(self, data_root: Path) -> bool:
        return (data_root / self.folder).is_dir()

    def load(self, spec: ClipSpec) -> Trial:
        return Trial(motion=self.load_motion(spec), profile=spec.profile, labels=spec.labels, source=spec.path)


SOURCES: dict[str, Source] = {}


def register_source(source: Source) -> Source:
    """Add (or replace) a source in the registry; returns it so it can be used as a module-level constant."""
    SOURCES[source.name] = source
    return source


def to_canonical(motion: Motion, *, knee_flipped: bool = False) -> Motion:
    """Columns in canonical order (absent ones masked) with the canonical (positive-flexion) knee sign."""
    selected = motion.select(CANONICAL_COORDINATES)
    if knee_flipped:
        values = selected.values.copy()
        for name in KNEE_COORDINATES:
            values[:, selected.index(name)] *= -1.0
        selected = selected.with_values(values)
    return selected


def forward_speed(motion: Motion) -> float:
    """Mean horizontal pelvis speed (m/s) from ``pelvis_tx/tz``: the walking speed of an overground clip."""
    horizontal = np.stack([motion["pelvis_tx"], motion["pelvis_tz"]], axis=1)
    return float(np.linalg.norm(horizontal[-1] - horizontal[0]) / motion.duration)


def _profiles(table: Path) -> dict[str, Profile]:
    return read_subject_table(table) if table.exists() else {}


# --- Fukuchi 2017 running: ik/<speed>/<runner>_<speed>_ik_simple.mot, or its raw C3D where that is absent ---------


def _fukuchi_clip(
    runner: str, tens: str, tenths: str, path: Path, profiles: dict[str, Profile], retargeted: bool
) -> ClipSpec:
    speed = float(f"{tens}.{tenths}")
    return ClipSpec(
        clip_id=f"fukuchi/{runner}/T{tens}{tenths}",
        source="fukuchi",
        path=path,
        subject=runner,
        profile=profiles.get(runner, Profile(subject_id=runner)),
        retargeted=retargeted,
        labels=Labels(action="run", speed=speed, text=f"run on a treadmill at {speed} m/s"),
    )


def _fukuchi_discover(root: Path) -> list[ClipSpec]:
    """Every shipped IK motion; and every running C3D without one whose runner has the scaled model and the IK
    setup of that speed (a data root of new runners may hold only their captures)."""
    base = root / "fukuchi-running"
    profiles = _profiles(base / "participantInfo.csv")
    specs, solved = [], set()
    for path in sorted(base.glob("ik/T*/*_ik_simple.mot")):
        match = re.match(r"(RBDS\d+)_T(\d)(\d)_ik_simple", path.stem)
        if match:
            specs.append(_fukuchi_clip(*match.groups(), path, profiles, retargeted=False))
            solved.add(match.groups())
    from biomotion.data.fukuchi_chain import runner_files

    for path in sorted(base.glob("c3d/*runT*.c3d")):
        match = re.fullmatch(r"(RBDS\d+)runT(\d)(\d)", path.stem)
        if not match or match.groups() in solved:
            continue
        runner, tens, tenths = match.groups()
        files = runner_files(base, runner, f"T{tens}{tenths}")
        if (
            all(files[k].exists() for k in ("generic", "scale_setup", "ik_setup", "static"))
            and (base / runner / f"{runner}_simple.osim").exists()
        ):
            specs.append(_fukuchi_clip(runner, tens, tenths, path, profiles, retargeted=True))
    return sorted(specs, key=lambda spec: spec.clip_id)


def _fukuchi_load(spec: ClipSpec) -> Motion:
    """The shipped IK motion; or the C3D put through the source's own chain (`biomotion.data.fukuchi_chain`: it
    reproduces the shipped files within about 1 deg), kept to the shipped files' columns (the runner's simple
    model) and their knee sign, which is then made canonical like theirs."""
    if spec.path.suffix.lower() != ".c3d":
        return to_canonical(read_motion(spec.path), knee_flipped=True)
    from biomotion.body.model import BodyModel
    from biomotion.data.fukuchi_chain import as_simple, solve_trial

    base, runner, speed = spec.path.parents[1], spec.subject, spec.clip_id.rsplit("/", 1)[1]
    result, _ = solve_trial(base, runner, speed)
    columns = BodyModel.from_osim(base / runner / f"{runner}_simple.osim").coordinate_names
    return to_canonical(as_simple(result.motion).select(columns), knee_flipped=True)


FUKUCHI = register_source(
    Source(
        name="fukuchi",
        folder="fukuchi-running",
        discover=_fukuchi_discover,
        load_motion=_fukuchi_load,
        description="Fukuchi 2017 treadmill running at 2.5/3.5/4.5 m/s: shipped OpenSim IK, or the raw C3D put through "
        "the source's processing chain where no IK is shipped (16 lower-body coordinates)",
        treadmill=True,
    )
)


# --- OpenCap Subject4: IK/<trial>_ik.mot ------------------------------------------------------------------------

_OPENCAP_ACTIVITIES = (  # (trial-name prefix, action, style), longest prefixes first
    ("walkingTS", "walk", "trunk sway"),
    ("walkingTI", "walk", "toe-in"),
    ("walkingTO", "walk", "toe-out"),
    ("walking", "walk", "normal"),
    ("DJAsym", "drop jump", "asymmetric"),
    ("DJ", "drop jump", "normal"),
    ("squatsAsym", "squat", "asymmetric"),
    ("squats", "squat", "normal"),
    ("STSweakLegs", "sit-to-stand", "weak legs"),
    ("STSAsym", "sit-to-stand", "asymmetric"),
    ("STS", "sit-to-stand", "normal"),
    ("static", "static", "normal"),
)

#: An OpenCap (AddBiomechanics) subject folder's scaled model, which its ``IK/*_ik.mot`` and setups use.
OPENCAP_MODEL_FILE = "Models/optimized_scale_and_markers.osim"


def _opencap_profile(subject_dir: Path) -> Profile:
    """A subject's mass and height from the ScaleTool setup AddBiomechanics writes beside the models
    (``Models/rescaling_setup.xml``; Subject4: 62.6 kg, 1.68 m, as ``opencap/SOURCE.md`` says); the height is read
    as metres, or as millimetres (OpenSim's unit for it) when above 3. Absent or unset (-1) values stay unknown."""
    from biomotion.io.setup import read_scale_setup

    setup_file = subject_dir / "Models" / "rescaling_setup.xml"
    if not setup_file.is_file():
        return Profile(subject_id=subject_dir.name)
    setup = read_scale_setup(setup_file)
    height = setup.height / 1000.0 if setup.height > 3.0 else setup.height
    return Profile(
        subject_id=subject_dir.name, mass=setup.mass if setup.mass > 0 else None, height=height if height > 0 else None
    )


def _opencap_discover(root: Path) -> list[ClipSpec]:
    specs = []
    for subject_dir in sorted(p for p in (root / "opencap").glob("Subject*") if p.is_dir()):
        subject = subject_dir.name
        profile = _opencap_profile(subject_dir)
        for path in sorted(subject_dir.glob("IK/*_ik.mot")):
            if path.stem.endswith("_manual_scaling_ik"):  # the lab's hand-scaled model: same trials again
                continue
            trial = path.stem.removesuffix("_ik")
            activity = next(((a, s) for prefix, a, s in _OPENCAP_ACTIVITIES if trial.startswith(prefix)), None)
            if activity is None:
                continue
            action, style = activity
            text = action if style == "normal" else f"{action}, {style}"
            specs.append(
                ClipSpec(
                    clip_id=f"opencap/{subject}/{trial}",
                    source="opencap",
                    path=path,
                    subject=subject,
                    profile=profile,
                    labels=Labels(action=action, style=style, text=text),
                )
            )
    return specs


OPENCAP = register_source(
    Source(
        name="opencap",
        folder="opencap",
        discover=_opencap_discover,
        load_motion=lambda spec: to_canonical(read_motion(spec.path)),
        description="OpenCap lab validation: walking variants, drop jumps, squats, sit-to-stand (33 coordinates)",
        overground=True,
    )
)


# --- Hamner & Delp 2013 running: <subject>/Run_<speed>.mot ------------------------------------------------------


def _hamner_discover(root: Path) -> list[ClipSpec]:
    base = root / "Hamner2013"
    profiles = _profiles(base / "subjects.csv")
    specs = []
    for path in sorted(base.glob("subject*/Run_*.mot")):
        match = re.fullmatch(r"Run_(\d+)", path.stem)
        if not match:
            continue
        subject, speed = path.parent.name, float(match.group(1))
        specs.append(
            ClipSpec(
                clip_id=f"hamner/{subject}/Run_{match.group(1)}",
                source="hamner",
                path=path,
                subject=subject,
                profile=profiles.get(subject, Profile(subject_id=subject)),
                labels=Labels(action="run", speed=speed, text=f"run on a treadmill at {speed:g} m/s"),
            )
        )
    return specs


def _hamner_load(spec: ClipSpec) -> Motion:
    motion = read_motion(spec.path)  # SIMM header without inDegrees: degrees (Hamner2013/SOURCE.md)
    coordinates = [n for n in motion.names if n in CANONICAL_COORDINATES]
    return to_canonical(motion.select(coordinates), knee_flipped=True)


HAMNER = register_source(
    Source(
        name="hamner",
        folder="Hamner2013",
        discover=_hamner_discover,
        load_motion=_hamner_load,
        description="Hamner & Delp 2013 treadmill running at 2-5 m/s, full body with arms (37 coordinates)",
        treadmill=True,
    )
)


# --- Schreiber & Moissenet 2019 walking: <subject>/C{4,5}_xx_ik.mot ---------------------------------------------

_SCHREIBER_CONDITIONS = {"C4": "spontaneous", "C5": "fast"}


def _schreiber_discover(root: Path) -> list[ClipSpec]:
    base = root / "SchreiberMoissenet2019"
    profiles = _profiles(base / "subjects.csv")
    specs = []
    for path in sorted(base.glob("*/C*_ik.mot")):
        match = re.fullmatch(r"(C\d)_(\d+)_ik", path.stem)
        if not match or match.group(1) not in _SCHREIBER_CONDITIONS:
            continue
        subject, style = path.parent.name, _SCHREIBER_CONDITIONS[match.group(1)]
        specs.append(
            ClipSpec(
                clip_id=f"schreiber/{subject}/{match.group(1)}_{match.group(2)}",
                source="schreiber",
                path=path,
                subject=subject,
                profile=profiles.get(subject, Profile(subject_id=subject)),
                labels=Labels(action="walk", style=style, text=f"walk overground at a {style} speed"),
            )
        )
    return specs


SCHREIBER = register_source(
    Source(
        name="schreiber",
        folder="SchreiberMoissenet2019",
        discover=_schreiber_discover,
        load_motion=lambda spec: to_canonical(read_motion(spec.path)),
        description="Schreiber & Moissenet 2019 overground walking, spontaneous and fast (Rajagopal, 39 coordinates)",
        overground=True,
    )
)


# --- Bandai-Namco BVH: bandai-namco/dataset-{1,2}/*.bvh.gz, retargeted onto the canonical model -----------------

BANDAI_MODEL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"


def _hips_rest_offset(path: Path) -> tuple[float, float, float]:
    """The OFFSET line of the ``Hips`` joint in a BVH header (cm)."""
    with gzip.open(path, "rt") as handle:
        seen_hips = False
        for number, line in enumerate(handle, 1):  # noqa: B007 - the last line number names a missing OFFSET
            words = line.split()
            if words[-1:] == ["Hips"]:
                seen_hips = True
            elif seen_hips and words[:1] == ["OFFSET"]:
                return tuple(float(w) for w in words[1:4])
            elif words[:1] == ["MOTION"]:
                break
    raise DataFormatError(path, "no OFFSET for a joint named Hips in the hierarchy", line=number)


def _bandai_discover(root: Path) -> list[ClipSpec]:
    """Every clip present, labelled from its name (``dataset-N_content_style_take``, bandai-namco/SOURCE.md).

    The datasets name no actors. The rest OFFSET of ``Hips`` differs between groups of styles (three main groups
    per dataset, as the three actors the upstream README names), so it stands in for the subject and a split keeps
    a group's clips together.
    """
    specs = []
    for path in sorted((root / "bandai-namco").glob("dataset-*/*.bvh.gz")):
        parts = path.name.removesuffix(".bvh.gz").split("_")
        if len(parts) != 4:
            raise DataFormatError(path, "expected a name dataset-N_content_style_take.bvh.gz")
        dataset, content, style, take = parts
        x, y, z = _hips_rest_offset(path)
        action = content.replace("-", " ")
        specs.append(
            ClipSpec(
                clip_id=f"bandai-namco/{dataset}/{content}_{style}_{take}",
                source="bandai-namco",
                path=path,
                subject=f"{dataset}/hips@{x:.0f},{y:.0f},{z:.0f}",
                retargeted=True,
                labels=Labels(action=action, style=style, text=action if style == "normal" else f"{action}, {style}"),
            )
        )
    return specs


@functools.lru_cache(maxsize=2)
def _generic_model(root: Path):
    from biomotion.body.model import BodyModel

    path = root / BANDAI_MODEL
    if not path.exists():
        raise DataFormatError(path, "the Bandai-Namco clips are retargeted onto this model, which is absent")
    return BodyModel.from_osim(path)


def _bandai_load(spec: ClipSpec) -> Motion:
    """The clip retargeted onto the canonical (Rajagopal 2016) model (`biomotion.ik.skeleton`, default rules)."""
    from biomotion.ik.skeleton import joint_positions, retarget_skeleton
    from biomotion.io.bvh import read_bvh

    root = spec.path.parents[2]
    return to_canonical(retarget_skeleton(joint_positions(read_bvh(spec.path)), _generic_model(root)).motion)


BANDAI = register_source(
    Source(
        name="bandai-namco",
        folder="bandai-namco",
        discover=_bandai_discover,
        load_motion=_bandai_load,
        description="Bandai-Namco stylised motion (BVH, 30 fps), retargeted onto Rajagopal 2016: locomotion, gestures, "
        "fighting, dance in styles such as elderly, exhausted, youthful (39 coordinates)",
        overground=True,
    )
)


def discover_all(data_root: Path, names: Iterable[str] | None = None) -> tuple[list[ClipSpec], list[str]]:
    """Clips of every registered source present under ``data_root``; also the names of sources skipped (absent)."""
    names = list(names or SOURCES)
    unknown = [name for name in names if name not in SOURCES]
    if unknown:
        raise ConfigError(f"unknown source {', '.join(map(repr, unknown))}; registered: {', '.join(SOURCES)}")
    clips: list[ClipSpec] = []
    skipped: list[str] = []
    for name in names:
        source = SOURCES[name]
        if not source.present(data_root):
            skipped.append(f"{name} (no {source.folder}/ under {data_root})")
            continue
        found = source.discover(data_root)
        if not found:
            skipped.append(f"{name} ({source.folder}/ holds no clips)")
        clips.extend(found)
    return clips, skipped
