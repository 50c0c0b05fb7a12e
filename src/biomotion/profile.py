"""Who moves: `Profile` (biodata, sport, injuries) and `InjuryRecord`.

A profile conditions generation (PG-BIG Sec. 3.2, A.6) and scales the body model. Every field is optional:
an absent field is None and is masked downstream, never invented. A field that is present is checked: an unknown
field name (``agee``) is refused naming the closest known one, a number must lie in its documented range
(`RANGES`), and a failure is a `biomotion.errors.ProfileError` (a ConfigError) that names the field.
"""

from __future__ import annotations

import datetime
import difflib
import math
import numbers
import reprlib
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from biomotion.errors import ProfileError


@dataclass(frozen=True)
class InjuryRecord:
    """One past injury: where (``"knee"``), what (``"ACL rupture"``) and when (free text or ISO date)."""

    location: str | None = None
    diagnosis: str | None = None
    date: str | None = None

    def __post_init__(self) -> None:
        for name in ("location", "diagnosis", "date"):
            object.__setattr__(self, name, _text(getattr(self, name), name))


def _shown(value: Any) -> str:
    """A short repr for messages. A profile holds whatever YAML built, a nested alias "bomb" included (a few lines
    that expand to a billion items), whose full repr would never end."""
    shower = reprlib.Repr()
    shower.maxlevel, shower.maxlist, shower.maxtuple, shower.maxdict = 2, 4, 4, 4
    shower.maxstring = shower.maxother = 60
    return shower.repr(value)


def _text(value: Any, name: str) -> str | None:
    """A text field as text: numbers and dates (YAML reads an unquoted ISO date as a date) become their text; anything
    else (a list, a mapping) is refused."""
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, (numbers.Real, datetime.date)) and not isinstance(value, bool):
        return str(value)
    raise ProfileError(f"{name} must be text, got {_shown(value)}", field=name)


def _scalar(value: Any) -> bool:
    return value is None or isinstance(value, (str, numbers.Real, datetime.date))


SEXES = ("F", "M")
RANGES: dict[str, tuple[float, float, str]] = {
    "height": (0.3, 2.8, "m"),
    "mass": (2.0, 400.0, "kg"),
    "age": (0.0, 130.0, "years"),
    "experience_years": (0.0, 100.0, "years"),
}
"""Documented range (inclusive) and unit of each numeric field: values outside are a unit mistake or a typo."""
INJURY_FIELDS = ("location", "diagnosis", "date")
TEXT_FIELDS = ("subject_id", "sex", "dominance", "sport", "level")
"""Fields that hold text; a number or date given for one is kept as its text."""
SYNONYMS = {
    "weight": "mass",
    "body_mass": "mass",
    "stature": "height",
    "gender": "sex",
    "id": "subject_id",
    "subject": "subject_id",
    "experience": "experience_years",
    "dominant_side": "dominance",
}
"""Names people use for a field, suggested when a profile uses them (difflib would not find most)."""


def _unknown(keys: list[str], known: tuple[str, ...], what: str) -> ProfileError:
    """The error for unknown field names: each with the closest known one, then the known ones."""
    named = []
    for key in keys:
        close = (
            [SYNONYMS[key.lower()]]
            if SYNONYMS.get(key.lower()) in known
            else difflib.get_close_matches(key.lower(), known, n=1, cutoff=0.5)
        )
        named.append(f"{key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    return ProfileError(
        f"unknown {what}{'s' if len(keys) > 1 else ''} {', '.join(named)}; known: {', '.join(known)}", field=keys[0]
    )


@dataclass(frozen=True)
class Profile:
    """A person: SI units (height in m, mass in kg), age in years.

    Attributes:
        subject_id: identifier within its source (``RBDS001``, ``Subject4`` ...).
        sex: ``"F"`` or ``"M"``.
        dominance: ``"R"`` or ``"L"`` (dominant leg/hand as the source reports it).
        sport, level: e.g. ``"running"``, ``"recreational"`` / ``"competitive"`` / ``"elite"``.
        experience_years: years practising the sport.
        injuries: past injuries, oldest first where the source says.
        extra: any other field a source provides (kept, not interpreted).
    """

    subject_id: str | None = None
    age: float | None = None
    sex: str | None = None
    height: float | None = None
    mass: float | None = None
    dominance: str | None = None
    sport: str | None = None
    level: str | None = None
    experience_years: float | None = None
    injuries: tuple[InjuryRecord, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.sex is not None and self.sex not in SEXES:
            raise ProfileError(f"sex must be one of {SEXES} or None, got {_shown(self.sex)}", field="sex")
        for name, (low, high, unit) in RANGES.items():
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise ProfileError(f"{name} must be a number (SI units: m, kg, years), got {_shown(value)}", field=name)
            if not (math.isfinite(value) and low <= value <= high):
                hint = (
                    f": in metres, {value / 100:g} for {value:g} cm" if name == "height" and 30 <= value <= 280 else ""
                )
                raise ProfileError(f"{name}={value} is outside [{low:g}, {high:g}] {unit}{hint}", field=name)
        for name in TEXT_FIELDS:
            object.__setattr__(self, name, _text(getattr(self, name), name))
        if not isinstance(self.extra, Mapping):
            raise ProfileError(f"extra must be a mapping of other fields, got {_shown(self.extra)}", field="extra")
        for key, value in self.extra.items():  # kept as given, and written into reports: values or flat lists
            if not (_scalar(value) or (isinstance(value, (list, tuple)) and all(_scalar(v) for v in value))):
                raise ProfileError(
                    f"extra.{key} must be a value or a list of values, got {_shown(value)}", field="extra"
                )
        object.__setattr__(self, "injuries", tuple(self.injuries))
        for number, injury in enumerate(self.injuries):
            if not isinstance(injury, InjuryRecord):
                raise ProfileError(
                    f"injuries[{number}] must be an InjuryRecord, got {_shown(injury)}", field=f"injuries[{number}]"
                )

    @property
    def weight(self) -> float | None:
        """Body weight in N (mass x standard gravity), or None without a mass."""
        return None if self.mass is None else self.mass * 9.80665

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["injuries"] = [asdict(i) for i in self.injuries]
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Profile:
        """The inverse of `to_dict`, and how profile files are read: the keys must be `Profile` fields (other
        information goes under ``extra``), ``injuries`` a list of mappings with keys among `INJURY_FIELDS`.

        Raises:
            ProfileError: an unknown key (named with the closest field), a value of the wrong type or outside
                `RANGES`; ``error.field`` names the field.
        """
        names = tuple(f.name for f in fields(cls))
        if not isinstance(data, Mapping):
            raise ProfileError(f"a profile is a mapping of fields ({', '.join(names)}), got {type(data).__name__}")
        unknown = [str(key) for key in data if key not in names]
        if unknown:
            raise _unknown(unknown, names, "profile field")
        listed = data.get("injuries") or ()
        if isinstance(listed, (str, Mapping)) or not isinstance(listed, (list, tuple)):
            raise ProfileError(
                f"injuries must be a list of {{{', '.join(INJURY_FIELDS)}}} mappings, got {_shown(listed)}",
                field="injuries",
            )
        injuries = []
        for number, injury in enumerate(listed):
            if isinstance(injury, InjuryRecord):
                injuries.append(injury)
                continue
            if not isinstance(injury, Mapping):
                raise ProfileError(
                    f"injuries[{number}] must be a mapping with keys among {', '.join(INJURY_FIELDS)}, "
                    f"got {_shown(injury)}",
                    field=f"injuries[{number}]",
                )
            unknown = [str(key) for key in injury if key not in INJURY_FIELDS]
            if unknown:
                error = _unknown(unknown, INJURY_FIELDS, f"injuries[{number}] field")
                raise ProfileError(str(error), field=f"injuries[{number}].{unknown[0]}")
            injuries.append(InjuryRecord(**injury))
        extra = data.get("extra") or {}
        if not isinstance(extra, Mapping):
            raise ProfileError(f"extra must be a mapping of other fields, got {_shown(extra)}", field="extra")
        values = {k: v for k, v in data.items() if k not in ("injuries", "extra")}
        return cls(**values, injuries=tuple(injuries), extra=dict(extra))
