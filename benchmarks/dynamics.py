"""Rigid-body dynamics speed, side by side with Pinocchio, OpenSim's inverse dynamics tool and a per-frame cvxopt
QP; writes docs/results/dynamics.md.

    python benchmarks/dynamics.py [--data-root ../shared/data] [--trial DJ1] [--repeats 7] [--threads 1 2]

All on one real trial: OpenCap Subject4 (``Models/optimized_scale_and_markers.osim``, 22 bodies, 35 coordinates)
and its AddBiomechanics IK ``IK/<trial>_ik.mot``, coupled knee coordinates filled from their couplers, low-pass
filtered at 6 Hz and differentiated with quintic splines (`biomotion.analysis.chain.model_motion`,
`Motion.filtered(6).derivatives()`), so every method gets the same q, q̇, q̈.

- biomotion: `inverse_dynamics` on all frames in one call, float64, without autograd, with autograd on (q
  requires grad: the forward pass that records the graph), and forward plus backward (the gradient of the summed
  torques with respect to q); float32 with autograd; best wall-clock time of ``--repeats`` runs, at each number
  of torch intra-op threads in ``--threads`` (`biomotion.body.kinematics.torch_threads`); and the same function
  compiled by ``torch.compile`` (inductor, static shapes; it fuses the many small elementwise operations the
  recursion over the tree is made of into generated C++ loops, and needs a C++ compiler), autograd on and forward
  plus backward, its one-off compile time reported beside the table; and float32 compiled on ``BATCH_TILES``
  copies of the trial in one batch (a batch of trials), with float32's largest torque difference from float64.
- Pinocchio: a model of the same size built from the BodyModel: the same bodies, masses and inertias at the same
  joint placements (default pose), a free-flyer root for the pelvis, each CustomJoint coordinate as one revolute
  joint about the first rotation axis it drives (or one prismatic joint along its translation axis), welded bodies
  merged into their parent. Approximation: coordinate-dependent joint translations (e.g. the knee's
  spline-driven translation) are left out, so the torques differ from ours while the size and work per frame are
  the same. ``pin.rnea`` and ``pin.computeRNEADerivatives`` in a Python loop over frames.
- OpenSim 4.6: ``InverseDynamicsTool`` on the same filtered coordinates (its filter off), plate 1 applied to
  calcn_r and plate 2 to calcn_l (opencap/SOURCE.md), timed around ``run()`` (model set-up, splines, ID, output).
- Force inference: the quadratic program `infer_ground_reaction` solves for every frame (PhysPT Eq. 5 with the
  contact prior: same P, q, x >= 0), by our batched Newton method on its 6-variable dual in one tensor program
  (`_nonnegative_least_squares`, given A, r and the prior's diagonal, P = (AᵀA + diag)/W²) vs
  ``cvxopt.solvers.qp`` frame by frame (PhysPT's way, given P and q), with the root residual and objective of
  both; building the inputs is outside both timings, each the best of ``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from biomotion.analysis.chain import analyze, model_motion
from biomotion.body.contact import (
    ContactSettings,
    _friction_edges,
    _nonnegative_least_squares,
    _point_kinematics,
    foot_points,
    infer_ground_reaction,
    root_coordinates,
)
from biomotion.body.dynamics import inverse_dynamics
from biomotion.body.kinematics import forward_kinematics, joint_transform, torch_threads
from biomotion.body.model import BodyModel
from biomotion.io.atomic import atomic_write
from biomotion.io.mot import read_ground_reaction, read_motion, read_storage, write_motion

REPO = Path(__file__).resolve().parents[1]
SUBJECT = "opencap/Subject4"
MODEL = "Models/optimized_scale_and_markers.osim"
#: copies of the trial in the large-batch rows: a batch of trials, as dataset labelling and guidance run them
BATCH_TILES = 16


def best_time(function, repeats: int) -> float:
    """Best wall-clock seconds of ``repeats`` calls after one warm-up call."""
    function()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


# ---- inputs ----------------------------------------------------------------------------------------------------


def load_trial(root: Path, trial: str):
    model = BodyModel.from_osim(root / SUBJECT / MODEL)
    motion = read_motion(root / SUBJECT / "IK" / f"{trial}_ik.mot")
    coordinates = model_motion(motion, model).filtered(6.0)
    qd, qdd = coordinates.derivatives()
    q, qd, qdd = (torch.tensor(np.ascontiguousarray(a), dtype=torch.float64) for a in (coordinates.values, qd, qdd))
    plates = read_ground_reaction(root / SUBJECT / "ID" / f"{trial}_grf.mot")
    return model, motion, coordinates, q, qd, qdd, plates


# ---- biomotion -------------------------------------------------------------------------------------------------


def ours(model: BodyModel, q, qd, qdd, repeats: int) -> dict[str, float]:
    """Frames/s of our inverse dynamics, in the current thread setting."""
    frames = q.shape[0]
    q_grad = q.clone().requires_grad_()
    model32 = model.to(torch.float32)
    q32, qd32, qdd32 = q.float().requires_grad_(), qd.float(), qdd.float()
    tiled = [x.repeat(4, 1) for x in (q, qd, qdd)]

    def no_grad() -> None:
        with torch.no_grad():
            inverse_dynamics(model, q, qd, qdd)

    def batch4() -> None:
        with torch.no_grad():
            inverse_dynamics(model, *tiled)

    def backward() -> None:
        inverse_dynamics(model, q_grad, qd, qdd).sum().backward()

    return {
        "no autograd": frames / best_time(no_grad, repeats),
        "autograd on (forward)": frames / best_time(lambda: inverse_dynamics(model, q_grad, qd, qdd), repeats),
        "forward + backward (d/dq)": frames / best_time(backward, repeats),
        "autograd on, float32": frames / best_time(lambda: inverse_dynamics(model32, q32, qd32, qdd32), repeats),
        "no autograd, 4x frames in one batch": 4 * frames / best_time(batch4, repeats),
    }


def compile_inverse_dynamics(model: BodyModel, q, qd, qdd):
    """({dtype: ``torch.compile``d `inverse_dynamics` of ``model`` in float64 and float32, autograd on}, seconds
    the first float64 call took), or (None, why) when this machine cannot compile (no C++ compiler, unsupported
    platform)."""
    compiled = {}
    for dtype in (torch.float64, torch.float32):
        typed = model.to(dtype)
        compiled[dtype] = torch.compile(lambda a, b, c, m=typed: inverse_dynamics(m, a, b, c), dynamic=False)
    start = time.perf_counter()
    try:
        torques = compiled[torch.float64](q.clone().requires_grad_(), qd, qdd)
    except Exception as error:  # inductor raises many kinds (compiler missing, codegen failure)
        return None, f"{type(error).__name__}: {str(error).splitlines()[0][:120]}"
    seconds = time.perf_counter() - start
    if not torch.allclose(torques.detach(), inverse_dynamics(model, q, qd, qdd), atol=1e-8):
        raise RuntimeError("the compiled inverse dynamics differs from the eager one")
    compiled[torch.float32](*(x.float().repeat(BATCH_TILES, 1) for x in (q, qd, qdd)))  # its own compile, untimed
    return compiled, seconds


def float32_error(model: BodyModel, q, qd, qdd) -> float:
    """Largest |float32 - float64| torque of `inverse_dynamics` on the trial (N·m)."""
    reference = inverse_dynamics(model, q, qd, qdd)
    single = inverse_dynamics(model.to(torch.float32), q.float(), qd.float(), qdd.float())
    return float((single.double() - reference).abs().max())


def compiled_speeds(compiled, q, qd, qdd, repeats: int) -> dict[str, float]:
    """Frames/s of the compiled inverse dynamics (see `compile_inverse_dynamics`), in the current thread setting."""
    frames = q.shape[0]
    f64, f32 = compiled[torch.float64], compiled[torch.float32]
    q_grad = q.clone().requires_grad_()
    q32, qd32, qdd32 = q.float().requires_grad_(), qd.float(), qdd.float()
    tiled = [
        q32.detach().repeat(BATCH_TILES, 1).requires_grad_(),
        qd32.repeat(BATCH_TILES, 1),
        qdd32.repeat(BATCH_TILES, 1),
    ]
    return {
        "compiled, autograd on (forward)": frames / best_time(lambda: f64(q_grad, qd, qdd), repeats),
        "compiled, forward + backward (d/dq)": frames
        / best_time(lambda: f64(q_grad, qd, qdd).sum().backward(), repeats),
        "compiled, autograd on, float32": frames / best_time(lambda: f32(q32, qd32, qdd32), repeats),
        f"compiled, autograd on, float32, {BATCH_TILES}x frames in one batch": BATCH_TILES
        * frames
        / best_time(lambda: f32(*tiled), repeats),
    }


def whole_chain(motion, model: BodyModel, plates, repeats: int) -> float:
    """Frames/s of `analyze` (filter, splines, inferred and measured-load torques, COM, ZMP, energy)."""
    return motion.n_frames / best_time(lambda: analyze(motion, model, plates), max(1, repeats // 3))


# ---- Pinocchio -------------------------------------------------------------------------------------------------


def pinocchio_model(model: BodyModel):
    """(pin.Model, {pin joint id: our coordinates}) of the same size as ``model`` (see the module docstring)."""
    import pinocchio as pin

    def se3(rotation, translation):
        return pin.SE3(np.asarray(rotation, dtype=float), np.asarray(translation, dtype=float))

    pm = pin.Model()
    pm.gravity = pin.Motion(np.concatenate([model.gravity.numpy(), np.zeros(3)]))
    carrier = {-1: (0, pin.SE3.Identity())}  # body -> (pin joint that moves it, body frame in that joint frame)
    coordinates_of: dict[int, list[int]] = {}
    for j in model.joint_order:
        joint = model.joints[j]
        parent, in_parent = carrier[joint.parent]
        inertia = pin.Inertia(
            float(model.masses[joint.child]), model.coms[joint.child].numpy(), model.inertias[joint.child].numpy()
        )
        if not joint.coordinates:
            carrier[joint.child] = (parent, in_parent * se3(*joint_transform(joint, model.defaults)))
            pm.appendBodyToJoint(parent, inertia, carrier[joint.child][1])
            continue
        placement, current = in_parent * se3(joint.parent_rotation, joint.parent_translation), parent
        if joint.parent < 0 and len(joint.coordinates) == 6:
            current = pm.addJoint(current, pin.JointModelFreeFlyer(), placement, joint.name)
            coordinates_of[current] = list(joint.coordinates)
        else:
            dofs = [(c, next((a for a in joint.axes if a.coordinate == c), None)) for c in joint.coordinates]
            dofs.sort(key=lambda d: 0 if d[1] is not None and not d[1].rotation else 1)  # translations are in F
            for c, axis in dofs:
                unit = axis.axis.numpy() if axis is not None else np.array([1.0, 0.0, 0.0])
                kind = (
                    pin.JointModelPrismaticUnaligned
                    if axis is not None and not axis.rotation
                    else pin.JointModelRevoluteUnaligned
                )
                current = pm.addJoint(current, kind(unit), placement, model.coordinate_names[c])
                coordinates_of[current] = [c]
                placement = pin.SE3.Identity()
        carrier[joint.child] = (current, se3(joint.child_rotation, joint.child_translation).inverse())
        pm.appendBodyToJoint(current, inertia, carrier[joint.child][1])
    return pm, coordinates_of


def pinocchio(model: BodyModel, q, qd, qdd, repeats: int) -> dict[str, float | int]:
    import pinocchio as pin

    pm, coordinates_of = pinocchio_model(model)
    data = pm.createData()
    frames = q.shape[0]
    configuration, velocity, acceleration = (
        np.zeros((frames, pm.nq)),
        np.zeros((frames, pm.nv)),
        np.zeros((frames, pm.nv)),
    )
    root = model.joints[model.joint_order[0]].child
    poses = forward_kinematics(model, q)
    for joint, columns in coordinates_of.items():
        jm = pm.joints[joint]
        if len(columns) == 6:  # free flyer: position and quaternion of the pelvis, its six rates as given
            configuration[:, jm.idx_q : jm.idx_q + 3] = poses.positions[:, root].numpy()
            configuration[:, jm.idx_q + 3 : jm.idx_q + 7] = [
                pin.Quaternion(r).coeffs() for r in poses.rotations[:, root].numpy()
            ]
        else:
            configuration[:, jm.idx_q] = q[:, columns[0]].numpy()
        velocity[:, jm.idx_v : jm.idx_v + len(columns)] = qd[:, columns].numpy()
        acceleration[:, jm.idx_v : jm.idx_v + len(columns)] = qdd[:, columns].numpy()

    def rnea() -> None:
        for t in range(frames):
            pin.rnea(pm, data, configuration[t], velocity[t], acceleration[t])

    def derivatives() -> None:
        for t in range(frames):
            pin.computeRNEADerivatives(pm, data, configuration[t], velocity[t], acceleration[t])

    return {
        "rnea": frames / best_time(rnea, repeats),
        "derivatives": frames / best_time(derivatives, repeats),
        "nq": pm.nq,
        "nv": pm.nv,
        "joints": pm.njoints - 1,
        "mass": float(sum(i.mass for i in pm.inertias)),
    }


# ---- OpenSim ---------------------------------------------------------------------------------------------------

EXTERNAL_LOADS = """<?xml version="1.0" encoding="UTF-8"?>
<OpenSimDocument Version="40000"><ExternalLoads name="plates"><objects>{forces}</objects>
<datafile>{datafile}</datafile></ExternalLoads></OpenSimDocument>
"""
EXTERNAL_FORCE = """<ExternalForce name="{body}_plate"><applied_to_body>{body}</applied_to_body>
<force_expressed_in_body>ground</force_expressed_in_body><point_expressed_in_body>ground</point_expressed_in_body>
<force_identifier>ground_force_{k}_v</force_identifier><point_identifier>ground_force_{k}_p</point_identifier>
<torque_identifier>ground_force_{k}_m</torque_identifier></ExternalForce>"""


def opensim_inverse_dynamics(root: Path, trial: str, coordinates) -> dict[str, float]:
    """Frames/s of OpenSim's InverseDynamicsTool on ``coordinates`` with the plates on the feet."""
    from biomotion.settings import opensim_oracle

    osim = opensim_oracle()

    osim.Logger.setLevelString("error")
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        # radians: from degrees OpenSim 4.6 leaves the coupled knee_angle_*_beta speeds in deg/s
        # (biomotion.validation.muscles.rajagopal_walk_inputs)
        write_motion(folder / "coordinates.mot", coordinates, in_degrees=False)
        forces = "".join(EXTERNAL_FORCE.format(body=body, k=k) for k, body in ((1, "calcn_r"), (2, "calcn_l")))
        (folder / "loads.xml").write_text(
            EXTERNAL_LOADS.format(forces=forces, datafile=(root / SUBJECT / "ID" / f"{trial}_grf.mot").resolve())
        )
        tool = osim.InverseDynamicsTool()
        tool.setModelFileName(str((root / SUBJECT / MODEL).resolve()))
        tool.setCoordinatesFileName(str(folder / "coordinates.mot"))
        tool.setLowpassCutoffFrequency(-1.0)
        tool.setExternalLoadsFileName(str(folder / "loads.xml"))
        excluded = osim.ArrayStr()
        excluded.append("Muscles")
        tool.setExcludedForces(excluded)
        tool.setStartTime(float(coordinates.times[0]))
        tool.setEndTime(float(coordinates.times[-1]))
        tool.setResultsDir(str(folder))
        tool.setOutputGenForceFileName("id.sto")
        tool.printToXML(str(folder / "setup.xml"))  # run from a setup file, as users do (and loads attach)
        tool = osim.InverseDynamicsTool(str(folder / "setup.xml"))
        start = time.perf_counter()
        if not tool.run():
            raise RuntimeError("OpenSim InverseDynamicsTool failed")
        seconds = time.perf_counter() - start
        frames = len(read_storage(folder / "id.sto").times)
    return {"frames_per_s": frames / seconds, "frames": frames}


# ---- force inference -------------------------------------------------------------------------------------------


def contact_problem(model: BodyModel, q, qd, qdd, settings: ContactSettings):
    """The batched QP of `infer_ground_reaction` (same construction): P [T, n, n], b [T, n] (minimise
    ½xᵀPx − bᵀx, x >= 0), the weighted root force r_w [T, 6], edge map a_w [T, 6, n] and prior diagonal d [T, n]
    (P = (a_wᵀa_w + diag d)/W², b = a_wᵀr_w/W²)."""
    points, roots = foot_points(model), root_coordinates(model)
    with torch.no_grad():
        free = inverse_dynamics(model, q, qd, qdd)[..., roots]
        positions, velocities, jacobian = _point_kinematics(model, q, qd, points, roots)
        rest = torch.quantile(positions[..., 1], settings.rest_percentile / 100.0, dim=0)
        gate = torch.sigmoid(
            -(positions[..., 1] - rest - settings.height_offset) / settings.height_scale
        ) * torch.sigmoid(-(velocities[..., 1].abs() - settings.speed_offset) / settings.speed_scale)
        per_edge = torch.einsum("tkcd,ec->tdke", jacobian, _friction_edges(settings.friction, q.dtype))
        a = per_edge.reshape(*per_edge.shape[:2], -1)
        scale = torch.ones(6, dtype=q.dtype)
        scale[[i for i, c in enumerate(roots) if model.motion_types[c] == "rotational"]] = 1.0 / settings.moment_length
        a_w, r_w = a * scale[:, None], free * scale
        weight = model.total_mass * 9.80665
        penalty = settings.prior_weight * (1.0 / gate.clamp(min=1e-6) - 1.0)
        d = penalty.repeat_interleave(4, dim=-1) + 1e-9
        p = (a_w.transpose(-1, -2) @ a_w + torch.diag_embed(d)) / weight**2
        b = (a_w.transpose(-1, -2) @ r_w[..., None]).squeeze(-1) / weight**2
    return p, b, r_w, a_w.contiguous(), d


def cvxopt_solve(p: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Frame by frame: min ½xᵀPx − bᵀx s.t. x >= 0 with cvxopt's interior-point QP (default tolerances)."""
    import cvxopt

    cvxopt.solvers.options["show_progress"] = False
    n = p.shape[-1]
    g, h = cvxopt.matrix(-np.eye(n)), cvxopt.matrix(np.zeros(n))
    return np.stack(
        [
            np.array(cvxopt.solvers.qp(cvxopt.matrix(p[t]), cvxopt.matrix(-b[t]), g, h)["x"]).ravel()
            for t in range(p.shape[0])
        ]
    )


def force_inference(model: BodyModel, q, qd, qdd, repeats: int) -> dict[str, float]:
    settings = ContactSettings()
    frames = q.shape[0]
    p, b, r_w, a_w, d = contact_problem(model, q, qd, qdd, settings)
    with torch.no_grad():
        ours_x = _nonnegative_least_squares(a_w, r_w, d, settings.iterations)
        ours_seconds = best_time(lambda: _nonnegative_least_squares(a_w, r_w, d, settings.iterations), repeats)
        inference = frames / best_time(lambda: infer_ground_reaction(model, q, qd, qdd, settings), max(1, repeats // 3))
    p_np, b_np = p.numpy(), b.numpy()
    theirs_x = cvxopt_solve(p_np, b_np)
    cvxopt_seconds = best_time(lambda: cvxopt_solve(p_np, b_np), repeats)  # best of repeats, as ours

    def objective(x: np.ndarray) -> np.ndarray:
        return 0.5 * np.einsum("ti,tij,tj->t", x, p_np, x) - np.einsum("ti,ti->t", b_np, x)

    def residual(x: np.ndarray) -> float:  # RMS over frames of the unexplained weighted root force (N)
        left = r_w.numpy() - np.einsum("tdn,tn->td", a_w.numpy(), x)
        return float(np.sqrt(np.mean(np.sum(left**2, -1))))

    # objective + ½|r|²/W² = ½|A x - r|²/W² + prior >= 0: the per-frame cost each solver reached
    offset = 0.5 * (r_w.numpy() ** 2).sum(-1) / float(model.total_mass * 9.80665) ** 2
    mine, theirs = objective(ours_x.numpy()) + offset, objective(theirs_x) + offset
    return {
        "ours_solver": frames / ours_seconds,
        "cvxopt": frames / cvxopt_seconds,
        "ours_inference": inference,
        "ours_residual": residual(ours_x.numpy()),
        "cvxopt_residual": residual(theirs_x),
        "cost_ratio": float(mine.sum() / theirs.sum()),
        "worst_frame": float(np.max((mine - theirs) / theirs.sum() * frames)),
        "variables": p.shape[-1],
    }


# ---- report ----------------------------------------------------------------------------------------------------


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        )
    except (OSError, StopIteration):
        pass
    versions = [f"torch {torch.__version__}"]
    for name, module in (("pin", "pinocchio"), ("opensim", "opensim"), ("cvxopt", "cvxopt")):
        try:
            versions.append(f"{name} {__import__(module).__version__}")
        except ImportError:
            pass
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return (
        f"{cpu}, {os.cpu_count()} cores, load average {load} (shared machine); Python "
        f"{platform.python_version()}, " + ", ".join(versions)
    )


def report(
    args,
    trial: str,
    model: BodyModel,
    frames: int,
    speeds: dict[int, dict[str, float]],
    chain: dict[int, float],
    pin_result,
    opensim_result,
    grf,
    compile_note: str,
    float32_error_nm: float,
) -> str:
    base = pin_result["rnea"] if pin_result else None

    def ratio(value: float) -> str:
        return f"{value / base:.2f}" if base else "-"

    threads = sorted(speeds)
    single = speeds[1] if 1 in speeds else speeds[threads[0]]
    pad = "".join(" | -" for _ in threads[1:])
    lines = [
        "# Rigid-body dynamics: speed vs Pinocchio, OpenSim and cvxopt",
        "",
        f"OpenCap Subject4 `{trial}` ({frames} frames), model `{MODEL}` ({model.n_bodies} bodies, {model.n_q} "
        f"coordinates). Produced by `python benchmarks/dynamics.py --trial {trial} --repeats {args.repeats} "
        f"--threads {' '.join(map(str, threads))}`; best wall-clock time of the repeats. Absolute times vary "
        "with the machine and its load; the ratios, measured in the same run, are the result. On a busy shared "
        "machine (load average below) rows measured seconds apart still vary by up to 2x from run to run.",
        "",
        f"Machine: {machine()}; {time.strftime('%Y-%m-%d')}.",
        "",
        "## Inverse dynamics",
        "",
        "| method | "
        + " | ".join(f"frames/s, {t} thread{'s' * (t > 1)}" for t in threads)
        + f" | vs Pinocchio `rnea` ({1 if 1 in speeds else threads[0]} thread) |",
        "|---|" + "---|" * len(threads) + "---|",
    ]
    for name in single:
        lines.append(
            f"| biomotion `inverse_dynamics`, {name} | "
            + " | ".join(f"{speeds[t][name]:,.0f}" for t in threads)
            + f" | {ratio(single[name])} |"
        )
    if pin_result:
        lines += [
            f"| Pinocchio `pin.rnea`, Python loop over frames | {pin_result['rnea']:,.0f}{pad} | 1 |",
            f"| Pinocchio `pin.computeRNEADerivatives`, Python loop | {pin_result['derivatives']:,.0f}{pad} | "
            f"{ratio(pin_result['derivatives'])} |",
        ]
    if opensim_result:
        lines.append(
            f"| OpenSim 4.6 `InverseDynamicsTool` (whole tool run) | {opensim_result['frames_per_s']:,.0f}"
            f"{pad} | {ratio(opensim_result['frames_per_s'])} |"
        )
    lines += [""]
    if pin_result:
        lines += [
            f"Pinocchio model built from the BodyModel: nq {pin_result['nq']}, nv {pin_result['nv']} "
            f"(= our {model.n_q} coordinates), {pin_result['joints']} joints, {pin_result['mass']:.2f} kg "
            "(see the benchmark's docstring for the approximation). Pinocchio runs single-threaded.",
            "",
        ]
    lines += [compile_note, ""]
    lines += [
        "Accuracy: tests/body checks every model against OpenSim's inverse dynamics solver to 1e-4 N·m in "
        "float64 (measured about 1e-12). The float32 rows differ from float64 on this trial by at most "
        f"{float32_error_nm:.1e} N·m.",
        "",
    ]
    lines += [
        "## Force inference (PhysPT Eq. 5: non-negative friction-cone forces at 10 foot points)",
        "",
        f"The same QP per frame ({grf['variables']} variables, x >= 0; A, r and the prior's diagonal as "
        "`infer_ground_reaction` builds them, given to cvxopt as P = (AᵀA + diag)/W² and q = −Aᵀr/W²). Residual: "
        "RMS over frames of the root force the forces leave unexplained (N, moments / 1 m; the flight phase of a "
        "drop jump has no contact to explain it). Cost: ½|A x − r|² plus the contact prior, "
        f"summed over frames (worst single frame: {grf['worst_frame']:+.1e} of the mean cost per frame).",
        "",
        "| solver | frames/s | root residual RMS | total cost / cvxopt's |",
        "|---|---|---|---|",
        "| biomotion batched Newton on the 6-variable dual (exact line search, each frame stops when exact), all "
        f"frames in one tensor program | {grf['ours_solver']:,.0f} | {grf['ours_residual']:.3f} | "
        f"{grf['cost_ratio']:.6f} |",
        f"| cvxopt `solvers.qp` (default tolerances), frame by frame | {grf['cvxopt']:,.0f} | "
        f"{grf['cvxopt_residual']:.3f} | 1 |",
        f"| ratio | **{grf['ours_solver'] / grf['cvxopt']:.1f}x** | | |",
        "",
        f"The whole `infer_ground_reaction` (inverse dynamics twice, contact kinematics, the solve): "
        f"{grf['ours_inference']:,.0f} frames/s, {grf['ours_inference'] / grf['cvxopt']:.1f}x the cvxopt solve "
        "alone.",
        "",
        "## Whole analysis chain",
        "",
        "`biomotion.analysis.chain.analyze` with the plates (filter, splines, inferred and measured-load torques, COM, "
        "ZMP, energy):",
        "",
        "| threads | frames/s |",
        "|---|---|",
        *(f"| {t} | {chain[t]:,.0f} |" for t in sorted(chain)),
        "",
        "torch's intra-op threads cost more than they give for these many small operations when the cores are "
        "busy: run them inside `biomotion.body.kinematics.torch_threads(1)` and parallelise over trials.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data-root", default=str(REPO.parent / "shared" / "data"))
    parser.add_argument("--trial", default="DJ1")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--out", default=str(REPO / "docs" / "results" / "dynamics.md"))
    args = parser.parse_args(argv)
    root = Path(args.data_root)
    model, motion, coordinates, q, qd, qdd, plates = load_trial(root, args.trial)
    speeds, chain = {}, {}
    with torch_threads(1):
        compiled, compile_seconds = compile_inverse_dynamics(model, q, qd, qdd)
    compile_note = (
        f"`torch.compile` rows: the first call compiled for {compile_seconds:.1f} s (once per model and "
        "frame count; the result equals the eager function to 1e-8 N·m)."
        if compiled is not None
        else f"`torch.compile` rows left out: it failed here ({compile_seconds})."
    )
    for threads in args.threads:
        with torch_threads(threads):
            speeds[threads] = ours(model, q, qd, qdd, args.repeats)
            if compiled is not None:
                speeds[threads].update(compiled_speeds(compiled, q, qd, qdd, args.repeats))
            chain[threads] = whole_chain(motion, model, plates, args.repeats)
        print(f"{threads} thread(s): {speeds[threads]}, analyze {chain[threads]:.0f} frames/s", file=sys.stderr)
    with torch_threads(1):
        try:
            pin_result = pinocchio(model, q, qd, qdd, args.repeats)
        except ImportError:
            pin_result = None
        try:
            opensim_result = opensim_inverse_dynamics(root, args.trial, coordinates)
        except ImportError:
            opensim_result = None
        grf = force_inference(model, q, qd, qdd, args.repeats)
    text = report(
        args,
        args.trial,
        model,
        q.shape[0],
        speeds,
        chain,
        pin_result,
        opensim_result,
        grf,
        compile_note,
        float32_error(model, q, qd, qdd),
    )
    with atomic_write(args.out) as handle:
        handle.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
