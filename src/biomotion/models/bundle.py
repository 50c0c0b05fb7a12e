"""What a trained generator ships in one safetensors file: prior weights, action vocabulary, guidance bounds.

The guidance bounds are PG-BIG Table 1's statistical limits, measured on the training split per action (a run's
COM speed has nothing in common with a squat's): the 95th percentile of each coordinate's |dq/dt| and the
5th/95th percentiles of COM speed and COM acceleration magnitude; and, in the same form, the 95th percentile of
each coordinate's |d3q/dt3| for the smoothness term we add (`biomotion.guidance.losses.angular_jerk`). Actions with too
few frames fall back to the bounds over all actions (key ``"*"``). With them goes each action's population posture,
from which `biomotion.generation.posture` measures how a person's reference clips deviate from the population: per
coordinate, a least-squares line through the training clips' mean values against their labelled speed,
P(v) = P + b (v - v_mean) (running faster bends the knees more: 4.7 deg per m/s on the training runners), or the
mean of the clips' means where the action's clips do not all carry a speed or share one. The population amplitude
is the same line through each clip's standard deviation over time per coordinate, from which
`biomotion.generation.posture.amplitude_ratio` measures how much more or less than the population a person moves
each joint (the identity term of `biomotion.guidance.losses.amplitude`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.errors import ModelError
from biomotion.models.actions import ActionVocabulary
from biomotion.models.prior import PriorConfig, ProfileActionPrior

FORMAT = "biomotion-generator/1"
ALL_ACTIONS = "*"
MIN_FRAMES = 30  # fewer frames of an action than this: use the all-action bounds


@dataclass(frozen=True)
class GuidanceBounds:
    """Percentile bounds of one action: ``speed_high`` [39] (rad/s or m/s, NaN where never observed),
    ``com_speed`` (low, high) m/s, ``com_acceleration`` (low, high) m/s^2, and the frames behind them; the
    population posture: ``posture`` [39] (NaN where never observed) at the mean labelled speed ``posture_speed``
    (m/s, NaN without speeds) and its change per m/s ``posture_slope`` [39] (module docstring; all empty in
    bundles saved before postures existed)."""

    speed_high: tuple[float, ...]
    com_speed: tuple[float, float]
    com_acceleration: tuple[float, float]
    frames: int
    jerk_high: tuple[float, ...] = ()
    posture: tuple[float, ...] = ()
    posture_slope: tuple[float, ...] = ()
    posture_speed: float = float("nan")
    amplitude: tuple[float, ...] = ()
    amplitude_slope: tuple[float, ...] = ()
    energy: tuple[float, ...] = ()

    def to_dict(self) -> dict:
        finite = lambda values: [None if not np.isfinite(v) else v for v in values]
        return {
            "speed_high": finite(self.speed_high),
            "jerk_high": finite(self.jerk_high),
            "com_speed": list(self.com_speed),
            "com_acceleration": list(self.com_acceleration),
            "frames": self.frames,
            "posture": finite(self.posture),
            "posture_slope": finite(self.posture_slope),
            "posture_speed": finite([self.posture_speed])[0],
            "amplitude": finite(self.amplitude),
            "amplitude_slope": finite(self.amplitude_slope),
            "energy": finite(self.energy),
        }

    @classmethod
    def from_dict(cls, d: dict) -> GuidanceBounds:
        values = lambda key: tuple(float("nan") if v is None else float(v) for v in d.get(key, ()))
        speed = d.get("posture_speed")
        return cls(
            values("speed_high"),
            tuple(d["com_speed"]),
            tuple(d["com_acceleration"]),
            int(d["frames"]),
            values("jerk_high"),
            values("posture"),
            values("posture_slope"),
            float("nan") if speed is None else float(speed),
            values("amplitude"),
            values("amplitude_slope"),
            values("energy"),
        )


def _p95(rows: np.ndarray) -> tuple[float, ...]:
    with np.errstate(all="ignore"):
        return tuple(float(np.nanpercentile(col, 95)) if np.isfinite(col).any() else float("nan") for col in rows.T)


def population_posture(
    clip_means: np.ndarray, speeds: np.ndarray, *, with_speed: bool = True
) -> tuple[tuple[float, ...], tuple[float, ...], float]:
    """(posture at the mean speed, slope per m/s, mean speed) from the clips' mean coordinates [C, 39] (NaN where
    a clip lacks a coordinate) and labelled speeds [C] (NaN where unlabelled). The slope is fitted, per coordinate,
    over the clips that have it, only when ``with_speed`` and every clip has a speed and not all are the same;
    otherwise it is 0 and the posture is the mean of the clips' means."""
    use_speed = with_speed and bool(np.isfinite(speeds).all()) and np.ptp(speeds) > 0
    centre = float(speeds.mean()) if use_speed else float("nan")
    posture, slope = [], []
    for column in clip_means.T:
        known = np.isfinite(column)
        if not known.any():
            posture.append(float("nan"))
            slope.append(0.0)
        elif use_speed and np.ptp(speeds[known]) > 0:
            b, a = np.polyfit(speeds[known] - centre, column[known], 1)
            posture.append(float(a))
            slope.append(float(b))
        else:
            posture.append(float(column[known].mean()))
            slope.append(0.0)
    return tuple(posture), tuple(slope), centre


def _bounds(
    speeds: list[np.ndarray],
    jerks: list[np.ndarray],
    com_v: list[np.ndarray],
    com_a: list[np.ndarray],
    clip_means: list[np.ndarray],
    clip_speeds: list[float],
    clip_stds: list[np.ndarray],
    clip_energies: list[float],
    per_action: bool,
) -> GuidanceBounds:
    v, a = np.concatenate(com_v), np.concatenate(com_a)
    labelled = np.array(clip_speeds, dtype=np.float64)
    posture = population_posture(np.stack(clip_means), labelled, with_speed=per_action)
    amplitude, amplitude_slope, _ = population_posture(np.stack(clip_stds), labelled, with_speed=per_action)
    (energy,), (energy_slope,), _ = population_posture(
        np.array(clip_energies, dtype=np.float64)[:, None], labelled, with_speed=per_action
    )
    return GuidanceBounds(
        _p95(np.concatenate(speeds)),
        (float(np.percentile(v, 5)), float(np.percentile(v, 95))),
        (float(np.percentile(a, 5)), float(np.percentile(a, 95))),
        len(v),
        _p95(np.concatenate(jerks)),
        *posture,
        amplitude,
        amplitude_slope,
        (energy, energy_slope),
    )


GRAVITY = 9.80665  # m/s^2, as `biomotion.metrics.smoothness`


def com_energy_per_kg(com, rate: float):
    """[T - 1] mechanical energy of the whole-body COM as a point mass, per kg of body mass (J/kg): 1/2 |c'|^2 +
    g c_y with forward differences and heights averaged over each frame pair, exactly `biomotion.metrics.smoothness
    .mechanical_energy` over the body mass (its std over a clip is PG-BIG Sec. 4.2's energy consistency per kg).
    ``com`` [..., T, 3] (m, y up), a NumPy array or a tensor (differentiable)."""
    velocity = (com[..., 1:, :] - com[..., :-1, :]) * rate
    height = 0.5 * (com[..., 1:, 1] + com[..., :-1, 1])
    return 0.5 * (velocity**2).sum(-1) + GRAVITY * height


@torch.no_grad()
def action_bounds(cache, body, indices: list[int]) -> dict[str, GuidanceBounds]:
    """Per-action `GuidanceBounds` over the clips ``indices`` of ``cache`` (forward differences at the cache rate;
    COM from the canonical ``body`` model, absent coordinates at the model default)."""
    from biomotion.body.kinematics import center_of_mass
    from biomotion.metrics.plausibility import com_acceleration, com_speed

    rate = cache.rate
    defaults = body.defaults.numpy()
    groups: dict[str, tuple[list, list, list, list]] = {}
    for i in indices:
        record = cache.records[i]
        q = np.asarray(cache.values[record["offset"] : record["offset"] + record["n_frames"]], dtype=np.float64)
        if len(q) < 4:
            continue
        mask = cache.masks[i]
        speed = np.abs(np.diff(q, axis=0)) * rate
        speed[:, ~mask] = np.nan
        mean = np.where(mask, q.mean(0), np.nan)
        amplitude = np.where(mask, q.std(0), np.nan)
        labelled = record["labels"].get("speed")
        jerk = np.abs(np.diff(q, 3, axis=0)) * rate**3
        jerk[:, ~mask] = np.nan
        full = np.where(mask[None], q, defaults[None])
        com = center_of_mass(body, torch.from_numpy(full).to(body.dtype))
        v, a = com_speed(com, rate)[:, 0].numpy(), com_acceleration(com, rate)[:, 0].numpy()
        energy = float(com_energy_per_kg(com.numpy(), rate).std())
        for key in (record["labels"]["action"], ALL_ACTIONS):
            bucket = groups.setdefault(key, ([], [], [], [], [], [], [], []))
            labelled_speed = np.nan if labelled is None else labelled
            for items, value in zip(bucket, (speed, jerk, v, a, mean, labelled_speed, amplitude, energy)):
                items.append(value)
    return {
        k: _bounds(*g, per_action=k != ALL_ACTIONS)
        for k, g in groups.items()
        if k == ALL_ACTIONS or sum(map(len, g[2])) >= MIN_FRAMES
    }


class GeneratorBundle:
    """A trained prior with its vocabulary and guidance bounds (saved together, loaded together)."""

    def __init__(
        self,
        prior: ProfileActionPrior,
        vocabulary: ActionVocabulary,
        bounds: dict[str, GuidanceBounds],
        tokenizer_sha256: str = "",
        train_subjects: tuple[str, ...] = (),
    ) -> None:
        self.prior, self.vocabulary, self.bounds = prior, vocabulary, bounds
        self.tokenizer_sha256 = tokenizer_sha256
        #: "source/subject" of every training clip's subject: anyone else is unseen (`biomotion eval generation`)
        self.train_subjects = tuple(train_subjects)

    def bounds_for(self, action: str) -> GuidanceBounds:
        """The action's bounds, or the all-action bounds when the action had too few training frames."""
        return self.bounds.get(action, self.bounds[ALL_ACTIONS])

    def posture(self, action: str, speed: float | None = None) -> torch.Tensor | None:
        """[39] the action's population posture at ``speed`` (m/s; None: at the action's mean speed) — the
        all-action one where the action never had a coordinate, NaN where no training clip had it — or None for
        a bundle saved without postures."""
        own, everyone = self.bounds_for(action), self.bounds[ALL_ACTIONS]
        if not own.posture or not everyone.posture:
            return None
        posture = torch.tensor(own.posture, dtype=torch.float64)
        if speed is not None and np.isfinite(own.posture_speed):
            posture = posture + torch.tensor(own.posture_slope, dtype=torch.float64) * (speed - own.posture_speed)
        return torch.where(torch.isfinite(posture), posture, torch.tensor(everyone.posture, dtype=torch.float64))

    def amplitude(self, action: str, speed: float | None = None) -> torch.Tensor | None:
        """[39] the action's population amplitude at ``speed`` (each coordinate's standard deviation over a clip,
        a line in the labelled speed as `posture`; the all-action one where the action never had a coordinate,
        NaN where no training clip had it), or None for a bundle saved without amplitudes."""
        own, everyone = self.bounds_for(action), self.bounds[ALL_ACTIONS]
        if not own.amplitude or not everyone.amplitude:
            return None
        amplitude = torch.tensor(own.amplitude, dtype=torch.float64)
        if speed is not None and np.isfinite(own.posture_speed):
            amplitude = amplitude + torch.tensor(own.amplitude_slope, dtype=torch.float64) * (speed - own.posture_speed)
        amplitude = torch.where(
            torch.isfinite(amplitude), amplitude, torch.tensor(everyone.amplitude, dtype=torch.float64)
        )
        return amplitude.clamp_min(0.0)

    def energy(self, action: str, speed: float | None = None) -> float | None:
        """The action's population COM energy fluctuation at ``speed``: the std over a clip of `com_energy_per_kg`
        (J/kg), a line in the labelled speed as `posture` (the all-action value where the action has none), or
        None for a bundle saved without it."""
        own, everyone = self.bounds_for(action), self.bounds[ALL_ACTIONS]
        chosen = own if len(own.energy) == 2 and np.isfinite(own.energy[0]) else everyone
        if len(chosen.energy) != 2 or not np.isfinite(chosen.energy[0]):
            return None
        value, slope = chosen.energy
        if speed is not None and chosen is own and np.isfinite(own.posture_speed):
            value += slope * (speed - own.posture_speed)
        return max(float(value), 0.0)

    def high(self, action: str, quantity: str = "speed_high") -> torch.Tensor:
        """[39] upper bound of ``quantity`` (``speed_high`` or ``jerk_high``); coordinates never observed for the
        action take the all-action bound, and those never observed at all are unbounded."""
        own = torch.tensor(getattr(self.bounds_for(action), quantity))
        fallback = torch.tensor(getattr(self.bounds[ALL_ACTIONS], quantity))
        return torch.where(torch.isfinite(own), own, fallback).nan_to_num(float("inf"))

    def save(self, path: str | Path) -> None:
        from safetensors.torch import save

        from biomotion.io.atomic import atomic_write

        state = {k: v.detach().contiguous().cpu() for k, v in self.prior.state_dict().items()}
        metadata = {
            "format": FORMAT,
            "config": json.dumps(self.prior.config.to_dict()),
            "vocabulary": json.dumps(self.vocabulary.to_dict()),
            "bounds": json.dumps({k: b.to_dict() for k, b in self.bounds.items()}),
            "coordinates": json.dumps(list(CANONICAL_COORDINATES)),
            "tokenizer_sha256": self.tokenizer_sha256,
            "train_subjects": json.dumps(list(self.train_subjects)),
        }
        with atomic_write(path, "wb") as handle:
            handle.write(save(state, metadata=metadata))

    @classmethod
    def load(cls, path: str | Path) -> GeneratorBundle:
        from biomotion.io.tensors import read_metadata, read_tensors

        path = Path(path)
        if not path.exists():
            raise ModelError(f"generator weights not found: {path}")
        meta = read_metadata(path, "generator weights")
        if meta.get("format") != FORMAT:
            raise ModelError(f"{path}: not a biomotion generator ({FORMAT}); format is {meta.get('format')!r}")
        prior = ProfileActionPrior(PriorConfig.from_dict(json.loads(meta["config"])))
        prior.load_state_dict(read_tensors(path, "generator weights"))
        bounds = {k: GuidanceBounds.from_dict(v) for k, v in json.loads(meta["bounds"]).items()}
        return cls(
            prior.eval(),
            ActionVocabulary.from_dict(json.loads(meta["vocabulary"])),
            bounds,
            meta.get("tokenizer_sha256", ""),
            tuple(json.loads(meta.get("train_subjects", "[]"))),
        )
