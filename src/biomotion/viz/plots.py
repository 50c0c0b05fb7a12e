"""Figures (matplotlib, written as PNG and SVG side by side): joint angles against a reference band, inferred vs
measured ground reaction, muscle activations with EMG envelopes, COM and ZMP paths over the support polygon, and
metric distributions for ``biomotion eval``.

Every ``plot_*`` function takes arrays or the project's value types, writes ``<path>.png`` and ``<path>.svg``
(atomically, whatever suffix ``path`` has) and returns the two paths. Figures are built on `matplotlib.figure.Figure`
with the Agg canvas, never through pyplot's global state, so they are safe in batch workers.

Cycle normalization follows gait analysis practice (e.g. Winter 2009, *Biomechanics and Motor Control of Human
Movement*, 4th ed.): each cycle is resampled to 0-100 % in 101 points so that cycles of different length can be
averaged, and a reference is drawn as its mean +/- 1 standard deviation.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from biomotion.errors import ConfigError
from biomotion.io.atomic import atomic_write
from biomotion.motion import GroundReaction, Motion

CYCLE_POINTS = 101
DEFAULT_ANGLES = (
    "hip_flexion_r",
    "hip_adduction_r",
    "knee_angle_r",
    "ankle_angle_r",
    "hip_flexion_l",
    "hip_adduction_l",
    "knee_angle_l",
    "ankle_angle_l",
)
AXIS_NAMES = ("anterior-posterior (x)", "vertical (y)", "medio-lateral (z)")

Cycles = Sequence[tuple[float, float]]


def _figure(width: float, height: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=110, layout="constrained")


def save_figure(figure, path: str | Path) -> tuple[Path, Path]:
    """Write ``figure`` as ``<path>.png`` and ``<path>.svg`` (both replaced atomically); returns their paths."""
    import matplotlib

    stem = Path(path)
    stem = stem.with_suffix("") if stem.suffix.lower() in (".png", ".svg") else stem
    written = []
    for fmt in ("png", "svg"):
        target = stem.parent / f"{stem.name}.{fmt}"
        buffer = io.BytesIO()
        with matplotlib.rc_context({"svg.hashsalt": "biomotion"}):
            figure.savefig(buffer, format=fmt, metadata={"Date": None} if fmt == "svg" else None)
        with atomic_write(target, "wb") as handle:
            handle.write(buffer.getvalue())
        written.append(target)
    return written[0], written[1]


def contact_cycles(forces: GroundReaction, channel: str | int, threshold: float = 20.0) -> list[tuple[float, float]]:
    """Gait cycles of one foot: (strike, next strike) times, a strike being the frame the vertical force rises
    above ``threshold`` N (a fixed vertical-force threshold, the usual force-plate definition of foot contact)."""
    index = forces.names.index(channel) if isinstance(channel, str) else int(channel)
    loaded = np.nan_to_num(forces.force[:, index, 1]) > threshold
    strikes = forces.times[np.flatnonzero(loaded[1:] & ~loaded[:-1]) + 1]
    return list(zip(strikes[:-1].tolist(), strikes[1:].tolist()))


def normalize_cycles(
    times: np.ndarray, values: np.ndarray, cycles: Cycles | None = None, points: int = CYCLE_POINTS
) -> np.ndarray:
    """[C, points, ...] ``values`` [T, ...] linearly resampled onto 0-100 % of each (start, stop) cycle; without
    ``cycles`` the whole span is one cycle."""
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    cycles = [(times[0], times[-1])] if cycles is None else list(cycles)
    flat = values.reshape(len(times), -1)
    out = []
    for start, stop in cycles:
        if not times[0] - 1e-9 <= start < stop <= times[-1] + 1e-9:
            raise ConfigError(f"cycle ({start}, {stop}) s is not inside the data ({times[0]}, {times[-1]}) s")
        grid = np.linspace(start, stop, points)
        out.append(np.stack([np.interp(grid, times, column) for column in flat.T], axis=1))
    return np.stack(out).reshape((len(cycles), points) + values.shape[1:])


def _angle_columns(motion: Motion, coordinates: Sequence[str] | None) -> list[str]:
    if coordinates is not None:
        missing = [c for c in coordinates if c not in motion.names]
        if missing:
            raise ConfigError(f"coordinates not in the motion: {', '.join(missing)}")
        return list(coordinates)
    chosen = [c for c in DEFAULT_ANGLES if c in motion.names and motion.mask[motion.index(c)]]
    return chosen or [n for n, rot, m in zip(motion.names, motion.rotational(), motion.mask) if rot and m][:8]


def _in_display_units(motion: Motion, names: Sequence[str], values: np.ndarray) -> tuple[np.ndarray, list[str]]:
    rotational = np.array([motion.rotational()[motion.index(n)] for n in names])
    return np.where(rotational, np.degrees(values), values), ["deg" if r else "m" for r in rotational]


def plot_joint_angles(
    motion: Motion,
    path: str | Path,
    *,
    coordinates: Sequence[str] | None = None,
    cycles: Cycles | None = None,
    reference: Motion | Sequence[Motion] | None = None,
    reference_cycles: Sequence[Cycles | None] | None = None,
    title: str | None = None,
    label: str = "motion",
    reference_label: str = "reference",
) -> tuple[Path, Path]:
    """Joint angles (degrees; lengths in m) per coordinate, one panel each.

    With ``cycles`` or a ``reference`` the x axis is 0-100 % of the cycle: each cycle of ``motion`` is drawn thin
    and their mean bold (no cycles: the whole trial is one cycle), over the band mean +/- 1 SD of all cycles of
    all ``reference`` motions (``reference_cycles[i]`` for motion i, None = its whole span). Without either, the
    angles are drawn against time.
    """
    names = _angle_columns(motion, coordinates)
    references = [] if reference is None else [reference] if isinstance(reference, Motion) else list(reference)
    ref_cycles = list(reference_cycles) if reference_cycles is not None else [None] * len(references)
    if len(ref_cycles) != len(references):
        raise ConfigError(f"{len(ref_cycles)} reference cycle lists for {len(references)} reference motions")
    normalized = cycles is not None or bool(references)
    columns = min(4, len(names))
    rows = -(-len(names) // columns)
    figure = _figure(3.2 * columns, 2.5 * rows)
    axes = np.atleast_1d(figure.subplots(rows, columns, squeeze=False)).ravel()
    values, units = _in_display_units(motion, names, motion.select(names).values)
    band = None
    if references:
        stacked = np.concatenate(
            [
                normalize_cycles(r.times, _in_display_units(r, names, r.select(_angle_columns(r, names)).values)[0], c)
                for r, c in zip(references, ref_cycles)
            ]
        )
        band = (stacked.mean(axis=0), stacked.std(axis=0), stacked.shape[0])
    percent = np.linspace(0, 100, CYCLE_POINTS)
    curves = normalize_cycles(motion.times, values, cycles) if normalized else None
    for k, (ax, name, unit) in enumerate(zip(axes, names, units)):
        if band is not None:
            mean, sd, count = band
            ax.fill_between(
                percent,
                mean[:, k] - sd[:, k],
                mean[:, k] + sd[:, k],
                color="0.75",
                alpha=0.6,
                linewidth=0,
                label=f"{reference_label} mean ± 1 SD (n={count})",
            )
            ax.plot(percent, mean[:, k], color="0.45", linewidth=1, linestyle="--")
        if curves is not None:
            for c in range(curves.shape[0]):
                ax.plot(percent, curves[c, :, k], color="tab:blue", linewidth=0.7, alpha=0.5 if len(curves) > 1 else 1)
            ax.plot(percent, curves[:, :, k].mean(axis=0), color="tab:blue", linewidth=1.8, label=label)
            ax.set_xlim(0, 100)
            ax.set_xlabel("cycle (%)")
        else:
            ax.plot(motion.times, values[:, k], color="tab:blue", linewidth=1.2, label=label)
            ax.set_xlabel("time (s)")
        ax.set_title(name, fontsize=10)
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
    for ax in axes[len(names) :]:
        ax.set_visible(False)
    axes[0].legend(fontsize=7, loc="best")
    figure.suptitle(title or "joint angles")
    return save_figure(figure, path)


def plot_ground_reaction(
    measured: GroundReaction,
    path: str | Path,
    *,
    inferred: GroundReaction | None = None,
    pairs: Sequence[tuple[str, str]] | None = None,
    body_weight: float | None = None,
    title: str | None = None,
    label: str = "measured",
    other_label: str = "inferred",
) -> tuple[Path, Path]:
    """Ground reaction force components over time, one column per channel (plate or foot), one row per axis.

    ``inferred`` (e.g. forces inferred from kinematics) is drawn dashed over ``measured``; ``pairs`` lists
    (measured channel, inferred channel) names (default: channels in order). ``body_weight`` (N) expresses forces
    in body weights. ``label`` names the first set in the legend (``"inferred"`` when only inferred forces are
    drawn); ``other_label`` names the dashed set (e.g. ``"measured"`` under learned forces).
    """
    if inferred is not None and pairs is None:
        pairs = list(zip(measured.names, inferred.names))
    channels = [p[0] for p in pairs] if pairs is not None else list(measured.names)
    scale = 1.0 / body_weight if body_weight else 1.0
    figure = _figure(max(5.5, 3.6 * len(channels)), 6.5)
    axes = figure.subplots(3, len(channels), squeeze=False, sharex=True)
    for c, channel in enumerate(channels):
        force = measured.force[:, measured.names.index(channel)] * scale
        other = None
        if inferred is not None:
            other = inferred.force[:, inferred.names.index(pairs[c][1])] * scale
        for a in range(3):
            ax = axes[a, c]
            ax.plot(measured.times, force[:, a], color="black", linewidth=1.3, label=f"{label} {channel}")
            if other is not None:
                ax.plot(
                    inferred.times,
                    other[:, a],
                    color="tab:red",
                    linewidth=1.3,
                    linestyle="--",
                    label=f"{other_label} {pairs[c][1]}",
                )
            ax.grid(alpha=0.3)
            if c == 0:
                ax.set_ylabel(f"{AXIS_NAMES[a]}\n" + ("(BW)" if body_weight else "(N)"), fontsize=9)
        axes[0, c].set_title(channel, fontsize=10)
        axes[0, c].legend(fontsize=7, loc="upper right")
        axes[2, c].set_xlabel("time (s)")
    figure.suptitle(
        title or (f"{other_label} vs {label} ground reaction" if inferred is not None else "ground reaction")
    )
    return save_figure(figure, path)


def plot_activations(
    times: np.ndarray,
    names: Sequence[str],
    values: np.ndarray,
    path: str | Path,
    *,
    emg: tuple[np.ndarray, Sequence[str], np.ndarray] | None = None,
    pairs: Mapping[str, str] | None = None,
    title: str | None = None,
    xlabel: str = "time (s)",
) -> tuple[Path, Path]:
    """Activation heatmap (muscles x time, 0-1) and, with ``emg`` = (times, channel names, envelopes), one panel
    per muscle in ``pairs`` (muscle -> EMG channel) overlaying the activation and the envelope scaled to its peak
    (EMG amplitude depends on the electrodes and the skin, so only its shape compares with an activation)."""
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    names = list(names)
    overlay = list((pairs or {}).items()) if emg is not None else []
    for muscle, channel in overlay:
        if muscle not in names or channel not in list(emg[1]):
            raise ConfigError(f"cannot pair activation {muscle!r} with EMG channel {channel!r}")
    columns = min(5, len(overlay)) or 1
    rows = -(-len(overlay) // columns)
    figure = _figure(max(8.0, 2.6 * columns), 0.16 * len(names) + 2.0 + 2.0 * rows)
    grid = figure.add_gridspec(1 + rows, columns, height_ratios=[max(2.0, 0.16 * len(names))] + [1.6] * rows)
    heat = figure.add_subplot(grid[0, :])
    image = heat.imshow(
        values.T,
        aspect="auto",
        origin="upper",
        cmap="YlOrRd",
        vmin=0,
        vmax=1,
        interpolation="nearest",
        extent=(times[0], times[-1], len(names) - 0.5, -0.5),
    )
    heat.set_yticks(range(len(names)), names, fontsize=max(4, min(9, 300 // max(len(names), 1))))
    heat.set_xlabel(xlabel)
    figure.colorbar(image, ax=heat, label="activation", fraction=0.03, pad=0.01)
    for k, (muscle, channel) in enumerate(overlay):
        ax = figure.add_subplot(grid[1 + k // columns, k % columns])
        emg_times, emg_names, envelopes = emg
        envelope = np.asarray(envelopes, dtype=float)[:, list(emg_names).index(channel)]
        ax.plot(emg_times, envelope / np.nanmax(envelope), color="0.4", linewidth=1.2, label=f"EMG {channel}")
        ax.plot(times, values[:, names.index(muscle)], color="tab:red", linewidth=1.4, label=muscle)
        ax.set_ylim(0, 1.05)
        ax.set_title(f"{muscle} vs {channel}", fontsize=9)
        ax.set_xlabel(xlabel, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        if k == 0:
            ax.legend(fontsize=6, loc="upper right")
    figure.suptitle(title or "muscle activations")
    return save_figure(figure, path)


def plot_balance(
    com: np.ndarray,
    zmp: np.ndarray,
    path: str | Path,
    *,
    support: np.ndarray | None = None,
    polygons: int = 8,
    title: str | None = None,
) -> tuple[Path, Path]:
    """Top view (x forward, z to the side; OpenSim ground frame) of the COM ground projection and the ZMP path
    over support polygons [T, P, 3] (NaN rows after a frame's last vertex), ``polygons`` of them drawn evenly
    through the trial; the polygons' vertices are joined in order and closed."""
    from matplotlib.collections import PolyCollection

    com, zmp = np.asarray(com, dtype=float), np.asarray(zmp, dtype=float)
    figure = _figure(8.0, 4.5)
    ax = figure.subplots()
    if support is not None:
        support = np.asarray(support, dtype=float)
        frames = np.unique(np.linspace(0, len(support) - 1, polygons).round().astype(int))
        shapes = [support[f][np.isfinite(support[f]).all(axis=1)][:, [0, 2]] for f in frames]
        shapes = [s for s in shapes if len(s) >= 3]
        ax.add_collection(
            PolyCollection(
                shapes,
                facecolors=(0.95, 0.6, 0.2, 0.12),
                edgecolors=(0.85, 0.45, 0.05, 0.9),
                linewidths=1.0,
                label="support polygon",
            )
        )
    ax.plot(com[:, 0], com[:, 2], color="tab:red", linewidth=1.8, label="COM (ground projection)")
    ax.plot(zmp[:, 0], zmp[:, 2], color="tab:purple", linewidth=0.9, marker=".", markersize=2.5, label="ZMP")
    for series, color in ((com, "tab:red"), (zmp, "tab:purple")):
        finite = np.flatnonzero(np.isfinite(series[:, [0, 2]]).all(axis=1))
        if finite.size:
            ax.plot(*series[finite[0], [0, 2]], marker="o", color=color, markersize=6, fillstyle="none")
            ax.plot(*series[finite[-1], [0, 2]], marker="s", color=color, markersize=6, fillstyle="none")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x (m, forward)")
    ax.set_ylabel("z (m, right)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    ax.set_title(title or "COM and ZMP over the support polygon (o start, □ end)", fontsize=10)
    return save_figure(figure, path)


def plot_metric_distributions(
    metrics: Mapping[str, Mapping[str, Sequence[float]] | Sequence[float]],
    path: str | Path,
    *,
    title: str | None = None,
    bins: int = 20,
) -> tuple[Path, Path]:
    """One panel per metric: histograms of each group (e.g. generated vs reference) on shared bins, with each
    group's median marked. ``metrics`` maps metric name -> {group: values} (or directly to values)."""
    names = list(metrics)
    if not names:
        raise ConfigError("no metric to plot")
    columns = min(3, len(names))
    rows = -(-len(names) // columns)
    figure = _figure(3.6 * columns, 2.8 * rows)
    axes = figure.subplots(rows, columns, squeeze=False).ravel()
    colors = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
    for ax, name in zip(axes, names):
        groups = metrics[name] if isinstance(metrics[name], Mapping) else {"": metrics[name]}
        arrays = {g: np.asarray(v, dtype=float)[np.isfinite(np.asarray(v, dtype=float))] for g, v in groups.items()}
        pooled = np.concatenate(list(arrays.values()))
        if pooled.size == 0:
            raise ConfigError(f"metric {name!r} has no finite value")
        edges = np.histogram_bin_edges(pooled, bins=bins)
        for (group, values), color in zip(arrays.items(), colors * len(arrays)):
            ax.hist(
                values,
                bins=edges,
                histtype="stepfilled",
                alpha=0.35,
                color=color,
                label=f"{group} (n={values.size})" if group else f"n={values.size}",
            )
            ax.hist(values, bins=edges, histtype="step", color=color, linewidth=1.2)
            if values.size:
                ax.axvline(np.median(values), color=color, linestyle="--", linewidth=1.2)
        ax.set_title(name, fontsize=10)
        ax.set_ylabel("count")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes[len(names) :]:
        ax.set_visible(False)
    figure.suptitle(title or "metric distributions (dashed: median)")
    return save_figure(figure, path)
