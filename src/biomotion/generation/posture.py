"""A person's posture: how their reference clips deviate from the population, carried over to generated motion.

PG-BIG personalises through the subject profiler alone (A.6): reference latents, biodata and metadata condition the
prior, which must learn from its training subjects how a person's clips differ from everyone else's. Trained on
about a hundred clips, ours has learnt little of it (`biomotion eval generation`, unseen subjects: an identity
probe recognises 75 % of the real clips and 24 % of the guided clips generated without what this module adds; 74 %
with it; docs/decisions/posture-centring.md). The most stable part of how a person moves is their
mean posture (pelvis tilt, trunk lean, how far the knees stay bent, how the arms are carried), and it can be
measured from the references directly, without learning:

    offset_j = mean over references r of ( mean_t q_rj(t) - P_j(action of r, speed of r) ),

with P(action, speed) the population posture (`biomotion.models.bundle.GuidanceBounds`: per coordinate, the
training clips' mean values as a line in the labelled speed), so the task and the speed of a reference do not leak
into the person's deviation. The generated clip is then centred on the person's posture for the request,

    target_j = P_j(requested action, requested speed) + offset_j,

by adding to every decoded frame ``target - mean_t q_j(t)`` of the prior's sample, before guidance: the prior still
sets the motion, the person sets where it is centred (whatever the prior already made of the references, so nothing
is counted twice), and guidance and foot planting then restore contact with the floor, with a guidance term
(`biomotion.guidance.losses.posture`) holding each clip's mean at the target meanwhile. This is the simplest form
of style transfer, a constant offset per coordinate, measured per person.

Only rotational coordinates are centred: not the pelvis translations (height and travel), nor ``pelvis_rotation``,
which holds the lab's walking direction rather than the person; nor the coupled knee ``_beta`` (set from the knee
angle in every generated clip; sources leave it free or lack it); nor any coordinate no reference has. A reference's
action and speed are given (dataset labels) or, when not known (``biomotion generate --reference FILE``), the
action is the one whose population posture is nearest and the speed is the action's mean.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from biomotion.body.canonical import CANONICAL_COORDINATES, COUPLED_COORDINATES
from biomotion.models.bundle import GeneratorBundle

NOT_POSTURE = ("pelvis_rotation", "pelvis_tx", "pelvis_ty", "pelvis_tz", *COUPLED_COORDINATES)
POSTURE_COORDINATES = torch.tensor([n not in NOT_POSTURE for n in CANONICAL_COORDINATES])


def nearest_action(mean: torch.Tensor, known: torch.Tensor, bundle: GeneratorBundle) -> str | None:
    """The vocabulary action whose population posture is nearest (RMS over the posture coordinates both have) to
    a clip's mean coordinates ``mean`` [39] (``known`` [39] bool); None for a bundle without postures."""
    best, chosen = float("inf"), None
    for action in bundle.vocabulary.actions:
        population = bundle.posture(action)
        if population is None:
            return None
        both = known & POSTURE_COORDINATES & torch.isfinite(population)
        if both.any():
            distance = float(((mean - population)[both] ** 2).mean())
            if distance < best:
                best, chosen = distance, action
    return chosen


def posture_offset(
    references: Sequence[tuple[torch.Tensor, torch.Tensor]],
    bundle: GeneratorBundle,
    actions: Sequence[str | None] = (),
    speeds: Sequence[float | None] = (),
) -> torch.Tensor | None:
    """[39] the person's deviation from the population posture (module docstring; NaN where no reference has the
    coordinate, and on the coordinates that are not posture), or None when the bundle has no population postures.

    Args:
        references: (q [T, 39], mask [39]) of each reference clip, canonical coordinates as the prior sees them.
        bundle: the generator bundle whose population postures are the baseline.
        actions, speeds: each reference's action label and speed (m/s) where known; missing or None entries are
            inferred (nearest population posture; the action's mean speed).
    """
    total = torch.zeros(len(CANONICAL_COORDINATES), dtype=torch.float64)
    count = torch.zeros_like(total)
    for k, (q, mask) in enumerate(references):
        mean = q.double().mean(0)
        action = actions[k] if k < len(actions) and actions[k] is not None else nearest_action(mean, mask, bundle)
        population = None if action is None else bundle.posture(action, speeds[k] if k < len(speeds) else None)
        if population is None:
            continue
        use = mask & POSTURE_COORDINATES & torch.isfinite(population)
        total += torch.where(use, mean - population, 0.0)
        count += use.double()
    if not count.any():
        return None
    return torch.where(count > 0, total / count.clamp_min(1), float("nan"))


#: Ratios of a person's amplitude to the population's are clamped to this range, and measured only where the
#: population moves the coordinate by at least ``MIN_AMPLITUDE`` rad (std over a clip): below it the ratio is noise.
AMPLITUDE_RATIO_RANGE = (0.5, 2.0)
MIN_AMPLITUDE = 0.01


def amplitude_ratio(
    references: Sequence[tuple[torch.Tensor, torch.Tensor]],
    bundle: GeneratorBundle,
    actions: Sequence[str | None] = (),
    speeds: Sequence[float | None] = (),
) -> torch.Tensor | None:
    """[39] how much more or less than the population the person moves each coordinate: the mean over references
    of (std over time of the reference) / (population amplitude for the reference's action and speed,
    `GeneratorBundle.amplitude`), clamped to `AMPLITUDE_RATIO_RANGE`; NaN where no reference has the coordinate,
    where the population barely moves it, and on the coordinates that are not posture (`POSTURE_COORDINATES`).
    None when the bundle has no population amplitudes. The person's amplitude for a request is the population's
    for it times this ratio, as the posture target is the population's plus `posture_offset`: the speed of a
    reference does not leak into it (knees swing wider at 4.5 m/s than at 2.5 for everyone). Arguments as
    `posture_offset`."""
    total = torch.zeros(len(CANONICAL_COORDINATES), dtype=torch.float64)
    count = torch.zeros_like(total)
    for k, (q, mask) in enumerate(references):
        mean = q.double().mean(0)
        action = actions[k] if k < len(actions) and actions[k] is not None else nearest_action(mean, mask, bundle)
        population = None if action is None else bundle.amplitude(action, speeds[k] if k < len(speeds) else None)
        if population is None:
            continue
        use = mask & POSTURE_COORDINATES & torch.isfinite(population) & (population >= MIN_AMPLITUDE)
        ratio = (q.double().std(0) / population.clamp_min(MIN_AMPLITUDE)).clamp(*AMPLITUDE_RATIO_RANGE)
        total += torch.where(use, ratio, 0.0)
        count += use.double()
    if not count.any():
        return None
    return torch.where(count > 0, total / count.clamp_min(1), float("nan"))


def centring_shift(q: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """[B, 39] what to add to every frame of clips ``q`` [B, T, 39] so that each clip's mean is ``target`` [39]
    where ``target`` is finite (0 elsewhere)."""
    known = torch.isfinite(target)
    return torch.where(known, torch.nan_to_num(target).to(q.dtype) - q.mean(1), torch.zeros((), dtype=q.dtype))
