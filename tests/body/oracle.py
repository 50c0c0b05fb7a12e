"""OpenSim 4.6 as the oracle for the body-model tests: load a model with its forces off, set states, read
poses, markers, mass matrices and inverse dynamics in CoordinateSet order. Importing it skips without opensim."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import DATA_ROOT

osim = pytest.importorskip("opensim", reason="the opensim package (validate extra) is the oracle here")
osim.Logger.setLevelString("error")

#: Models named in the brief, as globs under the data root (any subjects present are used).
MODEL_GLOBS = (
    "opensim-models/Models/Rajagopal/Rajagopal2016.osim",
    "opensim-models/Models/Rajagopal/RajagopalLaiUhlrich2023.osim",
    "opensim-models/Models/Gait2392_Simbody/subject01.osim",
    "opensim-models/Pipelines/Gait2392_Simbody/OutputReference/subject01_simbody.osim",
    "fukuchi-running/*/*_simple.osim",
    "fukuchi-running/generic-models/*.osim",
    "opencap/Subject4/Models/*.osim",
    "Hamner2013/*/*.osim",
    "SchreiberMoissenet2019/*/*.osim",
)


def model_paths() -> list[str]:
    """Every model of MODEL_GLOBS present, relative to the data root (for test ids)."""
    found = []
    for pattern in MODEL_GLOBS:
        found += sorted(str(p.relative_to(DATA_ROOT)) for p in DATA_ROOT.glob(pattern))
    return found


class Oracle:
    """An OpenSim model with every force disabled, all coordinates unlocked, and the coordinate -> u map."""

    def __init__(self, path: str | Path, extra_forces: tuple = ()) -> None:
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
        return np.array([vec3(joints.get(i).getChildFrame().getPositionInGround(self.state))
                         for i in range(joints.getSize())])

    def inverse_dynamics(self, qdd) -> np.ndarray:
        udot = osim.Vector(self.state.getNU(), 0.0)
        for i in range(self.n):
            udot.set(self.u_index[i], float(qdd[i]))
        tau = self.solver.solve(self.state, udot)
        return np.array([tau.get(self.u_index[i]) for i in range(self.n)])

    def mass_matrix(self) -> np.ndarray:
        matrix = osim.Matrix()
        self.model.getMatterSubsystem().calcM(self.state, matrix)
        return np.array([[matrix.get(self.u_index[i], self.u_index[j]) for j in range(self.n)]
                         for i in range(self.n)])


def vec3(v) -> list[float]:
    return [v.get(i) for i in range(3)]


def random_poses(model, rng: np.random.Generator, count: int) -> np.ndarray:
    """[count, n_q] uniform in each coordinate's range (unbounded ranges limited to +-2)."""
    low = np.clip(model.ranges[:, 0].numpy(), -2.0, 2.0)
    high = np.clip(model.ranges[:, 1].numpy(), -2.0, 2.0)
    return rng.uniform(low, high, size=(count, model.n_q))
