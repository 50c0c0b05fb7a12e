"""Metric objects describe themselves (name, label, unit, direction, paper, equation, display) and the registry of
the evaluation reads everything it prints from them."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

import biomotion.metrics as M
from biomotion.errors import BiomotionError
from biomotion.metrics.base import ARROWS, DESCRIPTION, Metric
from biomotion.metrics.registry import DIVERSITY, ClipSetMetric, every_metric, metrics, paired_metrics, record

DOCS = Path(__file__).resolve().parents[2] / "docs" / "metrics.md"


def _model():
    """What the registry reads from a body model: coordinate names and ranges (rad, m)."""
    names = ("pelvis_tx", "hip_flexion_r", "knee_angle_r")
    return SimpleNamespace(coordinate_names=names, ranges=torch.tensor([[-5.0, 5.0], [-0.5, 2.0], [-2.0, 0.0]]))


REGISTERED = {
    "bvh": every_metric("bvh"),
    "coordinates": every_metric("coordinates", _model()),
    "coordinates, physics": every_metric("coordinates", _model(), physics=True),
}


def _described(metric) -> None:
    assert metric.higher_is_better in (True, False, None), metric
    for field in ("name", "label", "unit", "paper", "equation"):
        assert isinstance(getattr(metric, field), str) and getattr(metric, field).strip(), (metric, field)
    assert re.fullmatch(r"[a-z0-9_]+", metric.name), metric.name
    assert isinstance(metric.display_unit, str) and metric.display_scale > 0
    assert metric.arrow == ARROWS[metric.higher_is_better]


@pytest.mark.parametrize("kind", REGISTERED)
def test_every_registered_metric_has_direction_paper_equation_and_unit(kind):
    registered = REGISTERED[kind]
    names = [m.name for m in registered]
    assert len(names) == len(set(names)), names
    for metric in registered:
        _described(metric)
        if isinstance(metric, ClipSetMetric):
            assert all(getattr(metric, f) == getattr(metric.metric, f) for f in DESCRIPTION)


def test_every_metric_class_describes_itself():
    classes = [
        c
        for c in (getattr(M, n) for n in M.__all__)
        if isinstance(c, type) and issubclass(c, Metric) and c is not Metric
    ]
    assert len(classes) >= 25
    for cls in classes:
        _described(cls())


def test_registry_lists_the_report_columns_in_order():
    assert [m.name for m in metrics("bvh")] == [
        "penetration",
        "penetration_median",
        "floating",
        "floating_median",
        "skate_ratio",
        "foot_contact_velocity",
        "jerk",
        "energy_com",
        "entropy",
    ]
    assert [m.name for m in metrics("coordinates", _model(), physics=True)][7:] == [
        "energy_com",
        "energy_body",
        "zmp_in_support",
        "joint_range",
        "entropy",
    ]
    assert [m.name for m in paired_metrics()] == ["mje", "p_mje", "accl", "vel", "fidelity", "gaussian_w2"]
    with pytest.raises(BiomotionError, match="body model"):
        metrics("coordinates")


def test_configured_variants_name_themselves():
    median = M.Penetration(ground="clip_median")
    assert (median.name, median.label) == ("penetration_median", "Penetration (clip median)")
    assert "public evaluator" in median.paper and M.Penetration().name == "penetration"
    assert M.Floating("clip_median", stance_speed=None).name == "floating_median"
    assert (M.JerkIndex().name, M.JerkIndex(squared=False).name) == ("jerk_index", "jerk")
    assert M.JerkIndex(squared=False).display_unit == "m/s³"
    energy = M.EnergyConsistency(std=True, energy="body")
    assert (energy.name, energy.label, energy.unit) == ("energy_body", "Energy std (body)", "J")
    assert M.EnergyConsistency(energy="com").name == "energy_var_com"
    assert M.EnergyConsistency().name == "energy_consistency"
    per_frame = M.AccelerationError(per_frame=True)
    assert (per_frame.name, per_frame.unit, per_frame.display_unit, per_frame.display_scale) == (
        "accl_per_frame",
        "m/frame^2",
        "mm/frame²",
        1000.0,
    )
    assert M.Fidelity(align="linear").name == "fidelity_linear"
    excess = M.ComVelocityViolation(statistic="excess")
    assert (excess.name, excess.unit, excess.display_scale) == ("com_velocity_violation_excess", "m/s", 1.0)
    assert excess.equation.startswith("L_v")
    assert (M.ComVelocityViolation().unit, M.ComVelocityViolation().display_unit) == ("1", "%")
    assert (M.GaussianFidelity().display_unit, M.GaussianFidelity(unit="m").display_unit) == ("", "cm")
    assert DIVERSITY.higher_is_better is None and DIVERSITY.display_scale == 100.0


def test_a_metric_without_direction_is_refused():
    class Undirected(Metric):
        name, label, unit, paper, equation = "undirected", "Undirected", "m", "none", "x"

        def score(self, x):
            return x

    with pytest.raises(AttributeError, match="higher_is_better"):
        ClipSetMetric(Undirected(), lambda s: (s,))


def test_record_reads_label_unit_scale_and_direction_from_the_object():
    values = torch.tensor([0.01, 0.03, float("nan")], dtype=torch.float64)
    rec = record(M.Penetration(ground="clip_median"), values)
    assert (rec["label"], rec["unit"], rec["better"]) == ("Penetration (clip median)", "cm", "↓")
    assert rec["mean"] == pytest.approx(2.0) and rec["count"] == 2 and rec["values"][2] is None
    assert record(M.ZMPInsideSupport(), torch.tensor([0.5]))["better"] == "↑"
    assert record(M.MotionEntropy(), torch.tensor([3.2]))["better"] == "→"
    assert record(M.VelocityError(), torch.tensor([1.5]))["unit"] == "m/s"  # no display unit: the SI unit

    class HigherPenetration(M.Penetration):
        higher_is_better = True

    assert record(HigherPenetration(), values)["better"] == "↑"


def test_docs_list_every_registered_metric():
    text = DOCS.read_text(encoding="utf-8")
    for metric in REGISTERED["coordinates, physics"]:
        assert f"`{metric.name}`" in text, metric.name
