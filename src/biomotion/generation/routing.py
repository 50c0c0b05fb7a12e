"""Which shipped generator answers a request: the lab bundle or the full-body one.

Two bundles ship (`docs/generation.md`):

- ``checkpoints/``: trained on the lab sources (Fukuchi runners, OpenCap, Hamner, Schreiber), whose people have
  biodata; it knows run, walk (and its gait variants), squat, sit-to-stand, drop jump and static;
- ``checkpoints/full-body/``: trained on the same sources plus the Bandai-Namco BVH clips (retargeted onto the
  Rajagopal model), so it also knows their contents and styles ("wave both hands", "bow", "walk, elderly",
  "run, exhausted" ...). No Bandai actor has biodata.

A request goes to the full-body bundle only when its best match there is a label the lab bundle lacks and that
match scores at least `ROUTING_MARGIN` above the lab bundle's best (`ActionVocabulary.match_score`: 1 for an exact
name, else the sentence-embedding cosine similarity). So "run at 3.5 m/s", "running" or "walk slowly" stay with
the lab bundle, while "elderly walking" (0.93 against the lab's 0.56 for "walk") or "waving" go to the full-body one.

For a label only the full-body bundle knows, the person's biodata does not condition the prior: the prior never
saw biodata with those labels (a runner's biodata with "wave both hands" was sampled as walking in a trial on the
example profile), so it is masked, as the prior's training masks it (`biomotion.models.conditioning`); the
person's reference clips still condition it and the body model is still scaled to the person.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from biomotion.generation.pipeline import GENERATOR_FILE
from biomotion.models.bundle import GeneratorBundle

FULL_BODY = "full-body"
"""Folder, inside the lab checkpoints folder, of the full-body bundle."""
ROUTING_MARGIN = 0.05
"""Score by which the full-body bundle's best label must beat the lab bundle's to take a request."""


@dataclass(frozen=True)
class Route:
    """The checkpoints folder that answers a request, and why: the best label of each bundle and its score
    (``full_body_label`` None where no full-body bundle ships); ``biodata``: whether the person's biodata may
    condition the prior (False for a label only the full-body bundle knows)."""

    checkpoints: Path
    lab_label: str
    lab_score: float
    full_body_label: str | None = None
    full_body_score: float | None = None
    biodata: bool = True

    @property
    def full_body(self) -> bool:
        return not self.biodata

    def describe(self) -> str:
        """One line for the console."""
        if self.full_body:
            return (
                f"full-body bundle ({self.checkpoints}): {self.full_body_label!r} scores "
                f"{self.full_body_score:.2f} against the lab bundle's {self.lab_label!r} {self.lab_score:.2f}; "
                "its actors have no biodata, so the profile's biodata is masked (the model is still scaled "
                "to the person)"
            )
        return f"lab bundle ({self.checkpoints})"


def full_body_checkpoints(checkpoints: str | Path) -> Path | None:
    """The full-body bundle's folder inside ``checkpoints``, or None where none ships there."""
    folder = Path(checkpoints) / FULL_BODY
    return folder if (folder / GENERATOR_FILE).is_file() else None


def _vocabulary(checkpoints: Path):
    return GeneratorBundle.load(checkpoints / GENERATOR_FILE).vocabulary


def route(text: str, checkpoints: str | Path) -> Route:
    """The bundle for the action ``text``: ``checkpoints`` (the lab bundle) unless its ``full-body`` folder
    holds a bundle whose best label for ``text`` is one the lab bundle lacks and beats the lab bundle's best
    label by `ROUTING_MARGIN` (module docstring)."""
    checkpoints = Path(checkpoints)
    lab = _vocabulary(checkpoints)
    lab_label, lab_score = lab.match_score(text)
    full_body = full_body_checkpoints(checkpoints)
    if full_body is None:
        return Route(checkpoints, lab_label, lab_score)
    label, score = _vocabulary(full_body).match_score(text)
    known = label in lab.prompts or label in lab.actions
    if not known and score >= lab_score + ROUTING_MARGIN:
        return Route(full_body, lab_label, lab_score, label, score, biodata=False)
    return Route(checkpoints, lab_label, lab_score, label, score)


def vocabulary_listing(checkpoints: str | Path) -> str:
    """The actions each shipped bundle knows, with their styles and training speeds (range, median), for the console
    (``biomotion generate --list-actions``); the full-body bundle's list leaves out what the lab bundle has."""

    def styles(vocabulary, action: str) -> set[str]:
        return {e.style for e in vocabulary.entries(action) if e.style not in (None, "normal")}

    def lines(vocabulary, known: dict[str, set[str]]) -> list[str]:
        out = []
        for action in vocabulary.actions:
            new = sorted(styles(vocabulary, action) - known.get(action, set()))
            if action in known and not new:
                continue
            speed = vocabulary.typical_speed(action) if action not in known else None
            span = vocabulary.speed_range(action)
            speeds = f" ({round(span[0], 2):g}-{round(span[1], 2):g} m/s, median {speed:.2f})" if speed else ""
            out.append(f"  {action}{speeds}" + (f"; styles: {', '.join(new)}" if new else ""))
        return out

    checkpoints = Path(checkpoints)
    lab = _vocabulary(checkpoints)
    listing = [f"lab bundle, {checkpoints}:", *lines(lab, {})]
    full_body = full_body_checkpoints(checkpoints)
    if full_body is not None:
        listing += [
            f"full-body bundle (biodata masked), {full_body}:",
            *lines(_vocabulary(full_body), {a: styles(lab, a) for a in lab.actions}),
        ]
    return "\n".join(listing)
