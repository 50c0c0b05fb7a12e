"""The value types that travel through every stage: `Motion`, `Markers`, `GroundReaction`.

All three are immutable time series on a shared clock (seconds), stored as NumPy arrays in SI units (rad, m, N,
N·m) in OpenSim's ground frame (y up). Resampling (with an anti-alias low-pass), filtering, slicing and selection
are methods, so no stage needs its own helper for them. Tensors are made on request with ``to_torch``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from biomotion.errors import DataFormatError

TRANSLATION_SUFFIXES = ("_tx", "_ty", "_tz")


def is_translation(name: str) -> bool:
    """True for OpenSim coordinates that are lengths (``pelvis_tx`` ...), False for angles.

    OpenSim files do not mark each column's unit; models name their translational coordinates with the
    ``_tx/_ty/_tz`` suffixes, which is the rule the readers and writers use to convert degrees at the boundary.
    """
    return name.endswith(TRANSLATION_SUFFIXES)


def _uniform_rate(times: np.ndarray) -> float:
    """Mean rate (n - 1) / duration: robust to time columns rounded to a few decimals (TRC files)."""
    if times.size < 2:
        return float("nan")
    return float((times.size - 1) / (times[-1] - times[0]))


def lowpass(
    values: np.ndarray, rate: float, cutoff_hz: float, order: int = 4, axis: int = 0, padlen: int | None = None
) -> np.ndarray:
    """Zero-lag Butterworth low-pass (``filtfilt``), the filter biomechanics labs use (Winter 2009, ch. 3).

    ``order`` is the order of the single pass; the zero-lag double pass doubles it. The ends are extended by odd
    reflection over ``padlen`` samples (default: scipy's 3 x filter length; OpenSim's tools pad half the signal).
    NaN gaps are bridged by linear interpolation for filtering and put back afterwards, so an occluded marker
    stays occluded.
    """
    import scipy.signal

    if not 0 < cutoff_hz < rate / 2:
        raise ValueError(f"cutoff {cutoff_hz} Hz must lie in (0, {rate / 2}) for data sampled at {rate} Hz")
    values = np.asarray(values, dtype=float)
    moved = np.moveaxis(values, axis, 0)
    flat = moved.reshape(moved.shape[0], -1)
    gaps = ~np.isfinite(flat)
    filled = _bridge_gaps(flat, gaps)
    sos = _butterworth(order, cutoff_hz, rate).copy()  # scipy's filter needs a writable array
    padlen = 3 * (2 * len(sos) + 1) if padlen is None else padlen
    padlen = min(padlen, flat.shape[0] - 2)
    if flat.shape[0] < 2:
        return values.copy()
    out = scipy.signal.sosfiltfilt(sos, filled, axis=0, padlen=max(padlen, 0))
    out[gaps] = np.nan
    return np.moveaxis(out.reshape(moved.shape), 0, axis)


@lru_cache(maxsize=64)
def _butterworth(order: int, cutoff_hz: float, rate: float) -> np.ndarray:
    """Second-order sections of a low-pass Butterworth filter; designed once per (order, cutoff, rate), since a
    chain of analyses filters many signals with the same few filters (callers take a copy)."""
    import scipy.signal

    return scipy.signal.butter(order, cutoff_hz, btype="low", fs=rate, output="sos")


def _bridge_gaps(flat: np.ndarray, gaps: np.ndarray) -> np.ndarray:
    """Linear interpolation across NaN runs (constant at the ends); all-NaN columns become zeros."""
    filled = flat.copy()
    index = np.arange(flat.shape[0])
    for column in np.flatnonzero(gaps.any(axis=0)):
        good = ~gaps[:, column]
        filled[:, column] = np.interp(index, index[good], flat[good, column]) if good.any() else 0.0
    return filled


def _resample(times: np.ndarray, values: np.ndarray, new_times: np.ndarray, rate: float) -> np.ndarray:
    """Resample along axis 0: anti-alias low-pass when the new rate is lower, then cubic interpolation.

    A sample of the result is NaN where its nearest source sample was NaN.
    """
    import scipy.interpolate

    old_rate = _uniform_rate(times)
    flat = values.reshape(values.shape[0], -1).astype(float)
    gaps = ~np.isfinite(flat)
    if rate < old_rate and flat.shape[0] > 12:
        smooth = lowpass(flat, old_rate, 0.4 * rate)
    else:
        smooth = flat.copy()
    bridged = _bridge_gaps(smooth, gaps)
    if flat.shape[0] >= 4:
        out = scipy.interpolate.CubicSpline(times, bridged, axis=0)(new_times)
    else:
        out = np.stack([np.interp(new_times, times, bridged[:, j]) for j in range(bridged.shape[1])], axis=1)
    nearest = np.clip(np.searchsorted(times, new_times), 0, len(times) - 1)
    left = np.clip(nearest - 1, 0, len(times) - 1)
    closer_left = np.abs(times[left] - new_times) < np.abs(times[nearest] - new_times)
    nearest = np.where(closer_left, left, nearest)
    out[gaps[nearest]] = np.nan
    return out.reshape((len(new_times),) + values.shape[1:])


def within_window(times: np.ndarray, start: float | None, stop: float | None) -> np.ndarray:
    """[T] True where ``start <= t <= stop`` (seconds; None = open end), to a nanosecond, so a bound written
    with a few digits still keeps the frame it names."""
    keep = np.ones(len(times), dtype=bool)
    if start is not None:
        keep &= times >= start - 1e-9
    if stop is not None:
        keep &= times <= stop + 1e-9
    return keep


@dataclass(frozen=True)
class _Series:
    """A time series on ``times`` (seconds, strictly increasing); subclasses say which arrays follow the clock."""

    times: np.ndarray

    _timed: tuple[str, ...] = field(default=(), init=False, repr=False)

    @property
    def n_frames(self) -> int:
        return int(self.times.shape[0])

    @property
    def rate(self) -> float:
        """Sampling rate in Hz (frames per second over the whole span)."""
        return _uniform_rate(self.times)

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0]) if self.n_frames else 0.0

    def _check_times(self, source: str | None = None) -> None:
        if self.times.ndim != 1:
            raise DataFormatError(source, f"times must be 1-D, got shape {self.times.shape}")
        if self.times.size == 0:
            raise DataFormatError(source, "no frames")
        if not np.all(np.isfinite(self.times)):
            raise DataFormatError(
                source, "time column holds NaN or inf", frame=int(np.flatnonzero(~np.isfinite(self.times))[0])
            )
        steps = np.diff(self.times)
        if np.any(steps <= 0):
            bad = int(np.flatnonzero(steps <= 0)[0]) + 1
            raise DataFormatError(
                source, f"time does not increase ({self.times[bad - 1]} then {self.times[bad]})", frame=bad
            )
        for name in self._timed:
            array = getattr(self, name)
            if array.shape[0] != self.times.shape[0]:
                raise DataFormatError(source, f"{name} has {array.shape[0]} frames but times has {self.n_frames}")

    def slice(self, start: float | None = None, stop: float | None = None):
        """Frames with ``start <= t <= stop`` (seconds; None = open end)."""
        return self.frames(np.flatnonzero(within_window(self.times, start, stop)))

    def frames(self, index: np.ndarray | slice):
        """Frames picked by an index array or a Python slice."""
        return replace(self, times=self.times[index], **{n: getattr(self, n)[index] for n in self._timed})

    def resample(self, rate: float, start: float | None = None, stop: float | None = None):
        """Uniformly resampled copy at ``rate`` Hz, from ``start`` to ``stop`` (default: the series' span).

        Down-sampling first applies a zero-lag 4th-order Butterworth low-pass at 0.4 x the new rate (80 % of the
        new Nyquist frequency) so that no aliasing enters; then each channel is interpolated with a cubic spline.
        """
        if rate <= 0:
            raise ValueError(f"rate must be positive, got {rate}")
        t0 = self.times[0] if start is None else start
        t1 = self.times[-1] if stop is None else stop
        count = int(np.floor((t1 - t0) * rate + 1e-6)) + 1
        new_times = t0 + np.arange(count) / rate
        return replace(self, times=new_times, **self._resampled(new_times, rate))

    def _resampled(self, new_times: np.ndarray, rate: float) -> dict[str, np.ndarray]:
        """Every timed array at ``new_times`` (`_resample`), resampled together: the columns are independent, so
        one filter pass and one spline over all of them give what one per array would."""
        arrays = {n: getattr(self, n) for n in self._timed}
        flat = np.concatenate([a.reshape(a.shape[0], -1).astype(float) for a in arrays.values()], axis=1)
        sampled = _resample(self.times, flat, new_times, rate)
        out, start = {}, 0
        for name, array in arrays.items():
            width = int(np.prod(array.shape[1:], dtype=int))
            out[name] = sampled[:, start : start + width].reshape((len(new_times),) + array.shape[1:])
            start += width
        return out

    def at(self, new_times: np.ndarray):
        """Copy sampled at ``new_times`` (uniform), with the same anti-alias rule as `resample`; NaN outside the
        recorded span."""
        new_times = np.asarray(new_times, dtype=float)
        rate = _uniform_rate(new_times) if new_times.size > 1 else self.rate
        outside = (new_times < self.times[0] - 1e-9) | (new_times > self.times[-1] + 1e-9)
        arrays = self._resampled(new_times, rate)
        for sampled in arrays.values():
            sampled[outside] = np.nan  # no extrapolation beyond the recording
        return replace(self, times=new_times, **arrays)

    def filtered(self, cutoff_hz: float, order: int = 4, padlen: int | None = None):
        """Zero-lag Butterworth low-pass of every channel (see `lowpass`)."""
        return replace(
            self, **{n: lowpass(getattr(self, n), self.rate, cutoff_hz, order, padlen=padlen) for n in self._timed}
        )


@dataclass(frozen=True)
class Motion(_Series):
    """Generalized coordinates over time.

    Attributes:
        times: [T] seconds.
        names: OpenSim coordinate names, one per column.
        values: [T, n] in SI (rad for rotations, m for translations).
        mask: [n] bool, True where the coordinate was measured; False columns hold placeholder values
            (for a source that lacks that coordinate) and must be ignored by losses and metrics.
    """

    names: tuple[str, ...] = ()
    values: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    mask: np.ndarray | None = None

    _timed: tuple[str, ...] = field(default=("values",), init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "times", np.asarray(self.times, dtype=float))
        object.__setattr__(self, "values", np.ascontiguousarray(self.values, dtype=float))
        object.__setattr__(self, "names", tuple(self.names))
        if self.mask is None:
            object.__setattr__(self, "mask", np.ones(len(self.names), dtype=bool))
        else:
            object.__setattr__(self, "mask", np.asarray(self.mask, dtype=bool))
        if self.values.ndim != 2 or self.values.shape[1] != len(self.names):
            raise DataFormatError(None, f"values shape {self.values.shape} does not match {len(self.names)} names")
        if self.mask.shape != (len(self.names),):
            raise DataFormatError(None, f"mask shape {self.mask.shape} does not match {len(self.names)} names")
        if len(set(self.names)) != len(self.names):
            raise DataFormatError(None, "duplicate coordinate names")
        self._check_times()

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no coordinate {name!r} in motion (has {', '.join(self.names)})") from None

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[:, self.index(name)]

    def select(self, names: Sequence[str], fill: float = 0.0) -> Motion:
        """Columns in the order of ``names``; names this motion lacks are added with ``fill`` and mask False."""
        columns, mask = [], []
        for name in names:
            if name in self.names:
                columns.append(self.values[:, self.index(name)])
                mask.append(bool(self.mask[self.index(name)]))
            else:
                columns.append(np.full(self.n_frames, fill))
                mask.append(False)
        values = np.stack(columns, axis=1) if columns else np.zeros((self.n_frames, 0))
        return Motion(times=self.times, names=tuple(names), values=values, mask=np.array(mask, dtype=bool))

    def rename(self, mapping: dict[str, str]) -> Motion:
        return replace(self, names=tuple(mapping.get(n, n) for n in self.names))

    def with_values(self, values: np.ndarray) -> Motion:
        return replace(self, values=np.asarray(values, dtype=float))

    def rotational(self) -> np.ndarray:
        """[n] bool, True for angle columns (see `is_translation`)."""
        return np.array([not is_translation(n) for n in self.names], dtype=bool)

    def derivatives(self) -> tuple[np.ndarray, np.ndarray]:
        """(velocities, accelerations) [T, n] from an interpolating quintic spline through the values.

        OpenSim's tools differentiate coordinates the same way (quintic GCV splines, Woltring 1986) after their
        low-pass filter; call `filtered` first for noisy data.
        """
        import scipy.interpolate

        degree = min(5, self.n_frames - 1)
        degree -= 1 - degree % 2  # odd degrees only (1, 3, 5)
        if self.n_frames < 2:
            raise DataFormatError(None, "need at least two frames to differentiate")
        spline = scipy.interpolate.make_interp_spline(self.times, self.values, k=degree, axis=0)
        return spline.derivative(1)(self.times), spline.derivative(2)(self.times) if degree > 1 else np.zeros_like(
            self.values
        )

    def smoothed(self, cutoff_hz: float, order: int = 3) -> tuple[Motion, np.ndarray, np.ndarray]:
        """(filtered motion, velocities, accelerations) the way OpenSim's inverse dynamics tool prepares
        coordinates: pad half the signal at each end by odd reflection (value and slope kept), zero-lag
        Butterworth low-pass, quintic spline through the padded filtered signal, then drop the padding — so the
        derivatives have no spline end effects inside the trial (opensim-core InverseDynamicsTool::run,
        Signal::Pad, Signal::LowpassIIR)."""
        import scipy.interpolate

        n = self.n_frames
        pad = n // 2
        if pad < 2:
            return self, *self.derivatives()
        x = self.values
        head = 2.0 * x[0] - x[pad:0:-1]
        tail = 2.0 * x[-1] - x[-2 : -pad - 2 : -1]
        padded = np.concatenate([head, x, tail])
        step = (self.times[-1] - self.times[0]) / (n - 1)
        times = self.times[0] + step * np.arange(-pad, n + pad)
        filtered = lowpass(padded, 1.0 / step, cutoff_hz, order)
        spline = scipy.interpolate.make_interp_spline(times, filtered, k=5, axis=0)
        inner = slice(pad, pad + n)
        return (
            self.with_values(filtered[inner]),
            spline.derivative(1)(times[inner]),
            spline.derivative(2)(times[inner]),
        )

    def to_torch(self, dtype=None, device=None):
        """Values as a ``torch.Tensor`` [T, n]."""
        import torch

        return torch.as_tensor(self.values, dtype=dtype or torch.float64, device=device)


@dataclass(frozen=True)
class Markers(_Series):
    """Marker trajectories: ``positions`` [T, M, 3] in metres, lab (ground) frame, NaN where occluded."""

    names: tuple[str, ...] = ()
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))

    _timed: tuple[str, ...] = field(default=("positions",), init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "times", np.asarray(self.times, dtype=float))
        object.__setattr__(self, "positions", np.ascontiguousarray(self.positions, dtype=float))
        object.__setattr__(self, "names", tuple(self.names))
        if self.positions.ndim != 3 or self.positions.shape[1:] != (len(self.names), 3):
            raise DataFormatError(
                None, f"positions shape {self.positions.shape} does not match [T, {len(self.names)}, 3]"
            )
        self._check_times()

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no marker {name!r} (has {', '.join(self.names)})") from None

    def __getitem__(self, name: str) -> np.ndarray:
        return self.positions[:, self.index(name)]

    def select(self, names: Sequence[str]) -> Markers:
        """Markers in the order of ``names``; absent ones are all-NaN (occluded throughout)."""
        out = np.full((self.n_frames, len(names), 3), np.nan)
        for j, name in enumerate(names):
            if name in self.names:
                out[:, j] = self.positions[:, self.index(name)]
        return Markers(times=self.times, names=tuple(names), positions=out)

    def rename(self, mapping: dict[str, str]) -> Markers:
        return replace(self, names=tuple(mapping.get(n, n) for n in self.names))

    def occluded(self) -> np.ndarray:
        """[T, M] bool, True where a marker has no position."""
        return ~np.isfinite(self.positions).all(axis=-1)


@dataclass(frozen=True)
class GroundReaction(_Series):
    """External ground reaction loads, one channel per force plate or per foot, in the lab (ground) frame.

    Attributes:
        names: one label per plate/foot (``"1"``, ``"r"``, ``"l"`` ...).
        force: [T, P, 3] N.
        cop: [T, P, 3] centre of pressure, m; NaN where the load is too light for a meaningful CoP.
        moment: [T, P, 3] free moment about the CoP, N·m (for a plate on the floor only the vertical part is
            non-zero).
        bodies: optional body each channel is applied to (``calcn_r`` ...), as an OpenSim ExternalLoads file says.
    """

    names: tuple[str, ...] = ()
    force: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    cop: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    moment: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    bodies: tuple[str | None, ...] | None = None

    _timed: tuple[str, ...] = field(default=("force", "cop", "moment"), init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "times", np.asarray(self.times, dtype=float))
        object.__setattr__(self, "names", tuple(self.names))
        for name in ("force", "cop", "moment"):
            array = np.ascontiguousarray(getattr(self, name), dtype=float)
            object.__setattr__(self, name, array)
            if array.ndim != 3 or array.shape[1:] != (len(self.names), 3):
                raise DataFormatError(None, f"{name} shape {array.shape} does not match [T, {len(self.names)}, 3]")
        if self.bodies is None:
            object.__setattr__(self, "bodies", (None,) * len(self.names))
        elif len(self.bodies) != len(self.names):
            raise DataFormatError(None, f"{len(self.bodies)} bodies for {len(self.names)} channels")
        else:
            object.__setattr__(self, "bodies", tuple(self.bodies))
        self._check_times()

    @property
    def n_channels(self) -> int:
        return len(self.names)

    def total_force(self) -> np.ndarray:
        """[T, 3] sum over channels."""
        return self.force.sum(axis=1)

    def select(self, names: Sequence[str]) -> GroundReaction:
        index = [self.names.index(n) for n in names]
        return GroundReaction(
            times=self.times,
            names=tuple(names),
            force=self.force[:, index],
            cop=self.cop[:, index],
            moment=self.moment[:, index],
            bodies=tuple(self.bodies[i] for i in index),
        )

    def assign(self, bodies: Sequence[str | None]) -> GroundReaction:
        """Copy with each channel applied to the given body."""
        return replace(self, bodies=tuple(bodies))
