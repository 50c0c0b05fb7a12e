"""Differentiable muscle-activation surrogate for inference-time biomechanical guidance (PG-BIG Sec. 3.3, A.7-A.8).

PG-BIG refines generated motion with gradients of a guidance loss whose muscle term bounds the activations
a_{t,m} predicted from the kinematics by a surrogate of OpenSim's (non-differentiable) static optimization:
``L_act = 1/T sum_t sum_m max(0, a_tm - a_m^high, a_m^low - a_tm)`` with the 5th/95th percentiles of the training
labels as bounds (Table 1). The surrogate maps joint kinematics to activations (A.7) and is validated by R^2 and
RMSE against the static-optimization targets (A.8, Table 7); BIGE (Maheshwari 2025) trains its surrogate with an
L1 loss, as we do (`biomotion.training.train_surrogate`).

Ours is a small temporal convolution network rather than PG-BIG's transformer encoder, sized for a CPU: input
canonical coordinates q [B, T, 39] (`biomotion.body.canonical`, SI units, ``config.rate`` Hz) and an optional
coordinate mask [B, 39]; output sigmoid activations [B, T, M] of the Rajagopal 2016 muscles. Per frame it sees

- positions of every coordinate except the coupled knee ``_beta`` ones (a function of the knee angle) and the
  heading-like pelvis_tx, pelvis_tz and pelvis_rotation, which grow or wander over a clip and do not change the
  joint torques (gravity is vertical);
- velocities and accelerations of every coordinate but the knee ``_beta`` ones, by central finite differences
  along T (the edge frames copy their neighbour's value);
- with ``config.contact`` (ours), per foot contact point of the canonical body (`biomotion.body.contact.foot_points`,
  five per foot), its height above the point's 2nd-percentile height over the sequence and its vertical velocity:
  the labels' ground reaction is inferred with a contact gate on exactly these quantities (PhysPT Eq. 4, the
  rest height taken over the whole clip), which a receptive field of 17 frames cannot see from the coordinates
  alone. The heights come from forward kinematics of the body given to the surrogate, or from the caller (guidance
  already has its foot points);
- with ``config.smooth_hz`` > 0 (ours), the coordinates low-passed the way the labels' inverse dynamics low-passes
  them (`smoothing_taps`: the zero-lag Butterworth's impulse response, 35 taps at 6 Hz and 30 Hz, wider than the
  receptive field) and their velocities and accelerations; off in the shipped config (measured, not kept:
  docs/decisions/surrogate-recipe.md);
- with ``config.dilation`` > 1 (ours), a wider receptive field at the same cost (WaveNet's dilated convolutions,
  van den Oord et al. 2016); 1 in the shipped config (a second of context did not help);

standardised with mean/std buffers from the training split, then a Conv1d stem and residual blocks (kernel 5,
replicate padding; block i dilated by ``config.dilation ** i``, so the receptive field is 1 + (kernel - 1)
(1 + sum_i dilation^i) frames: 17 with the shipped kernel 5, depth 3 and dilation 1) shared by two 1x1 heads:
the activations (sigmoid) and the whole-body COM velocity and acceleration [B, T, 6] (``COM_OUTPUTS``, ground frame,
m/s and m/s^2; PG-BIG A.7-A.8: "80 activations plus COM terms", validated by COM velocity and acceleration R^2),
de-standardised with the ``com_mean``/``com_std`` buffers of the training labels. With ``config.members`` m > 1 (ours)
the network is m such networks side by side, each ``width`` wide and started from its own random weights: one stem,
then grouped convolutions and heads, so a member's channels see only its own; each member is fitted to the labels on
its own (`predict_members`, `biomotion.training.train_surrogate`) and a prediction is the members' mean, a deep ensemble
(Lakshminarayanan, Pritzel & Blundell 2017, "Simple and scalable predictive uncertainty estimation using deep
ensembles", NeurIPS), which removes part of the error that depends on the random start; the shipped config keeps
one network, since at this time budget width helps more than members (docs/decisions/surrogate-recipe.md).
Masked coordinates are set to 0 before anything
else, which is also how the labels treated absent coordinates (`biomotion.training.surrogate_labels`). Everything
is differentiable with respect to q.

Buffers ``low``/``high`` hold the 5th/95th percentile of each muscle's training-split labels (PG-BIG Table 1
activation bounds); ``names`` are the muscle names. `MuscleSurrogate.save`/`load` keep the config and names in
the safetensors metadata, so a file is self-contained.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import scipy.signal
import torch
import torch.nn.functional as F
from torch import nn

from biomotion.body.canonical import CANONICAL_COORDINATES, COUPLED_COORDINATES, DEFAULT_RATE
from biomotion.body.contact import ContactSettings, foot_points
from biomotion.body.kinematics import forward_kinematics, points_in_ground
from biomotion.body.mirror import NEGATED, mirror_permutation
from biomotion.errors import ConfigError, ModelError
from biomotion.settings import settings_from_dict

N_COORDS = len(CANONICAL_COORDINATES)
FORMAT = "biomotion-muscle-surrogate/1"
_NO_POSITION = ("pelvis_tx", "pelvis_tz", "pelvis_rotation")
#: The COM head's outputs: whole-body COM velocity and acceleration in the ground frame (m/s, m/s^2).
#: The whole-body COM columns of the surrogate labels: position, velocity, acceleration (m, m/s, m/s²).
COM_COLUMNS = ("com_x", "com_y", "com_z", "com_vx", "com_vy", "com_vz", "com_ax", "com_ay", "com_az")
COM_OUTPUTS = ("com_vx", "com_vy", "com_vz", "com_ax", "com_ay", "com_az")
#: Canonical indices whose positions / derivatives are features.
POSITION_COORDS = tuple(i for i, n in enumerate(CANONICAL_COORDINATES) if n not in COUPLED_COORDINATES + _NO_POSITION)
DERIVATIVE_COORDS = tuple(i for i, n in enumerate(CANONICAL_COORDINATES) if n not in COUPLED_COORDINATES)
N_FEATURES = len(POSITION_COORDS) + 2 * len(DERIVATIVE_COORDS)
#: Quantile of a foot point's height over a sequence taken as its rest height (the labels' contact gate's rule).
REST_QUANTILE = ContactSettings().rest_percentile / 100.0
#: Order of one pass of the labels' coordinate low-pass (`biomotion.motion.Motion.smoothed`'s default).
LABEL_FILTER_ORDER = 3


@dataclass(frozen=True)
class SurrogateConfig:
    """Network sizes. ``rate``: frame rate (Hz) of the q the surrogate is given; ``contact``: foot-contact
    features from forward kinematics of the canonical body; ``members``: networks of ``width`` channels averaged
    (a deep ensemble; see the module docstring); ``smooth_hz`` > 0: the coordinates low-passed at this cutoff,
    and their derivatives, are features too (`smoothing_taps`); 0 leaves them out."""

    width: int = 128
    depth: int = 3
    kernel: int = 5
    dropout: float = 0.1
    rate: float = DEFAULT_RATE
    contact: bool = False
    members: int = 1
    smooth_hz: float = 0.0
    dilation: int = 1

    @property
    def context(self) -> int:
        """Frames on each side that one output frame depends on: the convolutions' half receptive field,
        (kernel - 1) / 2 (1 + sum_i dilation^i), plus the one frame of the central differences of the features."""
        return (self.kernel - 1) // 2 * (1 + sum(self.dilation**i for i in range(self.depth))) + 1

    @classmethod
    def from_dict(cls, values: dict) -> SurrogateConfig:
        config = settings_from_dict(cls, values, "surrogate model")
        if config.kernel % 2 == 0 or config.kernel < 1:
            raise ConfigError(f"surrogate kernel must be odd, got {config.kernel}")
        if config.members < 1:
            raise ConfigError(f"surrogate members must be at least 1, got {config.members}")
        if config.dilation < 1:
            raise ConfigError(f"surrogate dilation must be at least 1, got {config.dilation}")
        if not 0.0 <= config.smooth_hz < config.rate / 2:
            raise ConfigError(
                f"surrogate smooth_hz must be 0 (off) or below the Nyquist frequency {config.rate / 2:g} "
                f"Hz, got {config.smooth_hz}"
            )
        return config


def finite_differences(q: torch.Tensor, rate: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Velocities and accelerations of q [..., T, n] along T: central differences (q[t+1] - q[t-1]) rate / 2 and
    (q[t+1] - 2 q[t] + q[t-1]) rate^2; the first and last frame copy their neighbour's value. Two frames: one
    forward difference for both and zero acceleration; one frame: zeros."""
    t = q.shape[-2]
    if t >= 3:
        velocity = (q[..., 2:, :] - q[..., :-2, :]) * (rate / 2)
        acceleration = (q[..., 2:, :] - 2 * q[..., 1:-1, :] + q[..., :-2, :]) * rate**2
        pad = lambda x: torch.cat([x[..., :1, :], x, x[..., -1:, :]], dim=-2)
        return pad(velocity), pad(acceleration)
    if t == 2:
        velocity = (q[..., 1:, :] - q[..., :1, :]) * rate
        return velocity.expand_as(q), torch.zeros_like(q)
    return torch.zeros_like(q), torch.zeros_like(q)


def smoothing_taps(cutoff_hz: float, rate: float, order: int = LABEL_FILTER_ORDER, tail: float = 1e-4) -> torch.Tensor:
    """The impulse response of the labels' zero-lag Butterworth low-pass (`biomotion.motion.lowpass`: ``order``
    per pass, run forward and backward) as a symmetric FIR [2K + 1], cut where its taps fall below ``tail`` of the
    peak. A convolution with it low-passes q the way `biomotion.training.surrogate_labels` does before its inverse
    dynamics, differentiably and in one batched operation."""
    sos = scipy.signal.butter(order, cutoff_hz, btype="low", fs=rate, output="sos")
    n = 8 * int(np.ceil(rate / cutoff_hz)) + 1
    impulse = np.zeros(2 * n + 1)
    impulse[n] = 1.0
    response = scipy.signal.sosfiltfilt(sos, impulse, padlen=0)
    k = int(np.max(np.flatnonzero(np.abs(response) >= tail * np.abs(response).max())) - n)
    taps = response[n - k : n + k + 1]
    return torch.as_tensor(taps / taps.sum(), dtype=torch.float32)


def smooth(q: torch.Tensor, taps: torch.Tensor) -> torch.Tensor:
    """q [B, T, n] convolved along T with symmetric ``taps`` [2K + 1] (one depthwise convolution); the ends are
    extended by odd reflection (value and slope kept, as `biomotion.motion.Motion.smoothed` pads) when T > K, else
    by their edge value."""
    k = (len(taps) - 1) // 2
    if q.shape[-2] > k:
        head = 2 * q[..., :1, :] - q[..., 1 : k + 1, :].flip(-2)
        tail = 2 * q[..., -1:, :] - q[..., -k - 1 : -1, :].flip(-2)
    else:
        head, tail = q[..., :1, :].expand(*q.shape[:-2], k, -1), q[..., -1:, :].expand(*q.shape[:-2], k, -1)
    padded = torch.cat([head, q, tail], dim=-2).transpose(-1, -2)
    channels = q.shape[-1]
    weight = taps.to(q.dtype).view(1, 1, -1).expand(channels, 1, -1)
    return F.conv1d(padded, weight, groups=channels).transpose(-1, -2)


class _Block(nn.Module):
    """x + Conv1x1(Dropout(GELU(Conv_k(GELU(x)))))."""

    def __init__(self, width: int, kernel: int, dropout: float, groups: int = 1, dilation: int = 1) -> None:
        super().__init__()
        self.conv = nn.Conv1d(
            width,
            width,
            kernel,
            padding=dilation * (kernel // 2),
            padding_mode="replicate",
            groups=groups,
            dilation=dilation,
        )
        self.mix = nn.Conv1d(width, width, 1, groups=groups)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.mix(self.dropout(F.gelu(self.conv(F.gelu(x)))))


class MuscleSurrogate(nn.Module):
    """Canonical coordinates q [B, T, 39] (+ mask [B, 39]) -> muscle activations [B, T, M] in (0, 1) and COM
    velocity and acceleration [B, T, 6].

    See the module docstring (PG-BIG Sec. 3.3 guidance, A.8 surrogate). ``names``: the M muscle names;
    buffers ``mean``/``std`` (feature standardisation), ``low``/``high`` (5th/95th percentile activation
    bounds per muscle, PG-BIG Table 1) and ``com_mean``/``com_std`` (COM output scale) are set from the
    training split by `set_normalisation`, `set_bounds` and `set_com_scale`.
    """

    def __init__(self, names: Sequence[str], config: SurrogateConfig | None = None, body=None) -> None:
        super().__init__()
        self.config = config = config or SurrogateConfig()
        self.names = tuple(names)
        if not self.names:
            raise ModelError("a muscle surrogate needs at least one muscle name")
        self.body, self.points, self.point_mirror = None, None, None
        n_features = N_FEATURES
        if config.contact:
            if body is None:
                raise ModelError(
                    "this muscle surrogate computes foot-contact features: give it the canonical body "
                    "model (biomotion.data.clips.body_model(data_root), Rajagopal 2016)"
                )
            self.body = body.to(torch.float32)
            self.points = foot_points(self.body)
            self.point_mirror = torch.as_tensor(mirror_permutation(self.points.names))
            n_features += 2 * len(self.points.names)
        if config.smooth_hz > 0:
            self.register_buffer("taps", smoothing_taps(config.smooth_hz, config.rate), persistent=False)
            n_features += N_FEATURES
        w, k, m = config.width * config.members, config.kernel, config.members
        self.stem = nn.Conv1d(n_features, w, k, padding=k // 2, padding_mode="replicate")
        self.blocks = nn.Sequential(*[_Block(w, k, config.dropout, m, config.dilation**i) for i in range(config.depth)])
        self.head = nn.Conv1d(w, m * len(self.names), 1, groups=m)
        self.com_head = nn.Conv1d(w, m * len(COM_OUTPUTS), 1, groups=m)
        self.register_buffer("mean", torch.zeros(n_features))
        self.register_buffer("std", torch.ones(n_features))
        self.register_buffer("low", torch.zeros(len(self.names)))
        self.register_buffer("high", torch.ones(len(self.names)))
        self.register_buffer("com_mean", torch.zeros(len(COM_OUTPUTS)))
        self.register_buffer("com_std", torch.ones(len(COM_OUTPUTS)))

    @property
    def n_muscles(self) -> int:
        return len(self.names)

    # -- features -------------------------------------------------------------------------------------------
    def _check(self, q: torch.Tensor, mask: torch.Tensor | None) -> None:
        if q.ndim != 3 or q.shape[-1] != N_COORDS:
            raise ModelError(f"muscle surrogate expects q [B, T, {N_COORDS}]; got {tuple(q.shape)}")
        if mask is not None and tuple(mask.shape) != (q.shape[0], N_COORDS):
            raise ModelError(f"muscle surrogate expects mask [B, {N_COORDS}]; got {tuple(mask.shape)}")

    def _masked(self, q: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        q = q.to(self.mean.dtype)
        if mask is None:
            return q
        return torch.where(mask.to(torch.bool).unsqueeze(-2), q, torch.zeros_like(q))

    def foot_heights(self, q: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor | None:
        """Heights [B, T, K] of the body's foot points (``self.points``) for q [B, T, 39], masked coordinates
        at 0 as in the features; None for a surrogate without contact features."""
        if self.body is None:
            return None
        self._check(q, mask)
        q = self._masked(q, mask)
        poses = forward_kinematics(self.body, q.reshape(-1, q.shape[-1]))
        return points_in_ground(poses, self.points.bodies, self.points.offsets)[..., 1].reshape(*q.shape[:2], -1)

    def raw_features(
        self, q: torch.Tensor, mask: torch.Tensor | None = None, heights: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Unstandardised per-frame features [B, T, F]: positions, velocities, accelerations and, with contact
        features, the foot points' heights above their rest height and vertical velocities (``heights`` [B, T, K]
        as `foot_heights` gives them, computed here when not given)."""
        self._check(q, mask)
        q = self._masked(q, mask)
        velocity, acceleration = finite_differences(q, self.config.rate)
        d = list(DERIVATIVE_COORDS)
        parts = [q[..., list(POSITION_COORDS)], velocity[..., d], acceleration[..., d]]
        if self.config.smooth_hz > 0:
            low = smooth(q, self.taps)
            low_velocity, low_acceleration = finite_differences(low, self.config.rate)
            parts += [low[..., list(POSITION_COORDS)], low_velocity[..., d], low_acceleration[..., d]]
        if self.config.contact:
            heights = self.foot_heights(q) if heights is None else heights.to(q.dtype)
            above = heights - torch.quantile(heights, REST_QUANTILE, dim=-2, keepdim=True)
            parts += [above, finite_differences(above, self.config.rate)[0]]
        return torch.cat(parts, dim=-1)

    def features(
        self, q: torch.Tensor, mask: torch.Tensor | None = None, heights: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Standardised features [B, T, F]."""
        return (self.raw_features(q, mask, heights) - self.mean) / self.std

    @torch.no_grad()
    def set_normalisation(
        self,
        q: torch.Tensor,
        mask: torch.Tensor | None = None,
        weights: torch.Tensor | None = None,
        heights: torch.Tensor | None = None,
    ) -> None:
        """Feature mean/std from training windows q [N, T, 39] (mask [N, 39], foot heights [N, T, K]);
        ``weights`` [N, T] leaves out padding frames. Constant features keep std 1."""
        f = self.raw_features(q, mask, heights).double()
        w = (torch.ones(f.shape[:2], dtype=torch.float64) if weights is None else weights.double()).unsqueeze(-1)
        count = w.sum()
        mean = (f * w).sum((0, 1)) / count
        std = (((f - mean) ** 2 * w).sum((0, 1)) / count).sqrt()
        self.mean.copy_(mean.to(self.mean.dtype))
        self.std.copy_(torch.where(std > 1e-6, std, torch.ones_like(std)).to(self.std.dtype))

    @torch.no_grad()
    def set_bounds(self, activations: torch.Tensor, low: float = 0.05, high: float = 0.95) -> None:
        """``low``/``high`` buffers from training labels [N, M]: per-muscle quantiles (PG-BIG Table 1)."""
        if activations.ndim != 2 or activations.shape[1] != self.n_muscles:
            raise ModelError(f"bounds need activations [N, {self.n_muscles}]; got {tuple(activations.shape)}")
        a = activations.double()
        self.low.copy_(torch.quantile(a, low, dim=0).to(self.low.dtype))
        self.high.copy_(torch.quantile(a, high, dim=0).to(self.high.dtype))

    @torch.no_grad()
    def set_com_scale(self, com: torch.Tensor) -> None:
        """``com_mean``/``com_std`` buffers from training labels [N, 6] (`COM_OUTPUTS`): the COM head predicts
        (com - com_mean) / com_std."""
        if com.ndim != 2 or com.shape[1] != len(COM_OUTPUTS):
            raise ModelError(f"COM scale needs labels [N, {len(COM_OUTPUTS)}]; got {tuple(com.shape)}")
        c = com.double()
        std = c.std(0)
        self.com_mean.copy_(c.mean(0).to(self.com_mean.dtype))
        self.com_std.copy_(torch.where(std > 1e-6, std, torch.ones_like(std)).to(self.com_std.dtype))

    # -- model ----------------------------------------------------------------------------------------------
    def _trunk(
        self, q: torch.Tensor, mask: torch.Tensor | None = None, heights: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Hidden sequence [B, members x width, T]: the members' channels side by side."""
        return F.gelu(self.blocks(self.stem(self.features(q, mask, heights).transpose(1, 2))))

    def _per_member(self, out: torch.Tensor) -> torch.Tensor:
        """A head's output [B, members x C, T] as [B, members, T, C]."""
        return out.view(out.shape[0], self.config.members, -1, out.shape[-1]).transpose(2, 3)

    def predict_members(
        self, q: torch.Tensor, mask: torch.Tensor | None = None, heights: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Each member's activations [B, members, T, M] and COM velocity and acceleration [B, members, T, 6]
        (what training fits, each member on its own)."""
        hidden = self._trunk(q, mask, heights)
        com = self._per_member(self.com_head(hidden)) * self.com_std + self.com_mean
        return torch.sigmoid(self._per_member(self.head(hidden))), com

    def forward(
        self, q: torch.Tensor, mask: torch.Tensor | None = None, heights: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Activations [B, T, M] in (0, 1) from canonical coordinates q [B, T, 39] (mask [B, 39] optional:
        masked coordinates are treated as 0; foot heights [B, T, K] optional, see `raw_features`)."""
        return self.predict(q, mask, heights)[0]

    def predict(
        self, q: torch.Tensor, mask: torch.Tensor | None = None, heights: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Activations [B, T, M] and COM velocity and acceleration [B, T, 6] (`COM_OUTPUTS`, ground frame, m/s and
        m/s^2) in one pass: the mean over the members."""
        activations, com = self.predict_members(q, mask, heights)
        return activations.mean(1), com.mean(1)

    def predict_symmetric(
        self, q: torch.Tensor, mask: torch.Tensor | None = None, heights: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """`predict` made exactly left-right equivariant: the mean of the prediction on the motion and the mirror
        image of the prediction on its mirror image (`biomotion.body.mirror`: limb coordinates change sides,
        midline rotations and pelvis_tz change sign; muscles change sides, the COM's z components change sign).

        The body and its muscles are left-right symmetric, so the activations of a mirrored motion are the mirrored
        activations; one network only approximates that (it was trained on both images of every clip), and
        averaging the two images removes the asymmetric part of its error: on the 24 held-out clips of
        `biomotion validate muscles` the shipped network's mean R² over muscles is 0.901 this way and 0.886 for one
        pass (``surrogate_r2``, ``surrogate_r2_one_pass``). Both images run as one batch;
        the mirror image's foot heights are the motion's with the feet swapped (the body is symmetric), so forward
        kinematics runs once.
        Guidance keeps the single pass (`forward`) inside its 40 iterations, where only the activation bounds
        matter."""
        swap = torch.as_tensor(mirror_permutation(CANONICAL_COORDINATES))
        sign = torch.tensor([-1.0 if n in NEGATED else 1.0 for n in CANONICAL_COORDINATES], dtype=q.dtype)
        both = torch.cat([q, q[..., swap] * sign])
        masks = None if mask is None else torch.cat([mask, mask[..., swap]])
        if self.config.contact and heights is None:
            heights = self.foot_heights(q, mask)
        both_heights = None if heights is None else torch.cat([heights, heights[..., self.point_mirror]])
        activations, com = self.predict(both, masks, both_heights)
        count = q.shape[0]
        muscles = torch.as_tensor(mirror_permutation(self.names))
        flip_z = torch.tensor([1.0, 1.0, -1.0] * (len(COM_OUTPUTS) // 3), dtype=com.dtype)
        return (
            0.5 * (activations[:count] + activations[count:][..., muscles]),
            0.5 * (com[:count] + com[count:] * flip_z),
        )

    # -- persistence ----------------------------------------------------------------------------------------
    def save(self, path: str | Path, metadata: dict[str, str] | None = None) -> None:
        """Weights and buffers to ``path`` (safetensors, written atomically) with the config and the muscle
        names in its metadata."""
        from safetensors.torch import save

        from biomotion.io.atomic import atomic_write

        state = {k: v.detach().contiguous().cpu() for k, v in self.state_dict().items()}
        meta = {
            "format": FORMAT,
            "config": json.dumps(asdict(self.config)),
            "muscles": json.dumps(list(self.names)),
            **(metadata or {}),
        }
        with atomic_write(path, "wb") as handle:
            handle.write(save(state, metadata=meta))

    @classmethod
    def load(cls, path: str | Path, map_location: str = "cpu", body=None) -> MuscleSurrogate:
        """A surrogate saved by `save`, in eval mode; ``body``: the canonical body model, needed by a surrogate
        with contact features (ignored by one without)."""
        from biomotion.io.tensors import read_metadata, read_tensors

        meta = read_metadata(path, "muscle-surrogate weights")
        if meta.get("format") != FORMAT or "config" not in meta or "muscles" not in meta:
            raise ModelError(f"{path}: not a muscle-surrogate file (format {meta.get('format')!r})")
        model = cls(json.loads(meta["muscles"]), SurrogateConfig.from_dict(json.loads(meta["config"])), body)
        model.load_state_dict(read_tensors(path, "muscle-surrogate weights", device=map_location))
        return model.eval()

    @staticmethod
    def training_subjects(path: str | Path) -> set[str] | None:
        """``source/subject`` of the people a saved surrogate was trained on, from its metadata or, for weights
        saved before it recorded them, its model card (``<name>.json`` beside it, ``data.train_subjects``); None
        where neither says."""
        meta = MuscleSurrogate.metadata(path)
        if "train_subjects" in meta:
            return set(json.loads(meta["train_subjects"]))
        card = Path(path).with_suffix(".json")
        if card.is_file():
            subjects = json.loads(card.read_text()).get("data", {}).get("train_subjects")
            if subjects is not None:
                return set(subjects)
        return None

    @staticmethod
    def metadata(path: str | Path) -> dict[str, str]:
        """The safetensors metadata of a saved surrogate (config, muscles, and what `save` was given)."""
        from biomotion.io.tensors import read_metadata

        return read_metadata(path, "muscle-surrogate weights")
