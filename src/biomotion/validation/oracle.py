"""OpenSim 4.6 as an oracle: a model with its forces off and coordinates unlocked, states set in CoordinateSet
order, body poses, markers, mass matrix and inverse dynamics read back; and the InverseDynamicsTool run fresh.

Only validation and tests import this module; `biomotion analyze` and `generate` never need OpenSim.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from biomotion.errors import ConfigError


def opensim():
    """The ``opensim`` module, or a ConfigError saying how to install it."""
    try:
        from biomotion.settings import opensim_oracle

        osim = opensim_oracle()
    except ImportError:  # pragma: no cover - depends on the environment
        raise ConfigError("validation needs the opensim package: pip install 'biomotion[validate]'") from None
    osim.Logger.setLevelString("error")
    return osim


class Oracle:
    """An OpenSim model with every force disabled, all coordinates unlocked, and the coordinate -> u map."""

    def __init__(self, path: str | Path, extra_forces: tuple = ()) -> None:
        osim = opensim()
        self.osim = osim
        self.model = osim.Model(str(path))
        forces = self.model.updForceSet()
        for i in range(forces.getSize()):
            forces.get(i).set_appliesForce(False)
        for force in extra_forces:
            self.model.addForce(force)
        self.state = self.model.initSystem()
        self.coords = self.model.getCoordinateSet()
        self.n = self.coords.getSize()
        for i in range(self.n):
            self.coords.get(i).setLocked(self.state, False)
            self.coords.get(i).setSpeedValue(self.state, float(i + 1))
        u = np.array([self.state.getU().get(k) for k in range(self.state.getNU())])
        self.u_index = [int(np.flatnonzero(u == i + 1)[0]) for i in range(self.n)]
        self.solver = osim.InverseDynamicsSolver(self.model)

    @property
    def coordinate_names(self) -> list[str]:
        return [self.coords.get(i).getName() for i in range(self.n)]

    def set(self, q, qd=None, time: float = 0.0) -> None:
        self.state.setTime(time)
        for i in range(self.n):
            self.coords.get(i).setValue(self.state, float(q[i]), False)
            self.coords.get(i).setSpeedValue(self.state, 0.0 if qd is None else float(qd[i]))
        self.model.realizeVelocity(self.state)

    def body_poses(self) -> tuple[np.ndarray, np.ndarray]:
        bodies = self.model.getBodySet()
        rotations, positions = [], []
        for b in range(bodies.getSize()):
            transform = bodies.get(b).getTransformInGround(self.state)
            positions.append([transform.p().get(i) for i in range(3)])
            rotations.append([[transform.R().get(i, j) for j in range(3)] for i in range(3)])
        return np.array(rotations), np.array(positions)

    def markers(self) -> np.ndarray:
        markers = self.model.getMarkerSet()
        return np.array([vec3(markers.get(i).getLocationInGround(self.state)) for i in range(markers.getSize())])

    def joint_centers(self) -> np.ndarray:
        joints = self.model.getJointSet()
        return np.array(
            [vec3(joints.get(i).getChildFrame().getPositionInGround(self.state)) for i in range(joints.getSize())]
        )

    def inverse_dynamics(self, qdd) -> np.ndarray:
        udot = self.osim.Vector(self.state.getNU(), 0.0)
        for i in range(self.n):
            udot.set(self.u_index[i], float(qdd[i]))
        tau = self.solver.solve(self.state, udot)
        return np.array([tau.get(self.u_index[i]) for i in range(self.n)])

    def mass_matrix(self) -> np.ndarray:
        matrix = self.osim.Matrix()
        self.model.getMatterSubsystem().calcM(self.state, matrix)
        return np.array([[matrix.get(self.u_index[i], self.u_index[j]) for j in range(self.n)] for i in range(self.n)])


def vec3(v) -> list[float]:
    return [v.get(i) for i in range(3)]


def random_poses(model, rng: np.random.Generator, count: int) -> np.ndarray:
    """[count, n_q] uniform in each coordinate's range (unbounded ranges limited to +-2)."""
    low = np.clip(model.ranges[:, 0].numpy(), -2.0, 2.0)
    high = np.clip(model.ranges[:, 1].numpy(), -2.0, 2.0)
    return rng.uniform(low, high, size=(count, model.n_q))


def run_inverse_dynamics_tool(
    model_path: Path,
    coordinates: Path,
    external_loads: Path | None,
    out_dir: Path,
    start: float,
    end: float,
    cutoff_hz: float = 6.0,
) -> Path:
    """Run OpenSim's InverseDynamicsTool fresh; returns the generalized-forces ``.sto`` it wrote."""
    osim = opensim()
    model = osim.Model(str(model_path))
    model.initSystem()
    tool = osim.InverseDynamicsTool()
    tool.setModel(model)
    tool.setCoordinatesFileName(str(coordinates))
    tool.setLowpassCutoffFrequency(cutoff_hz)
    if external_loads is not None:
        tool.setExternalLoadsFileName(str(external_loads))
    tool.setStartTime(start)
    tool.setEndTime(end)
    out_dir.mkdir(parents=True, exist_ok=True)
    tool.setResultsDir(str(out_dir))
    tool.setOutputGenForceFileName("opensim_id.sto")
    excluded = osim.ArrayStr()
    excluded.append("Muscles")
    tool.setExcludedForces(excluded)
    if not tool.run():
        raise RuntimeError(f"OpenSim's InverseDynamicsTool failed on {coordinates}")
    return out_dir / "opensim_id.sto"
