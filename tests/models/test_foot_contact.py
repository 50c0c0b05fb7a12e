"""Foot contact (PG-BIG Sec. 3.1 / Table 1): stance mask, the tokenizer's contact channels and penetration term."""

from __future__ import annotations

import pytest
import torch

from biomotion.body.model import BodyModel
from biomotion.models.foot_contact import (
    CONTACT_GROUPS,
    FootKinematics,
    group_members,
    points_in_contact,
    stance_mask,
)
from biomotion.models.vqvae import N_COORDS, MotionVQVAE, VQVAEConfig
from tests.conftest import data_path


def test_stance_is_low_and_slower_than_the_body_so_a_low_swing_is_not_stance():
    """A walk at 1 m/s (pelvis 1 m/s): a stance point sliding at 0.3 m/s and a swing point skimming 2 cm above
    the floor at 2.5 m/s; both below 5 cm. Height alone calls both stance; the speed test keeps only the first
    (limit 1.5 m/s); a standing clip keeps the 0.5 m/s floor."""
    rate, t = 30.0, torch.arange(30) / 30.0
    q = torch.zeros(1, 30, 39)
    q[0, :, 3] = t  # pelvis_tx: 1 m/s
    feet = torch.zeros(1, 30, 2, 3)
    feet[0, :, 0, 0], feet[0, :, 0, 1] = 0.3 * t, 0.01  # sliding stance point
    feet[0, :, 1, 0], feet[0, :, 1, 1] = 2.5 * t, 0.02  # low swing point
    assert stance_mask(feet, q, rate, ratio=None).all()
    mask = stance_mask(feet, q, rate, ratio=1.5)
    assert mask[0, :, 0].all() and not mask[0, :, 1].any()
    standing = torch.zeros_like(q)
    mask = stance_mask(feet, standing, rate, ratio=1.5)  # limit: the 0.5 m/s floor
    assert mask[0, :, 0].all() and not mask[0, :, 1].any()
    feet[0, :, 0, 1] = 0.08  # above 5 cm: never stance
    assert not stance_mask(feet, q, rate, ratio=1.5)[0, :, 0].any()


def test_each_channel_covers_its_foot_points_and_no_other():
    names = (
        "heel_med_r",
        "heel_lat_r",
        "met1_r",
        "met5_r",
        "toe_r",
        "heel_med_l",
        "heel_lat_l",
        "met1_l",
        "met5_l",
        "toe_l",
    )
    members = group_members(names)
    assert [g for g, _ in CONTACT_GROUPS] == ["heel_r", "forefoot_r", "heel_l", "forefoot_l"]
    assert members.sum(1).tolist() == [2, 3, 2, 3] and members.sum(0).tolist() == [1] * 10
    assert members[0, :2].all() and members[1, 2:5].all() and members[2, 5:7].all() and members[3, 7:].all()


@pytest.fixture(scope="module")
def feet():
    return FootKinematics(BodyModel.from_osim(data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")))


def _standing(feet: FootKinematics, frames: int = 16) -> torch.Tensor:
    """The default pose with the pelvis lowered so the lowest foot point touches y = 0."""
    q = feet.defaults.repeat(1, frames, 1).clone()
    lowest = feet.points(q)[..., 1].amin()
    q[..., 4] -= lowest
    return q


def test_standing_on_the_floor_is_contact_everywhere_and_lifted_is_none(feet):
    """Default pose, feet flat on the floor, still: every channel in contact on every frame. The same pose 10 cm
    up (above the 5 cm stance height): none. Masked coordinates take the defaults, so junk in them changes
    nothing."""
    q = _standing(feet)
    mask = torch.ones(1, N_COORDS, dtype=torch.bool)
    assert feet.labels(q, mask, 30.0).eq(1.0).all()
    lifted = q.clone()
    lifted[..., 4] += 0.10
    assert feet.labels(lifted, mask, 30.0).eq(0.0).all()
    junk = q.clone()
    junk[..., 20:] = 3.0  # trunk and arm coordinates far off ...
    mask[:, 20:] = False  # ... but masked
    assert feet.labels(junk, mask, 30.0).eq(1.0).all()
    assert points_in_contact(torch.tensor([[[True, False, False, True]]]), feet.members).tolist() == [
        [[True, True] + [False] * 3 + [False] * 2 + [True] * 3]
    ]


def test_penetration_is_the_mean_depth_below_the_floor_in_cm(feet):
    """Lowering a standing pose by 2 cm puts every foot point 2 cm (plus its standing height, 0 for the lowest)
    below the floor; raising it removes all penetration. Differentiable in the coordinates."""
    q = _standing(feet)
    mask = torch.ones(1, N_COORDS, dtype=torch.bool)
    heights = feet.points(q)[..., 1]
    sunk = q.clone()
    sunk[..., 4] -= 0.02
    expected = 100 * torch.relu(0.02 - heights).mean()
    torch.testing.assert_close(feet.penetration_cm(sunk, mask), expected)
    assert float(expected) > 1.0
    raised = q.clone()
    raised[..., 4] += 0.01
    assert float(feet.penetration_cm(raised, mask)) == 0.0
    sunk.requires_grad_(True)
    feet.penetration_cm(sunk, mask).backward()
    assert float(sunk.grad[..., 4].sum()) < 0  # raising the pelvis reduces penetration


def test_tokenizer_contact_channels_are_decoded_and_trained():
    """With ``foot_contact`` the decoder gives four probabilities per frame and the loss includes a binary
    cross-entropy against labels, which a few steps on fixed labels drive down; without it there are none and
    the old checkpoints' layout is unchanged (39 output channels)."""
    torch.manual_seed(0)
    plain = MotionVQVAE(VQVAEConfig(width=32, code_dim=16, codebook_size=32))
    assert plain.decoder[-1].out_channels == N_COORDS and plain.contact_channels == 0
    config = VQVAEConfig(width=32, code_dim=16, codebook_size=32, foot_contact=True, w_contact=1.0)
    model = MotionVQVAE(config)
    assert model.decoder[-1].out_channels == N_COORDS + 4
    g = torch.Generator().manual_seed(0)
    x = torch.randn(4, 32, N_COORDS, generator=g).cumsum(1) * 0.05
    mask = torch.ones(4, N_COORDS, dtype=torch.bool)
    labels = (torch.arange(32)[None, :, None] % 8 < 4).float().expand(4, 32, 4).clone()
    model.set_normalisation(x, mask)
    with torch.no_grad():
        q, probability = model.decode_with_contact(model.encode(x, mask)[0])
        assert plain.decode_with_contact(plain.encode(x, mask)[0])[1] is None
    assert q.shape == x.shape and probability.shape == (4, 32, 4)
    assert float(probability.min()) >= 0 and float(probability.max()) <= 1
    optimiser = torch.optim.AdamW(model.parameters(), lr=3e-3)
    first = None
    for _ in range(60):
        _, losses = model(x, mask, labels)
        first = first if first is not None else losses["contact"].item()
        optimiser.zero_grad()
        losses["loss"].backward()
        optimiser.step()
    assert {"contact", "contact_accuracy"} <= set(losses)
    assert losses["contact"].item() < 0.5 * first and losses["contact_accuracy"].item() > 0.9


def test_guidance_reads_its_contact_mask_from_the_decoder_when_it_has_channels(feet):
    """Guide.contact: with contact channels (and ``decoded_contact``), m_t is the points of the channels decoded
    above 0.5, whatever the kinematics say; without channels, or with ``decoded_contact`` off, it is
    `stance_mask` of the decoded feet."""
    from biomotion.guidance.refine import GuidanceConfig, Guide, Kinematics
    from biomotion.models.bundle import GuidanceBounds

    bounds = GuidanceBounds((1.0,) * N_COORDS, (0.0, 5.0), (0.0, 50.0), 100)
    tokenizer = MotionVQVAE(VQVAEConfig(width=32, code_dim=16, codebook_size=32, foot_contact=True))
    high = torch.ones(N_COORDS)
    q = _standing(feet)  # still, feet flat on the floor: all stance kinematically
    k = Kinematics(q, feet.points(q), torch.zeros(1, q.shape[1], 3))
    decoded = torch.zeros(1, q.shape[1], 4)
    decoded[:, :8, 0] = 0.9  # right heel only, first half
    k_decoded = Kinematics(k.q, k.feet, k.com, decoded)
    guide = Guide(tokenizer, feet.body, bounds, high, high)
    mask = guide.contact(k_decoded)
    assert mask[0, :8].tolist() == [[True, True] + [False] * 8] * 8 and not mask[0, 8:].any()
    assert guide.contact(k).all()  # no channels decoded: the kinematic rule
    off = Guide(tokenizer, feet.body, bounds, high, high, config=GuidanceConfig(decoded_contact=False))
    assert off.contact(k_decoded).all()
