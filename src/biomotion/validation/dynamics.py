"""``biomotion validate kinematics|dynamics``: the body model against OpenSim 4.6, and GRF from kinematics against
force plates.

Figures (keys of the JSON report):
- ``fk_max_err_m``: max body-origin (and marker) error vs OpenSim over random in-range poses of every model found;
- ``id_solver_max_err_nm``: our inverse dynamics vs OpenSim's InverseDynamicsSolver given identical q, q̇, q̈ and
  external loads (gait2392 subject01 walk, the trials of OpenCap Subject4 and of any other subject under
  ``opencap/``, each plate applied to the foot `biomotion.analysis.chain.plate_feet` finds on it);
- ``id_ref_rmse_rel``: end to end (our filtering and differentiation vs OpenSim's InverseDynamicsTool run fresh on
  the same model, coordinates, GRF and 6 Hz filter): RMSE / peak |moment| per coordinate whose peak > 10 N·m;
- ``grf_vertical_r2``, ``grf_vertical_rmse_bw``, ``grf_com_baseline_rmse_bw``: vertical GRF inferred from
  kinematics vs the plates, over all evaluated frames of the Fukuchi T35 runners (their shipped IK, or for a
  runner with only captures, the C3D solved by the source's own chain) and the OpenCap trials;
- ``*_plates_filtered``: the same against the plates' vertical force low-passed exactly as the coordinates are
  (`Motion.smoothed` at the evaluation's cutoff). The GRF bar's runner-1 baseline (R² 0.976, RMSE 0.152 BW
  at 10 Hz) is stated without saying what was done to the plates; on RBDS001 the baseline reads 0.172 BW against
  the raw plates and 0.158 against plates filtered this way, so that figure was most likely measured against
  filtered plates. The bar figures above stay on the raw plates, the measurement itself; these are beside them.
- ``grf_learned_shipped_*``: the same vertical GRF from the shipped learned ground reaction
  (`biomotion.models.ground_forces`, ``checkpoints/ground_forces.safetensors``) on the same frames, beside the
  physics-only rows: ``_held_out`` pools the trials of people it was never trained on (OpenCap, and any Fukuchi
  runner missing from its ``train_subjects``), ``_trained_on`` the Fukuchi runners it was trained on, where it is
  not a held-out figure (``biomotion eval ground-forces`` gives the leave-subject-out ones). Left out, and said
  so, when no shipped weights are present.
- ``zmp_cop_rmse_m`` (and ``zmp_cop_rmse_m_per_source``): the ZMP from kinematics against the plates' combined
  centre of pressure on the same trials (`biomotion.analysis.chain.zmp_to_plate_cop`), the real-data check of the ZMP
  that the balance metrics use. Not a bar.

Clock rule: IK and plates share the capture clock in both sources (Fukuchi IK times come from the C3D, OpenCap's
``_ik.mot`` and ``_grf.mot`` share their time base), so no offset is applied or estimated. (Checked without the
plates: the Fukuchi model markers posed by the IK match the C3D markers best at zero frame offset. The shift
that would minimise the GRF error is −4 to −8 ms on the Fukuchi runners and +4 to +6 ms on OpenCap: no one
physical lag explains both, and taking it from the plates would fit the test frames.) Frame rule for the GRF comparison
(`biomotion.analysis.chain.plate_frames`): frames where a foot the kinematics put on a support — the floor (lowest
contact point within 2 cm of its rest height, vertical speed below 0.2 m/s) or a level where that foot stood
still for 0.1 s without load on the plates (the drop-jump box) — carries < 20 N on the plates are left out: that
foot is beside the plates (overground walking) or on something they do not measure, so the plate total is
incomplete there. The rule uses no fitted quantity. Sit-to-stand trials are not in the GRF comparison (the bar
names drop jumps, squats and walking): the chair carries weight that no plate measures and that a feet-only
contact model cannot place.
"""

from __future__ import annotations

import hashlib
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from biomotion.analysis.chain import (
    analyze,
    model_motion,
    plate_feet,
    plate_frames,
    torque_labels,
    unwrapped,
    vertical_agreement,
    zmp_to_plate_cop,
)
from biomotion.body.dynamics import ExternalLoad, inverse_dynamics
from biomotion.body.kinematics import forward_kinematics, marker_positions
from biomotion.body.model import BodyModel
from biomotion.data.sources import OPENCAP_MODEL_FILE
from biomotion.io.c3d import read_c3d_forces
from biomotion.io.mot import (
    read_ground_reaction,
    read_motion,
    read_storage,
    torque_columns,
    write_external_loads_xml,
    write_ground_reaction,
    write_motion,
)
from biomotion.motion import GroundReaction, Motion
from biomotion.validation.oracle import Oracle, opensim, random_poses, run_inverse_dynamics_tool

#: Models the kinematics check covers, as globs under the data root (whatever subjects are present are used).
MODEL_GLOBS = (
    "opensim-models/Models/Rajagopal/Rajagopal2016.osim",
    "opensim-models/Models/Rajagopal/RajagopalLaiUhlrich2023.osim",
    "opensim-models/Models/Gait2392_Simbody/subject01.osim",
    "opensim-models/Pipelines/Gait2392_Simbody/OutputReference/subject01_simbody.osim",
    "fukuchi-running/*/*_simple.osim",
    "fukuchi-running/generic-models/*.osim",
    "opencap/*/Models/*.osim",
    "Hamner2013/*/*.osim",
    "SchreiberMoissenet2019/*/*.osim",
)

GAIT = "opensim-models/Pipelines/Gait2392_Simbody/"
OPENCAP = "opencap"


def check_forward_kinematics(data_root: Path, poses_per_model: int = 3, progress: bool = True) -> dict:
    """Max body-origin and marker error vs OpenSim over random in-range poses of every model present."""
    paths = [p for pattern in MODEL_GLOBS for p in sorted(data_root.glob(pattern))]
    rng = np.random.default_rng(0)
    per_model, worst = {}, 0.0
    for path in tqdm(paths, desc="FK vs OpenSim", unit="model", disable=not progress):
        model, oracle = BodyModel.from_osim(path), Oracle(path)
        q = random_poses(model, rng, poses_per_model)
        poses = forward_kinematics(model, torch.tensor(q))
        markers = marker_positions(model, torch.tensor(q), poses)
        error = 0.0
        for k in range(poses_per_model):
            oracle.set(q[k])
            _, origins = oracle.body_poses()
            error = max(error, float(np.abs(poses.positions[k].numpy() - origins).max()))
            if model.marker_names:
                error = max(error, float(np.abs(markers[k].numpy() - oracle.markers()).max()))
        per_model[str(path.relative_to(data_root))] = error
        worst = max(worst, error)
    return {
        "fk_max_err_m": worst if paths else None,  # None, not 0: no model, nothing measured
        "fk_models": len(paths),
        "fk_per_model_max_err_m": per_model,
    }


def _opensim_external_force(osim, storage, channel: str, body: str, labels: tuple[str, ...]):
    """An OpenSim ExternalForce for a GRF channel, with the torque columns named as in the file."""
    torque = torque_columns(channel, labels)
    torque_identifier = torque[0][:-1] if torque else f"{channel.replace('force', 'torque')}_"
    force = osim.ExternalForce(storage, f"{channel}_v", f"{channel}_p", torque_identifier, body, "ground", "ground")
    force.setName(f"{channel}_on_{body}")
    return force


def _id_solver_case(
    model_path: Path, motion_path: Path, grf_path: Path, assignment: dict[str, str], frames: slice
) -> float:
    """Max |τ_ours − τ_OpenSim| at motion frames that coincide with a GRF sample: identical q, q̇, q̈ (central
    differences of the IK), and the same plate samples applied as OpenSim ExternalForces from the same file."""
    model = BodyModel.from_osim(model_path)
    motion = model_motion(read_motion(motion_path), model)
    forces = read_ground_reaction(grf_path)
    q = motion.values
    dt = float(np.median(np.diff(motion.times)))
    qd = np.gradient(q, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    candidates = np.arange(len(q))[frames]
    rows = np.searchsorted(forces.times, motion.times[candidates] - 1e-9)
    rows = np.clip(rows, 0, forces.n_frames - 1)
    same = np.abs(forces.times[rows] - motion.times[candidates]) < 1e-6
    index, rows = candidates[same], rows[same]
    osim = opensim()
    storage = osim.Storage(str(grf_path))
    labels = read_storage(grf_path).labels
    extra = tuple(_opensim_external_force(osim, storage, name, body, labels) for name, body in assignment.items())
    oracle = Oracle(model_path, extra)
    loads = []
    for name, body in assignment.items():
        j = forces.names.index(name)
        loads.append(
            ExternalLoad(
                body,
                torch.tensor(forces.force[rows, j]),
                torch.tensor(forces.cop[rows, j]),
                torch.tensor(forces.moment[rows, j]),
            )
        )
    tau = inverse_dynamics(
        model, torch.tensor(q[index]), torch.tensor(qd[index]), torch.tensor(qdd[index]), loads
    ).numpy()
    worst = 0.0
    for i, k in enumerate(index):
        oracle.set(q[k], qd[k], time=float(forces.times[rows[i]]))
        worst = max(worst, float(np.abs(tau[i] - oracle.inverse_dynamics(qdd[k])).max()))
    return worst


def _opencap_trials(data_root: Path) -> list[tuple[str, Path, Path, Path]]:
    """(name, model, IK motion, GRF) of every trial with both of every subject under ``opencap/`` (Subject4 and any
    other AddBiomechanics subject in the same layout), static trials left out."""
    cases = []
    for folder in sorted(p for p in (data_root / OPENCAP).glob("*") if (p / OPENCAP_MODEL_FILE).is_file()):
        for grf in sorted((folder / "ID").glob("*_grf.mot")):
            trial = grf.name.removesuffix("_grf.mot")
            if (folder / "IK" / f"{trial}_ik.mot").exists() and not trial.startswith("static"):
                cases.append(
                    (
                        f"opencap/{folder.name}/{trial}",
                        folder / OPENCAP_MODEL_FILE,
                        folder / "IK" / f"{trial}_ik.mot",
                        grf,
                    )
                )
    return cases


def _plate_bodies(model_path: Path, motion_path: Path, forces: GroundReaction) -> dict[str, str]:
    """Each loaded plate's foot body (`biomotion.analysis.chain.plate_feet`) on the trial's IK motion."""
    model = BodyModel.from_osim(model_path)
    motion = model_motion(read_motion(motion_path), model)
    return plate_feet(forces, model, torch.tensor(motion.values, dtype=model.dtype), motion.times)


def check_inverse_dynamics_solver(data_root: Path, progress: bool = True) -> dict:
    cases = []
    if (data_root / GAIT / "subject01_walk1_ik.mot").exists():
        cases.append(
            (
                "gait2392/subject01_walk1",
                data_root / GAIT / "OutputReference/subject01_simbody.osim",
                data_root / GAIT / "subject01_walk1_ik.mot",
                data_root / GAIT / "subject01_walk1_grf.mot",
                {"ground_force": "calcn_r", "1_ground_force": "calcn_l"},
            )
        )
    for name, model_path, motion_path, grf_path in _opencap_trials(data_root):
        cases.append(
            (
                name,
                model_path,
                motion_path,
                grf_path,
                _plate_bodies(model_path, motion_path, read_ground_reaction(grf_path)),
            )
        )
    errors = {}
    for name, model_path, motion_path, grf_path, assignment in tqdm(
        cases, desc="ID vs OpenSim solver", unit="trial", disable=not progress
    ):
        errors[name] = _id_solver_case(model_path, motion_path, grf_path, assignment, slice(5, -5, 5))
    return {"id_solver_max_err_nm": max(errors.values()) if errors else None, "id_solver_per_trial_max_err_nm": errors}


def _end_to_end_case(
    model_path: Path, motion_path: Path, forces: GroundReaction, assignment: dict[str, str], tmp: Path
) -> dict:
    """Our ID pipeline vs OpenSim's InverseDynamicsTool, both from the same coordinates with a 6 Hz filter.

    OpenSim is given the coordinates `analyze` works on: the IK's, with 2π wraps of angles removed (`unwrapped`:
    the same poses; OpenSim's tool would filter such a jump as motion). Only the file's own columns are written:
    OpenSim's tool given a coupled coordinate's column follows it instead of its coupler."""
    motion = read_motion(motion_path)
    model = BodyModel.from_osim(model_path)
    columns = [name for name in model.coordinate_names if name in motion.names]
    coordinates = write_motion(tmp / "coordinates.mot", unwrapped(model_motion(motion, model), model).select(columns))
    start = max(float(motion.times[0]), float(forces.times[0]))
    end = min(float(motion.times[-1]), float(forces.times[-1]))
    # both tools filter the whole trial and are compared where the plates recorded
    forces = forces.assign([assignment.get(name) for name in forces.names]).select(list(assignment))
    grf_file = write_ground_reaction(tmp / "grf.mot", forces)
    loads_file = write_external_loads_xml(tmp / "loads.xml", forces, str(grf_file))
    reference = read_storage(
        run_inverse_dynamics_tool(model_path, coordinates, loads_file, tmp / "opensim", start, end)
    )
    ours = analyze(motion, model, forces, cutoff_hz=6.0)
    labels = torque_labels(model)
    out = {}
    for i, label in enumerate(labels):
        if label not in reference.labels:
            continue
        expected = reference.data[:, reference.labels.index(label)]
        got = np.interp(reference.times, ours.motion.times, ours.torques[:, i])
        peak = float(np.abs(expected).max())
        if peak > 10.0:
            out[label] = float(np.sqrt(np.mean((got - expected) ** 2)) / peak)
    return out


def check_inverse_dynamics_end_to_end(data_root: Path, progress: bool = True) -> dict:
    cases = []
    if (data_root / GAIT / "subject01_walk1_ik.mot").exists():
        cases.append(
            (
                "gait2392/subject01_walk1",
                data_root / GAIT / "OutputReference/subject01_simbody.osim",
                data_root / GAIT / "subject01_walk1_ik.mot",
                read_ground_reaction(data_root / GAIT / "subject01_walk1_grf.mot"),
                {"ground_force": "calcn_r", "1_ground_force": "calcn_l"},
            )
        )
    for name, model_path, motion_path, grf_path in _opencap_trials(data_root):
        forces = read_ground_reaction(grf_path)
        cases.append((name, model_path, motion_path, forces, _plate_bodies(model_path, motion_path, forces)))
    per_trial = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, model_path, motion_path, forces, assignment in tqdm(
            cases, desc="ID vs OpenSim ID tool", unit="trial", disable=not progress
        ):
            folder = Path(tmp) / name.replace("/", "_")
            folder.mkdir()
            per_trial[name] = _end_to_end_case(model_path, motion_path, forces, assignment, folder)
    worst = max((v for trial in per_trial.values() for v in trial.values()), default=None)
    return {"id_ref_rmse_rel": worst, "id_ref_rmse_rel_per_trial": per_trial}


def _fukuchi_chain_motion(base: Path, runner: str) -> Motion:
    """A runner's T35 coordinates from their C3D by the source's own processing chain
    (`biomotion.data.fukuchi_chain`, within about 1 deg of the shipped IK), in the simple model's columns and sign."""
    from biomotion.data.fukuchi_chain import as_simple, solve_trial

    result, _ = solve_trial(base, runner, "T35")
    return as_simple(result.motion)


def _grf_cases(data_root: Path) -> tuple[list[tuple[str, Path, object, object]], list[str]]:
    """(name, model, motion loader, plate loader) of every trial with plates, and what was skipped and why.

    A Fukuchi runner's motion is the shipped ``ik/T35`` IK; where a runner has none (a data root of new runners
    may hold only their captures) it is solved from the running C3D by the source's chain, as the dataset
    registry does."""
    from biomotion.data.fukuchi_chain import runner_files

    cases, skipped = [], []
    fukuchi = data_root / "fukuchi-running"
    for c3d in sorted(fukuchi.glob("c3d/*runT35.c3d")):
        runner = c3d.name.removesuffix("runT35.c3d")
        ik = fukuchi / f"ik/T35/{runner}_T35_ik_simple.mot"
        model = fukuchi / runner / f"{runner}_simple.osim"
        chain = [
            k
            for k in ("generic", "scale_setup", "ik_setup", "static")
            if not runner_files(fukuchi, runner, "T35")[k].exists()
        ]
        if not model.exists():
            skipped.append(f"GRF check: fukuchi-running/{runner}: no {model.name}")
        elif ik.exists():
            cases.append(
                (f"fukuchi/{runner}/T35", model, lambda p=ik: read_motion(p), lambda c=c3d: read_c3d_forces(c))
            )
        elif not chain:
            cases.append(
                (
                    f"fukuchi/{runner}/T35 (C3D, source chain)",
                    model,
                    lambda r=runner: _fukuchi_chain_motion(fukuchi, r),
                    lambda c=c3d: read_c3d_forces(c),
                )
            )
        else:
            skipped.append(
                f"GRF check: fukuchi-running/{runner}: no ik/T35 motion, and the chain lacks {', '.join(chain)}"
            )
    for name, model_path, motion_path, grf_path in _opencap_trials(data_root):
        if name.rsplit("/", 1)[1].startswith("STS"):  # seated: the chair carries weight no plate measures
            continue
        cases.append(
            (name, model_path, lambda p=motion_path: read_motion(p), lambda g=grf_path: read_ground_reaction(g))
        )
    return cases, skipped


def _shipped_learned(skipped: list[str]):
    """The shipped learned ground reaction, or None (and a line in ``skipped``) when its weights are absent."""
    from biomotion.models.ground_forces import SHIPPED, LearnedGroundReaction

    if not SHIPPED.is_file():
        skipped.append(f"learned GRF row: no shipped weights at {SHIPPED}")
        return None
    return LearnedGroundReaction.load(SHIPPED)


def _learned_vertical(learned, result, motion: Motion, model: BodyModel, cutoff_hz: float) -> np.ndarray:
    """[T] total vertical force (N) of the learned ground reaction on ``result``'s frames (its features computed
    at the cutoff the weights were trained with)."""
    from biomotion.analysis.ground_features import ground_features

    source = result if learned.cutoff_hz == cutoff_hz else analyze(motion, model, cutoff_hz=learned.cutoff_hz)
    return learned.predict(ground_features(source)).vertical_bw * result.body_weight


def check_ground_reaction(data_root: Path, cutoff_hz: float = 10.0, progress: bool = True) -> dict:
    """Vertical GRF inferred from kinematics vs plates, per trial and pooled over all evaluated frames; the shipped
    learned ground reaction beside it (module docstring)."""
    rows, pooled = [], {"ours": [], "base": [], "plates": [], "filtered": []}
    zmp_distances: dict[str, list[np.ndarray]] = {}
    cases, skipped = _grf_cases(data_root)
    learned_model = _shipped_learned(skipped)
    trained_on = (learned_model.train_subjects or set()) if learned_model is not None else set()
    learned_pooled: dict[bool, dict[str, list[np.ndarray]]] = {True: {"l": [], "p": []}, False: {"l": [], "p": []}}
    for name, model_path, load_motion, load_forces in tqdm(
        cases, desc="GRF vs plates", unit="trial", disable=not progress
    ):
        model = BodyModel.from_osim(model_path)
        motion = load_motion()
        forces = load_forces().slice(motion.times[0] - 0.1, motion.times[-1] + 0.1)
        started = time.perf_counter()
        result = analyze(motion, model, forces, cutoff_hz=cutoff_hz)
        seconds = time.perf_counter() - started
        keep = plate_frames(result)
        weight = result.body_weight
        total = result.measured.force[:, :, 1].sum(1)
        plates = total[keep]
        filtered = (
            Motion(times=result.motion.times, values=total[:, None], names=("plates_fy",))
            .smoothed(cutoff_hz)[0]
            .values[keep, 0]
        )
        ours = result.inferred.force[keep, :, 1].sum(1)
        base = float(model.total_mass) * (9.80665 + result.com_acceleration[keep, 1])
        a, b = vertical_agreement(ours, plates, weight), vertical_agreement(base, plates, weight)
        a_f, b_f = vertical_agreement(ours, filtered, weight), vertical_agreement(base, filtered, weight)
        zmp = zmp_to_plate_cop(result, keep)
        zmp_distances.setdefault(name.split("/")[0], []).append(zmp)
        learned_row = {}
        if learned_model is not None:
            held_out = "/".join(name.split("/")[:2]) not in trained_on
            learned = _learned_vertical(learned_model, result, motion, model, cutoff_hz)[keep]
            agreement = vertical_agreement(learned, plates, weight)
            learned_row = {
                "learned_r2": agreement["r2"],
                "learned_rmse_bw": agreement["rmse_bw"],
                "learned_held_out": held_out,
            }
            learned_pooled[held_out]["l"].append(learned / weight)
            learned_pooled[held_out]["p"].append(plates / weight)
        rows.append(
            {
                "trial": name,
                "frames": int(keep.sum()),
                "frames_left_out": int((~keep).sum()),
                "r2": a["r2"],
                "rmse_bw": a["rmse_bw"],
                "baseline_r2": b["r2"],
                "baseline_rmse_bw": b["rmse_bw"],
                "rmse_bw_plates_filtered": a_f["rmse_bw"],
                "baseline_rmse_bw_plates_filtered": b_f["rmse_bw"],
                "zmp_cop_frames": int(zmp.size),
                "zmp_cop_rmse_m": _rms(zmp),
                "analysis_seconds": seconds,
                **learned_row,
            }
        )
        for key, value in (
            ("ours", ours / weight),
            ("base", base / weight),
            ("plates", plates / weight),
            ("filtered", filtered / weight),
        ):
            pooled[key].append(value)
    if not rows:
        return {
            "grf_vertical_r2": None,
            "grf_vertical_rmse_bw": None,
            "grf_com_baseline_rmse_bw": None,
            "zmp_cop_rmse_m": None,
            "grf_trials": [],
            "skipped": skipped,
        }
    plates, filtered = np.concatenate(pooled["plates"]), np.concatenate(pooled["filtered"])
    ours = vertical_agreement(np.concatenate(pooled["ours"]), plates, 1.0)
    base = vertical_agreement(np.concatenate(pooled["base"]), plates, 1.0)
    ours_f = vertical_agreement(np.concatenate(pooled["ours"]), filtered, 1.0)
    base_f = vertical_agreement(np.concatenate(pooled["base"]), filtered, 1.0)
    learned_figures = {}
    if learned_model is not None:
        every = {k: learned_pooled[True][k] + learned_pooled[False][k] for k in ("l", "p")}
        for suffix, parts in (("", every), ("_held_out", learned_pooled[True]), ("_trained_on", learned_pooled[False])):
            agreement = (
                vertical_agreement(np.concatenate(parts["l"]), np.concatenate(parts["p"]), 1.0) if parts["l"] else {}
            )
            learned_figures[f"grf_learned_shipped_vertical_r2{suffix}"] = agreement.get("r2")
            learned_figures[f"grf_learned_shipped_vertical_rmse_bw{suffix}"] = agreement.get("rmse_bw")
        learned_figures["grf_learned_shipped_weights_sha256"] = hashlib.sha256(
            learned_model.path.read_bytes()
        ).hexdigest()
    return {
        "grf_vertical_r2": ours["r2"],
        "grf_vertical_rmse_bw": ours["rmse_bw"],
        "grf_com_baseline_r2": base["r2"],
        "grf_com_baseline_rmse_bw": base["rmse_bw"],
        "grf_vertical_r2_plates_filtered": ours_f["r2"],
        "grf_vertical_rmse_bw_plates_filtered": ours_f["rmse_bw"],
        "grf_com_baseline_r2_plates_filtered": base_f["r2"],
        "grf_com_baseline_rmse_bw_plates_filtered": base_f["rmse_bw"],
        "grf_cutoff_hz": cutoff_hz,
        "grf_frames": int(len(plates)),
        "zmp_cop_rmse_m": _rms(np.concatenate([d for ds in zmp_distances.values() for d in ds])),
        "zmp_cop_rmse_m_per_source": {source: _rms(np.concatenate(ds)) for source, ds in zmp_distances.items()},
        **learned_figures,
        "grf_trials": rows,
        "skipped": skipped,
    }


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(x**2))) if x.size else None


def validate_kinematics(data_root: Path, progress: bool = True) -> dict:
    return check_forward_kinematics(data_root, progress=progress)


def validate_dynamics(data_root: Path, progress: bool = True) -> dict:
    report: dict = {"skipped": []}
    for check in (
        check_inverse_dynamics_solver(data_root, progress),
        check_inverse_dynamics_end_to_end(data_root, progress),
        check_ground_reaction(data_root, progress=progress),
    ):
        report["skipped"] += check.pop("skipped", [])
        report.update(check)
    return report
