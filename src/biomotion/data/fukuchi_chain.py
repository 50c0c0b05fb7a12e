"""Fukuchi 2017 running: the source's own processing chain, reproduced and checked against its shipped IK.

Reference: ``fukuchi-running/SOURCE.md`` ("Processing chain", "Known quirks") and the scripts of the source
repository it names (``aaronsfox/pfjrf-methods``: ``data/extract_data.py``, ``data/process_data.py``). Per runner:

1. Static trial (``c3d/<r>static.c3d``): the C3D markers in metres, unfiltered, as the source wrote them to its
   static TRC (it filtered only the running trials; the static trials have no gaps).
2. Scaling of the **complex** generic model (``generic-models/Uhlrich2022_LowerLimb_Fukuchi2017.osim``) with
   `biomotion.ik.scaling.scale_static`: ScaleTool measurements over the whole static trial, mass distribution
   preserved, total mass from ``participantInfo.csv`` (the setup's ``<mass>``, the same number, when the table
   lacks the runner), then marker placement on the averaged static frames. The complex setup was not shipped,
   but the source built both setups in one script from one measurement set and one placer task set, leaving out
   of the simple setup only the ``r_patella``/``l_patella`` measurements (pair GTR-Knee onto patella X Y Z). So
   ``<r>/<r>_scaleSetup_simple.xml`` is read and those two are added back (`complex_scale_setup`); the patella
   carries no marker and ends its chain, so they move no marker. With them our factors equal the source's
   ``RBDS001_scaleSet_complex.xml`` to its 6 digits.
3. Placement objective (`assembler_weights`): OpenSim's MarkerPlacer solves the static pose with Simbody's
   Assembler, whose marker goal is 1/2 sum w r^2 / sum w but whose gradient of it is twice that (``Markers::
   calcGoalGradient`` divides by sum w, not 2 sum w), so the optimizer stops where the coordinate tasks weigh half
   what `biomotion.ik.markers.solve_ik` gives them. The placer's coordinate-task weights are therefore halved
   here: OpenSim 4.6's InverseKinematicsSolver at accuracy 1e-8 on the RBDS001 and RBDS05 static trials then
   equals our pose within 1e-4 rad (at the tool's full weights the two differ by up to 1.4 deg). The T35 IK
   setups have no coordinate task, so only placement is concerned.
4. Welds: the source replaced ``mtp_r/l`` and ``subtalar_r/l`` by weld joints with coinciding frames (OpenSim's
   ``ModOpReplaceJointsWithWelds``), i.e. ``mtp_angle_*`` and ``subtalar_angle_*`` at 0. The generic model
   already locks them at a default of 0, so placement saw that pose too; `weld` makes it explicit before scaling.
5. Running trial (``c3d/<r>runT35.c3d``, `running_markers`): exact zeros are gaps; every coordinate column with
   a gap is fitted, on its visible samples in mm, with scipy's cubic smoothing spline (``UnivariateSpline``,
   k = 3, s = 2 mm^2) whose values fill the gap; then every column gets a 4th-order Butterworth low-pass at
   10 Hz, zero-lag. Labels are used as recorded: RBDS001 T35's swapped R.MT1/R.MT5 ("Known quirks") stay
   swapped, as the shipped IK was solved from them.
6. IK (`solve_ik`) on the scaled, placed, welded model with the marker weights of ``<r>/<r>_T35_ikSetup.xml``,
   on the frames OpenSim's IK tool takes for its time window: from the frame nearest its start to the frame
   nearest its end (`window`). Clamped coordinates stay in range; knee flexion stops at 120 deg.
7. Simple-model columns (`as_simple`): ``knee_angle_r/l_beta`` dropped, ``knee_angle_r/l`` sign-flipped.

`fukuchi_chain` compares step 7 with ``ik/T35/<r>_T35_ik_simple.mot`` frame by frame: RMSE and mean error per
coordinate (deg for rotations, m for the pelvis translations). `validate_fukuchi_chain` runs every runner under
the data root that has the files; ``fukuchi_ik_rmse_deg`` is the worst rotational-coordinate RMSE over them,
``fukuchi_ik_rmse_m`` the worst translational one.

What is left (measured on the 9 runners with a T35 C3D): the source's placement stopped short of its optimum
(the MarkerPlacer calls the Assembler at its default accuracy, 1e-4; a fresh OpenSim 4.6 ScaleTool run repeats
the source's static pose to 1e-5 rad), leaving static joint angles up to 2.5 deg (RBDS05 knee) from the optimum
and the placed markers up to 5 mm (median 1-2 mm) from ours; that offset carries into every IK frame, so the
remaining error is mostly a constant bias per coordinate. Solved on OpenSim's own placed markers, this IK
matches the shipped files within 0.55 deg on all 9 runners (in pelvis tilt against hip flexion, the flattest
direction of the objective, where OpenSim's IK also stops short, by about 0.3 deg).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import scipy.interpolate
import torch

from biomotion.body.model import BodyModel
from biomotion.errors import DataFormatError
from biomotion.ik.markers import IKResult, solve_ik
from biomotion.ik.scaling import scale_static
from biomotion.io.c3d import read_c3d_markers
from biomotion.io.mot import read_motion
from biomotion.io.setup import Measurement, ScaleSetup, read_ik_setup, read_scale_setup
from biomotion.io.tables import read_subject_table
from biomotion.motion import Markers, Motion, is_translation, lowpass

FUKUCHI = "fukuchi-running"
COMPLEX_MODEL = "generic-models/Uhlrich2022_LowerLimb_Fukuchi2017.osim"
SUBJECTS = "participantInfo.csv"
MARKER_FILTER_HZ = 10.0  # the source's marker low-pass
SPLINE_SMOOTHING_MM2 = 2.0  # the source's UnivariateSpline ``s``, on data in mm
WELDED = ("mtp_angle_r", "mtp_angle_l", "subtalar_angle_r", "subtalar_angle_l")
KNEES = ("knee_angle_r", "knee_angle_l")
#: the complex setup's measurements that the simple one leaves out (source ``process_data.py``)
PATELLA = (
    Measurement("r_patella", (("R.GTR", "R.Knee"),), (("patella_r", "XYZ"),)),
    Measurement("l_patella", (("L.GTR", "L.Knee"),), (("patella_l", "XYZ"),)),
)


def runner_files(base: Path, runner: str, speed: str = "T35") -> dict[str, Path]:
    """The files the chain needs for one runner's trial at ``speed`` (``T25``, ``T35``, ``T45``), under the
    ``fukuchi-running`` folder ``base``; ``reference`` is the shipped IK it is compared with."""
    return {
        "generic": base / COMPLEX_MODEL,
        "scale_setup": base / runner / f"{runner}_scaleSetup_simple.xml",
        "ik_setup": base / runner / f"{runner}_{speed}_ikSetup.xml",
        "static": base / "c3d" / f"{runner}static.c3d",
        "trial": base / "c3d" / f"{runner}run{speed}.c3d",
        "reference": base / "ik" / speed / f"{runner}_{speed}_ik_simple.mot",
    }


def running_markers(path: Path, cutoff_hz: float = MARKER_FILTER_HZ) -> Markers:
    """A running C3D's markers as the source's TRC had them: spline-filled gaps, 10 Hz low-pass (step 5);
    ``cutoff_hz`` sets another low-pass (the chain keeps the source's)."""
    markers = read_c3d_markers(path, zero_is_missing=True)
    flat = markers.positions.reshape(markers.n_frames, -1) * 1000.0  # mm, one column per coordinate
    for column in np.flatnonzero(np.isnan(flat).any(axis=0)):
        seen = np.isfinite(flat[:, column])
        if seen.sum() > 3:
            spline = scipy.interpolate.UnivariateSpline(
                markers.times[seen], flat[seen, column], k=3, s=SPLINE_SMOOTHING_MM2
            )
            flat[~seen, column] = spline(markers.times[~seen])
    smooth = lowpass(flat, markers.rate, cutoff_hz) / 1000.0
    return dataclasses.replace(markers, positions=smooth.reshape(markers.positions.shape))


def complex_scale_setup(simple: ScaleSetup) -> ScaleSetup:
    """The complex model's ScaleTool setup: the simple one plus the patella measurements (step 2)."""
    return dataclasses.replace(simple, measurements=simple.measurements + PATELLA)


def assembler_weights(setup: ScaleSetup) -> ScaleSetup:
    """``setup`` with its placer coordinate-task weights halved: the objective OpenSim's placement converges on
    (step 3)."""
    tasks = tuple(dataclasses.replace(task, weight=task.weight / 2) for task in setup.placer_tasks.coordinate_tasks)
    return dataclasses.replace(setup, placer_tasks=dataclasses.replace(setup.placer_tasks, coordinate_tasks=tasks))


def weld(model: BodyModel, names: tuple[str, ...] = WELDED) -> BodyModel:
    """``model`` with the named coordinates locked at 0: their joints as welds with coinciding frames."""
    index = torch.tensor([model.coordinate_index(name) for name in names])
    locked, defaults = model.locked.clone(), model.defaults.clone()
    locked[index] = True
    defaults[index] = 0.0
    return dataclasses.replace(model, locked=locked, defaults=defaults)


def subject_mass(base: Path, runner: str) -> float | None:
    """The runner's mass (kg) from ``participantInfo.csv``; None when the table or its row is absent."""
    table = base / SUBJECTS
    profile = read_subject_table(table).get(runner) if table.exists() else None
    return None if profile is None else profile.mass


def complex_model(base: Path, runner: str) -> BodyModel:
    """The runner's scaled, marker-placed, welded complex model (steps 1-4)."""
    files = runner_files(base, runner)
    setup = assembler_weights(complex_scale_setup(read_scale_setup(files["scale_setup"])))
    generic = weld(BodyModel.from_osim(files["generic"]))
    static = read_c3d_markers(files["static"], zero_is_missing=True)
    return scale_static(generic, static, setup, mass=subject_mass(base, runner)).model


def window(times: np.ndarray, time_range: tuple[float, float]) -> tuple[float, float]:
    """The first and last frame times OpenSim's IK tool solves for ``time_range``: the frames nearest its ends."""
    nearest = np.abs(times[:, None] - np.asarray(time_range)[None, :]).argmin(axis=0)
    return float(times[nearest[0]]), float(times[nearest[1]])


def as_simple(motion: Motion) -> Motion:
    """The complex model's coordinates as the simple model's: knee betas dropped, knee angles negated (step 7)."""
    kept = [name for name in motion.names if not name.endswith("_beta")]
    out = motion.select(kept)
    return out.with_values(out.values * np.where(np.isin(kept, KNEES), -1.0, 1.0))


def solve_trial(
    base: Path, runner: str, speed: str = "T35", marker_cutoff_hz: float = MARKER_FILTER_HZ
) -> tuple[IKResult, BodyModel]:
    """Steps 1-6 for one running trial: the IK result on the runner's complex model, and that model
    (``marker_cutoff_hz``: the markers' low-pass, the source's 10 Hz unless given)."""
    files = runner_files(base, runner, speed)
    model = complex_model(base, runner)
    setup = read_ik_setup(files["ik_setup"])
    markers = running_markers(files["trial"], marker_cutoff_hz)
    return solve_ik(
        model,
        markers,
        weights=setup.marker_weights,
        coordinate_tasks=setup.coordinate_tasks,
        time_range=window(markers.times, setup.time_range),
    ), model


def fukuchi_chain(data_root: Path, runner: str) -> dict:
    """Run the chain (module docstring) for one runner's 3.5 m/s trial and compare it with the shipped
    ``ik/T35/<runner>_T35_ik_simple.mot`` on that file's frames.

    Returns:
        ``coordinate_rmse`` and ``coordinate_bias`` (mean of ours minus shipped) per column of the shipped file,
        in deg for rotations and m for translations; ``rmse_deg`` / ``rmse_m``, the worst of each kind;
        ``marker_rmse_m``, our IK's marker RMS error; ``knee_clamped_frames``, frames where our knee flexion
        sits at its 120 deg limit; ``frames``; ``seconds``, the whole chain's wall time.
    """
    began = time.perf_counter()
    base = Path(data_root) / FUKUCHI
    files = runner_files(base, runner)
    ik, model = solve_trial(base, runner)
    reference = read_motion(files["reference"])
    ours = as_simple(ik.motion).select(reference.names)
    if ours.n_frames != reference.n_frames or not np.allclose(ours.times, reference.times, atol=1e-4):
        raise DataFormatError(
            files["reference"],
            f"its {reference.n_frames} frames "
            f"({reference.times[0]}-{reference.times[-1]} s) are not the "
            f"{ours.n_frames} frames the IK setup's window selects",
        )
    error = ours.values - reference.values
    translational = np.array([is_translation(name) for name in reference.names])
    unit = np.where(translational, 1.0, np.degrees(1.0))
    rmse = np.sqrt(np.mean(error**2, axis=0)) * unit
    bias = error.mean(axis=0) * unit
    knees = [model.coordinate_index(name) for name in KNEES]
    at_limit = (ik.motion.values[:, knees] >= model.ranges[knees, 1].numpy() - 1e-6).any(axis=1)
    return {
        "coordinate_rmse": {name: round(float(v), 6) for name, v in zip(reference.names, rmse)},
        "coordinate_bias": {name: round(float(v), 6) for name, v in zip(reference.names, bias)},
        "rmse_deg": round(float(rmse[~translational].max()), 4),
        "rmse_m": round(float(rmse[translational].max()), 6),
        "marker_rmse_m": round(ik.rmse, 6),
        "knee_clamped_frames": int(at_limit.sum()),
        "frames": int(reference.n_frames),
        "seconds": round(time.perf_counter() - began, 2),
    }


def validate_fukuchi_chain(data_root: Path, runners: list[str] | None = None) -> dict:
    """`fukuchi_chain` on ``runners`` (default: every runner with a T35 C3D under the data root) that have every
    file `runner_files` names; the others are listed under ``skipped`` with the files they lack.

    Returns ``fukuchi_ik_rmse_deg`` / ``fukuchi_ik_rmse_m`` (the worst over the runners run; None when none ran),
    ``fukuchi_chain`` (runner -> `fukuchi_chain` detail) and ``skipped``.
    """
    base = Path(data_root) / FUKUCHI
    if runners is None:
        runners = sorted(p.name.removesuffix("runT35.c3d") for p in (base / "c3d").glob("*runT35.c3d"))
    detail: dict[str, dict] = {}
    skipped: list[str] = []
    for runner in runners:
        missing = [str(path.relative_to(base)) for path in runner_files(base, runner).values() if not path.exists()]
        if missing:
            skipped.append(f"{FUKUCHI}/{runner}: no {', '.join(missing)}")
            continue
        detail[runner] = fukuchi_chain(data_root, runner)
    return {
        "fukuchi_ik_rmse_deg": max((d["rmse_deg"] for d in detail.values()), default=None),
        "fukuchi_ik_rmse_m": max((d["rmse_m"] for d in detail.values()), default=None),
        "fukuchi_chain": detail,
        "skipped": skipped,
    }
