"""The real-data direction of each manipulated profile field (`biomotion.evaluation.manipulation_data`)."""

from __future__ import annotations

import csv
from types import SimpleNamespace

import numpy as np
import pytest

from biomotion.evaluation.generation import MANIPULATIONS, _real_data_table, kinematic_measures
from biomotion.evaluation.manipulation_data import action_clips, field_value, real_data_directions, sources_with_action
from biomotion.models.actions import ActionRequest
from tests.conftest import data_path

ACL = {"injuries": ({"location": "Left knee", "diagnosis": "ACL reconstruction"},)}
RUN = ActionRequest("run", None, 3.5, "run at 3.5 m/s")


def test_field_values_are_on_the_generators_scales():
    assert field_value({"level": "Elite"}, "level", {"level": "elite"}) == 1.0
    assert field_value({"level": "competitive"}, "level", {"level": "elite"}) == 0.5
    assert field_value({"level": None}, "level", {"level": "elite"}) is None
    assert field_value({"age": 40}, "age", {"age": 65.0}) == 40.0
    assert field_value({}, "age", {"age": 65.0}) is None
    assert field_value({"injuries": [], "extra": {"Injury": "No"}}, "injuries", ACL) == 0.0
    assert field_value({"injuries": []}, "injuries", ACL) is None  # no answer is not "no injury"
    assert field_value({"injuries": [{"location": "left knee "}]}, "injuries", ACL) == 1.0
    assert field_value({"injuries": [{"location": "Right ankle"}]}, "injuries", ACL) is None  # elsewhere: left out


def test_clips_of_the_action_match_label_and_speed():
    records = [
        {"labels": {"action": "run", "speed": 3.5}},
        {"labels": {"action": "run", "speed": 3.7}},
        {"labels": {"action": "run", "speed": 4.5}},
        {"labels": {"action": "walk", "speed": 3.5}},
        {"labels": {"action": "run", "speed": None}},
    ]
    assert action_clips(records, RUN) == [0, 1]
    assert action_clips(records, ActionRequest("run", None, None, "run")) == [0, 1, 2, 4]


class _Cache:
    """Cache stand-in: one clip per subject whose measure is known: a pelvis bounce growing with age."""

    rate = 30.0

    def __init__(self, ages: list[float], level: str = "competitive"):
        from tests.evaluation.test_generation_eval import _running

        self.records = [
            {
                "source": "lab",
                "subject": f"s{k}",
                "labels": {"action": "run", "speed": 3.5},
                "profile": {
                    "age": age,
                    "level": level,
                    "experience_years": 5.0,
                    "injuries": [],
                    "extra": {"Injury": "No"},
                },
            }
            for k, age in enumerate(ages)
        ]
        self.clips = [_running(0.72, 0.5, 0.01 + 0.001 * age, 3.5) for age in ages]

    def motion(self, i: int):
        return SimpleNamespace(values=self.clips[i])


def test_a_field_that_moves_the_measure_gets_its_direction_and_a_constant_one_none():
    manipulations = (
        ("age", {"age": 25.0}, {"age": 65.0}, "pelvis_excursion", -1, "test"),
        ("level", {"level": "recreational"}, {"level": "elite"}, "pelvis_excursion", -1, "test"),
        ("injury", {"injuries": ()}, ACL, "knee_rom_l", -1, "test"),
    )
    real = real_data_directions(_Cache([20, 30, 40, 50, 60]), RUN, manipulations, kinematic_measures)
    assert real["age"]["rho"] == pytest.approx(1.0)  # the bounce grows with age in every clip
    assert real["age"]["direction"] == "increase" and real["age"]["agrees"] is False
    assert real["age"]["values"] == {"from": 20.0, "to": 60.0}
    assert real["level"]["values"] == {"0.5": 5} and real["level"]["direction"] is None
    assert real["injury"]["values"] == {"0": 5} and real["injury"]["rho"] is None
    table = _real_data_table(real)
    assert "| age | pelvis_excursion | 5 | 20 to 60 | +1.00 | 0.00 | increase (p < 0.05; against" in table
    assert "| level | pelvis_excursion | 5 | 0.5: 5 | – | – | none: every subject has the same value |" in table


def test_the_fukuchi_runners_levels_are_read_as_the_participant_table_gives_them(data_root):
    """Real data: the subjects per level of the 3.5 m/s runs against a count straight from participantInfo.csv."""
    from biomotion.data.clips import build_temporary_cache

    table = data_path("fukuchi-running/participantInfo.csv")
    present = {
        int(path.name.split("_")[0].removeprefix("RBDS"))  # the runners whose 3.5 m/s IK ships
        for path in data_path("fukuchi-running/ik/T35").glob("RBDS*_T35_ik_simple.mot")
    }
    levels: dict[int, str] = {}
    with open(table, newline="") as handle:
        for row in csv.DictReader(handle):
            if int(row["Subject"]) in present:
                levels[int(row["Subject"])] = row["Level"].strip().lower()
    expected = {
        f"{v:g}": sum(1 for level in levels.values() if {"competitive": 0.5, "elite": 1.0}[level] == v)
        for v in (0.5, 1.0)
    }
    listed = sources_with_action(data_root, ["fukuchi", "opencap", "bandai-namco"], RUN)
    assert "opencap" not in listed and "bandai-namco" not in listed  # no run / runs without a speed label
    assert listed == ["fukuchi"]
    handle, cache = build_temporary_cache(data_root, sources=listed)
    with handle:
        real = real_data_directions(cache, RUN, MANIPULATIONS, kinematic_measures)
    assert real["level"]["subjects"] == len(levels)
    assert real["level"]["values"] == {k: n for k, n in expected.items() if n}
    assert np.isfinite(real["age"]["rho"]) and 0.0 <= real["age"]["p"] <= 1.0
