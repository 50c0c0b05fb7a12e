"""The control plot (`biomotion.viz.control_plot`): one panel per target, written as PNG and SVG, with the verdict
in each panel's title."""

from __future__ import annotations

import numpy as np
import pytest

from biomotion.analysis.control_measures import measure_series
from biomotion.guidance.control import Control
from biomotion.viz.control_plot import plot_control, write_control_plot

TIMES = np.arange(60) / 30.0


def test_every_kind_of_target_gets_a_panel_and_both_files_are_written(tmp_path):
    control = Control.from_dict(
        {
            "targets": [
                {"quantity": "grf_vertical", "kind": "max", "value": 2.2, "window": [0.5, 1.5]},
                {"quantity": "joint_torque", "coordinate": "knee_angle_r", "kind": "min", "value": -0.5},
                {"quantity": "joint_angle", "coordinate": "knee_angle_r", "kind": "value", "value": 40, "times": [1]},
                {"quantity": "joint_position", "body": "hand_r", "kind": "path", "path": [[0.5, 0.2, 1.0, 0.2]]},
            ]
        },
        "spec.yaml",
    )
    series = [
        1.0 + 1.5 * np.exp(-(((TIMES - 1.0) / 0.1) ** 2)),  # peak 2.5 inside the window: not met
        np.full(len(TIMES), -0.3),  # met
        np.full(len(TIMES), 41.0),  # degrees: met within 2
        np.tile([0.2, 1.0, 0.2], (len(TIMES), 1)),  # through the point: met
    ]
    measures = [measure_series(t, TIMES, s, n) for n, (t, s) in enumerate(zip(control.targets, series), 1)]
    free = [measure_series(t, TIMES, s * 1.1, n) for n, (t, s) in enumerate(zip(control.targets, series), 1)]
    figure = plot_control(control, measures, uncontrolled=free)
    axes = figure.get_axes()
    assert len(axes) == 4
    assert "NOT met (peak 2.5 BW at 1.00 s)" in axes[0].get_title()
    assert all(ax.get_title().split("\n")[1].startswith("met (") for ax in axes[1:])
    assert "spec.yaml: 3 of 4 target(s) met" in figure._suptitle.get_text()
    png, svg = write_control_plot(control, measures, tmp_path / "control", uncontrolled=free)
    assert png == tmp_path / "control.png" and svg == tmp_path / "control.svg"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and b"<svg" in svg.read_bytes()[:400]


def test_one_measure_per_target_is_required():
    control = Control.from_dict({"targets": [{"quantity": "com_height", "kind": "max", "value": 1.2}]}, "spec.yaml")
    with pytest.raises(ValueError, match="0 measures for the 1 targets of spec.yaml"):
        plot_control(control, [])
