"""Validation of muscle geometry and static optimization against OpenSim 4.6 (the oracle; needs ``opensim``).

`validate_muscles` returns the figures of the muscles issue:

- ``moment_arm_rmse_m``: worst RMSE over all (muscle, coordinate) pairs that OpenSim reports non-zero, between
  the shipped path functions and OpenSim's ``GeometryPath.computeMomentArm`` at fresh random poses in the sampled
  box (Rajagopal2016 and the gait2392 subject01 model); per-model detail alongside.
- ``so_r2_vs_opensim``: mean over muscles of R^2 between our activations and those of OpenSim's
  ``StaticOptimization`` analysis run fresh on the gait2392 subject01 walk (IK motion filtered at 6 Hz, the
  subject's model plus ``gait2392_SO_Residual_Actuators.xml``, GRF from ``subject01_walk1_grf.xml``, step
  interval 1, squared activations). Torques come from OpenSim's ``InverseDynamicsTool`` on the same motion and q,
  qdot from a ``Kinematics`` analysis run with the optimization, so both solvers get the same inputs.
- ``so_speedup``: OpenSim's SO wall time over ours (geometry, muscle forces and the batched solve), same frames;
- ``emg_onoff_agreement``: EMG on/off timing of the Rajagopal walk against our static optimization of the same
  trial (`biomotion.muscles.emg`), and the surrogate's under ``emg_onoff_agreement_surrogate``.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.errors import DataFormatError
from biomotion.muscles.emg import emg_check
from biomotion.muscles.geometry import MusclePaths, shipped_paths
from biomotion.muscles.properties import read_muscles
from biomotion.muscles.static_optimization import (
    StaticOptimizationResult,
    optimize_activations,
)

GAIT = "opensim-models/Pipelines/Gait2392_Simbody"
GAIT_MODEL = f"{GAIT}/OutputReference/subject01_simbody.osim"
RAJAGOPAL_MODEL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
RESIDUALS = {"pelvis_tilt": 80.0, "pelvis_list": 80.0, "pelvis_rotation": 80.0,
             "pelvis_tx": 100.0, "pelvis_ty": 200.0, "pelvis_tz": 100.0}   # see `gait_static_optimization`


def _read_sto(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "endheader")
    columns = lines[start + 1].split("\t")
    return columns, np.array([[float(v) for v in line.split()] for line in lines[start + 2:] if line.strip()])


def moment_arm_errors(paths: MusclePaths, model_path: str | Path, poses: int = 200, seed: int = 1,
                      muscles: list[str] | None = None) -> dict[tuple[str, str], float]:
    """RMSE (m) of ``paths``' moment arms against OpenSim's at ``poses`` random poses in the sampled box, for every
    (muscle, coordinate) pair whose OpenSim moment arm is non-zero (> 1e-4 m) at some pose."""
    from biomotion.muscles.fit_paths import OpenSimPaths

    oracle = OpenSimPaths(model_path)
    rng = np.random.default_rng(seed)
    q = oracle.sample_poses(paths.ranges.numpy(), poses, rng)
    names = muscles or list(paths.muscle_names)
    spanned = paths.spanned()
    candidates = [i for i in range(paths.n_q) if i not in oracle.dependent and not torch.isnan(paths.ranges[i, 0])]
    pairs = [(oracle.muscle_names.index(m), c) for m in names for c in candidates]
    reference = oracle.moment_arms(q, pairs)                                             # [N, P]
    ours = paths.moment_arms(torch.from_numpy(q)).numpy()
    errors = {}
    for p, (m, c) in enumerate(pairs):
        if np.abs(reference[:, p]).max() <= 1e-4:
            continue
        row = paths.muscle_names.index(oracle.muscle_names[m])
        estimate = ours[:, row, c] if spanned[row, c] else np.zeros(len(q))
        errors[(oracle.muscle_names[m], oracle.coordinate_names[c])] = float(
            np.sqrt(((estimate - reference[:, p]) ** 2).mean()))
    return errors


@dataclass(frozen=True)
class OpenSimStaticOptimization:
    times: np.ndarray            # [T]
    muscle_names: tuple[str, ...]
    activations: np.ndarray      # [T, M]
    coordinate_names: tuple[str, ...]
    q: np.ndarray                # [T, n_q] rad / m, the states OpenSim's SO used
    qdot: np.ndarray             # [T, n_q]
    torques: np.ndarray          # [T, n_q] OpenSim inverse dynamics of the same motion
    seconds: float               # wall time of OpenSim's SO run (AnalyzeTool.run)


def opensim_gait_static_optimization(data_root: str | Path, start: float, end: float,
                                     workdir: str | Path | None = None) -> OpenSimStaticOptimization:
    """Run OpenSim's StaticOptimization and InverseDynamicsTool on the gait2392 subject01 walk over
    [start, end] s (setup as in the module docstring) and read back what they produced."""
    import opensim

    opensim.Logger.setLevelString("error")
    data_root = Path(data_root).resolve()   # OpenSim resolves setup-file paths relative to the setup file
    root = data_root / GAIT
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        out = Path(tmp)
        tool = opensim.AnalyzeTool()
        tool.setName("so")
        tool.setModelFilename(str(Path(data_root) / GAIT_MODEL))
        force_sets = opensim.ArrayStr()
        force_sets.append(str(root / "gait2392_SO_Residual_Actuators.xml"))
        tool.setForceSetFiles(force_sets)
        tool.setReplaceForceSet(False)
        tool.setCoordinatesFileName(str(root / "subject01_walk1_ik.mot"))
        tool.setLowpassCutoffFrequency(6)
        tool.setExternalLoadsFileName(str(root / "subject01_walk1_grf.xml"))
        tool.setInitialTime(start)
        tool.setFinalTime(end)
        tool.setResultsDir(str(out))
        so = opensim.StaticOptimization()
        so.setStartTime(start)
        so.setEndTime(end)
        so.setStepInterval(1)
        so.setUseModelForceSet(True)
        so.setActivationExponent(2)
        so.setUseMusclePhysiology(True)
        tool.getAnalysisSet().cloneAndAppend(so)
        kinematics = opensim.Kinematics()
        kinematics.setInDegrees(False)
        kinematics.setStepInterval(1)
        tool.getAnalysisSet().cloneAndAppend(kinematics)
        tool.printToXML(str(out / "so_setup.xml"))
        runner = opensim.AnalyzeTool(str(out / "so_setup.xml"))
        tic = time.perf_counter()
        runner.run()
        seconds = time.perf_counter() - tic

        inverse = opensim.InverseDynamicsTool()
        inverse.setName("id")
        inverse.setModelFileName(str(Path(data_root) / GAIT_MODEL))
        inverse.setCoordinatesFileName(str(root / "subject01_walk1_ik.mot"))
        inverse.setLowpassCutoffFrequency(6)
        inverse.setExternalLoadsFileName(str(root / "subject01_walk1_grf.xml"))
        inverse.setStartTime(start)
        inverse.setEndTime(end)
        excluded = opensim.ArrayStr()
        excluded.append("Muscles")
        inverse.setExcludedForces(excluded)
        inverse.setResultsDir(str(out))
        inverse.setOutputGenForceFileName("id.sto")
        inverse.printToXML(str(out / "id_setup.xml"))
        opensim.InverseDynamicsTool(str(out / "id_setup.xml")).run()

        columns, activations = _read_sto(out / "so_StaticOptimization_activation.sto")
        q_columns, q = _read_sto(out / "so_Kinematics_q.sto")
        u_columns, u = _read_sto(out / "so_Kinematics_u.sto")
        id_columns, torques = _read_sto(out / "id.sto")
    coordinates = tuple(q_columns[1:])
    muscles = tuple(n for n in columns[1:] if n not in RESIDUALS and n not in ("FX", "FY", "FZ", "MX", "MY", "MZ"))
    picks = [columns.index(n) for n in muscles]
    id_index = {n.rsplit("_", 1)[0]: i for i, n in enumerate(id_columns)}
    n = min(len(activations), len(q), len(torques))
    for name, table in (("Kinematics", q), ("inverse dynamics", torques)):
        if not np.allclose(table[:n, 0], activations[:n, 0], atol=1e-5):
            raise DataFormatError(None, f"OpenSim's {name} frames do not line up with its static optimization",
                                  field="time")
    return OpenSimStaticOptimization(activations[:n, 0], muscles, activations[:n, picks], coordinates,
                                     q[:n, 1:], u[:n, [u_columns.index(c) for c in coordinates]],
                                     torques[:n, [id_index[c] for c in coordinates]], seconds)


def gait_static_optimization(data_root: str | Path, reference: OpenSimStaticOptimization,
                             paths: MusclePaths | None = None) -> tuple[StaticOptimizationResult, float]:
    """Our SO on the inputs of ``reference`` (gait2392 subject01) and its wall time (s). The pelvis residuals of
    ``gait2392_SO_Residual_Actuators.xml`` (FX/FY/FZ 100/200/100 N, MX/MY/MZ 80 N·m, controls in [-1, 1]) act
    only on the six pelvis coordinates, which no muscle spans, so they are modelled as reserves there: the muscle
    problem is unchanged."""
    paths = paths or shipped_paths("gait2392_subject01")
    muscles = read_muscles(Path(data_root) / GAIT_MODEL)
    columns = paths.select(reference.coordinate_names)
    q = torch.zeros(len(reference.q), paths.n_q, dtype=torch.float64)
    qdot = torch.zeros_like(q)
    q[:, columns] = torch.from_numpy(reference.q)
    qdot[:, columns] = torch.from_numpy(reference.qdot)
    torques = torch.from_numpy(reference.torques)
    tic = time.perf_counter()
    result = optimize_activations(paths, muscles, q, qdot, torques, reference.coordinate_names, RESIDUALS)
    return result, time.perf_counter() - tic


def r_squared(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-column coefficient of determination of ``estimate`` against ``reference`` [T, K]."""
    total = ((reference - reference.mean(0)) ** 2).sum(0)
    return 1 - ((estimate - reference) ** 2).sum(0) / np.maximum(total, 1e-12)


def validate_muscles(data_root: str | Path, poses: int = 200, start: float = 0.5, end: float = 2.5) -> dict:
    """The muscles issue's figures (see module docstring) computed fresh against OpenSim."""
    data_root = Path(data_root)
    os.environ.setdefault("OMP_NUM_THREADS", "2")
    geometry = {}
    for name, model in (("rajagopal2016", RAJAGOPAL_MODEL), ("gait2392_subject01", GAIT_MODEL)):
        errors = moment_arm_errors(shipped_paths(name), data_root / model, poses)
        worst = max(errors, key=errors.get)
        geometry[name] = {"pairs": len(errors), "worst_rmse_m": errors[worst], "worst_pair": list(worst),
                          "mean_rmse_m": float(np.mean(list(errors.values()))),
                          "pairs_over_2mm": sorted(f"{m}/{c}" for (m, c), e in errors.items() if e > 2e-3)}
    reference = opensim_gait_static_optimization(data_root, start, end)
    gait_static_optimization(data_root, reference)               # warm-up: first-call costs of torch
    result, seconds = gait_static_optimization(data_root, reference)
    ours = result.activations.numpy()[:, [result.muscle_names.index(m) for m in reference.muscle_names]]
    r2 = r_squared(ours, reference.activations)
    return {
        "moment_arm_rmse_m": max(g["worst_rmse_m"] for g in geometry.values()),
        "moment_arms": geometry,
        "so_r2_vs_opensim": float(r2.mean()),
        "so_r2_min": float(r2.min()),
        "so_r2_worst_muscle": reference.muscle_names[int(r2.argmin())],
        "so_frames": len(reference.times),
        "so_converged_frames": int(result.converged.sum()),
        "so_activation_rmse": float(np.sqrt(((ours - reference.activations) ** 2).mean())),
        "so_seconds_opensim": reference.seconds,
        "so_seconds_biomotion": seconds,
        "so_speedup": reference.seconds / seconds,
        "reserve_usage": result.reserve_usage(),
        **emg_check(data_root),
    }
