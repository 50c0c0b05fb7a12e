"""``biomotion retarget``: captured markers (TRC, C3D) → coordinates of a model, one trial or a folder of them.

Each trial is solved by `biomotion.ik.markers.solve_ik` (all frames at once) and written as an OpenSim ``.mot``;
a batch keeps going past a bad trial and writes ``summary.csv`` with one row per trial: frames, RMS and maximum
marker error, frames where no tracked marker was visible (dropped), and the error if the trial failed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np
from tqdm import tqdm

from biomotion.body.model import BodyModel
from biomotion.errors import BiomotionError, ConfigError
from biomotion.ik.markers import solve_ik
from biomotion.io.c3d import read_c3d_markers
from biomotion.io.mot import write_motion
from biomotion.io.tables import write_csv
from biomotion.io.trc import read_trc
from biomotion.motion import Markers

MARKER_SUFFIXES = (".trc", ".c3d")
SUMMARY_COLUMNS = ["trial", "frames", "rms_error_m", "max_error_m", "frames_dropped", "output", "error"]


def read_markers(path: Path) -> Markers:
    """Markers of a ``.trc`` or ``.c3d`` file, in metres (C3D exact zeros are gaps)."""
    if path.suffix.lower() == ".c3d":
        return read_c3d_markers(path)
    return read_trc(path)


def marker_files(source: Path) -> list[Path]:
    """``source`` itself, or every TRC/C3D file in the folder ``source`` (sorted)."""
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in MARKER_SUFFIXES)
        if not files:
            raise ConfigError(f"{source}: no .trc or .c3d files to retarget")
        return files
    if source.suffix.lower() not in MARKER_SUFFIXES:
        raise ConfigError(f"{source}: retarget reads .trc and .c3d marker files (BVH retargeting is not available yet)")
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
        return [self.trial, self.frames, self.rms_error_m, self.max_error_m, self.frames_dropped, self.output,
                self.error]


def retarget(sources: Iterable[Path], model: BodyModel, out: Path, *, weights: Mapping[str, float] | None = None,
             filter_hz: float | None = None, progress: bool = True) -> list[TrialSummary]:
    """Solve IK for every marker file and write ``<trial>.mot`` plus ``summary.csv`` into ``out``.

    ``weights`` are marker weights (default: every model marker found in the data, weight 1); ``filter_hz``
    low-passes the markers first (zero-lag Butterworth; the Fukuchi chain uses 10 Hz). A trial that fails is
    recorded with its error and the batch goes on; malformed input still names its file and line.
    """
    out.mkdir(parents=True, exist_ok=True)
    summaries = []
    for path in tqdm(list(sources), desc="retargeting", unit="trial", disable=not progress):
        name = path.name.removesuffix(path.suffix)
        try:
            markers = read_markers(path)
            if filter_hz:
                markers = markers.filtered(filter_hz)
            result = solve_ik(model, markers, weights=dict(weights) if weights else None)
            output = write_motion(out / f"{name}.mot", result.motion)
            visible = np.isfinite(result.errors).any(axis=1)
            summaries.append(TrialSummary(name, result.motion.n_frames, float(result.rmse),
                                          float(np.nanmax(result.errors)), int((~visible).sum()), output.name))
        except BiomotionError as error:
            summaries.append(TrialSummary(name, 0, float("nan"), float("nan"), 0, "", str(error)))
    write_csv(out / "summary.csv", SUMMARY_COLUMNS, [s.row() for s in summaries])
    return summaries
