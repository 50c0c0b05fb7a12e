"""nimblephysics (AddBiomechanics' engine) as the marker-IK peer of `benchmarks/ik.py`: one trial, JSON on stdout.

    PYTHON_WITH_NIMBLE benchmarks/nimble_peer.py TRIAL.npz

Runs in its own interpreter and imports nothing from biomotion: nimblephysics 0.10.52.1 (PyPI) crashes (a
segmentation fault in ``MarkerFitter``'s constructor) under numpy 2, which biomotion's environment has, so
`benchmarks/ik.py --nimble-python` hands each trial over in a ``.npz`` file (``positions`` [T, M, 3] m, ``names``,
``weights`` per name, ``model`` the scaled ``.osim``) to an interpreter with numpy < 2.

Two solvers, each timed around its call only:

- ``MarkerFitter.runKinematicsPipeline`` with the model's scales kept (``setDontRescaleBodies``, ``setSkipBilevel``):
  AddBiomechanics' pipeline. Its anthropometric step measures the skeleton's height from the bone meshes, which the
  shared data leaves out, and it stops with "getHeight() computed a height of 0"; the error is reported.
- ``Skeleton.fitMarkersToWorldPositions`` frame after frame, each from the previous frame's pose (OpenSim's
  sequential warm start; the first frame from the root moved onto the markers, 10 starts): the IK solver
  MarkerFitter runs inside. Every weighted marker of the IK setup weighs 1 here: with the setup's own weights (10,
  5, 2.5) nimble's damped least squares diverges on these trials (marker RMS error over 0.5 m).

Marker RMS error: every visible (frame, marker) sample of the weighted markers, the model's markers at the solved
poses (nimble's own forward kinematics).
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np


def main(path: str) -> int:
    import nimblephysics_libs._nimblephysics as nimble

    data = np.load(path)
    names_all = [str(n) for n in data["names"]]
    positions = data["positions"]
    weights = dict(zip([str(n) for n in data["weight_names"]], data["weights"]))
    osim = nimble.biomechanics.OpenSimParser.parseOsim(str(data["model"]))
    skeleton = osim.skeleton
    names = [n for n in names_all if n in osim.markersMap and weights.get(n, 0.0) > 0]
    columns = [names_all.index(n) for n in names]
    observed = positions[:, columns]
    out: dict = {"frames": int(positions.shape[0]), "markers": len(names), "nimblephysics": _version()}

    observations = [
        {n: observed[t, k].astype(float) for k, n in enumerate(names) if np.isfinite(observed[t, k]).all()}
        for t in range(observed.shape[0])
    ]
    fitter = nimble.biomechanics.MarkerFitter(skeleton, osim.markersMap)
    params = nimble.biomechanics.InitialMarkerFitParams().setGroupScales(skeleton.getGroupScales())
    params = params.setDontRescaleBodies(True).setSkipBilevel(True)
    began = time.perf_counter()
    try:
        fitter.runKinematicsPipeline(observations, [False] * len(observations), params, 20)
        out["marker_fitter"] = {"seconds": time.perf_counter() - began}
    except RuntimeError as error:
        out["marker_fitter"] = {"error": str(error)}

    osim = nimble.biomechanics.OpenSimParser.parseOsim(str(data["model"]))  # fresh: the pipeline left its state
    skeleton = osim.skeleton
    markers = [osim.markersMap[n] for n in names]
    poses = np.zeros((observed.shape[0], skeleton.getNumDofs()))
    # start the first frame with the root where the markers are: the translation that puts the model's markers'
    # centroid on the data's (nimble's solver starts from the skeleton's current pose)
    start = skeleton.getPositions()
    seen0 = np.isfinite(observed[0]).all(-1)
    model0 = np.asarray(skeleton.getMarkerWorldPositions(markers)).reshape(-1, 3)
    dofs = [d.getName() for d in skeleton.getDofs()]
    translation = [k for k, name in enumerate(dofs) if name.endswith(("_tx", "_ty", "_tz"))]
    if len(translation) == 3:
        start[translation] += (observed[0, seen0] - model0[seen0]).mean(0)
        skeleton.setPositions(start)
    began = time.perf_counter()
    for t in range(observed.shape[0]):
        seen = np.isfinite(observed[t]).all(-1)
        chosen = [markers[k] for k in np.flatnonzero(seen)]
        target = observed[t, seen].reshape(-1)
        w = np.ones(len(chosen))  # the setup's 10/5/2.5 weights make nimble's solver diverge on these trials
        skeleton.fitMarkersToWorldPositions(chosen, target, w, False, 1e-7, 100 if t else 500, 1 if t else 10)
        poses[t] = skeleton.getPositions()
    seconds = time.perf_counter() - began
    errors = []
    for t in range(observed.shape[0]):
        skeleton.setPositions(poses[t])
        world = np.asarray(skeleton.getMarkerWorldPositions(markers)).reshape(-1, 3)
        seen = np.isfinite(observed[t]).all(-1)
        errors.append(np.linalg.norm(world[seen] - observed[t, seen], axis=-1))
    errors = np.concatenate(errors)
    out["sequential_ik"] = {"seconds": seconds, "marker_rmse_m": float(np.sqrt(np.mean(errors**2)))}
    print(json.dumps(out))
    return 0


def _version() -> str | None:
    try:
        from importlib.metadata import version

        return version("nimblephysics")
    except Exception:  # noqa: BLE001 - the figure is informative only
        return None


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1]))
