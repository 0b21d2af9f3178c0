"""Re-anchoring: long streams kept in the regime the model was trained on.

The model learnt from 2-10 s clips, so it never saw a clip position past ~200 steps; a stream
left to run drifts into other actions after ~5 s. Re-anchored, the stream goes on, every
`span` steps, as if it were a fresh clip that starts with its last `keep` steps
(TokenStream.continue_from): the positions the model sees stay small and the motion goes on
from where it is. A prompt switch re-anchors at once under the new prompt from only the last
`switch_keep` steps, so the new action starts as a fresh clip of it would (keeping the whole
`keep` there, the model first goes on with the old action: measured in docs/long_streams.md). A prompt that asks for something that ends (`settles`: sit
down, bow, jump three times, "..., then ...") runs until the model ends its clip, then the
stream holds: it goes on, re-anchored, under `Anchoring.hold_prompt`.

Only which tokens are drawn changes: the decoder sees one continuous token stream, so the
frames still equal an offline decode of the tokens, and the cache never holds more than
`span` steps.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mogo.align import plain_words, primitive_of
from mogo.align_words import NUMBERS
from mogo.token_generator import TokenStream

# Primitives that happen once and are done; the others (walk, jog, run, spin, wave, clap,
# jumping jacks, squat, punch, idle) go on for as long as the stream runs.
ONE_OFF = frozenset({"sit", "bow", "turn", "jump", "kick", "stretch", "raise_arms"})
_COUNTS = frozenset(NUMBERS[1:]) | {"once", "twice", "then"}


@dataclass(frozen=True)
class Anchoring:
    """How a stream re-anchors: a fresh clip every `span` steps, starting with the last `keep`
    steps (at a prompt switch, `switch_keep`); `max_one_off` steps at most before a one-off
    prompt holds (the bundle's longest clip, 9.8 s, where the model has not ended it itself);
    the prompt of the hold."""
    span: int = 40
    keep: int = 10
    switch_keep: int = 1
    max_one_off: int = 196
    hold_prompt: str = "a person stands still."

    def __post_init__(self):
        if not 1 <= self.keep < self.span:
            raise ValueError(f"anchoring needs 1 <= keep < span, got keep={self.keep}, "
                             f"span={self.span}")
        if not 1 <= self.switch_keep <= self.keep:
            raise ValueError(f"anchoring needs 1 <= switch_keep <= keep, got "
                             f"switch_keep={self.switch_keep}, keep={self.keep}")


def settles(text: str) -> bool:
    """Whether a prompt asks for something that ends, after which the stream holds: a one-off
    action (ONE_OFF), a count ("waves three times", "four steps") or a sequence ("then")."""
    words = plain_words(text)
    return bool(_COUNTS.intersection(words)) or any(w.isdigit() for w in words) \
        or primitive_of(words) in ONE_OFF


class Anchor:
    """One stream's re-anchoring: its last `keep` token steps, and whether it holds."""

    def __init__(self, anchoring: Anchoring, tokens: TokenStream,
                 embed: Callable[[str], np.ndarray], text: str):
        self.anchoring, self._tokens, self._embed = anchoring, tokens, embed
        self.recent = np.zeros((0, tokens.generator.num_levels), np.int64)
        self.anchors = 0  # re-anchors so far
        self.holding = False
        self._tokens.allow_end = settles(text)

    def switch(self, text: str, embedding: np.ndarray) -> None:
        """A new prompt: a fresh clip under it at once, from the last `switch_keep` steps."""
        self._tokens.set_prompt(embedding)
        self.holding = False
        self._tokens.allow_end = settles(text)
        if len(self.recent):
            self._reanchor(self.anchoring.switch_keep)

    def continued(self, tokens: np.ndarray) -> None:
        """The stream goes on from these steps (MotionStream.continue_from)."""
        self.recent = np.asarray(tokens, np.int64)[-self.anchoring.keep:]

    def step(self) -> np.ndarray:
        """The next token step, re-anchoring or settling into the hold where due."""
        row = self._tokens.step()
        if row is None:  # the model ended a one-off prompt's clip
            self._hold()
            row = self._tokens.step()
        self.recent = np.concatenate([self.recent, row[None]])[-self.anchoring.keep:]
        if self._tokens.allow_end:
            if self._tokens.steps >= self.anchoring.max_one_off:
                self._hold()
        elif self._tokens.steps >= self.anchoring.span:
            self._reanchor()
        return row

    def _hold(self) -> None:
        self._tokens.set_prompt(self._embed(self.anchoring.hold_prompt))
        self._tokens.allow_end = False
        self.holding = True
        self._reanchor()

    def _reanchor(self, keep: int | None = None) -> None:
        self._tokens.continue_from(self.recent[-(keep or self.anchoring.keep):])
        self.anchors += 1
