"""Profile-action prior: causal teacher forcing, sampling past the context length, masked profiles."""

from __future__ import annotations

import torch

from biomotion.models.conditioning import BIODATA_FIELDS, METADATA_FIELDS
from biomotion.models.prior import Condition, PriorConfig, ProfileActionPrior


def _prior(use_profile: bool = True) -> ProfileActionPrior:
    torch.manual_seed(0)
    config = PriorConfig(
        codebook_size=12,
        code_dim=6,
        action_size=4,
        width=16,
        layers=2,
        heads=2,
        max_tokens=8,
        dropout=0.0,
        use_profile=use_profile,
    )
    return ProfileActionPrior(config).eval()


def _condition(batch: int, references: int = 5) -> Condition:
    g = torch.Generator().manual_seed(1)
    return Condition(
        torch.randn(batch, references, 6, generator=g),
        torch.ones(batch, references, dtype=torch.bool),
        torch.randn(batch, 2 * len(BIODATA_FIELDS), generator=g),
        torch.randn(batch, 2 * len(METADATA_FIELDS), generator=g),
        torch.randn(batch, 8, generator=g),
    )


def test_teacher_forcing_is_causal():
    prior, cond = _prior(), _condition(2)
    codes = torch.randint(12, (2, 7))
    changed = codes.clone()
    changed[:, 4] = (codes[:, 4] + 1) % 12
    with torch.no_grad():
        a, b = prior(codes, cond), prior(changed, cond)
    assert a.shape == (2, 7, 12)
    torch.testing.assert_close(a[:, :5], b[:, :5])  # logits up to step 4 never see code 4
    assert not torch.allclose(a[:, 5:], b[:, 5:])  # later steps do


def test_sampling_any_length_and_priming():
    prior, cond = _prior(), _condition(3)
    g = torch.Generator().manual_seed(2)
    codes = prior.sample(cond, 20, generator=g, prefix=torch.zeros(3, 4, dtype=torch.long))  # > max_tokens
    assert codes.shape == (3, 20) and int(codes.min()) >= 0 and int(codes.max()) < 12
    top1 = prior.sample(cond, 6, top_k=1, generator=g)
    torch.testing.assert_close(top1, prior.sample(cond, 6, top_k=1, generator=g))  # top-1 is deterministic


def test_profile_branches_without_input_use_their_absent_embedding():
    prior = _prior()
    cond = _condition(1)
    empty = Condition(
        torch.zeros(1, 1, 6),
        torch.zeros(1, 1, dtype=torch.bool),
        torch.zeros_like(cond.biodata),
        torch.zeros_like(cond.metadata),
        cond.action,
    )
    other = Condition(
        torch.randn(1, 1, 6),
        torch.zeros(1, 1, dtype=torch.bool),
        torch.zeros_like(cond.biodata),
        torch.zeros_like(cond.metadata),
        cond.action,
    )
    with torch.no_grad():  # invalid reference latents and all-masked biodata/metadata carry no information
        torch.testing.assert_close(prior.condition_vector(empty), prior.condition_vector(other))
    population = _prior(use_profile=False)
    assert population.condition_vector(cond).shape == (1, 16)
