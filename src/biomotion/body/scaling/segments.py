"""Segment-by-segment scale factors from ANSUR II body measures: the generic model scaled to a `Profile` by its
segments where the profile gives them.

`biomotion.body.scaling.stature` scales every body by the stature ratio. A person measured as the ANSUR II survey
measures (Gordon et al. 2014, "2012 Anthropometric Survey of U.S. Army Personnel", NATICK/TR-15/007; landmark
heights and lengths in millimetres) can be scaled segment by segment instead, as OpenSim's ScaleTool scales a body
by the ratio of a measured length to the model's (Delp et al. 2007, IEEE TBME 54:1940):

    factor(segment) = L_person / E[L | stature = H_generic]

``L`` is the segment's length from the measures (`SEGMENTS`: a landmark-height difference or a direct length),
``E[L | stature]`` its least-squares line on stature over the ANSUR II men (4082; the generic Rajagopal 2016 subject
is a man of 1.70 m), evaluated at the generic model's stature ``H_generic``: the length the generic model's segment
stands for. Measuring the model's own segment between joint centres instead would compare joint centres with skin
landmarks (the trochanterion lies several centimetres above the hip centre); the ratio to the population's length
at the model's stature needs no such correspondence. The factor applies to all three axes of the segment's bodies
(right and left alike), as OpenSim setups scale a segment by one measurement. Bodies whose segment was not measured
keep the stature ratio (`biomotion.body.scaling.stature`).

The lines are fitted once from ``anthropometry/ANSUR_II_MALE_Public.csv`` and shipped as ``ansur_segments.json``
beside this module (``biomotion train segments --data-root ../shared/data --out
src/biomotion/body/scaling/ansur_segments.json`` writes it again; a test checks the shipped file against a fresh
fit).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from biomotion.errors import ConfigError

LINES_FILE = Path(__file__).with_name("ansur_segments.json")
ANSUR_MEN = "anthropometry/ANSUR_II_MALE_Public.csv"
#: factors outside this range mean a wrong unit or a wrong measure (ANSUR II measures are in millimetres)
FACTOR_RANGE = (0.5, 1.6)


@dataclass(frozen=True)
class SegmentMeasure:
    """A segment's length from ANSUR II measures (``top - bottom``, or ``top`` alone) and the model bodies it
    scales (each name as is, and with ``_r`` / ``_l``)."""

    name: str
    top: str
    bottom: str | None
    bodies: tuple[str, ...]

    def length(self, measures: Mapping[str, float]) -> float | None:
        """The segment's length (mm) from ``measures``, None when one of its measures is absent."""
        if self.top not in measures or (self.bottom is not None and self.bottom not in measures):
            return None
        return float(measures[self.top]) - (0.0 if self.bottom is None else float(measures[self.bottom]))


SEGMENTS = (
    SegmentMeasure("thigh", "trochanterionheight", "tibialheight", ("femur", "patella")),
    SegmentMeasure("shank", "tibialheight", "lateralmalleolusheight", ("tibia",)),
    SegmentMeasure("foot", "footlength", None, ("talus", "calcn", "toes")),
    SegmentMeasure("pelvis", "bicristalbreadth", None, ("pelvis",)),
    SegmentMeasure("trunk", "cervicaleheight", "iliocristaleheight", ("torso",)),
    SegmentMeasure("upper_arm", "acromionradialelength", None, ("humerus",)),
    SegmentMeasure("forearm", "radialestylionlength", None, ("ulna", "radius")),
    SegmentMeasure("hand", "handlength", None, ("hand",)),
)
MEASURES = tuple(sorted({m for s in SEGMENTS for m in (s.top, s.bottom) if m is not None}))


@lru_cache(maxsize=1)
def shipped_lines() -> dict:
    return json.loads(LINES_FILE.read_text())


def measures_of(values: Mapping[str, object]) -> dict[str, float]:
    """The ANSUR II segment measures (mm) among ``values`` (e.g. a `Profile`'s ``extra``), as numbers."""
    out = {}
    for name in MEASURES:
        value = values.get(name)
        if value is None or (isinstance(value, str) and not value.strip()):
            continue
        try:
            out[name] = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"ANSUR measure {name} must be a number of millimetres, got {value!r}") from None
    return out


def segment_factors(measures_mm: Mapping[str, float], generic_height: float) -> dict[str, float]:
    """Scale factor of every segment whose measures are given (module docstring); ``generic_height`` in m."""
    lines = shipped_lines()["segments"]
    factors = {}
    for segment in SEGMENTS:
        length = segment.length(measures_mm)
        if length is None:
            continue
        line = lines[segment.name]
        expected = line["intercept_mm"] + line["slope"] * 1000.0 * generic_height
        factor = length / expected
        if not FACTOR_RANGE[0] <= factor <= FACTOR_RANGE[1]:
            named = segment.top if segment.bottom is None else f"{segment.top} - {segment.bottom}"
            raise ConfigError(
                f"{segment.name} length {named} = {length:g} mm gives a scale factor of {factor:.3g} "
                f"against {expected:.0f} mm at the generic model's {generic_height:.2f} m; ANSUR II "
                "measures are in millimetres"
            )
        factors[segment.name] = factor
    return factors


def body_factors(body_names: tuple[str, ...], factors: Mapping[str, float], default: float) -> dict[str, float]:
    """Each body's factor: its segment's, else ``default`` (the stature ratio)."""
    of_body = {}
    for segment in SEGMENTS:
        if segment.name in factors:
            for body in segment.bodies:
                for name in (body, f"{body}_r", f"{body}_l"):
                    of_body[name] = factors[segment.name]
    return {body: of_body.get(body, default) for body in body_names}
