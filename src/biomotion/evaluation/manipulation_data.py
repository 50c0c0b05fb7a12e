"""What the real clips say about a manipulated profile field: the direction the data could have taught.

PG-BIG Sec. 4.5 varies one profile field with the action fixed and checks that the generated kinematics move the
way the literature says (`biomotion.evaluation.generation.MANIPULATIONS`). A generator learns only what its data
shows, so beside each such row `biomotion eval generation` reports what the real clips of the same action under
the data root show: per subject with a known value of the field, the mean of the same kinematic measure over its
clips of the action, and Spearman's rank correlation between field and measure across subjects (with its
two-sided p-value and the subject count). A field the data holds at one value, or for fewer than
`MIN_SUBJECTS` subjects, gets no direction.

Field values: numbers as the profile gives them (age, experience_years); ``level`` on the generator's ordinal
scale (`biomotion.models.conditioning.LEVELS`: recreational 0, competitive 0.5, elite 1); ``injuries`` 1 for a
subject with an injury at a location of the manipulated injury (e.g. "Left knee", case-insensitive), 0 for a
subject whose profile answers that it has none (`biomotion.models.conditioning.injury_known`, as the generator
reads it), and left out otherwise (an injury elsewhere, or no answer). Clips of the action: the
same action label and, when the request has a speed, a labelled speed within `SPEED_TOLERANCE` of it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from biomotion.models.actions import ActionRequest
from biomotion.models.conditioning import LEVELS, injury_known
from biomotion.profile import Profile

MIN_SUBJECTS = 3
MAX_LISTED = 4  # a field with at most this many distinct values lists the subjects per value
SPEED_TOLERANCE = 0.25  # m/s


def field_value(profile: Mapping, key: str, high: Mapping) -> float | None:
    """The value of the manipulated field ``key`` in ``profile`` (a cache record's profile dict) on a numeric
    scale (module docstring); ``high`` is the manipulation's high change, which names the injury location."""
    if key == "level":
        return LEVELS.get(str(profile.get("level") or "").strip().lower())
    if key == "injuries":
        if not injury_known(Profile.from_dict(profile)):
            return None
        recorded = profile.get("injuries") or []
        if not recorded:
            return 0.0
        wanted = {str(i["location"]).strip().lower() for i in high["injuries"]}
        return 1.0 if any(str(i.get("location", "")).strip().lower() in wanted for i in recorded) else None
    value = profile.get(key)
    return None if value is None else float(value)


def _matches(action: ActionRequest, label: str | None, speed: float | None) -> bool:
    """A clip labelled ``label`` at ``speed`` is of ``action`` (label, and speed within `SPEED_TOLERANCE` when the
    request has one)."""
    if label != action.action:
        return False
    return action.speed is None or (speed is not None and abs(float(speed) - action.speed) <= SPEED_TOLERANCE)


def action_clips(records: Sequence[Mapping], action: ActionRequest) -> list[int]:
    """Indices of the cache records of ``action``."""
    return [
        i
        for i, record in enumerate(records)
        if _matches(action, record["labels"].get("action"), record["labels"].get("speed"))
    ]


def sources_with_action(data_root: str | Path, sources: Sequence[str], action: ActionRequest) -> list[str]:
    """The ``sources`` present under ``data_root`` whose clips include ``action``, read from their file listings
    (`Source.discover`), so that no motion is loaded or retargeted for the others."""
    from biomotion.data.registry import SOURCES

    root = Path(data_root)
    return [
        name
        for name in sources
        if name in SOURCES
        and SOURCES[name].present(root)
        and any(_matches(action, spec.labels.action, spec.labels.speed) for spec in SOURCES[name].discover(root))
    ]


def real_data_directions(
    cache,
    action: ActionRequest,
    manipulations: Sequence[tuple],
    measures: Callable[[np.ndarray, float], Mapping[str, float]],
) -> dict:
    """Per manipulated field (rows of `MANIPULATIONS`: field, low change, high change, measure, sign, source) the
    Spearman correlation across the subjects of ``cache`` between the field and ``measures(q, rate)[measure]``
    on their clips of ``action``: ``rho``, ``p``, ``subjects``, ``values`` (subjects per field value, or the
    range of a field with more than `MAX_LISTED` values),
    ``direction`` ("increase"/"decrease", None without one) and ``agrees`` (the documented sign, None without a
    direction)."""
    picked = action_clips(cache.records, action)
    per_subject: dict[str, list[Mapping[str, float]]] = {}
    profiles: dict[str, Mapping] = {}
    for i in picked:
        record = cache.records[i]
        key = f"{record['source']}/{record['subject']}"
        per_subject.setdefault(key, []).append(measures(cache.motion(i).values, cache.rate))
        profiles[key] = record.get("profile") or {}
    out = {}
    for field, _, high, measure, sign, _ in manipulations:
        ((key, _),) = high.items()
        pairs = [
            (field_value(profiles[s], key, high), float(np.nanmean([m[measure] for m in rows])))
            for s, rows in per_subject.items()
        ]
        pairs = [(x, y) for x, y in pairs if x is not None and np.isfinite(x) and np.isfinite(y)]
        distinct, counts = np.unique([x for x, _ in pairs], return_counts=True)
        row = {
            "measure": measure,
            "clips": len(picked),
            "subjects": len(pairs),
            "values": (
                {f"{x:g}": int(n) for x, n in zip(distinct, counts)}
                if len(distinct) <= MAX_LISTED
                else {"from": float(distinct[0]), "to": float(distinct[-1])}
            ),
            "rho": None,
            "p": None,
            "direction": None,
            "agrees": None,
        }
        if len(pairs) >= MIN_SUBJECTS and len(distinct) > 1:
            rho, p = spearmanr([x for x, _ in pairs], [y for _, y in pairs])
            if np.isfinite(rho) and rho != 0:
                row.update(
                    rho=float(rho),
                    p=float(p),
                    direction="increase" if rho > 0 else "decrease",
                    agrees=bool(np.sign(rho) == sign),
                )
        out[field] = row
    return out
