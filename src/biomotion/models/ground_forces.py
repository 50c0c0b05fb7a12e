"""Learned ground reaction: a small temporal network that corrects Newton's ground force m(g + a_COM) from the
kinematics, trained supervised on force plates (`biomotion.models.ground_forces_fit`).

Why: from motion alone the PhysPT contact model (Sec. 3.2.3, Eq. 4-5; `biomotion.body.contact`) can only place the
root force the kinematics ask for, and that force is Newton's m(g + a_COM) up to the model's mass distribution and
the filtering of the coordinates: on the Fukuchi runners both read about 0.2 BW RMSE against the plates
(``validate dynamics``). What they miss is systematic — the upper body that the runners' models lump into the
pelvis, the impact the 10 Hz low-pass of the markers smooths away — and can be learned from plates. GaitDynamics
(Tan et al. 2024, "Dynamics as a prior for learning ground reaction forces from kinematics") learns vertical GRF from
kinematics to about 0.12 BW; here the network is much smaller and predicts a *correction* to the physics baseline,
so where the baseline is already right (walking, squats) it has little to add.

Inputs: the per-frame features of `biomotion.analysis.ground_features` (dimensionless: forces in body weights,
accelerations in g, lengths in leg lengths, horizontal vectors in the pelvis's heading frame), resampled to
`GroundForcesConfig.rate_hz` and standardised with the training set's mean and spread. Outputs per frame (`OUTPUTS`):
the total ground force's correction to the baseline in body weights (forward, up, right), the right foot's share of
the total (logit), and each foot's centre of pressure as a fraction along its heel-to-toe axis and a sideways offset
in leg lengths. `LearnedGroundReaction.predict` turns them into per-foot forces in N and CoPs in m in the ground frame,
vertical force non-negative; `ground_reaction` is the estimator `biomotion.analysis.chain.analyze` takes
(``estimator=``) to compute joint torques from learned forces.

Network (`GroundForceNet`): a 1x1 input projection, residual blocks of dilated "same" 1-D convolutions (kernel 5,
dilations 1, 2, 4, 8: a receptive field of 61 frames, 0.6 s at 100 Hz, about one running stride), a 1x1 output
projection. The three force corrections have their local mean removed (a Hann window of ``zero_mean_s``): by
Newton's second law the impulse of the ground force over any stretch of time is m·(g·Δt + Δv_COM), which the
baseline already has whenever the COM's velocity is right, and what it misses — segments lumped into the pelvis
moving relative to it, soft tissue, the low-pass of the coordinates — is motion about the model's COM that stays
bounded, so its force averages out. The correction may reshape the force within a stride (sharpen an impact,
move a peak) but not add or remove body weight, which is what it would otherwise do on motions unlike its
training trials. Predictions are averaged with those on the left-right mirror image of the input (`MIRROR_INDEX`), so
the two feet are treated alike. Weights and config are one ``.safetensors`` file, the config and the feature names
in its metadata (`save`, `load`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from biomotion.analysis.chain import Analysis
from biomotion.analysis.ground_features import (
    FEATURE_NAMES,
    MIRROR_INDEX,
    MIRROR_SIGN,
    GroundFeatures,
    check_motion,
    from_heading,
    ground_features,
)
from biomotion.body.model import BodyModel
from biomotion.errors import ConfigError, ModelError
from biomotion.motion import GroundReaction, Motion
from biomotion.settings import settings_from_dict

FORMAT = "biomotion.ground_forces.v1"
#: the shipped checkpoint, trained on every Fukuchi runner of ../shared/data (checkpoints/ground_forces.md)
SHIPPED = Path(__file__).resolve().parents[3] / "checkpoints" / "ground_forces.safetensors"
#: output channels, in order
OUTPUTS = (
    "delta_forward_bw",
    "delta_vertical_bw",
    "delta_right_bw",
    "share_right_logit",
    "cop_along_r",
    "cop_side_r",
    "cop_along_l",
    "cop_side_l",
)
#: the heel-to-toe fraction a CoP may take: sigmoid output mapped to [−0.1, 1.1] of the axis
ALONG_RANGE = (-0.1, 1.1)
#: below this vertical force (N) a foot's CoP is undefined (NaN) and its load is left out
MIN_FOOT_FORCE_N = 1.0


@dataclass(frozen=True)
class GroundForcesConfig:
    """Network settings (YAML ``model:``; stored in the weights' metadata)."""

    width: int = 48
    kernel: int = 5
    dilations: tuple[int, ...] = (1, 2, 4, 8)
    dropout: float = 0.1
    rate_hz: float = 100.0
    cutoff_hz: float = 10.0  # low-pass of the coordinates the features are computed on
    zero_mean_s: float = 1.0  # the force corrections have zero local mean over a Hann window this long (0: off)
    features: tuple[str, ...] = FEATURE_NAMES

    @classmethod
    def from_dict(cls, values: dict) -> GroundForcesConfig:
        values = dict(values)
        for key in ("dilations", "features"):
            if key in values:
                values[key] = tuple(values[key])
        config = settings_from_dict(cls, values, "ground-forces model")
        if config.kernel < 1 or config.kernel % 2 == 0:
            raise ConfigError(f"ground-forces kernel must be odd, got {config.kernel}")
        unknown = sorted(set(config.features) - set(FEATURE_NAMES))
        if unknown:
            raise ConfigError(f"unknown ground-forces features: {unknown}; known: {list(FEATURE_NAMES)}")
        if config.rate_hz <= 0 or config.cutoff_hz <= 0 or config.zero_mean_s < 0:
            raise ConfigError("ground-forces rate_hz and cutoff_hz must be positive, zero_mean_s at least 0")
        return config

    @property
    def receptive_field(self) -> int:
        """Frames one output depends on."""
        return 1 + (self.kernel - 1) * sum(self.dilations)


class _Block(nn.Module):
    """x + Conv1x1(Dropout(GELU(Conv_k,dilated(GELU(x)))))."""

    def __init__(self, width: int, kernel: int, dilation: int, dropout: float) -> None:
        super().__init__()
        self.conv = nn.Conv1d(
            width, width, kernel, padding=dilation * (kernel // 2), dilation=dilation, padding_mode="replicate"
        )
        self.mix = nn.Conv1d(width, width, 1)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.mix(self.dropout(F.gelu(self.conv(F.gelu(x)))))


class GroundForceNet(nn.Module):
    """Standardised features [B, T, F] -> raw outputs [B, T, len(OUTPUTS)] (`OUTPUTS`)."""

    def __init__(self, config: GroundForcesConfig) -> None:
        super().__init__()
        self.config = config
        n = len(config.features)
        self.register_buffer("mean", torch.zeros(n))
        self.register_buffer("scale", torch.ones(n))
        self.project = nn.Conv1d(n, config.width, 1)
        self.blocks = nn.ModuleList(_Block(config.width, config.kernel, d, config.dropout) for d in config.dilations)
        self.head = nn.Conv1d(config.width, len(OUTPUTS), 1)
        nn.init.zeros_(self.head.weight)  # starts as the physics baseline
        nn.init.zeros_(self.head.bias)
        index = [config.features.index(FEATURE_NAMES[MIRROR_INDEX[FEATURE_NAMES.index(f)]]) for f in config.features]
        sign = [MIRROR_SIGN[FEATURE_NAMES.index(f)] for f in config.features]
        self.register_buffer("mirror_index", torch.tensor(index), persistent=False)
        self.register_buffer("mirror_sign", torch.tensor(sign, dtype=torch.float32), persistent=False)
        taps = max(3, int(round(config.zero_mean_s * config.rate_hz)) | 1) if config.zero_mean_s > 0 else 0
        window = torch.hann_window(taps + 2, periodic=False)[1:-1] if taps else torch.zeros(0)
        self.register_buffer("local_mean", (window / window.sum()).view(1, 1, -1), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.project(((x - self.mean) / self.scale).transpose(1, 2))
        for block in self.blocks:
            h = block(h)
        y = self.head(F.gelu(h))  # [B, 8, T]
        if self.local_mean.numel():
            force = y[:, :3]
            half = self.local_mean.shape[-1] // 2
            padded = F.pad(force.reshape(-1, 1, force.shape[-1]), (half, half), mode="replicate")
            mean = F.conv1d(padded, self.local_mean).view_as(force)
            y = torch.cat([force - mean, y[:, 3:]], dim=1)
        return y.transpose(1, 2)

    def mirror_inputs(self, x: torch.Tensor) -> torch.Tensor:
        """Features [..., F] of the left-right mirror image of the motion."""
        return x[..., self.mirror_index] * self.mirror_sign

    @staticmethod
    def mirror_outputs(y: torch.Tensor) -> torch.Tensor:
        """Outputs [..., 8] of a mirrored input taken back to the original sides: the sideways force and CoP
        offsets change sign, the feet swap."""
        return torch.stack(
            [y[..., 0], y[..., 1], -y[..., 2], -y[..., 3], y[..., 6], -y[..., 7], y[..., 4], -y[..., 5]], dim=-1
        )

    def symmetric(self, x: torch.Tensor) -> torch.Tensor:
        """The mean of the outputs on ``x`` and (mirrored back) on its mirror image."""
        return 0.5 * (self(x) + self.mirror_outputs(self(self.mirror_inputs(x))))


@dataclass(frozen=True)
class GroundForcePrediction:
    """`LearnedGroundReaction.predict` on a motion's frames.

    Attributes:
        times: [T] s. force: [T, 2, 3] N per foot (right, left) in the ground frame, vertical ≥ 0.
        cop: [T, 2, 3] m, on each foot's rest level (NaN where the foot carries < `MIN_FOOT_FORCE_N`).
        total_bw: [T, 3] the total in body weights, ground frame. body_weight: N.
    """

    times: np.ndarray
    force: np.ndarray
    cop: np.ndarray
    total_bw: np.ndarray
    body_weight: float

    @property
    def vertical_bw(self) -> np.ndarray:
        """[T] total vertical force in body weights."""
        return self.total_bw[:, 1]

    def ground_reaction(self) -> GroundReaction:
        """Per-foot loads on ``calcn_r``/``calcn_l`` (free moments zero), for inverse dynamics and files."""
        return GroundReaction(
            times=self.times,
            names=("r", "l"),
            force=self.force,
            cop=self.cop,
            moment=np.zeros_like(self.force),
            bodies=("calcn_r", "calcn_l"),
        )


def resample_rows(times: np.ndarray, values: np.ndarray, new_times: np.ndarray) -> np.ndarray:
    """values [T, ...] at ``new_times`` by linear interpolation along T (ends held)."""
    flat = values.reshape(len(times), -1)
    out = np.stack([np.interp(new_times, times, flat[:, j]) for j in range(flat.shape[1])], axis=-1)
    return out.reshape((len(new_times),) + values.shape[1:])


def model_times(times: np.ndarray, rate_hz: float) -> np.ndarray:
    """The network's uniform clock over a motion's span."""
    count = int(np.floor((times[-1] - times[0]) * rate_hz + 1e-6)) + 1
    return times[0] + np.arange(count) / rate_hz


class LearnedGroundReaction:
    """A trained `GroundForceNet` with what it needs to predict on an analysed motion (module docstring).

    ``name`` ("learned") is what `biomotion.analysis.chain.analyze` records as the torques' force source.
    """

    name = "learned"

    def __init__(self, net: GroundForceNet, metadata: dict[str, str] | None = None, path: Path | None = None) -> None:
        self.net = net.eval()
        self.config = net.config
        self.cutoff_hz = net.config.cutoff_hz
        self.metadata = dict(metadata or {})
        self.path = path

    # -- prediction ----------------------------------------------------------------------------------------
    def outputs(self, features: GroundFeatures) -> np.ndarray:
        """Raw outputs [T, 8] on the features' frames (network run at its rate, mirror-averaged, interpolated
        back)."""
        columns = [FEATURE_NAMES.index(f) for f in self.config.features]
        grid = model_times(features.times, self.config.rate_hz)
        x = torch.as_tensor(resample_rows(features.times, features.values[:, columns], grid), dtype=torch.float32)
        with torch.no_grad():
            y = self.net.symmetric(x[None])[0].numpy().astype(float)
        return resample_rows(grid, y, features.times)

    def predict(self, features: GroundFeatures) -> GroundForcePrediction:
        """Per-foot ground forces and CoPs on the features' frames (see `GroundForcePrediction`)."""
        return decode(features, self.outputs(features))

    def check(self, motion: Motion, model: BodyModel) -> None:
        """One-line `ModelError`/`DataFormatError` for a motion (model order) the network cannot take: a model
        without a floating base, both legs and feet; shorter than ``MIN_SECONDS``
        (`biomotion.analysis.ground_features`); coordinates not finite."""
        check_motion(motion, model)

    def ground_reaction(self, result: Analysis) -> GroundReaction:
        """The learned per-foot ground reaction of an analysed motion (the estimator protocol of
        `biomotion.analysis.chain.analyze`); one-line `ModelError`/`DataFormatError` for a motion it cannot take
        (`biomotion.analysis.ground_features.check_motion`)."""
        return self.predict(ground_features(result)).ground_reaction()

    # -- persistence ---------------------------------------------------------------------------------------
    def save(self, path: str | Path, metadata: dict[str, str] | None = None) -> None:
        """Weights to ``path`` (safetensors, atomic) with the config, the output names and ``metadata``."""
        from safetensors.torch import save

        from biomotion.io.atomic import atomic_write

        state = {k: v.detach().contiguous().cpu() for k, v in self.net.state_dict().items()}
        meta = {
            **self.metadata,
            **(metadata or {}),
            "format": FORMAT,
            "config": json.dumps(asdict(self.config)),
            "outputs": json.dumps(list(OUTPUTS)),
        }
        with atomic_write(path, "wb") as handle:
            handle.write(save(state, metadata=meta))
        self.metadata = {k: v for k, v in meta.items() if k not in ("format", "config", "outputs")}

    @classmethod
    def load(cls, path: str | Path | None = None) -> LearnedGroundReaction:
        """A model saved by `save` (default: the shipped checkpoint, `SHIPPED`)."""
        from safetensors import safe_open
        from safetensors.torch import load_file

        path = Path(path) if path is not None else SHIPPED
        if not path.is_file():
            raise ModelError(
                f"{path}: no learned ground-forces weights there (train them: `biomotion train ground-forces`)"
            )
        try:
            with safe_open(str(path), framework="pt") as handle:
                meta = dict(handle.metadata() or {})
        except Exception as error:  # noqa: BLE001 - any unreadable file gets one line
            raise ModelError(f"{path}: not a safetensors file ({error})") from None
        if meta.get("format") != FORMAT or "config" not in meta:
            raise ModelError(f"{path}: not a learned ground-forces file (format {meta.get('format')!r})")
        net = GroundForceNet(GroundForcesConfig.from_dict(json.loads(meta["config"])))
        net.load_state_dict(load_file(str(path)))
        extra = {k: v for k, v in meta.items() if k not in ("format", "config", "outputs")}
        return cls(net, extra, path)

    @property
    def train_subjects(self) -> set[str] | None:
        """``source/subject`` of the people the weights were trained on (metadata ``train_subjects``)."""
        text = self.metadata.get("train_subjects")
        return None if text is None else set(json.loads(text))


def learned_forces(path: str | Path | None = None) -> LearnedGroundReaction:
    """The learned ground-reaction model at ``path`` (default: the shipped checkpoint), to pass as
    ``biomotion.analyze_trial(..., forces=learned_forces())``."""
    return LearnedGroundReaction.load(path)


def decode(features: GroundFeatures, outputs: np.ndarray) -> GroundForcePrediction:
    """Raw network outputs [T, 8] (`OUTPUTS`) on the features' frames as per-foot forces and CoPs."""
    total = features.baseline + outputs[:, :3]  # BW, (forward, up, right)
    total[:, 1] = np.maximum(total[:, 1], 0.0)
    share = 1.0 / (1.0 + np.exp(-outputs[:, 3]))
    shares = np.stack([share, 1.0 - share], axis=1)  # [T, 2]
    weight = features.body_weight
    force = from_heading(features.forward, total[:, None, :] * shares[..., None]) * weight  # [T, 2, 3]
    low, high = ALONG_RANGE
    along = low + (high - low) / (1.0 + np.exp(-outputs[:, [4, 6]]))  # [T, 2]
    side = outputs[:, [5, 7]] * features.leg_length
    right = np.stack([-features.forward[:, 2], np.zeros(len(features.forward)), features.forward[:, 0]], axis=-1)
    cop = features.heel + along[..., None] * (features.toe - features.heel) + side[..., None] * right[:, None]
    light = force[..., 1] < MIN_FOOT_FORCE_N
    force[light] = 0.0
    cop[light] = np.nan
    return GroundForcePrediction(features.times, force, cop, from_heading(features.forward, total), weight)
