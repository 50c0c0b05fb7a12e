"""Musculotendon lengths and moment arms sampled from OpenSim 4.6, the oracle of the muscle-path fit and of its
validation (needs ``opensim``, the ``validate`` extra; imported only when an instance is made)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

FD_STEP = 1e-5  # rad (or m): central-difference step of the length derivatives (span probe, -dL/dq)
PROGRESS_FROM = 200  # sampling passes over this many poses show a progress bar


class OpenSimPaths:
    """Musculotendon lengths and moment arms of an .osim model from OpenSim (the oracle; needs ``opensim``)."""

    def __init__(self, model_path: str | Path) -> None:
        from biomotion.io.osim import read_osim
        from biomotion.settings import opensim_oracle

        # biomotion's reader first: it refuses entity declarations (OpenSim's parser would expand a "billion laughs")
        # and names the file and line of what is wrong, where OpenSim raises a C++ exception
        read_osim(model_path)
        opensim = opensim_oracle()

        opensim.Logger.setLevelString("error")
        self.opensim = opensim
        self.model = opensim.Model(str(model_path))
        coordinate_set = self.model.getCoordinateSet()
        self.coordinates = [coordinate_set.get(i) for i in range(coordinate_set.getSize())]
        for c in self.coordinates:
            c.set_locked(False)
        self.state = self.model.initSystem()
        self.coordinate_names = tuple(c.getName() for c in self.coordinates)
        muscles = self.model.getMuscles()
        self.muscles = [muscles.get(i) for i in range(muscles.getSize())]
        self.muscle_names = tuple(m.getName() for m in self.muscles)
        self.paths = [m.getGeometryPath() for m in self.muscles]
        self.couplers = []  # (dependent index, independent index, function, scale)
        constraints = self.model.getConstraintSet()
        index = {n: i for i, n in enumerate(self.coordinate_names)}
        for i in range(constraints.getSize()):
            coupler = opensim.CoordinateCouplerConstraint.safeDownCast(constraints.get(i))
            if coupler is not None and coupler.get_isEnforced():
                self.couplers.append(
                    (
                        index[coupler.getDependentCoordinateName()],
                        index[coupler.getIndependentCoordinateNames().get(0)],
                        coupler.getFunction(),
                        float(coupler.getPropertyByName("scale_factor").toString()),
                    )
                )
        self.dependent = {d for d, _, _, _ in self.couplers}
        self.ranges = np.array([[c.getRangeMin(), c.getRangeMax()] for c in self.coordinates])
        self.defaults = np.array([c.getDefaultValue() for c in self.coordinates])

    def _set(self, q: np.ndarray) -> None:
        q = q.copy()
        for dependent, independent, function, scale in self.couplers:
            q[dependent] = scale * function.calcValue(self.opensim.Vector(1, float(q[independent])))
        for c, value in zip(self.coordinates, q):
            c.setValue(self.state, float(value), False)
        self.model.realizePosition(self.state)

    def _poses(self, q: np.ndarray, what: str):
        """``q``'s poses, with a progress bar on a pass of at least `PROGRESS_FROM` poses (the minutes of a fit)."""
        return tqdm(q, desc=f"OpenSim {what}", unit="pose", leave=False, disable=len(q) < PROGRESS_FROM)

    def lengths(self, q: np.ndarray) -> np.ndarray:
        """[N, M] lengths at poses ``q`` [N, n_q] (dependent coordinates are overwritten by their couplers)."""
        out = np.empty((len(q), len(self.paths)))
        for n, pose in enumerate(self._poses(q, "lengths")):
            self._set(pose)
            out[n] = [p.getLength(self.state) for p in self.paths]
        return out

    def difference_moment_arms(self, q: np.ndarray, columns: list[int]) -> np.ndarray:
        """[N, M, len(columns)] moment arms -dL/dq by central differences (total derivative through couplers)."""
        out = np.empty((len(q), len(self.paths), len(columns)))
        for j, column in enumerate(columns):
            step = np.zeros(q.shape[1])
            step[column] = FD_STEP
            out[:, :, j] = -(self.lengths(q + step) - self.lengths(q - step)) / (2 * FD_STEP)
        return out

    def moment_arms(self, q: np.ndarray, pairs: list[tuple[int, int]]) -> np.ndarray:
        """[N, len(pairs)] OpenSim's own moment arms (``GeometryPath.computeMomentArm``) for (muscle, coordinate)."""
        out = np.empty((len(q), len(pairs)))
        for n, pose in enumerate(self._poses(q, "moment arms")):
            self._set(pose)
            out[n] = [self.paths[m].computeMomentArm(self.state, self.coordinates[c]) for m, c in pairs]
        return out

    def configuration(self, m: int) -> str:
        """The current path configuration of muscle ``m`` (after `_set`): its active points in order, each wrap
        object that touches the path named where it acts, with the side it wraps on (sign of the z component of
        the two tangent points' cross product in the wrap object's frame: for a cylinder, which way round)."""
        path = self.paths[m]
        path.getLength(self.state)  # brings the path up to date
        current = path.getCurrentPath(self.state)
        ground = self.model.getGround()
        names, tangent = [], []
        for i in range(current.getSize()):
            point = current.get(i)
            if point.getConcreteClassName() != "PathWrapPoint":
                names.append(point.getName())
                continue
            wrap = self.opensim.PathWrapPoint.safeDownCast(point).getWrapObject()
            local = ground.findStationLocationInAnotherFrame(
                self.state, point.getLocationInGround(self.state), wrap.getFrame()
            )
            local = wrap.getTransform().shiftBaseStationToFrame(local)
            tangent.append((local.get(0), local.get(1)))
            if len(tangent) == 2:
                (x1, y1), (x2, y2) = tangent
                names.append(f"{wrap.getName()}{'+' if x1 * y2 - y1 * x2 > 0 else '-'}")
                tangent = []
        return "|".join(names)

    def configurations(self, q: np.ndarray) -> list[list[str]]:
        """[N][M] path configurations at poses ``q``."""
        out = []
        for pose in self._poses(q, "path configurations"):
            self._set(pose)
            out.append([self.configuration(m) for m in range(len(self.paths))])
        return out

    def muscle_samples(self, q: np.ndarray, m: int, coordinates: list[int]) -> tuple[np.ndarray, np.ndarray, list]:
        """Length [N], moment arms [N, len(coordinates)] and configurations [N] of muscle ``m`` alone."""
        lengths, arms, configurations = np.empty(len(q)), np.empty((len(q), len(coordinates))), []
        for n, pose in enumerate(q):
            self._set(pose)
            configurations.append(self.configuration(m))
            lengths[n] = self.paths[m].getLength(self.state)
            arms[n] = [self.paths[m].computeMomentArm(self.state, self.coordinates[c]) for c in coordinates]
        return lengths, arms, configurations

    def sample_poses(self, ranges: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
        """[n, n_q] poses uniform in ``ranges`` where finite, default values elsewhere."""
        q = np.tile(self.defaults, (n, 1))
        free = np.isfinite(ranges).all(1)
        q[:, free] = rng.uniform(ranges[free, 0], ranges[free, 1], size=(n, int(free.sum())))
        return q
