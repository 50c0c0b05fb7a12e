"""``biomotion retarget``: captured motion → coordinates of a model, one trial or a folder of them.

- Markers (TRC, C3D) on a subject-scaled model: `biomotion.ik.markers.solve_ik` (all frames at once).
- Skeletons (BVH, ``.bvh.gz``), or marker files holding joint centres when a joint map is given: the generic model
  is scaled to the skeleton and fitted to its joint centres (`biomotion.ik.skeleton`); the scaled model is
  written beside the motion as ``<trial>.osim``.

Each trial is written as an OpenSim ``.mot``; a batch keeps going past a bad trial and writes ``summary.csv`` with
one row per trial: frames, RMS and maximum marker (or joint-centre) error, frames where no tracked point was
visible (dropped), and the error if the trial failed.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from biomotion.body.model import BodyModel
from biomotion.errors import BiomotionError, ConfigError
from biomotion.ik.markers import check_marker_scale, solve_ik
from biomotion.ik.skeleton import FILTER_HZ, JointMap, joint_positions, retarget_skeleton, write_scaled_model
from biomotion.io.bvh import read_bvh
from biomotion.io.c3d import read_c3d_markers
from biomotion.io.mot import read_motion, write_motion
from biomotion.io.setup import IKSetup
from biomotion.io.tables import write_csv
from biomotion.io.trc import read_trc
from biomotion.motion import Markers, Motion

MARKER_SUFFIXES = (".trc", ".c3d")
SKELETON_SUFFIXES = (".bvh", ".bvh.gz")
SUMMARY_COLUMNS = ["trial", "frames", "rms_error_m", "max_error_m", "frames_dropped", "output", "error"]


def read_markers(path: Path, time_range: tuple[float, float] | None = None) -> Markers:
    """Markers of a ``.trc`` or ``.c3d`` file, in metres (C3D exact zeros are gaps); with ``time_range`` only the
    frames inside it (a TRC file parses only those rows)."""
    if path.suffix.lower() == ".c3d":
        markers = read_c3d_markers(path)
        return markers if time_range is None else markers.slice(*time_range)
    return read_trc(path, time_range)


def is_skeleton(path: Path) -> bool:
    return path.name.lower().endswith(SKELETON_SUFFIXES)


def _readable(path: Path) -> bool:
    return path.suffix.lower() in MARKER_SUFFIXES or is_skeleton(path)


def trial_name(path: Path) -> str:
    """The file name without its suffix (both of ``.bvh.gz``)."""
    name = path.name
    for suffix in (*SKELETON_SUFFIXES, *MARKER_SUFFIXES):
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return path.stem


def motion_files(source: Path) -> list[Path]:
    """``source`` itself, or every TRC, C3D and BVH file in the folder ``source`` (sorted)."""
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if _readable(p))
        if not files:
            raise ConfigError(f"{source}: no .trc, .c3d or .bvh(.gz) files to retarget")
        return files
    if not _readable(source):
        raise ConfigError(f"{source}: retarget reads .trc and .c3d marker files and .bvh(.gz) skeletons")
    if not source.exists():
        raise ConfigError(f"{source}: no such file")
    return [source]


@dataclass(frozen=True)
class TrialSummary:
    trial: str
    frames: int
    rms_error_m: float
    max_error_m: float
    frames_dropped: int
    output: str
    error: str = ""

    def row(self) -> list:
        return [
            self.trial,
            self.frames,
            self.rms_error_m,
            self.max_error_m,
            self.frames_dropped,
            self.output,
            self.error,
        ]


def _summary(name: str, frames: int, errors: np.ndarray, output: str) -> TrialSummary:
    visible = np.isfinite(errors).any(axis=1)
    return TrialSummary(
        name, frames, float(np.sqrt(np.nanmean(errors**2))), float(np.nanmax(errors)), int((~visible).sum()), output
    )


@dataclass(frozen=True)
class Retargeted:
    """One trial's coordinates on a model and how well they fit its captured points.

    Attributes:
        motion: coordinates of ``model`` (markers: the IK solution; skeletons: filtered, in range, feet on y = 0).
        model: the model solved on: the given one for markers, the generic one scaled to the skeleton otherwise.
        errors: [T, P] distance of each tracked point from its model counterpart (m), NaN where not seen.
        factors: body -> (sx, sy, sz) for a skeleton (the scaling it was fitted with); None for markers.
    """

    motion: Motion
    model: BodyModel
    errors: np.ndarray
    factors: dict[str, tuple[float, float, float]] | None = None

    @property
    def point_kind(self) -> str:
        """ "marker" or "joint centre": what the errors measure."""
        return "marker" if self.factors is None else "joint centre"

    def summary(self, name: str, output: str) -> TrialSummary:
        """The ``summary.csv`` row of this trial."""
        return _summary(name, self.motion.n_frames, self.errors, output)


def retarget_markers(
    markers: Markers,
    model: BodyModel,
    *,
    weights: Mapping[str, float] | None = None,
    filter_hz: float | None = None,
    setup: IKSetup | None = None,
    source: str | Path | None = None,
) -> Retargeted:
    """Inverse kinematics of ``markers`` on ``model`` (the subject's scaled model), after an optional
    ``filter_hz`` low-pass of the markers; an OpenSim IK ``setup`` adds its coordinate tasks (``from_file`` values
    from its coordinate file) and its time range, as OpenSim's InverseKinematicsTool does. Markers whose size is
    not the model's (a wrong length unit, `check_marker_scale`) are refused, naming ``source``, their file."""
    check_marker_scale(markers, model, source)
    tasks, data, time_range = (), None, None
    if setup is not None:
        tasks, time_range = setup.coordinate_tasks, setup.time_range
        if any(task.value_type == "from_file" for task in tasks):
            source = setup.file("coordinate_file")
            if source is None or not source.exists():
                raise ConfigError(
                    f"{setup.path}: its coordinate tasks read values from a coordinate file, and "
                    f"{source or 'none'} is not there"
                )
            data = read_motion(source)
    if filter_hz:
        markers = markers.filtered(filter_hz)
    result = solve_ik(
        model,
        markers,
        weights=dict(weights) if weights else None,
        coordinate_tasks=tasks,
        coordinate_data=data,
        time_range=time_range,
    )
    return Retargeted(result.motion, model, result.errors)


def retarget_joint_centres(
    source: Markers, generic: BodyModel, joint_map: JointMap | None = None, *, filter_hz: float | None = None
) -> Retargeted:
    """``generic`` scaled to the skeleton whose joint centres ``source`` holds and fitted to them
    (`biomotion.ik.skeleton.retarget_skeleton`); ``filter_hz`` (default 10) low-passes the coordinates."""
    result = retarget_skeleton(source, generic, joint_map, cutoff_hz=FILTER_HZ if filter_hz is None else filter_hz)
    return Retargeted(result.motion, result.model, result.errors, dict(result.factors))


def read_capture(path: Path, time_range: tuple[float, float] | None = None) -> Markers:
    """The captured points of a trial file: markers (``.trc``, ``.c3d``; only ``time_range`` when given) or a
    skeleton's joint centres (``.bvh``, ``.bvh.gz``)."""
    return joint_positions(read_bvh(path)) if is_skeleton(path) else read_markers(path, time_range)


def _retarget_markers(
    path: Path,
    model: BodyModel,
    out: Path,
    name: str,
    weights: Mapping[str, float] | None,
    filter_hz: float | None,
    setup: IKSetup | None,
) -> TrialSummary:
    # the filter runs over the whole capture (its edges are not the window's), so only unfiltered reads are cut
    time_range = setup.time_range if setup is not None else None
    markers = read_markers(path, None if filter_hz else time_range)
    result = retarget_markers(markers, model, weights=weights, filter_hz=filter_hz, setup=setup, source=path)
    output = write_motion(out / f"{name}.mot", result.motion)
    return result.summary(name, output.name)


def _retarget_skeleton(
    path: Path,
    model: BodyModel,
    model_path: Path,
    out: Path,
    name: str,
    joint_map: JointMap | None,
    filter_hz: float | None,
) -> TrialSummary:
    result = retarget_joint_centres(read_capture(path), model, joint_map, filter_hz=filter_hz)
    write_scaled_model(model_path, out / f"{name}.osim", model, result.factors, name=name)
    output = write_motion(out / f"{name}.mot", result.motion)
    return result.summary(name, output.name)


def retarget(
    sources: Iterable[Path],
    model: BodyModel,
    out: Path,
    *,
    weights: Mapping[str, float] | None = None,
    filter_hz: float | None = None,
    joint_map: JointMap | None = None,
    model_path: Path | None = None,
    setup: IKSetup | None = None,
    progress: bool = True,
) -> list[TrialSummary]:
    """Retarget every file and write ``<trial>.mot`` (and ``<trial>.osim`` for skeletons) plus ``summary.csv``.

    Marker files are solved on ``model`` as it is (the subject's scaled model), with marker ``weights``
    (default: every model marker found in the data, weight 1) after an optional ``filter_hz`` low-pass of the
    markers (zero-lag Butterworth; the Fukuchi chain uses 10 Hz). An OpenSim IK ``setup`` adds what its tool
    would use besides the weights: its coordinate tasks (``from_file`` values from its coordinate file) and its
    time range, as OpenSim's InverseKinematicsTool does with that setup. BVH files, and marker files when a
    ``joint_map`` is given, are joint centres: ``model`` is the generic model scaled to each skeleton (it must
    have been read from ``model_path``, which the scaled copy is written from), and ``filter_hz`` (default 10)
    low-passes the coordinates. A trial that fails is recorded with its error and the batch goes on; malformed
    input still names its file and line.
    """
    out.mkdir(parents=True, exist_ok=True)
    summaries = []
    for path in tqdm(list(sources), desc="retargeting", unit="trial", disable=not progress):
        name = trial_name(path)
        try:
            if is_skeleton(path) or joint_map is not None:
                if model_path is None:
                    raise ConfigError("retargeting a skeleton writes the scaled model: give the model's file")
                summaries.append(_retarget_skeleton(path, model, model_path, out, name, joint_map, filter_hz))
            else:
                summaries.append(_retarget_markers(path, model, out, name, weights, filter_hz, setup))
        except BiomotionError as error:
            summaries.append(TrialSummary(name, 0, float("nan"), float("nan"), 0, "", str(error)))
    write_csv(out / "summary.csv", SUMMARY_COLUMNS, [s.row() for s in summaries])
    return summaries
