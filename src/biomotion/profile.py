"""Who moves: `Profile` (biodata, sport, injuries) and `InjuryRecord`.

A profile conditions generation (PG-BIG Sec. 3.2, A.6) and scales the body model. Every field is optional:
an absent field is None and is masked downstream, never invented.
"""

from __future__ import annotations

import numbers
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass(frozen=True)
class InjuryRecord:
    """One past injury: where (``"knee"``), what (``"ACL rupture"``) and when (free text or ISO date)."""

    location: str | None = None
    diagnosis: str | None = None
    date: str | None = None


SEXES = ("F", "M")


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
            raise ValueError(f"sex must be one of {SEXES} or None, got {self.sex!r}")
        for name in ("age", "height", "mass", "experience_years"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Real)):
                raise ValueError(f"{name} must be a number (SI units: m, kg, years), got {value!r}")
        for name, low, high in (("height", 0.3, 2.8), ("mass", 2.0, 400.0), ("age", 0.0, 130.0)):
            value = getattr(self, name)
            if value is not None and not low <= value <= high:
                raise ValueError(f"{name}={value} is outside [{low}, {high}] (SI units: m, kg, years)")
        object.__setattr__(self, "injuries", tuple(self.injuries))

    @property
    def weight(self) -> float | None:
        """Body weight in N (mass x standard gravity), or None without a mass."""
        return None if self.mass is None else self.mass * 9.80665

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["injuries"] = [asdict(i) for i in self.injuries]
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Profile":
        known = {k: v for k, v in data.items() if k in cls.__dataclass_fields__ and k not in ("injuries", "extra")}
        injuries = tuple(InjuryRecord(**i) for i in data.get("injuries") or ())
        extra = dict(data.get("extra") or {})
        extra.update({k: v for k, v in data.items() if k not in cls.__dataclass_fields__})
        return cls(**known, injuries=injuries, extra=extra)
