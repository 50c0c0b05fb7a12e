"""Numeric conditioning inputs of the generator: biodata, motion metadata and the action, each with a mask.

PG-BIG A.6 (Fig. 5) feeds the subject profiler three things: tokenizer latents of the subject's reference clips,
**biodata** (age, sex, mass, height, sport, level, injury history) and **metadata** (joint velocities, COM velocity
and acceleration statistics). Sec. 3.2 adds the **action** embedding. Every field a profile or label lacks is
masked (value 0, mask 0), never invented (the profile's own rule, `biomotion.profile`).

Scales put every value near [-1, 1]: age / 50 y, mass / 70 kg, height / 1.7 m, experience / 10 y, level as
recreational 0 / competitive 0.5 / elite 1, sex F -1 / M +1. Injury history is a presence flag plus a multi-hot of
body regions (matched by keyword in the location and diagnosis text); it is known only where the source records
injuries (a non-empty list, or the Fukuchi table's ``Injury`` Yes/No column), otherwise masked.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from biomotion.body.canonical import CANONICAL_COORDINATES
from biomotion.models.actions import ActionRequest, ActionVocabulary
from biomotion.profile import Profile

LEVELS = {"recreational": 0.0, "amateur": 0.0, "competitive": 0.5, "elite": 1.0}
SPORTS = ("running",)
#: Injury regions and the keywords that place an injury in them (lower-case substrings).
INJURY_REGIONS: dict[str, tuple[str, ...]] = {
    "knee": ("knee", "patel", "acl", "menisc", "cruciate"),
    "ankle_foot": ("ankle", "foot", "achil", "aquil", "plantar", "toe", "calcane"),
    "shank": ("tibia", "fibula", "shin", "calf"),
    "hip_thigh": ("hip", "thigh", "hamstring", "groin", "femur", "quadriceps"),
    "back": ("back", "spine", "lumbar"),
}
BIODATA_FIELDS = (
    "age",
    "sex",
    "mass",
    "height",
    *(f"sport_{s}" for s in SPORTS),
    "level",
    "experience",
    "injury_any",
    *(f"injury_{r}" for r in INJURY_REGIONS),
)
METADATA_FIELDS = (
    *(f"speed_{c}" for c in CANONICAL_COORDINATES),
    "com_speed_mean",
    "com_speed_std",
    "com_acceleration_mean",
    "com_acceleration_std",
)


@dataclass(frozen=True)
class Features:
    """Values [..., n] and their mask [..., n] (1 where known)."""

    values: torch.Tensor
    mask: torch.Tensor

    def cat(self) -> torch.Tensor:
        """[..., 2n]: the masked values then the mask, the layout every branch takes."""
        return torch.cat([self.values * self.mask, self.mask], -1)


def injury_known(profile: Profile) -> bool:
    """Whether ``profile`` says anything of its injury history: injuries listed, or a table's Injury column
    answered yes or no (an empty list alone is no answer)."""
    return bool(profile.injuries) or str(profile.extra.get("Injury", "")).strip().lower() in ("yes", "no")


def biodata_features(profile: Profile | None) -> Features:
    """Biodata vector of ``profile`` (`BIODATA_FIELDS`); None gives an all-masked vector."""
    n = len(BIODATA_FIELDS)
    values, mask = np.zeros(n, np.float32), np.zeros(n, np.float32)
    if profile is None:
        return Features(torch.from_numpy(values), torch.from_numpy(mask))

    def put(name: str, value: float | None) -> None:
        if value is not None:
            i = BIODATA_FIELDS.index(name)
            values[i], mask[i] = value, 1.0

    put("age", None if profile.age is None else profile.age / 50.0)
    put("sex", None if profile.sex is None else (1.0 if profile.sex == "M" else -1.0))
    put("mass", None if profile.mass is None else profile.mass / 70.0)
    put("height", None if profile.height is None else profile.height / 1.7)
    if profile.sport is not None:
        for sport in SPORTS:
            put(f"sport_{sport}", float(profile.sport.strip().lower() == sport))
    put("level", LEVELS.get((profile.level or "").strip().lower()))
    put("experience", None if profile.experience_years is None else profile.experience_years / 10.0)
    if injury_known(profile):
        text = " ".join(f"{i.location or ''} {i.diagnosis or ''}".lower() for i in profile.injuries)
        put("injury_any", float(bool(profile.injuries)))
        for region, words in INJURY_REGIONS.items():
            put(f"injury_{region}", float(any(w in text for w in words)))
    return Features(torch.from_numpy(values), torch.from_numpy(mask))


def metadata_features(q: torch.Tensor, coordinate_mask: torch.Tensor, com: torch.Tensor, rate: float) -> Features:
    """Motion metadata of one clip (`METADATA_FIELDS`): mean |dq/dt| per canonical coordinate (masked where the
    coordinate is absent) and mean/std of COM speed and acceleration magnitude.

    Args:
        q: [T, 39] canonical coordinates (SI). coordinate_mask: [39] bool. com: [T, 3] COM (m). rate: Hz.
    """
    speed = (torch.diff(q, dim=0).abs() * rate).mean(0)
    com_v = torch.diff(com, dim=0) * rate
    com_a = torch.diff(com_v, dim=0) * rate
    v, a = com_v.norm(dim=-1), com_a.norm(dim=-1)
    values = torch.cat([speed, torch.stack([v.mean(), v.std(), a.mean() / 10.0, a.std() / 10.0])]).float()
    mask = torch.cat([coordinate_mask.float(), torch.ones(4)])
    return Features(torch.where(mask > 0, values, torch.zeros_like(values)), mask)


def mean_features(items: Sequence[Features]) -> Features:
    """Masked mean of several clips' features (one subject's reference set); empty gives all-masked."""
    values = torch.stack([f.values * f.mask for f in items]).sum(0)
    count = torch.stack([f.mask for f in items]).sum(0)
    return Features(values / count.clamp_min(1), (count > 0).float())


def action_features(request: ActionRequest, vocabulary: ActionVocabulary) -> Features:
    """One-hot action, one-hot style (absent style masked) and speed / 5 m/s (masked when not given)."""
    actions, styles = vocabulary.actions, vocabulary.styles
    values = np.zeros(len(actions) + len(styles) + 1, np.float32)
    mask = np.zeros_like(values)
    if request.action in actions:
        values[actions.index(request.action)] = 1.0
        mask[: len(actions)] = 1.0
    if request.style in styles:
        values[len(actions) + styles.index(request.style)] = 1.0
        mask[len(actions) : len(actions) + len(styles)] = 1.0
    if request.speed is not None:
        values[-1], mask[-1] = request.speed / 5.0, 1.0
    return Features(torch.from_numpy(values), torch.from_numpy(mask))


def action_size(vocabulary: ActionVocabulary) -> int:
    """Length of `action_features` for ``vocabulary``."""
    return len(vocabulary.actions) + len(vocabulary.styles) + 1
