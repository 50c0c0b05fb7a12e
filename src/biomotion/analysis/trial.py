"""`analyze_trial`: the whole lab chain on one trial, in memory — captured points → joint angles (IK) → joint
torques and ground forces (ID, measured plates or inferred) → COM, ZMP, energy → muscle activations (SO).

This is what ``biomotion analyze`` runs, without its files: every stage is a pure function of the trial and the
model, and the result holds values only (numpy arrays and `Motion` objects, SI units). A trial arrives as
coordinates (an IK result), as markers (solved by batched inverse kinematics on the subject's scaled model,
`biomotion.ik.retarget.retarget_markers`) or as a skeleton's joint centres (the generic model scaled to the
skeleton and fitted to it, PG-BIG A.5, `biomotion.ik.retarget.retarget_joint_centres`). Inverse dynamics follows
OpenSim's ID tool (`biomotion.analysis.chain.analyze`); static optimization follows OpenSim's StaticOptimization
(`biomotion.analysis.activations`).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biomotion.analysis.activations import load_paths, trial_activations
from biomotion.analysis.chain import Analysis, GroundForceEstimator, analyze
from biomotion.body.contact import ContactSettings
from biomotion.body.model import BodyModel
from biomotion.errors import BiomotionWarning, ConfigError, DataFormatError
from biomotion.ik.retarget import Retargeted, retarget_joint_centres, retarget_markers
from biomotion.ik.skeleton import JointMap
from biomotion.io.formats import is_skeleton
from biomotion.io.setup import IKSetup
from biomotion.motion import GroundReaction, Motion
from biomotion.muscles.geometry import MusclePaths
from biomotion.muscles.static_optimization import StaticOptimizationResult
from biomotion.trial import Trial


@dataclass(frozen=True)
class TrialAnalysis:
    """What `analyze_trial` found, as values.

    Attributes:
        dynamics: torques, ground reaction (inferred, and measured when plates were given), COM, ZMP, energy, on
            the filtered coordinates (`biomotion.analysis.chain.Analysis`).
        fit: the inverse kinematics that made the coordinates from captured points (errors per frame and point,
            the model solved on); None when the trial came as coordinates.
        activations: static-optimization activations and reserves per frame; None unless muscles were asked for.
    """

    dynamics: Analysis
    fit: Retargeted | None = None
    activations: StaticOptimizationResult | None = None

    @property
    def angles(self) -> Motion:
        """Joint angles and translations (rad, m), filtered, in model order: the coordinates the torques used."""
        return self.dynamics.motion

    @property
    def torques(self) -> np.ndarray:
        """[T, n_q] generalized forces (N·m, N), OpenSim's ``<coordinate>_moment|_force`` order."""
        return self.dynamics.torques

    @property
    def ground_reaction(self) -> GroundReaction:
        """Per foot, the loads the torques used: the learned ground reaction when an estimator was given, else the
        measured plates assigned to the feet when given, else the ground force inferred from the motion alone
        (PhysPT Eq. 4-5). ``dynamics.torques_source`` says which."""
        if self.dynamics.learned is not None:
            return self.dynamics.learned
        return self.dynamics.measured if self.dynamics.measured is not None else self.dynamics.inferred

    @property
    def model(self) -> BodyModel:
        """The model analysed on (for a skeleton: the generic model scaled to it)."""
        return self.dynamics.model


def analyze_trial(
    trial: Trial,
    *,
    model: BodyModel,
    forces: GroundReaction | GroundForceEstimator | None = None,
    setup: IKSetup | None = None,
    marker_weights: Mapping[str, float] | None = None,
    marker_filter_hz: float | None = None,
    skeleton: bool | None = None,
    joint_map: JointMap | None = None,
    muscles: MusclePaths | str | Path | None = None,
    muscle_model: str | Path | None = None,
    forces_trim: bool = False,
    cutoff_hz: float = 6.0,
    contact: ContactSettings = ContactSettings(),
) -> TrialAnalysis:
    """The lab chain on ``trial`` (see the module docstring); no file is read or written.

    Args:
        trial: coordinates (``trial.motion``) are analysed as they are; otherwise ``trial.markers`` are solved by
            inverse kinematics on ``model`` first — or, for a skeleton (``skeleton=True``; by default when the
            trial was read from a BVH file), taken as joint centres and fitted with the generic ``model`` scaled to
            them (``joint_map``: which model joint each is; default the built-in map that fits their names).
        model: the subject's scaled model (for a skeleton: the generic model).
        forces: measured ground reaction (plates); default ``trial.forces``. Plates are assigned to the feet
            unless every channel names its body. Without plates the torques use the inferred ground reaction.
            Plates that do not cover the trial's time span are refused (frames without force would get none and
            wrong torques), unless ``forces_trim``, which analyses only the frames they cover, with a warning.
            Or a ground-force estimator (`biomotion.analysis.chain.GroundForceEstimator`), such as the learned
            model ``biomotion.learned_forces()``: the torques then use its forces, and ``trial.forces``, when
            present, are kept for comparison; the estimator refuses, on one line, a motion it cannot take.
        setup, marker_weights, marker_filter_hz: markers only: an OpenSim IK setup (its weights, coordinate tasks,
            time range), explicit weights (default: the setup's, else every model marker found weighs 1), a
            zero-lag low-pass of the markers (Hz); for a skeleton, ``marker_filter_hz`` low-passes the
            coordinates (default 10 Hz).
        muscles: path functions fitted on the model (`MusclePaths`, a ``.safetensors`` file, or a shipped name
            such as ``"rajagopal2016"``): adds static-optimization activations. ``muscle_model`` is the ``.osim``
            file whose muscle parameters are used (default: the file ``model`` was read from).
        cutoff_hz: low-pass of the coordinates before differentiation (OpenSim's ID tool; 0 to skip).
    """
    if isinstance(forces, str):
        raise ConfigError(
            f"forces={forces!r}: give plates (a GroundReaction), None (plates of the trial, else inferred), or a "
            "ground-force estimator such as biomotion.learned_forces() for learned forces"
        )
    estimator = None if forces is None or isinstance(forces, GroundReaction) else forces
    forces = trial.forces if forces is None or estimator is not None else forces
    if forces is not None:
        trial = forces_cover(trial, forces, setup=setup, trim=forces_trim)
    fit = None
    if trial.motion is not None:
        motion = trial.motion
        check_coordinates(motion, model, trial.source)
    elif trial.markers is not None:
        if skeleton or (skeleton is None and trial.source is not None and is_skeleton(trial.source)):
            fit = retarget_joint_centres(trial.markers, model, joint_map, filter_hz=marker_filter_hz)
        else:
            weights = marker_weights if marker_weights is not None else (setup.marker_weights if setup else None)
            fit = retarget_markers(
                trial.markers, model, weights=weights, filter_hz=marker_filter_hz, setup=setup, source=trial.source
            )
        motion, model = fit.motion, fit.model
    else:
        raise ConfigError(f"{trial.source or 'the trial'}: holds neither coordinates nor markers to analyse")
    dynamics = analyze(motion, model, forces, cutoff_hz=cutoff_hz, contact=contact, estimator=estimator)
    activations = None
    if muscles is not None:
        paths = load_paths(muscles)[0] if isinstance(muscles, (str, Path)) else muscles
        activations = trial_activations(dynamics, muscle_model or model.spec.path, paths)
    return TrialAnalysis(dynamics, fit, activations)


#: How far beyond its range (rad) a joint's angle may go before the file is taken to be in other units or corrupted:
#: IK results leave the ranges of unclamped coordinates by a few degrees, never by a full turn, while degrees read as
#: radians put a 60-degree knee at 60 rad. The joints between the ground and the root body (free joints) turn freely.
RANGE_SLACK = 2 * np.pi
#: The largest coordinate value (rad or m, after unit conversion) taken as a number at all: 1600 turns, 10 km.
COORDINATE_LIMIT = 1e4


def check_coordinates(motion: Motion, model: BodyModel, source: str | Path | None = None) -> None:
    """Refuse, with a `DataFormatError` naming ``source`` (the file), frame and column, coordinates that cannot be
    analysed on ``model``: none of the motion's columns is a coordinate of the model (the wrong model or file); a
    value beyond `COORDINATE_LIMIT` (a corrupted number); an angle of a joint other than a free one beyond its range
    by more than `RANGE_SLACK` (angles in degrees read as radians: a file whose ``inDegrees`` header is wrong)."""
    present = [name for name in motion.names if name in model.coordinate_names]
    if not present:
        shown = ", ".join(motion.names[:5]) + (" ..." if len(motion.names) > 5 else "")
        raise DataFormatError(
            source,
            f"none of its {len(motion.names)} columns ({shown}) is a coordinate of model {model.name!r}: "
            "coordinates of another model?",
        )
    ranges = model.ranges.detach().cpu().numpy()
    for name in present:
        column = motion.names.index(name)
        values = motion.values[:, column]
        index = model.coordinate_index(name)
        joint = model.joints[model.coordinate_joint[index]]
        low, high = (-COORDINATE_LIMIT, COORDINATE_LIMIT)
        rotational = model.motion_types[index] == "rotational"
        if rotational and joint.parent >= 0:
            low, high = max(low, ranges[index, 0] - RANGE_SLACK), min(high, ranges[index, 1] + RANGE_SLACK)
        outside = np.flatnonzero((values < low) | (values > high))
        if len(outside):
            frame = int(outside[0])
            value = float(values[frame])
            if abs(value) > COORDINATE_LIMIT:
                what = f"{value:.4g} is not a plausible coordinate value (a corrupted number?)"
            else:
                what = (
                    f"{value:.4g} rad ({np.degrees(value):.4g} deg) is more than a full turn beyond the joint's "
                    f"range [{ranges[index, 0]:.3g}, {ranges[index, 1]:.3g}] rad: angles in degrees read as radians? "
                    "(check the file's inDegrees header)"
                )
            raise DataFormatError(source, what, frame=frame, field=name)


def forces_cover(
    trial: Trial,
    forces: GroundReaction,
    *,
    setup: IKSetup | None = None,
    trim: bool = False,
    source: str | Path | None = None,
) -> Trial:
    """``trial`` if ``forces`` cover its time span (within half a force sample; markers: the ``setup``'s time range),
    else a `DataFormatError` naming both spans (and ``source``, the force file), or with ``trim`` the trial cut to
    the span the forces cover (a `BiomotionWarning` says so)."""
    series = trial.motion if trial.motion is not None else trial.markers
    if series is None:
        return trial
    times = series.times
    if setup is not None and setup.time_range is not None and trial.motion is None:
        times = times[(times >= setup.time_range[0] - 1e-9) & (times <= setup.time_range[1] + 1e-9)]
    if len(times) == 0:
        return trial
    start, stop = float(forces.times[0]), float(forces.times[-1])
    tolerance = 0.5 / forces.rate if forces.n_frames > 1 and np.isfinite(forces.rate) else 0.0
    if times[0] >= start - tolerance and times[-1] <= stop + tolerance:
        return trial
    where = f"the ground reaction covers {start:.3f}-{stop:.3f} s but the motion runs {times[0]:.3f}-{times[-1]:.3f} s"
    if not trim:
        raise DataFormatError(
            source,
            f"{where} (frames without force would get none): give forces covering the motion, "
            "or trim the motion to them (forces_trim=True, `--forces-trim`)",
        )
    low, high = max(float(times[0]), start), min(float(times[-1]), stop)
    if low > high:
        raise DataFormatError(source, f"{where}: they do not overlap")
    warnings.warn(f"{where}; only {low:.3f}-{high:.3f} s is analysed", BiomotionWarning, stacklevel=3)
    return trial.slice(low, high)
