"""How close a prompt is to what the model was trained on, and which known caption a prompt
in other words is played as.

A bundle with a pretrained sentence encoder reads any words, but its motion model still knows
only the actions of its training captions: "a person does a backflip" is read perfectly and
then played as whatever known caption it lands nearest. The bundle carries sentence embeddings
of its training captions (manifest `text.repertoire`); a prompt's score is the cosine of its
own sentence embedding with the nearest of them, and the threshold set at export (with its
error rates in the manifest) tells familiar from far. Where the repertoire also has the
captions' prompt embeddings, a prompt the trained encoder cannot read is played as one of them
(KnownCaptions.nearest).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from mogo.align_words import (
    NUMBERS,
    SEQUENCE,
    TENS,
    WORD_SYNONYMS,
    caption_phrases,
    spoken_number,
    spoken_numbers,
)
from mogo.bundle import Bundle, BundleError, read_array
from mogo.manifest import Repertoire
from mogo.motion import untrusted

# How many steps, which side, which way and how many times: a prompt says these in the
# captions' own words ("then", "to the left", "twice"), yet the adapter blurs them ("applauds
# twice" lands near "claps its hands twice then raises its left arm"). Picking the caption a
# prompt is played as, each kind of these the prompt and a caption both name adds SAY_WEIGHT
# to the cosine where they agree and takes it off where they differ (chosen on the held-out
# and fresh phrasebooks, docs/text_encoder.md).
_SIDES = dict(
    left="left",
    leftward="left",
    counterclockwise="left",
    right="right",
    rightward="right",
    clockwise="right",
    both="both",
)
_WAYS = dict(forward="forward", backward="backward")
_COUNTS = {spoken_number(n): n for n in range(1000)} | {"once": 1, "twice": 2}
_UNDER_100 = (
    rf"(?:(?:{'|'.join(TENS[2:])})(?:-(?:{'|'.join(NUMBERS[1:10])}))?"
    rf"|{'|'.join(sorted(NUMBERS, key=len, reverse=True))})"
)
_COUNT = re.compile(
    rf"\b(?:(?:a|{'|'.join(NUMBERS[2:10])}) hundred(?: and {_UNDER_100})?"
    rf"|{_UNDER_100}|once|twice)\b"
)  # the spellings of _COUNTS
_AFTER = re.compile(r"\bafter\b(?! that| which)")  # "after X, Y" (SEQUENCE has the others)
SAY_WEIGHT = 0.1


@dataclass(frozen=True)
class Familiarity:
    """A prompt against the repertoire: `score`, the cosine with the nearest training caption;
    `nearest`, the closest captions, nearest first; `familiar`: score >= threshold; `played`,
    the known caption a prompt in words the model was not trained on is played as (None: the
    prompt is played as written)."""

    score: float
    threshold: float
    nearest: tuple[str, ...]
    played: str | None = None

    @property
    def familiar(self) -> bool:
        return self.score >= self.threshold

    @property
    def played_note(self) -> str | None:
        """A line naming the caption a familiar prompt in other words is played as (a far
        one's description names it already); None where there is nothing to tell."""
        if self.familiar and self.played is not None:
            return f"played as the known caption {self.played!r}"
        return None

    def describe(self) -> str:
        """One line for the user."""
        nearest = ", ".join(repr(c) for c in self.nearest)
        played = "" if self.played is None else f"; played as {self.played!r}"
        if self.familiar:
            return f"close to what this model knows ({self.score:.2f}); nearest: {nearest}{played}"
        return (
            f"far from what this model knows (similarity {self.score:.2f}, below "
            f"{self.threshold:.2f}); nearest: {nearest}{played}"
        )


class KnownCaptions:
    """The repertoire of a bundle: unit embeddings (N, dim) of N training captions, and where
    the bundle has them their prompt embeddings (N, text_dim), else None."""

    def __init__(self, bundle: Bundle, repertoire: Repertoire):
        self.threshold = repertoire.threshold
        path, captions = bundle.path(repertoire.embeddings), bundle.path(repertoire.captions)
        try:
            self.captions = untrusted.read_json(captions, "repertoire's captions")
        except ValueError as error:
            raise BundleError(str(error)) from None
        self.embeddings = read_array(path)
        self.prompts = (
            None if repertoire.prompts is None else read_array(bundle.path(repertoire.prompts))
        )
        if not isinstance(self.captions, list) or not all(
            isinstance(caption, str) for caption in self.captions
        ):
            raise BundleError(f"{captions}: not a list of captions (strings)")
        if self.embeddings.ndim != 2 or len(self.captions) != len(self.embeddings):
            raise BundleError(
                f"{path}: {self.embeddings.shape} embeddings for {len(self.captions)} captions"
            )
        if self.prompts is not None and (
            self.prompts.ndim != 2 or len(self.prompts) != len(self.captions)
        ):
            raise BundleError(
                f"{bundle.path(repertoire.prompts)}: {self.prompts.shape} prompt "
                f"embeddings for {len(self.captions)} captions"
            )
        if self.prompts is not None:  # the cosine's denominators and what captions say, once
            self._prompt_norms = np.linalg.norm(self.prompts, axis=1)
            self._says = _said_codes([what_it_says(caption) for caption in self.captions])

    def nearest(self, prompt: np.ndarray, text: str) -> int:
        """The index of the known prompt embedding at the highest cosine with `prompt`
        (1, text_dim), the adapted embedding of `text`, with the steps, sides, ways and counts
        `text` says agreeing (SAY_WEIGHT): the level graphs play the exact embeddings they were
        trained on far better than an adapter's approximation of them (docs/text_encoder.md)."""
        agreement = np.zeros(len(self.captions))
        for kind, value in what_it_says(text).items():
            if kind in self._says:  # +1 where a caption says the same, -1 where another
                codes, said = self._says[kind]
                agreement += np.where(said < 0, 0, np.where(said == codes.get(value, -2), 1, -1))
        similarity = self.prompts @ prompt[0] / self._prompt_norms / np.linalg.norm(prompt)
        return int(np.argmax(similarity + SAY_WEIGHT * agreement))

    def familiarity(
        self, sentence: np.ndarray, played: str | None = None, count: int = 3
    ) -> Familiarity:
        """`sentence`: a prompt's unit sentence embedding (dim,); `played`: the caption it is
        played as, if any."""
        similarity = self.embeddings @ sentence
        order = np.argsort(-similarity, kind="stable")
        nearest = []
        for index in order:  # distinct captions, without the final full stop
            caption = shown_caption(self.captions[index])
            if caption not in nearest:
                nearest.append(caption)
            if len(nearest) == count:
                break
        return Familiarity(
            round(float(similarity[order[0]]), 4),
            self.threshold,
            tuple(nearest),
            None if played is None else shown_caption(played),
        )


def shown_caption(caption: str) -> str:
    """A caption as the user sees it: without its final full stop."""
    return caption.strip().rstrip(".")


def _said_codes(says: list[dict[str, frozenset]]) -> dict[str, tuple[dict, np.ndarray]]:
    """Per kind: a code for each value the captions say, and each caption's code (-1: it says
    none of that kind), so a prompt is compared with every caption in a few array operations."""
    out = {}
    for kind in {kind for said in says for kind in said}:
        codes: dict[frozenset, int] = {}
        said = [codes.setdefault(s[kind], len(codes)) if kind in s else -1 for s in says]
        out[kind] = codes, np.array(said)
    return out


def what_it_says(text: str) -> dict[str, frozenset]:
    """The steps, sides, ways and counts a text names, by kind; kinds it does not name (but
    steps, at least one) are left out."""
    text = caption_phrases(spoken_numbers(text)).lower()
    words = [WORD_SYNONYMS.get(w, w) for w in re.findall(r"[a-z]+", text)]
    steps = 1 + len(SEQUENCE.findall(f" {text} ")) + len(_AFTER.findall(text))
    says = dict(
        steps=frozenset({steps}),
        side=frozenset(_SIDES[w] for w in words if w in _SIDES),
        way=frozenset(_WAYS[w] for w in words if w in _WAYS),
        count=frozenset(_COUNTS[n] for n in _COUNT.findall(text) if n in _COUNTS),
    )
    return {kind: values for kind, values in says.items() if values}
