"""The motion-text evaluator behind the distribution metrics: a motion encoder and a text encoder trained
contrastively into one embedding space, in the manner of T2M's evaluator (Guo et al. 2022, "Generating Diverse and
Natural 3D Human Motions from Text", CVPR, Sec. 5; FlexMotion Tables 1-3 score with it).

Motion encoder. Per frame, heading-invariant features of the canonical 39 generalized coordinates
(`clip_features`): the 36 coordinates other than the pelvis's horizontal position and heading (pelvis_tx,
pelvis_tz, pelvis_rotation: where a clip starts and faces says nothing about what it shows), and the velocities of
all 39, with the horizontal pelvis velocity turned into the heading frame by R_y(-pelvis_rotation) (forward and
sideways speed). Coordinates a clip lacks (its mask) are missing features: zero after the per-feature
standardisation fitted on the training clips, i.e. the training mean. A 1-D convolution and dilated residual blocks
(T2M-GPT's ResConv1D) over time, then the mean and standard deviation over the valid frames (length-agnostic
pooling: a 3 s crop and a 10 s clip of the same gait give the same statistics), then an MLP to the embedding.

Text encoder. An MLP over the frozen all-MiniLM-L6-v2 sentence embedding of the clip's text (the offline encoder
`biomotion.models.actions.sentence_encoder` that generation already ships; T2M uses word vectors and a GRU).

Both embeddings are L2-normalised; training (`biomotion.training.train_evaluator`) minimises the symmetric InfoNCE
loss (van den Oord et al. 2018; CLIP, Radford et al. 2021, Eq. in Fig. 3) of cosine similarities over temperature,
with every pair of equal texts in a batch counted as positive (`contrastive_loss`): the datasets' action and style
labels repeat, and a second "walk, happy" is not a negative of the first.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from biomotion.body.canonical import CANONICAL_COORDINATES, DEFAULT_RATE
from biomotion.errors import ModelError
from biomotion.settings import settings_from_dict

FORMAT = "biomotion-motion-text-evaluator/1"
N_COORDS = len(CANONICAL_COORDINATES)
_TX, _TZ, _HEADING = (CANONICAL_COORDINATES.index(n) for n in ("pelvis_tx", "pelvis_tz", "pelvis_rotation"))
POSITIONS = tuple(i for i in range(N_COORDS) if i not in (_TX, _TZ, _HEADING))
"""Coordinates whose values are features (all but the horizontal pelvis position and the heading)."""
N_FEATURES = len(POSITIONS) + N_COORDS
TEXT_DIM = 384
"""Width of the all-MiniLM-L6-v2 sentence embedding."""


def clip_features(values: np.ndarray, mask: np.ndarray | None, rate: float) -> np.ndarray:
    """Per-frame features [T, N_FEATURES] (float32) of one clip in canonical coordinates ``values`` [T, 39] (SI)
    with coordinate ``mask`` [39] (None: all present): values of `POSITIONS`, then the velocities of the 39
    coordinates (``numpy.gradient``, 1/s), horizontal pelvis velocity in the heading frame. Features of absent
    coordinates are NaN (the horizontal velocity needs tx, tz and the heading); a one-frame clip has zero
    velocities."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2 or values.shape[1] != N_COORDS:
        raise ModelError(f"the evaluator reads canonical coordinates [T, {N_COORDS}], got shape {values.shape}")
    mask = np.ones(N_COORDS, bool) if mask is None else np.asarray(mask, bool)
    if len(values) > 1:
        velocity = np.gradient(values, 1.0 / rate, axis=0)
    else:
        velocity = np.zeros_like(values)
    heading = values[:, _HEADING]
    vx, vz = velocity[:, _TX].copy(), velocity[:, _TZ].copy()
    velocity[:, _TX] = np.cos(heading) * vx - np.sin(heading) * vz  # forward (local x)
    velocity[:, _TZ] = np.sin(heading) * vx + np.cos(heading) * vz  # sideways (local z)
    velocity_mask = mask.copy()
    velocity_mask[[_TX, _TZ]] = mask[[_TX, _TZ, _HEADING]].all()
    features = np.concatenate([values[:, POSITIONS], velocity], axis=1)
    present = np.concatenate([mask[list(POSITIONS)], velocity_mask])
    features[:, ~present] = np.nan
    return features.astype(np.float32)


def pad_features(clips: list[np.ndarray], max_frames: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-frame features of several clips (`clip_features`, each cut to its first ``max_frames``) padded into
    [B, T, F] with frame validity [B, T]; NaN (absent) entries are kept for the model to fill."""
    if not clips:
        raise ModelError("no clips to embed")
    clips = [c[:max_frames] if max_frames else c for c in clips]
    length = max(len(c) for c in clips)
    x = np.zeros((len(clips), length, clips[0].shape[1]), np.float32)
    valid = np.zeros((len(clips), length), bool)
    for i, c in enumerate(clips):
        x[i, : len(c)], valid[i, : len(c)] = c, True
    return torch.from_numpy(x), torch.from_numpy(valid)


@dataclass(frozen=True)
class EvaluatorConfig:
    """Sizes of the evaluator (small enough to train in minutes on one CPU thread)."""

    width: int = 128
    depth: int = 3
    dilation_growth: int = 2
    embed_dim: int = 64
    text_hidden: int = 256
    dropout: float = 0.1
    temperature: float = 0.1
    rate: float = DEFAULT_RATE
    max_frames: int = 300
    """Frames of a clip the motion encoder reads (from its start; 10 s at 30 Hz)."""

    @classmethod
    def from_dict(cls, values: dict) -> EvaluatorConfig:
        return settings_from_dict(cls, values, "evaluator model")


class _Residual(nn.Module):
    """x + Conv1x1(GELU(Conv3_dilated(GELU(x)))) (T2M-GPT's ResConv1DBlock)."""

    def __init__(self, width: int, dilation: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv1d(width, width, 3, padding=dilation, dilation=dilation)
        self.conv2 = nn.Conv1d(width, width, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.gelu(self.conv1(F.gelu(x))))


class MotionTextEvaluator(nn.Module):
    """Motion and text encoders into one unit-sphere embedding space (module docstring)."""

    def __init__(self, config: EvaluatorConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or EvaluatorConfig()
        w = config.width
        self.register_buffer("mean", torch.zeros(N_FEATURES))
        self.register_buffer("std", torch.ones(N_FEATURES))
        self.stem = nn.Conv1d(N_FEATURES, w, 5, padding=2)
        self.blocks = nn.Sequential(*[_Residual(w, config.dilation_growth**k) for k in range(config.depth)])
        self.motion_head = nn.Sequential(nn.Linear(2 * w, w), nn.GELU(), nn.Linear(w, config.embed_dim))
        self.text_head = nn.Sequential(
            nn.Linear(TEXT_DIM, config.text_hidden),
            nn.GELU(),
            nn.Dropout(config.dropout),
            nn.Linear(config.text_hidden, config.embed_dim),
        )

    def set_normalisation(self, clips: list[np.ndarray]) -> None:
        """Per-feature mean and std over every present frame of the training ``clips`` (`clip_features`); a feature
        never present, or constant, keeps std 1."""
        stacked = np.concatenate(clips).astype(np.float64)
        present = np.isfinite(stacked)
        count = present.sum(0)
        mean = np.where(present, stacked, 0).sum(0) / np.maximum(count, 1)
        var = np.where(present, (stacked - mean) ** 2, 0).sum(0) / np.maximum(count, 1)
        std = np.sqrt(var)
        self.mean.copy_(torch.from_numpy(mean).float())
        self.std.copy_(torch.from_numpy(np.where((count > 1) & (std > 1e-6), std, 1.0)).float())

    def encode_motion(self, x: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """Unit embeddings [B, D] of padded per-frame features ``x`` [B, T, N_FEATURES] (NaN = absent) with frame
        validity ``valid`` [B, T]."""
        if x.ndim != 3 or x.shape[-1] != N_FEATURES or valid.shape != x.shape[:2]:
            raise ModelError(
                f"the motion encoder expects x [B, T, {N_FEATURES}] and valid [B, T]; got {tuple(x.shape)} and "
                f"{tuple(valid.shape)}"
            )
        z = torch.nan_to_num((x - self.mean) / self.std, nan=0.0)
        frames = valid.to(z.dtype)[..., None]
        keep = frames.transpose(1, 2)  # [B, 1, T]: padding is zero after every layer, as a convolution pads
        h = self.stem(z.transpose(1, 2) * keep) * keep
        for block in self.blocks:
            h = block(h) * keep
        h = h.transpose(1, 2)  # [B, T, W]
        count = frames.sum(1).clamp_min(1)
        mean = (h * frames).sum(1) / count
        std = (((h - mean[:, None]) ** 2 * frames).sum(1) / count + 1e-6).sqrt()
        return F.normalize(self.motion_head(torch.cat([mean, std], -1)), dim=-1)

    def encode_text(self, sentence_embeddings: torch.Tensor) -> torch.Tensor:
        """Unit embeddings [B, D] of MiniLM sentence embeddings [B, 384]."""
        if sentence_embeddings.ndim != 2 or sentence_embeddings.shape[-1] != TEXT_DIM:
            raise ModelError(
                f"the text encoder expects sentence embeddings [B, {TEXT_DIM}], got {tuple(sentence_embeddings.shape)}"
            )
        return F.normalize(self.text_head(sentence_embeddings), dim=-1)

    def forward(
        self, x: torch.Tensor, valid: torch.Tensor, sentence_embeddings: torch.Tensor, text_ids: torch.Tensor
    ) -> torch.Tensor:
        """The contrastive loss of a batch of motions and their texts (`contrastive_loss`)."""
        motion, text = self.encode_motion(x, valid), self.encode_text(sentence_embeddings)
        return contrastive_loss(motion, text, text_ids, self.config.temperature)

    def save(self, path: str | Path, metadata: dict[str, str] | None = None) -> None:
        """Weights and buffers to ``path`` (safetensors, written atomically) with the config in its metadata."""
        from safetensors.torch import save

        from biomotion.io.atomic import atomic_write

        state = {k: v.detach().contiguous().cpu() for k, v in self.state_dict().items()}
        meta = {"format": FORMAT, "config": json.dumps(asdict(self.config)), **(metadata or {})}
        with atomic_write(path, "wb") as handle:
            handle.write(save(state, metadata=meta))

    @classmethod
    def load(cls, path: str | Path) -> MotionTextEvaluator:
        """A model saved by `save`, in eval mode on the CPU; a file of another kind is a `ModelError`."""
        from biomotion.io.tensors import read_metadata, read_tensors

        meta = read_metadata(path, "evaluator weights")
        if meta.get("format") != FORMAT or "config" not in meta:
            raise ModelError(f"{path}: not motion-text evaluator weights (format {meta.get('format')!r})")
        model = cls(EvaluatorConfig.from_dict(json.loads(meta["config"])))
        model.load_state_dict(read_tensors(path, "evaluator weights"))
        return model.eval()


def contrastive_loss(
    motion: torch.Tensor, text: torch.Tensor, text_ids: torch.Tensor, temperature: float
) -> torch.Tensor:
    """Symmetric InfoNCE of unit embeddings ``motion`` [B, D] and ``text`` [B, D] (row i of each is a pair) with
    multiple positives: ``text_ids`` [B] marks rows with equal texts, and each row's target distribution is uniform
    over the rows sharing its text, motion-to-text and text-to-motion alike (the mean of the two cross-entropies)."""
    logits = motion @ text.T / temperature
    positive = (text_ids[:, None] == text_ids[None, :]).to(logits.dtype)
    target = positive / positive.sum(-1, keepdim=True)
    motion_to_text = -(target * F.log_softmax(logits, -1)).sum(-1).mean()
    text_to_motion = -(target * F.log_softmax(logits.T, -1)).sum(-1).mean()
    return 0.5 * (motion_to_text + text_to_motion)


def embed_sentences(texts: list[str]) -> torch.Tensor:
    """MiniLM sentence embeddings [N, 384] (float32, unit length) of ``texts`` from the offline encoder."""
    from biomotion.models.actions import sentence_encoder

    encoder = sentence_encoder()
    array = encoder.encode(list(texts), normalize_embeddings=True, convert_to_numpy=True, show_progress_bar=False)
    return torch.from_numpy(np.asarray(array, dtype=np.float32))


@torch.no_grad()
def embed_motions(
    model: MotionTextEvaluator,
    clips: list[np.ndarray],
    masks: list | None = None,
    rate: float | None = None,
    *,
    batch: int = 64,
) -> np.ndarray:
    """Motion embeddings [N, D] (float64) of clips in canonical coordinates (each [T, 39], SI) with optional
    coordinate masks; ``rate`` defaults to the evaluator's. Each clip is read up to ``config.max_frames``."""
    rate = rate or model.config.rate
    features = [clip_features(c, None if masks is None else masks[i], rate) for i, c in enumerate(clips)]
    was_training = model.training
    model.eval()
    out = []
    for start in range(0, len(features), batch):
        x, valid = pad_features(features[start : start + batch], model.config.max_frames)
        out.append(model.encode_motion(x, valid).double().numpy())
    model.train(was_training)
    return np.concatenate(out)


@torch.no_grad()
def embed_texts(model: MotionTextEvaluator, texts: list[str], sentences: torch.Tensor | None = None) -> np.ndarray:
    """Text embeddings [N, D] (float64) of ``texts`` (``sentences``: their MiniLM embeddings, when at hand)."""
    sentences = embed_sentences(texts) if sentences is None else sentences
    was_training = model.training
    model.eval()
    out = model.encode_text(sentences).double().numpy()
    model.train(was_training)
    return out


def clip_text(labels: dict) -> str:
    """The text of a cached clip's labels: its ``text``, else its action with its style ("walk, happy")."""
    if labels.get("text"):
        return str(labels["text"])
    return ", ".join(str(labels[k]) for k in ("action", "style") if labels.get(k)) or "motion"
