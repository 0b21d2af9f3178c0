"""Prompt alignment (the paper's TCA): free-form text -> caption-style atomic steps.

The model only saw captions like "a person walks forward, then waves with the right hand."
A prompt such as "make the guy stroll ahead and after that wave 3 times" works better as
the steps it was trained on, played one after another by prompt switching:

    aligner = RuleAligner(vocabulary)          # or LLMAligner() (mogo.llm_align)
    aligner.align("make the guy stroll ahead and after that wave 3 times")
    -> Alignment(steps=[AlignedStep("a person strolls ahead.", 3.3),
                        AlignedStep("a person waves three times.", 3.0)], source="rules")

The rules need nothing but the standard library; `vocabulary` (the words of the bundle's
training captions) lets them replace and report words the model never saw.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Iterable
from dataclasses import dataclass, replace

from mogo.align_wordnet import WORDNET_VERBS
from mogo.align_words import (
    CAUSATIVES,
    FILLERS,
    HEDGES,
    LEFT_ALONE,
    NOUNS,
    NUMBERS,
    SECONDS,
    SEQUENCE,
    SUBJECTS,
    VERBS,
    WORD_SYNONYMS,
    caption_phrases,
    spoken_number,
)
from mogo.motion.skeleton import MAX_SECONDS

MIN_STEP_SECONDS = 1.0


@dataclass(frozen=True)
class AlignedStep:
    prompt: str
    seconds: float


@dataclass(frozen=True)
class Alignment:
    steps: tuple[AlignedStep, ...]
    source: str  # "rules" or "llm"
    note: str | None = None  # what went wrong or was left as it was, for the user

    @property
    def seconds(self) -> float:
        return sum(step.seconds for step in self.steps)

    def schedule(self) -> list[tuple[str, float]]:
        """The steps as (prompt, seconds), for MotionGenerator.play."""
        return [(step.prompt, step.seconds) for step in self.steps]

    def scaled(self, seconds: float) -> Alignment:
        """The same steps stretched or shrunk proportionally to last `seconds` in all."""
        factor = seconds / self.seconds
        return replace(
            self,
            steps=tuple(AlignedStep(s.prompt, round(s.seconds * factor, 3)) for s in self.steps),
        )

    def describe(self) -> str:
        """One line: 'steps (rules): 3.3 s "a person walks forward." | ...'."""
        steps = " | ".join(f'{s.seconds:.1f} s "{s.prompt}"' for s in self.steps)
        return f"steps ({self.source}): {steps}"

    def as_dict(self) -> dict:
        return dict(
            source=self.source,
            note=self.note,
            steps=[dict(prompt=s.prompt, seconds=s.seconds) for s in self.steps],
        )


class PromptAligner:
    """Turns one free-form prompt into caption-style steps with durations."""

    def align(self, text: str) -> Alignment:
        raise NotImplementedError


_DOUBLED = {
    "jog",
    "run",
    "squat",
    "sit",
    "clap",
    "spin",
    "hop",
    "step",
    "sidestep",
    "jab",
    "put",
    "get",
    "trot",
    "swivel",
    "skip",
    "begin",
    "hit",
}
_AFTER_FIRST = re.compile(r"^after (.+?),\s*(.+)$")
_AFTER_LAST = re.compile(r"^(.+?)\s+after\s+(.+)$")
_LETTER_FIXES = str.maketrans(
    {
        "ß": "ss",
        "æ": "ae",
        "œ": "oe",
        "ø": "o",
        "ł": "l",
        "đ": "d",
        "’": "'",
        "‘": "'",
        "–": "-",
        "—": "-",
    }
)


def conjugate(verb: str, form: str) -> str:
    """Third person singular ("s") or gerund ("ing") of a regular verb (plus the few
    doubled consonants the captions and the rules use); the corpus's captions use it too."""
    if form == "s":
        if verb.endswith(("s", "sh", "ch", "x", "z", "o")):
            return verb + "es"
        if verb.endswith("y") and verb[-2] not in "aeiou":
            return verb[:-1] + "ies"
        return verb + "s"
    if verb in _DOUBLED:
        return verb + verb[-1] + "ing"
    if verb.endswith("e") and not verb.endswith("ee"):
        return verb[:-1] + "ing"
    return verb + "ing"


_SUBJECT_WORDS = {w for phrase in SUBJECTS + FILLERS for w in phrase.split()}
_JACKS = (["jumping", "jack"], ["jumping", "jacks"])
_SPOKEN = {spoken_number(n): n for n in range(1000)}  # the numbers the captions spell
_PRIMITIVE_OF = {
    verb: primitive
    for table in (WORDNET_VERBS, VERBS)  # the hand-written win
    for primitive, verbs in table.items()
    for verb in verbs
}
_BASE_OF = {conjugate(verb, form): verb for verb in _PRIMITIVE_OF for form in ("s", "ing")}
_BASE_OF.update({verb: verb for verb in _PRIMITIVE_OF})


def plain_words(text: str) -> list[str]:
    """Lowercase ASCII words: accents stripped, other scripts dropped, digits kept."""
    text = unicodedata.normalize("NFKD", text.lower().translate(_LETTER_FIXES))
    text = "".join(c for c in text if c.isascii() and not unicodedata.combining(c))
    return re.sub(r"[^a-z0-9]+", " ", text.replace("'", "")).split()


def edit_distance(a: str, b: str, limit: int) -> int:
    """Optimal-string-alignment distance (a swap of neighbours counts 1), capped at
    limit + 1."""
    if abs(len(a) - len(b)) > limit:
        return limit + 1
    before, row = None, list(range(len(b) + 1))
    for i, ca in enumerate(a, 1):
        current = [i]
        for j, cb in enumerate(b, 1):
            cost = min(row[j] + 1, current[j - 1] + 1, row[j - 1] + (ca != cb))
            if before is not None and i > 1 and j > 1 and ca == b[j - 2] and a[i - 2] == cb:
                cost = min(cost, before[j - 2] + 1)
            current.append(cost)
        before, row = row, current
    return min(row[-1], limit + 1)


class RuleAligner(PromptAligner):
    """Built-in rules, no network: style, splitting into steps, synonyms and typos onto
    the bundle's vocabulary, numbers, and durations from the corpus's segment lengths.

    vocabulary: the words the model knows (MotionGenerator.vocabulary()):
    synonyms replace only words outside it, and words still outside it are reported. None:
    no word is replaced or reported (typos are still fixed onto the rules' own words)."""

    def __init__(
        self, vocabulary: Iterable[str] | None = None, max_step_seconds: float = MAX_SECONDS
    ):
        self.vocabulary = None if vocabulary is None else frozenset(vocabulary)
        self.max_step_seconds = max_step_seconds
        phrases = SUBJECTS + FILLERS + CAUSATIVES + NUMBERS + LEFT_ALONE + tuple(NOUNS)
        self.known = frozenset(
            {w for phrase in phrases for w in phrase.split()}
            | set(_BASE_OF)
            | set(WORD_SYNONYMS)
            | set(WORD_SYNONYMS.values())
            | (self.vocabulary or set())
        )
        self._spellings = sorted(w for w in self.known if len(w) >= 3 and w.isalpha())

    def align(self, text: str) -> Alignment:
        if not isinstance(text, str):
            raise ValueError(f"a prompt must be text, got {type(text).__name__}")
        words = plain_words(text)
        if not any(w.isalpha() for w in words):
            raise ValueError(
                f"no usable words in the prompt {text!r} (after dropping "
                "accents, other scripts and punctuation nothing is left)"
            )
        steps, unknown, ignored = [], [], []
        for clause in self._clauses(text):
            step = self._step(clause, unknown)
            if step is None:
                ignored.append(" ".join(clause))
            else:
                steps.append(step)
        if not steps:
            raise ValueError(f"no motion in the prompt {text!r}: no verb or action the rules know")
        notes = []
        if unknown:
            notes.append(
                "the model does not know "
                + ", ".join(dict.fromkeys(unknown))
                + " (kept as written)"
            )
        if ignored:
            notes.append("ignored " + ", ".join(f"'{words}'" for words in ignored))
        return Alignment(tuple(steps), "rules", "; ".join(notes) or None)

    # -- splitting ------------------------------------------------------------------------------
    def _clauses(self, text: str) -> list[list[str]]:
        """The prompt cut into the clauses of its steps, in order, as corrected words."""
        text = unicodedata.normalize("NFKD", text.lower().translate(_LETTER_FIXES))
        text = re.sub(r"\b(\d+) ?x\b|\bx ?(\d+)\b", lambda m: f"{m[1] or m[2]} times", text)
        text = re.sub(r"[-_]", " ", text)
        text = caption_phrases(text)
        text = re.sub(r"\b(?:" + "|".join(HEDGES) + r")\b", " ", text)
        sentences = re.split(r"[;:!?\n]+|\.(?:\s+|$)", text)
        clauses = []
        for sentence in sentences:
            parts = SEQUENCE.split(" " + sentence + " ")
            for part in parts:
                clauses += self._commas(self._after(part))
        return [c for c in clauses if c]

    def _after(self, part: str) -> list[str]:
        """ "after X, Y" and "Y after X" -> X, Y ("after that" was cut before)."""
        part = part.strip(" ,")
        first = _AFTER_FIRST.match(part) or _AFTER_LAST.match(part)
        if first is None:
            return [part]
        x, y = first.groups()
        return [x, y] if first.re is _AFTER_FIRST else [y, x]

    def _commas(self, parts: list[str]) -> list[list[str]]:
        """Split on commas where a new action starts ("walk, jump, sit"); a comma before
        anything else ("walks forward, slowly") stays inside the step."""
        clauses: list[list[str]] = []
        for part in parts:
            for piece in part.split(","):
                words = [self._spelled(w) for w in plain_words(piece)]
                if not words:
                    continue
                stripped = self._strip(words)
                starts_action = bool(stripped) and self._is_action(stripped)
                if clauses and not starts_action:
                    clauses[-1] += words
                else:
                    clauses.append(words)
        return clauses

    # -- one step -------------------------------------------------------------------------------
    def _step(self, words: list[str], unknown: list[str]) -> AlignedStep | None:
        """One clause as a caption ("a person waves three times.") and its seconds; None when
        it names no action."""
        words = self._action(self._strip(words))
        if not words:
            return None
        gerund = words[0].endswith("ing") and words[0] in _BASE_OF
        phrase = []
        for k, word in enumerate(words):
            base = None if words[k : k + 2] in _JACKS else _BASE_OF.get(word)
            after_and = k > 0 and words[k - 1] == "and" and (gerund or word == base)
            if base is not None and (k == 0 or after_and):
                word = self._verb(base)
            elif word in WORD_SYNONYMS and not self._knows(word):
                word = WORD_SYNONYMS[word]
            phrase.append(word)
        if words[:2] in _JACKS or (words[0] not in _BASE_OF and self._is_action(words)):
            phrase.insert(0, "takes" if "bow" in words else "does")
        phrase = _spoken_numbers(phrase)
        unknown += [w for w in phrase if w.isalpha() and not self._knows(w)]
        prompt = "a person " + " ".join(phrase) + "."
        return AlignedStep(prompt, self._seconds(phrase))

    def _strip(self, words: list[str]) -> list[str]:
        """Drops leading filler, requests, subjects and modal verbs ("can you make the guy
        ..." -> "..."), until the words start with what the person does."""
        previous = None
        while words != previous:
            previous = words
            for phrase in FILLERS + SUBJECTS:
                n = len(phrase.split())
                if words[:n] == phrase.split() and len(words) > n:
                    words = words[n:]
                    break
            if (
                len(words) > 2
                and words[0] in CAUSATIVES
                and any(words[1 : 1 + len(s.split())] == s.split() for s in SUBJECTS)
            ):
                words = words[1:]
        return [] if " ".join(words) in FILLERS + SUBJECTS else words

    def _action(self, words: list[str]) -> list[str]:
        """The words from the first action on: what comes before it is dropped when the
        model cannot read it anyway ("la personne marche" -> "marche"); no action: []."""
        for k in range(len(words)):
            if self._is_action(words[k:]):
                skipped = words[:k]
                if all(w in _SUBJECT_WORDS or not self._knows(w) for w in skipped):
                    return words[k:]
                break
        return words if any(w in _BASE_OF or w in NOUNS for w in words) else []

    def _is_action(self, words: list[str]) -> bool:
        """Whether the words start with a verb or a counted action ("three squats")."""
        first = words[0]
        if first in _BASE_OF or words[:2] in _JACKS:
            return True
        nouns = [w for w in words[:3] if w in NOUNS]
        return bool(nouns) and (
            first in ("a", "an") or first in NUMBERS or first.isdigit() or first in NOUNS
        )

    def _verb(self, base: str) -> str:
        """The 3rd person form, replaced by its primitive's main verb when the bundle does
        not know it ("marches" -> "walks")."""
        finite = conjugate(base, "s")
        primitive = _PRIMITIVE_OF[base]
        if not self._knows(finite) and primitive is not None:
            return conjugate(VERBS[primitive][0], "s")
        return finite

    def _knows(self, word: str) -> bool:
        return True if self.vocabulary is None else word in self.vocabulary

    def _spelled(self, word: str) -> str:
        """A typo fixed to the nearest known word (1 edit for 4-6 letters, 2 from 7), the
        word itself when it is known, short or nothing is near."""
        if word in self.known or len(word) < 4 or not word.isalpha():
            return word
        limit = 1 if len(word) < 7 else 2
        best = min(self._spellings, key=lambda w: (edit_distance(word, w, limit), w[0] != word[0]))
        return best if edit_distance(word, best, limit) <= limit else word

    def _seconds(self, phrase: list[str]) -> float:
        """The step's primitive (its verb, else an action noun) and repetitions -> seconds,
        clamped to what one step of the model can hold; "for N seconds" wins."""
        text = " ".join(phrase)
        stated = re.search(r"\bfor (?:about )?(\w+) seconds?\b", text)
        if stated and _count(stated.group(1)):
            seconds = float(_count(stated.group(1)))
        else:
            primitive = primitive_of(phrase)
            estimate = SECONDS[primitive]
            if isinstance(estimate, tuple):
                base, per_repetition = estimate
                estimate = base + per_repetition * _repetitions(phrase)
            seconds = estimate
        return round(min(max(seconds, MIN_STEP_SECONDS), self.max_step_seconds), 2)


def primitive_of(words: list[str]) -> str | None:
    """The primitive plain words ask for: their first action verb's, else an action noun's
    ("does three squats"); None when they name none."""
    primitive = next(
        (
            _PRIMITIVE_OF[_BASE_OF[w]]
            for w in words
            if w in _BASE_OF and _PRIMITIVE_OF[_BASE_OF[w]] is not None
        ),
        None,
    )
    if "jumping" in words and ("jacks" in words or "jack" in words):
        primitive = "jumping_jacks"
    return primitive or next((NOUNS[w] for w in words if w in NOUNS), None)


def _count(word: str) -> int | None:
    """A number in digits or spelt ("seven", "sixty", "a hundred and thirty-five")."""
    if word.isdigit():
        return int(word)
    return _SPOKEN.get(word)


def _repetitions(phrase: list[str]) -> int:
    """ "three times", "twice", "4 squats" -> the count; 1 when none is said."""
    for k, word in enumerate(phrase):
        if word == "twice":
            return 2
        if (
            _count(word)
            and (k + 1 < len(phrase))
            and (phrase[k + 1] in ("times", "time") or phrase[k + 1] in NOUNS)
        ):
            return _count(word)
    return 1


def _spoken_numbers(phrase: list[str]) -> list[str]:
    """Digits as the captions write them: "3 times" -> "three times", "2 times" -> "twice",
    "90" -> "ninety"."""
    spoken, k = [], 0
    while k < len(phrase):
        word, count = phrase[k], _count(phrase[k])
        if count in (1, 2) and phrase[k + 1 : k + 2] in (["times"], ["time"]):
            spoken.append("once" if count == 1 else "twice")
            k += 1
        elif word.isdigit():
            spoken.append(spoken_number(count))
        else:
            spoken.append(word)
        k += 1
    return spoken
