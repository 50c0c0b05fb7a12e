"""Subject profiler: reference-clip latents + biodata + motion metadata -> one profile token (PG-BIG A.6, Fig. 5).

"The VQ-VAE encoder first encodes a subject-specific motion sequence, and attention pooling aggregates the
resulting latent features to produce a weighted representation of motion information. We then individually
project, normalize, and pass this motion vector, along with subject biodata ... and metadata ..., through GELU
activations. We concatenate the processed embeddings, then project and normalize them to yield the subject-specific
profile token." Each branch here is Linear -> LayerNorm -> GELU; a branch with nothing known (no reference clip,
no biodata) is replaced by a learned "absent" embedding, so a missing input is masked, not invented.
"""

from __future__ import annotations

import torch
from torch import nn

from biomotion.models.conditioning import BIODATA_FIELDS, METADATA_FIELDS


def branch(n_in: int, width: int) -> nn.Sequential:
    """Project, normalise, GELU (Fig. 5)."""
    return nn.Sequential(nn.Linear(n_in, width), nn.LayerNorm(width), nn.GELU())


class AttentionPooling(nn.Module):
    """Softmax-weighted mean over time of latents [B, N, D] with a validity mask [B, N] (A.6)."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.score = nn.Linear(dim, 1)

    def forward(self, latents: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        score = self.score(latents).squeeze(-1).masked_fill(~valid, float("-inf"))
        weights = torch.softmax(score, -1).nan_to_num(0.0)  # a row with no valid latent pools to zero
        return (weights.unsqueeze(-1) * latents).sum(-2)


class SubjectProfiler(nn.Module):
    """Profile token [B, width] from reference latents, biodata and metadata (all optional per sample)."""

    def __init__(self, code_dim: int, width: int) -> None:
        super().__init__()
        self.pool = AttentionPooling(code_dim)
        self.motion = branch(code_dim, width)
        self.biodata = branch(2 * len(BIODATA_FIELDS), width)
        self.metadata = branch(2 * len(METADATA_FIELDS), width)
        self.absent = nn.Parameter(torch.zeros(3, width))
        self.fuse = nn.Sequential(nn.Linear(3 * width, width), nn.LayerNorm(width))

    def forward(
        self, latents: torch.Tensor, latent_valid: torch.Tensor, biodata: torch.Tensor, metadata: torch.Tensor
    ) -> torch.Tensor:
        """Args: latents [B, N, code_dim] of the reference clips (concatenated), latent_valid [B, N] bool,
        biodata [B, 2 * n_bio] and metadata [B, 2 * n_meta] in `Features.cat` layout (values, then masks)."""
        has_motion = latent_valid.any(-1, keepdim=True)
        has_bio = biodata[:, len(BIODATA_FIELDS) :].sum(-1, keepdim=True) > 0
        has_meta = metadata[:, len(METADATA_FIELDS) :].sum(-1, keepdim=True) > 0
        parts = [
            torch.where(has, part, self.absent[i])
            for i, (has, part) in enumerate(
                (
                    (has_motion, self.motion(self.pool(latents, latent_valid))),
                    (has_bio, self.biodata(biodata)),
                    (has_meta, self.metadata(metadata)),
                )
            )
        ]
        return self.fuse(torch.cat(parts, -1))
