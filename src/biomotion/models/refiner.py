"""PhysPT refiner: a Transformer encoder-decoder that turns noisy motion into physically consistent motion and
infers the joint torques and ground contact forces behind it (Zhang et al. 2024, "PhysPT", Sec. 3.2).

Model (this module) and data (`Estimate`, `Refinement`) are kept apart as in Pinocchio: `PhysPT` holds the weights,
`Refiner` adds the constants of the canonical body (Rajagopal 2016, `biomotion.body`) and the contact model, and every
call returns a new value. The training loop is `biomotion.training.train_refiner`; the user surface
(`biomotion refine`, ``bm.refine``) is `biomotion.generation.refinement`.

Architecture (Sec. 3.2.1, Fig. 1), at the cache rate (30 Hz) on windows of ``window`` frames:

- input: the 39 canonical generalized coordinates q̂ (root included, Eq. 1) with the per-coordinate mask of the
  coordinates the source has. Each window is put in its own frame first (`window_frame`): the mean heading
  (``pelvis_rotation``) is subtracted and the horizontal pelvis translation is taken relative to its mean and turned
  by minus that heading, so a clip means the same wherever and whichever way it was recorded. Coordinates are
  standardised with training-set statistics, masked ones zeroed, and the mask is appended (78 features);
- encoder: an embedding of ``embed_kernel`` frames (1: PhysPT's linear layer; the shipped 5: a temporal
  convolution) plus a sinusoidal time encoding, then ``encoder_layers`` Transformer layers → the latent
  E_latent [T, d];
- decoder: ``decoder_layers`` Transformer layers whose queries are a second embedding of the same input (plus the
  time encoding), attending to E_latent; a linear head gives a residual Δq added to a base: the input itself
  (PhysPT, ``base_cutoff_hz`` None: an untrained model returns its input) or the input smoothed by a fixed
  zero-phase Gaussian with that cutoff (`smooth`; the shipped 4 Hz), so the network starts from a filter and
  learns what a filter cannot do: keep the real motion's sharp parts (foot strikes) and remove the slow errors
  (bounce, sway, drift). The head starts at zero;
- force heads on E_latent (Sec. 3.2.4 "Force Loss": "a linear layer to project E_latent to motion forces"): joint
  torques τ [T, 39] (generalized forces of every coordinate; the six root entries are the residual force the
  contact could not supply) and, per foot contact point (`biomotion.body.contact.foot_points`, 5 per foot), the
  non-negative magnitudes x along the four edges of a linearised friction cone.

Deviation from the paper, decoding. PhysPT decodes autoregressively (frame m + 1 from the m frames before it,
trained with teacher forcing then with its own predictions). Here the decoder is not autoregressive: its queries are
the noisy input itself, so one pass refines a whole window. Autoregressive decoding of a 64-frame window costs 64
sequential decoder passes, and a 10 s trial several windows of them, against the 0.5 s the refiner may take for such
a trial on 2 CPU cores (docs/decisions/refiner.md measures both); it would also need the paper's two-stage schedule
against exposure bias. The encoder-decoder split and every loss are the paper's.

Contact model (Sec. 3.2.3, Eq. 4-5). PhysPT writes the force at contact point p as λ_p = s_p A_p x_p: a gate
s_p = σ(−d)σ(−|v|) on the point's height and speed, times a matrix A_p built from its position and velocity, times
non-negative stiffness and damping parameters x_p found by a QP. `biomotion.body.contact.infer_ground_reaction`
solves that QP for our body with the same gate (on the height above the point's resting height and on its vertical
speed, `ContactSettings`) and, for x_p, non-negative magnitudes along the edges of a linearised friction cone
(μ = 0.8), which keeps every force inside the cone. The contact head predicts those x_p, and `FootContact` applies
the gate of the refined motion: λ_p = s_p(q) Σ_e x_pe e_e. Its targets λ̄ and τ̄ are that QP's on the clean clip.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from biomotion.body.canonical import CANONICAL_COORDINATES, DEFAULT_RATE
from biomotion.body.contact import ContactSettings, FootPoints, foot_points
from biomotion.body.kinematics import apply_couplers, forward_kinematics, joint_centers, points_in_ground
from biomotion.body.model import BodyModel
from biomotion.errors import ModelError
from biomotion.metrics.contact import STANCE_SPEED, contact_mask, foot_sliding
from biomotion.metrics.reconstruction import joint_error
from biomotion.metrics.smoothness import acceleration_error
from biomotion.settings import settings_from_dict

N_COORDS = len(CANONICAL_COORDINATES)
YAW = CANONICAL_COORDINATES.index("pelvis_rotation")
TX, TY, TZ = (CANONICAL_COORDINATES.index(n) for n in ("pelvis_tx", "pelvis_ty", "pelvis_tz"))
#: The floating base: three pelvis rotations and three translations, unactuated (their "torques" are residuals).
ROOT = tuple(range(6))
EDGES = 4  # edges of the linearised friction cone per contact point
#: Smallest standardisation scale (rad or m): a coordinate a source holds constant (the Bandai-Namco retargets' mtp and
#: subtalar angles) would otherwise turn a degree of noise into an error of tens of standard deviations.
STD_FLOOR = 0.05
GRAVITY = 9.80665
FORMAT = "biomotion-refiner/1"


@dataclass(frozen=True)
class RefinerConfig:
    """Sizes of the network (sized for a 2-core CPU; the paper uses 6 + 6 layers, 8 heads, width 1024, 16 frames)."""

    d_model: int = 128
    heads: int = 4
    encoder_layers: int = 3
    decoder_layers: int = 3
    feedforward: int = 256
    dropout: float = 0.0
    window: int = 64  # frames per window at ``rate``
    embed_kernel: int = 1  # frames the input embeddings see: 1 is PhysPT's linear layer, more a temporal convolution
    base_cutoff_hz: float | None = None  # None: refined = input + Δ (PhysPT); a cutoff: smoothed input + Δ (`smooth`)
    rate: float = DEFAULT_RATE

    @classmethod
    def from_dict(cls, values: dict) -> RefinerConfig:
        return settings_from_dict(cls, values, "refiner model")


# ---- the window frame ------------------------------------------------------------------------------------------


def window_frame(q: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """[B, 3] each window's frame: mean heading ψ̄ (``pelvis_rotation``, rad) and mean horizontal pelvis position
    (x̄, z̄) over its valid frames (q [B, T, 39], valid [B, T])."""
    weights = valid.to(q.dtype)[..., None] / valid.sum(-1).clamp(min=1).to(q.dtype)[:, None, None]
    return (q[..., [YAW, TX, TZ]] * weights).sum(1)


def _turn(x: torch.Tensor, z: torch.Tensor, angle: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(x, z) turned by ``angle`` about the vertical: a body yawed by ψ faces (cos ψ, −sin ψ) (y up, right-handed)."""
    c, s = torch.cos(angle), torch.sin(angle)
    return c * x + s * z, -s * x + c * z


def to_local(q: torch.Tensor, frame: torch.Tensor) -> torch.Tensor:
    """Coordinates in the window's frame: heading minus ψ̄, horizontal translation minus (x̄, z̄) turned by −ψ̄."""
    yaw, x0, z0 = (frame[:, k, None] for k in range(3))
    x, z = _turn(q[..., TX] - x0, q[..., TZ] - z0, -yaw)
    return torch.cat([q[..., :YAW], (q[..., YAW] - yaw)[..., None], x[..., None], q[..., TY : TY + 1], z[..., None],
                      q[..., TZ + 1 :]], -1)  # fmt: skip


def to_world(local: torch.Tensor, frame: torch.Tensor) -> torch.Tensor:
    """The inverse of `to_local`."""
    yaw, x0, z0 = (frame[:, k, None] for k in range(3))
    x, z = _turn(local[..., TX], local[..., TZ], yaw)
    return torch.cat([local[..., :YAW], (local[..., YAW] + yaw)[..., None], (x + x0)[..., None],
                      local[..., TY : TY + 1], (z + z0)[..., None], local[..., TZ + 1 :]], -1)  # fmt: skip


def finite_rates(q: torch.Tensor, rate: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(q̇, q̈) of q [..., T, n] sampled at ``rate`` Hz by central finite differences (one-sided at the ends), the
    scheme PhysPT Sec. 3.2.4 derives the training forces with; the targets and the Euler-Lagrange loss share it."""
    spacing = 1.0 / rate
    qd = torch.gradient(q, spacing=spacing, dim=-2)[0]
    return qd, torch.gradient(qd, spacing=spacing, dim=-2)[0]


def smooth(x: torch.Tensor, cutoff_hz: float, rate: float) -> torch.Tensor:
    """x [B, T, n] convolved along T with the zero-phase Gaussian kernel whose response is 1/√2 at ``cutoff_hz``
    (σ = √(ln 2) rate / (2π cutoff) frames; edges repeat the end frames)."""
    sigma = math.sqrt(math.log(2.0)) * rate / (2 * math.pi * cutoff_hz)
    half = max(1, math.ceil(3 * sigma))
    taps = torch.exp(-0.5 * (torch.arange(-half, half + 1, dtype=x.dtype) / sigma) ** 2)
    kernel = (taps / taps.sum()).view(1, 1, -1).expand(x.shape[-1], 1, -1)
    padded = F.pad(x.transpose(1, 2), (half, half), mode="replicate")
    return F.conv1d(padded, kernel, groups=x.shape[-1]).transpose(1, 2)


def time_encoding(length: int, width: int) -> torch.Tensor:
    """[length, width] sinusoidal encoding of the frame index (Vaswani et al. 2017, Sec. 3.5)."""
    position = torch.arange(length, dtype=torch.float32)[:, None]
    frequency = torch.exp(torch.arange(0, width, 2, dtype=torch.float32) * (-math.log(10000.0) / width))
    encoding = torch.zeros(length, width)
    encoding[:, 0::2] = torch.sin(position * frequency)
    encoding[:, 1::2] = torch.cos(position * frequency)
    return encoding


# ---- the network -----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Estimate:
    """What `PhysPT` gives for a batch of windows: refined coordinates q [B, T, 39] (world frame; masked columns keep
    the input's placeholders), torques [B, T, 39] (N·m or N) and contact-edge magnitudes [B, T, K, 4] (N, ≥ 0,
    before the contact gate)."""

    q: torch.Tensor
    torques: torch.Tensor
    edges: torch.Tensor


class PhysPT(nn.Module):
    """The Transformer encoder-decoder with its motion, torque and contact heads (module docstring)."""

    def __init__(self, config: RefinerConfig, n_points: int) -> None:
        super().__init__()
        self.config, self.n_points = config, n_points
        d = config.d_model
        self.register_buffer("mean", torch.zeros(N_COORDS))  # input standardisation (window frame)
        self.register_buffer("std", torch.ones(N_COORDS))
        self.register_buffer("torque_scale", torch.ones(N_COORDS))  # N·m or N per unit of the torque head
        self.register_buffer("force_scale", torch.ones(()))  # N per unit of the contact head

        def layer(kind: type[nn.Module]) -> nn.Module:
            return kind(d, config.heads, config.feedforward, config.dropout, batch_first=True, norm_first=True)

        kernel = config.embed_kernel
        self.encode_in = nn.Conv1d(2 * N_COORDS, d, kernel, padding=kernel // 2, padding_mode="replicate")
        self.decode_in = nn.Conv1d(2 * N_COORDS, d, kernel, padding=kernel // 2, padding_mode="replicate")
        self.encoder = nn.TransformerEncoder(
            layer(nn.TransformerEncoderLayer), config.encoder_layers, nn.LayerNorm(d), enable_nested_tensor=False
        )
        self.decoder = nn.TransformerDecoder(layer(nn.TransformerDecoderLayer), config.decoder_layers, nn.LayerNorm(d))
        self.motion_head = nn.Linear(d, N_COORDS)
        self.torque_head = nn.Linear(d, N_COORDS)
        self.contact_head = nn.Linear(d, n_points * EDGES)
        nn.init.zeros_(self.motion_head.weight)
        nn.init.zeros_(self.motion_head.bias)

    def set_normalisation(
        self, mean: torch.Tensor, std: torch.Tensor, torque_scale: torch.Tensor, weight: float
    ) -> None:
        """Standardisation of the window-frame coordinates, torque scale per coordinate, and the body weight (N)
        shared by the contact points as the contact head's unit."""
        self.mean.copy_(mean)
        self.std.copy_(std.clamp(min=STD_FLOOR))
        self.torque_scale.copy_(torque_scale.clamp(min=1.0))
        self.force_scale.fill_(weight / self.n_points)

    def forward(self, q: torch.Tensor, mask: torch.Tensor, valid: torch.Tensor) -> Estimate:
        """Refine windows q [B, T, 39] (SI, world frame) with coordinate mask [B, 39] and frame mask valid [B, T]."""
        frame = window_frame(q, valid)
        local = to_local(q, frame)
        present = mask[:, None, :].to(q.dtype)
        x = torch.cat([(local - self.mean) / self.std * present, present.expand_as(local)], -1)
        time = time_encoding(q.shape[1], self.config.d_model).to(q.dtype)
        padding = None if bool(valid.all()) else ~valid  # no mask: the fast attention path
        channels = x.transpose(1, 2)
        latent = self.encoder(self.encode_in(channels).transpose(1, 2) + time, src_key_padding_mask=padding)
        decoded = self.decoder(
            self.decode_in(channels).transpose(1, 2) + time,
            latent,
            tgt_key_padding_mask=padding,
            memory_key_padding_mask=padding,
        )
        base = (
            local if self.config.base_cutoff_hz is None else smooth(local, self.config.base_cutoff_hz, self.config.rate)
        )
        refined = to_world(base + self.motion_head(decoded) * self.std * present, frame)
        torques = self.torque_head(latent) * self.torque_scale
        edges = F.softplus(self.contact_head(latent)).unflatten(-1, (self.n_points, EDGES)) * self.force_scale
        return Estimate(refined, torques, edges)


# ---- the contact model -----------------------------------------------------------------------------------------


class FootContact:
    """The gate and friction cone of `biomotion.body.contact` (PhysPT Eq. 4) for the refiner's contact head."""

    def __init__(self, settings: ContactSettings = ContactSettings()) -> None:
        self.settings = settings
        mu = settings.friction
        self.cone = torch.tensor([[mu, 1.0, 0.0], [-mu, 1.0, 0.0], [0.0, 1.0, mu], [0.0, 1.0, -mu]])  # [4, 3]

    def gate(self, height: torch.Tensor, vertical_speed: torch.Tensor) -> torch.Tensor:
        """s = σ(−(h − h₀)/δh) σ(−(|v_y| − v₀)/δv) of a point's height above its rest height and vertical speed."""
        s = self.settings
        return torch.sigmoid(-(height - s.height_offset) / s.height_scale) * torch.sigmoid(
            -(vertical_speed.abs() - s.speed_offset) / s.speed_scale
        )

    def forces(self, edges: torch.Tensor, gate: torch.Tensor) -> torch.Tensor:
        """[..., K, 3] point forces (N, ground frame) from edge magnitudes [..., K, 4] and the gate [..., K]."""
        return gate[..., None] * (edges @ self.cone.to(edges.dtype))


# ---- the refiner: network + body -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Refinement:
    """A whole clip refined at the model's rate: coordinates q [T, 39] (masked columns as given), torques [T, 39],
    point forces [T, K, 3] (N, ground), point positions [T, K, 3] (m), contact gate [T, K]."""

    q: torch.Tensor
    torques: torch.Tensor
    point_forces: torch.Tensor
    point_positions: torch.Tensor
    gate: torch.Tensor
    points: FootPoints


class Refiner:
    """`PhysPT` with the canonical body it was trained on: physics of its outputs, whole clips, persistence.

    ``metadata`` travels with the weights: the subjects it was trained and validated on (an evaluation must leave
    them out), the low-pass cutoff tuned on the validation subjects, the training command."""

    def __init__(self, net: PhysPT, body: BodyModel, metadata: dict | None = None) -> None:
        self.net, self.config = net, net.config
        self.body = body.to(torch.float32)
        self.feet = foot_points(self.body)
        self.contact = FootContact()
        self.defaults = self.body.defaults.to(torch.float32)
        self.metadata = dict(metadata or {})

    @classmethod
    def new(cls, config: RefinerConfig, body: BodyModel) -> Refiner:
        return cls(PhysPT(config, len(foot_points(body).names)), body)

    # -- physics of coordinates (differentiable) -----------------------------------------------------------------
    def full(self, q: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """q [..., T, 39] with absent coordinates at the model's defaults and coupled ones (the patella's knee
        ``_beta``) set by their couplers: the pose the body model moves through."""
        return apply_couplers(self.body, torch.where(mask[..., None, :], q, self.defaults))

    def kinematics(self, q_full: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(joint centres [..., T, J, 3], foot contact points [..., T, K, 3]) of full coordinates (one FK pass)."""
        flat = q_full.reshape(-1, N_COORDS)
        poses = forward_kinematics(self.body, flat)
        joints = joint_centers(self.body, flat, poses).unflatten(0, q_full.shape[:-1])
        feet = points_in_ground(poses, self.feet.bodies, self.feet.offsets).unflatten(0, q_full.shape[:-1])
        return joints, feet

    # -- whole clips ---------------------------------------------------------------------------------------------
    @torch.no_grad()
    def refine(self, q: torch.Tensor, mask: torch.Tensor, *, hop: int | None = None) -> Refinement:
        """Refine one clip q [T, 39] (canonical, SI, at ``config.rate``, placed on the floor y = 0) with mask [39].

        The clip is cut into windows of ``config.window`` frames every ``hop`` (default half a window), all windows
        run as one batch, and their outputs are blended with Hann weights (overlap-add); a clip shorter than a
        window is one padded window. The contact gate then uses the refined clip's foot points: their height above
        each point's resting height (2nd percentile over the clip, as `biomotion.body.contact`) and their vertical
        speed (central differences)."""
        self.net.eval()
        q = q.to(torch.float32)
        n, window = q.shape[0], self.config.window
        hop = hop or max(1, window // 2)
        starts = list(range(0, max(n - window, 0) + 1, hop))
        if starts[-1] + window < n:
            starts.append(n - window)
        length = min(window, n)
        index = torch.tensor(starts)[:, None] + torch.arange(length)
        valid = torch.ones(len(starts), length, dtype=torch.bool)
        estimate = self.net(q[index], mask[None].expand(len(starts), -1), valid)
        weight = torch.sin(math.pi * (torch.arange(length) + 0.5) / length) ** 2 if len(starts) > 1 else None
        refined = _overlap_add(estimate.q, index, n, weight)
        torques = _overlap_add(estimate.torques, index, n, weight)
        edges = _overlap_add(estimate.edges.flatten(-2), index, n, weight).unflatten(-1, (-1, EDGES))
        refined = torch.where(mask, refined, q)
        forces, feet, gate = self._contact_forces(refined, mask, edges)
        return Refinement(refined, torques, forces, feet, gate, self.feet)

    def _contact_forces(
        self, q: torch.Tensor, mask: torch.Tensor, edges: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(point forces [T, K, 3], point positions [T, K, 3], gate [T, K]) of a whole clip."""
        _, feet = self.kinematics(self.full(q, mask))
        rest = torch.quantile(feet[..., 1], ContactSettings().rest_percentile / 100.0, dim=0)
        vertical = torch.gradient(feet[..., 1], spacing=1.0 / self.config.rate, dim=0)[0]
        gate = self.contact.gate(feet[..., 1] - rest, vertical)
        return self.contact.forces(edges, gate), feet, gate

    # -- persistence ---------------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Weights and buffers to ``path`` (safetensors, written atomically), config and metadata in its header."""
        from safetensors.torch import save

        from biomotion.io.atomic import atomic_write

        state = {k: v.detach().contiguous().cpu() for k, v in self.net.state_dict().items()}
        header = {"format": FORMAT, "config": json.dumps(asdict(self.config)), "n_points": str(self.net.n_points)}
        header["metadata"] = json.dumps(self.metadata)
        with atomic_write(path, "wb") as handle:
            handle.write(save(state, metadata=header))

    @classmethod
    def load(cls, path: str | Path, body: BodyModel) -> Refiner:
        """A refiner saved by `save`, in eval mode, on the canonical ``body``."""
        from safetensors import safe_open
        from safetensors.torch import load_file

        path = Path(path)
        if not path.is_file():
            raise ModelError(f"{path}: no refiner weights there (train them with `biomotion train refiner`)")
        try:
            with safe_open(str(path), framework="pt") as handle:
                header = handle.metadata() or {}
        except Exception as error:  # noqa: BLE001 - safetensors raises its own types for a foreign file
            raise ModelError(f"{path}: not a safetensors file ({error})") from None
        if header.get("format") != FORMAT:
            raise ModelError(f"{path}: not refiner weights (format {header.get('format')!r}, expected {FORMAT!r})")
        net = PhysPT(RefinerConfig.from_dict(json.loads(header["config"])), int(header["n_points"]))
        net.load_state_dict(load_file(str(path)))
        refiner = cls(net.eval(), body, json.loads(header.get("metadata", "{}")))
        if net.n_points != len(refiner.feet.names):
            raise ModelError(
                f"{path}: trained with {net.n_points} contact points, the body has {len(refiner.feet.names)}"
            )
        return refiner


def refinement_scores(
    refiner: Refiner, clean: torch.Tensor, pred: torch.Tensor, mask: torch.Tensor
) -> dict[str, float]:
    """What the refiner is judged by (PhysPT Sec. 4), of ``pred`` against ``clean`` (one clip [T, 39] at the
    refiner's rate, with its mask): ACCL (m/s², joint centres), FS (m/frame, foot contact points, over the clean
    clip's stance: points below 5 cm and slower than 0.5 m/s horizontally, PhysPT Supp. F's heuristic with the
    metrics' thresholds), root-relative MJE (m, joint centres; the Human3.6M
    protocol) and the ground-frame MJE, on the canonical body (`Refiner.full`, `Refiner.kinematics`)."""
    with torch.no_grad():
        joints, feet = refiner.kinematics(refiner.full(pred.float(), mask))
        clean_joints, clean_feet = refiner.kinematics(refiner.full(clean.float(), mask))
    contact = contact_mask(clean_feet, refiner.config.rate, speed=STANCE_SPEED)  # the clean clip's stance
    return {
        "accl": float(acceleration_error(joints, clean_joints, refiner.config.rate)),
        "fs": float(foot_sliding(feet, contact=contact)),
        "mje": float(joint_error(joints, clean_joints, root=0)),
        "mje_global": float(joint_error(joints, clean_joints)),
    }


def _overlap_add(values: torch.Tensor, index: torch.Tensor, n: int, weight: torch.Tensor | None) -> torch.Tensor:
    """[n, ...] the windows' values [W, L, ...] at frames ``index`` [W, L], averaged with per-frame ``weight`` [L]."""
    w = (torch.ones(index.shape[1]) if weight is None else weight).to(values.dtype)
    trailing = (1,) * (values.dim() - 2)
    total = values.new_zeros(n, *values.shape[2:])
    total.index_add_(0, index.flatten(), (values * w.view(1, -1, *trailing)).flatten(0, 1))
    count = values.new_zeros(n).index_add_(0, index.flatten(), w.expand(index.shape).flatten())
    return total / count.view(n, *trailing)
