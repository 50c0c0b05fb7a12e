"""`Trial`: one captured or generated performance — motion, markers, forces, who, what, and where it came from."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from biomotion.motion import GroundReaction, Markers, Motion
from biomotion.profile import Profile


@dataclass(frozen=True)
class Labels:
    """What the trial shows. ``action`` is a dataset label (``run``, ``walk``, ``drop jump`` ...), ``speed`` m/s."""

    action: str | None = None
    style: str | None = None
    speed: float | None = None
    text: str | None = None


@dataclass(frozen=True)
class Trial:
    """Motion + markers + ground reaction + profile + labels, each optional, plus the source path."""

    motion: Motion | None = None
    markers: Markers | None = None
    forces: GroundReaction | None = None
    profile: Profile = field(default_factory=Profile)
    labels: Labels = field(default_factory=Labels)
    source: Path | None = None

    def slice(self, start: float | None = None, stop: float | None = None) -> Trial:
        """Every time series cut to ``start <= t <= stop``."""
        return replace(
            self,
            **{
                name: getattr(self, name).slice(start, stop)
                for name in ("motion", "markers", "forces")
                if getattr(self, name) is not None
            },
        )

    def resample(self, rate: float) -> Trial:
        """Every time series resampled to ``rate`` Hz on the motion's span (see `Motion.resample`)."""
        span = self.motion or self.markers or self.forces
        if span is None:
            return self
        start, stop = float(span.times[0]), float(span.times[-1])
        return replace(
            self,
            **{
                name: getattr(self, name).resample(rate, start, stop)
                for name in ("motion", "markers", "forces")
                if getattr(self, name) is not None
            },
        )
