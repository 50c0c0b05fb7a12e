"""Profile-action prior: an autoregressive transformer over tokenizer codes, conditioned on [profile; action].

PG-BIG Sec. 3.2: the conditioning vector z_cond = [z_s; z_a] is expanded by a lightweight MLP into N_m = 8 memory
tokens M; temporal query tokens Q = E_pos + 1_T (x) z_cond attend to M in a transformer decoder whose outputs are
read out against the codebook. Following the paper (not the authors' parallel argmax code,
``pg-big-reference-notes.md``), the decoder is causal and code indices are sampled one at a time with temperature
and top-k, the T2M-GPT recipe (Zhang et al. 2023), so a clip of any length can be drawn. The query of step t also
carries the embedding of code t - 1 (a learned start code at t = 0).

With ``use_profile`` False the same network conditions on the action alone: the population-level T2M-GPT-style
baseline of `biomotion eval generation`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from biomotion.errors import ConfigError
from biomotion.models.profiler import SubjectProfiler
from biomotion.settings import settings_from_dict


@dataclass(frozen=True)
class PriorConfig:
    """Sizes. ``action_size`` and ``codebook_size``/``code_dim`` come from the action vocabulary and tokenizer."""

    codebook_size: int
    code_dim: int
    action_size: int
    width: int = 128
    layers: int = 3
    heads: int = 4
    memory_tokens: int = 8
    max_tokens: int = 64
    dropout: float = 0.1
    use_profile: bool = True

    @classmethod
    def from_dict(cls, values: dict) -> PriorConfig:
        return settings_from_dict(cls, values, "prior")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Condition:
    """Batched generator inputs: reference latents [B, N, D] + valid [B, N], biodata/metadata/action in
    `Features.cat` layout [B, 2n]."""

    latents: torch.Tensor
    latent_valid: torch.Tensor
    biodata: torch.Tensor
    metadata: torch.Tensor
    action: torch.Tensor


class ProfileActionPrior(nn.Module):
    """p(code_t | code_<t, profile, action) (PG-BIG Sec. 3.2)."""

    def __init__(self, config: PriorConfig) -> None:
        super().__init__()
        self.config = c = config
        self.profiler = SubjectProfiler(c.code_dim, c.width) if c.use_profile else None
        self.action = nn.Sequential(nn.Linear(2 * c.action_size, c.width), nn.LayerNorm(c.width), nn.GELU())
        cond = 2 * c.width if c.use_profile else c.width
        self.expand = nn.Sequential(
            nn.Linear(cond, 2 * c.width), nn.GELU(), nn.Linear(2 * c.width, c.memory_tokens * c.width)
        )
        self.query_cond = nn.Linear(cond, c.width)
        self.codes = nn.Embedding(c.codebook_size + 1, c.width)  # last row: the start code
        self.position = nn.Parameter(torch.zeros(c.max_tokens, c.width))
        nn.init.normal_(self.position, std=0.02)
        layer = nn.TransformerDecoderLayer(
            c.width, c.heads, 4 * c.width, c.dropout, batch_first=True, norm_first=True, activation="gelu"
        )
        self.decoder = nn.TransformerDecoder(layer, c.layers)
        self.head = nn.Sequential(nn.LayerNorm(c.width), nn.Linear(c.width, c.codebook_size))

    def condition_vector(self, cond: Condition) -> torch.Tensor:
        """z_cond = [z_s; z_a] [B, 2 width] (only z_a without the profile)."""
        z_a = self.action(cond.action)
        if self.profiler is None:
            return z_a
        z_s = self.profiler(cond.latents, cond.latent_valid, cond.biodata, cond.metadata)
        return torch.cat([z_s, z_a], -1)

    def memory(self, z_cond: torch.Tensor) -> torch.Tensor:
        """N_m memory tokens [B, N_m, width] (Sec. 3.2, MLP_expand)."""
        return self.expand(z_cond).view(z_cond.shape[0], self.config.memory_tokens, self.config.width)

    def logits(self, previous: torch.Tensor, z_cond: torch.Tensor, memory: torch.Tensor) -> torch.Tensor:
        """Next-code logits [B, L, K] from the codes before each step ``previous`` [B, L] (start code first)."""
        length = previous.shape[1]
        if length > self.config.max_tokens:
            raise ConfigError(f"prior context of {length} tokens exceeds max_tokens={self.config.max_tokens}")
        queries = self.codes(previous) + self.position[:length] + self.query_cond(z_cond).unsqueeze(1)
        causal = nn.Transformer.generate_square_subsequent_mask(length, device=previous.device)
        return self.head(self.decoder(queries, memory, tgt_mask=causal, tgt_is_causal=True))

    def forward(self, codes: torch.Tensor, cond: Condition) -> torch.Tensor:
        """Teacher-forced next-code logits [B, L, K] for ``codes`` [B, L] (entries < 0 are padding: they are not
        fed back as context)."""
        z_cond = self.condition_vector(cond)
        start = torch.full_like(codes[:, :1], self.config.codebook_size)
        return self.logits(torch.cat([start, codes[:, :-1].clamp_min(0)], 1), z_cond, self.memory(z_cond))

    @torch.no_grad()
    def sample(
        self,
        cond: Condition,
        n_tokens: int,
        *,
        temperature: float = 1.0,
        top_k: int | None = None,
        generator: torch.Generator | None = None,
        prefix: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Draw codes [B, n_tokens] autoregressively. Beyond ``max_tokens`` the context slides: each new code sees
        the last ``max_tokens - 1`` codes (the start code is dropped). ``prefix`` [B, P] primes the context with
        given codes (e.g. a reference clip of the person): they are seen, not returned."""
        z_cond = self.condition_vector(cond)
        memory = self.memory(z_cond)
        batch = z_cond.shape[0]
        context = torch.full((batch, 1), self.config.codebook_size, dtype=torch.long, device=z_cond.device)
        if prefix is not None:
            context = torch.cat([context, prefix.to(context)], 1)[:, -(self.config.max_tokens - 1) :]
        drawn = []
        for _ in range(n_tokens):
            logits = self.logits(context, z_cond, memory)[:, -1] / max(temperature, 1e-6)
            if top_k is not None and top_k < logits.shape[-1]:
                kth = logits.topk(top_k, -1).values[:, -1:]
                logits = logits.masked_fill(logits < kth, float("-inf"))
            code = torch.multinomial(torch.softmax(logits, -1), 1, generator=generator)
            drawn.append(code)
            context = torch.cat([context, code], 1)[:, -self.config.max_tokens :]
        return torch.cat(drawn, 1)
