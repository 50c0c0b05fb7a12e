"""`refine`: a noisy motion (markerless capture, a generated clip) through the PhysPT refiner, and what
``biomotion refine`` writes for it.

The refiner (`biomotion.models.refiner`) works on the canonical skeleton (Rajagopal 2016 names, root included) at
its own rate (30 Hz) on clips placed as the training clips were (`biomotion.data.placement`): pelvis translations
at the generic 1.70 m size, the floor at y = 0. `refine` takes a `Motion` as it comes and gives it back refined on
the same clock and in the same frame:

1. checks: every value finite, the six root coordinates and the hip, knee and ankle of both legs present under
   their canonical names, and at least `MIN_FRAMES` frames at the refiner's rate; a motion failing one is refused
   with a one-line `BiomotionError` that says which. Flexion-negative knees (Fukuchi ``_simple``, Hamner 2010) are
   read as such, with a warning, and written back with the sign they came with;
2. the canonical coordinates are resampled onto a uniform grid of about 30 Hz spanning exactly the input's first
   and last times (anti-alias low-pass when that is a lower rate, `Motion.at`), placed (translations times
   1.70 m / ``height`` when the height is known, floor and start at the origin), refined, and placed back;
3. the refined coordinates are interpolated back onto the input's times (cubic spline), coordinates the refiner does
   not know or the input lacks are copied unchanged;
4. forces: the refiner's contact points give each foot's force, centre of pressure and free moment (OpenSim's
   ExternalLoads layout, applied to ``calcn_r`` / ``calcn_l``), and its torque head the generalized forces of the
   39 canonical coordinates. They are the generic model's (75.3 kg, 1.70 m); with ``mass`` (and ``height``) they
   are scaled to the person by dynamic similarity (forces x m / m₀, moments x m / m₀ x h / h₀).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES, KNEE_COORDINATES
from biomotion.data.placement import GENERIC_HEIGHT
from biomotion.data.sources import to_canonical
from biomotion.errors import BiomotionWarning, DataFormatError, ModelError
from biomotion.models.refiner import Refiner
from biomotion.motion import GroundReaction, Motion

#: Shipped weights, beside the generator's (`biomotion.generation.pipeline.CHECKPOINTS`).
REFINER_FILE = "refiner.safetensors"
#: Fewest frames a clip may have at the refiner's rate (0.27 s at 30 Hz): the contact gate and the physics difference
#: positions twice, and a Transformer window of a handful of frames has nothing to compare a frame with.
MIN_FRAMES = 8
#: Coordinates a motion must have for the refiner to take it: the floating base and the sagittal leg joints.
REQUIRED = (
    *CANONICAL_COORDINATES[:6],
    *(f"{joint}_{side}" for side in "rl" for joint in ("hip_flexion", "knee_angle", "ankle_angle")),
)


@dataclass(frozen=True)
class Refined:
    """`refine`'s result, on the input's clock: the refined motion (the input's columns), the input itself, the
    ground reaction per foot (``r``, ``l`` on ``calcn_r``/``calcn_l``), the generalized forces [T, 39] of the
    canonical coordinates (`torque_labels`), the refiner's rate and the seconds it took."""

    motion: Motion
    original: Motion
    ground_reaction: GroundReaction
    torques: np.ndarray
    torque_labels: tuple[str, ...]
    rate: float
    seconds: float


def default_refiner_path() -> Path:
    from biomotion.generation.pipeline import CHECKPOINTS

    return CHECKPOINTS / REFINER_FILE


def load_refiner(model: Refiner | str | Path | None = None, data_root: str | Path | None = None) -> Refiner:
    """``model`` itself when it is a `Refiner`, else the weights at ``model`` (default: the shipped ones) on the
    canonical body from ``data_root`` (default `biomotion.settings.default_data_root`)."""
    if isinstance(model, Refiner):
        return model
    from biomotion.data.clips import body_model
    from biomotion.settings import default_data_root

    return Refiner.load(
        Path(model) if model is not None else default_refiner_path(), body_model(data_root or default_data_root())
    )


def check_motion(motion: Motion, rate: float, source: str | Path | None = None) -> None:
    """Refuse what the refiner cannot take (module docstring, step 1), naming what is wrong."""
    finite = np.isfinite(motion.values)
    if not finite.all():
        frame, column = np.argwhere(~finite)[0]
        raise DataFormatError(
            source, "holds NaN or inf: the refiner needs every value (fill gaps first)", frame=int(frame),
            field=motion.names[column],
        )  # fmt: skip
    missing = [n for n in REQUIRED if n not in motion.names or not motion.mask[motion.index(n)]]
    if missing:
        known = sum(n in CANONICAL_COORDINATES for n in motion.names)
        raise ModelError(
            f"{source or 'motion'}: unknown skeleton for the refiner: it needs the Rajagopal-family coordinates "
            f"{', '.join(missing)} ({known} of its {len(motion.names)} columns are canonical names)"
        )
    frames = int(round(motion.duration * rate)) + 1 if motion.n_frames > 1 else 1
    if frames < MIN_FRAMES:
        raise DataFormatError(
            source,
            f"too short for the refiner: {motion.n_frames} frames over {motion.duration:.3f} s are {frames} frames "
            f"at its {rate:g} Hz, it needs at least {MIN_FRAMES} ({(MIN_FRAMES - 1) / rate:.2f} s)",
        )


def _knees_negative(motion: Motion) -> bool:
    knees = [motion[n] for n in KNEE_COORDINATES if n in motion.names]
    return bool(knees) and float(np.median(np.concatenate(knees))) < 0.0


@dataclass(frozen=True)
class _Placement:
    """The translation scale and offset that put a clip where the refiner's training clips were."""

    scale: float
    offset: np.ndarray  # [3] subtracted from pelvis_tx/ty/tz after scaling

    def place(self, q: np.ndarray) -> np.ndarray:
        out = q.copy()
        out[:, 3:6] = out[:, 3:6] * self.scale - self.offset
        return out

    def unplace(self, q: np.ndarray) -> np.ndarray:
        out = q.copy()
        out[:, 3:6] = (out[:, 3:6] + self.offset) / self.scale
        return out

    def unplace_points(self, p: np.ndarray) -> np.ndarray:
        return (p + self.offset) / self.scale


def _placement(q: np.ndarray, mask: np.ndarray, refiner: Refiner, height: float | None) -> _Placement:
    from biomotion.body.contact import GROUND_PERCENTILE, lowest_foot_heights

    scale = GENERIC_HEIGHT / height if height else 1.0
    scaled = q.copy()
    scaled[:, 3:6] *= scale
    full = np.where(mask[None], scaled, refiner.body.defaults.double().numpy()[None]).astype(np.float32)
    floor = np.percentile(lowest_foot_heights(refiner.body, full), GROUND_PERCENTILE)
    return _Placement(scale, np.array([scaled[0, 3], floor, scaled[0, 5]]))


def _per_foot(forces: np.ndarray, positions: np.ndarray, feet: tuple[str, ...]) -> tuple[np.ndarray, ...]:
    """Per foot (right, left): force [T, 2, 3], centre of pressure on the floor [T, 2, 3] (NaN under 1 N) and free
    moment about it [T, 2, 3] (vertical part) from point forces and positions [T, K, 3]."""
    force, cop, moment = [], [], []
    for side in ("r", "l"):
        pick = np.array([f == side for f in feet])
        f, p = forces[:, pick], positions[:, pick]
        vertical = f[..., 1].sum(1)
        centre = (f[..., 1:2] * p).sum(1) / np.maximum(vertical, 1e-9)[:, None]
        centre[:, 1] = 0.0
        centre[vertical < 1.0] = np.nan
        arm = p - np.nan_to_num(centre)[:, None]
        torque = np.cross(arm, f).sum(1)
        force.append(f.sum(1))
        cop.append(centre)
        moment.append(np.stack([np.zeros(len(f)), torque[:, 1], np.zeros(len(f))], -1))
    return np.stack(force, 1), np.stack(cop, 1), np.stack(moment, 1)


def refine(
    motion: Motion,
    model: Refiner | str | Path | None = None,
    *,
    data_root: str | Path | None = None,
    height: float | None = None,
    mass: float | None = None,
    source: str | Path | None = None,
) -> Refined:
    """Refine ``motion`` with the PhysPT refiner ``model`` (a `Refiner`, a weights file, or None for the shipped
    one); see the module docstring. ``height`` (m) and ``mass`` (kg) of the person scale the placement and the
    forces; ``source`` names the motion in errors."""
    refiner = load_refiner(model, data_root)
    rate = refiner.config.rate
    check_motion(motion, rate, source)
    started = time.perf_counter()
    flipped = _knees_negative(motion)
    if flipped:
        warnings.warn(
            f"{source or 'motion'}: knee angles mostly negative: read as a flexion-negative model (Fukuchi "
            "_simple, Hamner 2010) and written back with that sign",
            BiomotionWarning,
            stacklevel=2,
        )
    canonical = to_canonical(motion, knee_flipped=flipped)
    count = int(round(motion.duration * rate)) + 1
    grid = canonical.at(np.linspace(motion.times[0], motion.times[-1], count))
    mask = canonical.mask.copy()
    placement = _placement(grid.values, mask, refiner, height)
    q = torch.from_numpy(placement.place(grid.values)).float()
    result = refiner.refine(q, torch.from_numpy(mask))
    refined_grid = grid.with_values(placement.unplace(result.q.double().numpy()))
    back = refined_grid.at(motion.times).values
    values = motion.values.copy()
    for j, name in enumerate(CANONICAL_COORDINATES):
        if mask[j] and name in motion.names:
            column = back[:, j] * (-1.0 if flipped and name in KNEE_COORDINATES else 1.0)
            values[:, motion.index(name)] = column
    size = (height / GENERIC_HEIGHT) if height else 1.0
    force_scale = (mass / float(refiner.body.total_mass)) if mass else 1.0
    force, cop, moment = _per_foot(
        result.point_forces.double().numpy(), result.point_positions.double().numpy(), result.points.feet
    )
    cop = placement.unplace_points(cop)
    ground = GroundReaction(
        times=grid.times,
        names=("r", "l"),
        force=force * force_scale,
        cop=cop,
        moment=moment * force_scale * size,
        bodies=("calcn_r", "calcn_l"),
    )
    translational = np.array([kind == "translational" for kind in refiner.body.motion_types])
    torques = result.torques.double().numpy() * force_scale * np.where(translational, 1.0, size)
    torques = np.stack([np.interp(motion.times, grid.times, column) for column in torques.T], 1)
    on_clock = GroundReaction(
        times=motion.times,
        names=ground.names,
        force=_interp(motion.times, grid.times, ground.force),
        cop=_interp(motion.times, grid.times, ground.cop),
        moment=_interp(motion.times, grid.times, ground.moment),
        bodies=ground.bodies,
    )
    labels = tuple(
        f"{name}_{'force' if kind == 'translational' else 'moment'}"
        for name, kind in zip(refiner.body.coordinate_names, refiner.body.motion_types)
    )
    return Refined(motion.with_values(values), motion, on_clock, torques, labels, rate, time.perf_counter() - started)


def _interp(times: np.ndarray, grid: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of [T_grid, ...] values onto ``times`` (NaN stays NaN where a neighbour is NaN)."""
    flat = values.reshape(len(grid), -1)
    out = np.stack([np.interp(times, grid, column) for column in flat.T], 1)
    return out.reshape(len(times), *values.shape[1:])


# ---- files ----------------------------------------------------------------------------------------------------


def write_refined(out: str | Path, refined: Refined, *, name: str = "refined", figures: bool = True) -> dict[str, Path]:
    """Write ``<name>.mot`` (the refined coordinates, degrees), ``grf.mot`` + ``grf_loads.xml`` (an OpenSim
    ExternalLoads pair for the inverse-dynamics tool), ``torques.sto`` (OpenSim's ``_moment``/``_force`` columns)
    and, with ``figures``, ``before_after.png``; returns the files by role."""
    from biomotion.io.mot import write_external_loads_xml, write_ground_reaction, write_motion, write_storage

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "motion": write_motion(out / f"{name}.mot", refined.motion, name=name),
        "grf": write_ground_reaction(out / "grf.mot", refined.ground_reaction, name="grf"),
        "grf_loads": write_external_loads_xml(out / "grf_loads.xml", refined.ground_reaction, "grf.mot"),
        "torques": write_storage(
            out / "torques.sto",
            refined.torque_labels,
            refined.motion.times,
            refined.torques,
            name="Generalized forces (PhysPT refiner)",
        ),
    }
    if figures:
        files["plot"] = plot_before_after(refined, out / "before_after.png")
    return files


PLOTTED = ("pelvis_ty", "pelvis_tx", "hip_flexion_r", "knee_angle_r", "ankle_angle_r", "lumbar_extension")


def plot_before_after(refined: Refined, path: str | Path) -> Path:
    """Input and refined coordinates (a few, in degrees or m) over time, and each foot's vertical ground force."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in PLOTTED if n in refined.motion.names]
    figure, axes = plt.subplots(len(names) + 1, 1, figsize=(8, 1.8 * (len(names) + 1)), sharex=True)
    times = refined.motion.times
    for axis, name in zip(axes, names):
        scale = 1.0 if name.startswith("pelvis_t") else 180.0 / np.pi
        axis.plot(times, refined.original[name] * scale, color="0.6", lw=1, label="input")
        axis.plot(times, refined.motion[name] * scale, color="C0", lw=1.5, label="refined")
        axis.set_ylabel(f"{name}\n({'m' if scale == 1.0 else 'deg'})", fontsize=8)
    axes[0].legend(fontsize=8, loc="upper right")
    for j, side in enumerate(refined.ground_reaction.names):
        axes[-1].plot(times, refined.ground_reaction.force[:, j, 1], lw=1.2, label=f"foot {side}")
    axes[-1].set_ylabel("vertical GRF\n(N)", fontsize=8)
    axes[-1].set_xlabel("time (s)")
    axes[-1].legend(fontsize=8, loc="upper right")
    figure.suptitle("PhysPT refiner: input and refined motion, inferred ground force", fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return Path(path)
