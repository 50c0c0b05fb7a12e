"""Control targets against what a generated clip achieved: one panel per target of a control spec.

Each panel draws the measured quantity over time (`biomotion.analysis.control_measures.TargetMeasure`: read back
from the clip's written files) and the target on it: a bound (``max``/``min``) as the shaded forbidden region over
its window, a ``value`` as markers at its times (with its tolerance as an error bar), a body ``path`` (or a body
position's ``value``) per axis, x, y and z, with its points as markers of the axis' colour. When the same targets
were measured on a run without control, that run is drawn dashed. Each panel's title says what the target asks and
whether it is met, with the measured extreme (peak, lowest value, largest error or distance), the same figures
``control.json`` records.

Measures are taken duck-typed (the fields of ``TargetMeasure``), since they are built in a layer above this one.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from biomotion.viz.plots import _figure, save_figure

AXIS_COLOURS = ("tab:blue", "tab:green", "tab:orange")
FORBIDDEN = "tab:red"


def plot_control(
    control: Any,
    achieved: Sequence[Any],
    *,
    uncontrolled: Sequence[Any] | None = None,
    title: str | None = None,
):
    """A figure (`matplotlib.figure.Figure`, Agg) with one panel per target: ``achieved`` holds one measure per
    target of ``control`` (a `biomotion.guidance.control.Control`, for its ``source`` and target count), in the
    spec's order; ``uncontrolled``: measures of the same targets on a run without control, drawn dashed."""
    if len(achieved) != len(control.targets):
        raise ValueError(f"{len(achieved)} measures for the {len(control.targets)} targets of {control.source}")
    if uncontrolled is not None and len(uncontrolled) != len(achieved):
        raise ValueError(f"{len(uncontrolled)} uncontrolled measures for {len(achieved)} targets")
    figure = _figure(8.0, 0.6 + 2.9 * len(achieved))
    axes = figure.subplots(len(achieved), 1, squeeze=False)[:, 0]
    for k, (ax, measure) in enumerate(zip(axes, achieved)):
        free = None if uncontrolled is None else uncontrolled[k]
        if measure.points is not None:
            _path_panel(ax, measure, free)
        elif measure.kind in ("max", "min"):
            _bound_panel(ax, measure, free)
        else:
            _value_panel(ax, measure, free)
        ax.set_title(f"{measure.index}. {measure.describe()}\n{measure.outcome()}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.set_xlim(float(measure.times[0]), float(measure.times[-1]))
        ax.legend(fontsize=7, loc="best")
    axes[-1].set_xlabel("time (s)")
    met = sum(bool(m.met) for m in achieved)
    figure.suptitle(title or f"{control.source}: {met} of {len(achieved)} target(s) met", fontsize=11)
    return figure


def write_control_plot(
    control: Any,
    achieved: Sequence[Any],
    path: str | Path,
    *,
    uncontrolled: Sequence[Any] | None = None,
    title: str | None = None,
) -> tuple[Path, Path]:
    """`plot_control` written as ``<path>.png`` and ``<path>.svg`` (`biomotion.viz.plots.save_figure`)."""
    return save_figure(plot_control(control, achieved, uncontrolled=uncontrolled, title=title), path)


def _label(measure: Any) -> str:
    unit = "0-1" if measure.quantity == "muscle_activation" else measure.unit
    return f"{measure.quantity.replace('_', ' ')} ({unit})"


def _bound_panel(ax, measure: Any, free: Any | None) -> None:
    if free is not None:
        ax.plot(free.times, free.series, color="grey", linestyle="--", linewidth=1.1, label="without control")
    ax.plot(measure.times, measure.series, color="black", linewidth=1.4, label="achieved")
    values = [np.nanmin(measure.series), np.nanmax(measure.series), measure.value]
    if free is not None:
        values += [np.nanmin(free.series), np.nanmax(free.series)]
    low, high = float(np.nanmin(values)), float(np.nanmax(values))
    pad = 0.12 * (high - low) if high > low else max(abs(high), 1.0) * 0.1
    low, high = low - pad, high + pad
    start, end = measure.window
    edge = (measure.value, high) if measure.kind == "max" else (low, measure.value)
    ax.fill_between([start, end], *edge, color=FORBIDDEN, alpha=0.13, linewidth=0, label="forbidden")
    ax.hlines(measure.value, start, end, color=FORBIDDEN, linewidth=1.2, label=f"{measure.kind} {measure.value:g}")
    ax.plot(
        [measure.at],
        [measure.achieved],
        marker="o",
        color="tab:green" if measure.met else FORBIDDEN,
        linestyle="none",
        label=f"{'peak' if measure.kind == 'max' else 'lowest'} {measure.achieved:.3g}",
    )
    ax.set_ylim(low, high)
    ax.set_ylabel(_label(measure), fontsize=8)


def _value_panel(ax, measure: Any, free: Any | None) -> None:
    if free is not None:
        ax.plot(free.times, free.series, color="grey", linestyle="--", linewidth=1.1, label="without control")
    ax.plot(measure.times, measure.series, color="black", linewidth=1.4, label="achieved")
    times = np.asarray(measure.target_times)
    ax.errorbar(
        times,
        np.full(len(times), measure.value),
        yerr=measure.tolerance,
        color=FORBIDDEN,
        marker="x",
        linestyle="none",
        capsize=3,
        label=f"target {measure.value:g} ± {measure.tolerance:g}",
    )
    ax.plot(times, np.asarray(measure.achieved), marker="o", color="black", fillstyle="none", linestyle="none")
    ax.set_ylabel(_label(measure), fontsize=8)


def _path_panel(ax, measure: Any, free: Any | None) -> None:
    times = np.asarray(measure.target_times)
    for a, (axis, colour) in enumerate(zip("xyz", AXIS_COLOURS)):
        if free is not None:
            ax.plot(free.times, free.series[:, a], color=colour, linestyle="--", linewidth=0.9, alpha=0.7)
        ax.plot(measure.times, measure.series[:, a], color=colour, linewidth=1.4, label=f"{measure.name} {axis}")
        ax.plot(times, measure.points[:, a], marker="o", color=colour, fillstyle="none", markersize=7, linestyle="none")
    ax.plot([], [], marker="o", color="black", fillstyle="none", linestyle="none", label="target points")
    if free is not None:
        ax.plot([], [], color="grey", linestyle="--", linewidth=0.9, label="without control")
    ax.set_ylabel(f"{measure.name} origin (m)", fontsize=8)
