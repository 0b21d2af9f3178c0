"""Re-anchoring: long streams kept in the regime the model was trained on.

The model learnt from 2-10 s clips, so it never saw a clip position past ~200 steps; a stream
left to run drifts into other actions after ~5 s. Re-anchored, the stream is a chain of clips
the model could have been trained on:

- where the model ends its clip (the end token: after one turn for a spin, after a few
  seconds for a walk), a fresh clip of the prompt starts at step 0 (TokenStream.restart): the
  action starts over at its own pace, as a clip of it does, instead of going on from a state
  no training clip was in (re-anchored after a whole spin, the model stood);
- where it has not ended it after `span` steps, the stream goes on as if it were a fresh clip
  that starts with its last `keep` steps (TokenStream.continue_from);
- a prompt switch re-anchors at once under the new prompt from only the last `switch_keep`
  steps, so the new action starts as a fresh clip of it would (keeping the whole `keep`
  there, the model first goes on with the old action: measured in docs/long_streams.md);
- a prompt that asks for something that ends (`settles`: sit down, bow, jump three times,
  "..., then ...") runs until the model ends its clip, then the stream holds: a fresh clip
  of `Anchoring.hold_prompt`, which starts standing still (re-anchored from the end of a
  turn, the hold went on turning slowly), then re-anchored from its last `still_keep` steps
  (STILL: the model does not end clips of standing still).

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
# Standing still has no cycle to start again: the model does not end a clip of it, which goes
# on re-anchored from its last still_keep steps (fresh clips of it, or re-anchors from 1 step,
# showed their first pose as a small settle every few seconds; re-anchored from 10 steps, a
# hold fell into a slow turn after minutes and kept it).
STILL = "idle"
_COUNTS = frozenset(NUMBERS[1:]) | {"once", "twice", "then"}


@dataclass(frozen=True)
class Anchoring:
    """How a stream re-anchors: where the model has not ended its clip after `span` steps, a
    fresh clip starting with the last `keep` steps (at a prompt switch, `switch_keep`; while
    standing still, `still_keep`: from 10, a slow turn carried on from clip to clip, from 1,
    each re-anchor settled into a fresh pose);
    `max_one_off` seconds at most before a one-off prompt holds, where the model has not
    ended it itself (None: the bundle's longest clip, its defaults.max_seconds); the prompt of
    the hold. The span is longer than the clips of short actions (a spin's turn: 2 s), so
    that the model ends them itself before."""

    span: int = 80
    keep: int = 10
    switch_keep: int = 1
    still_keep: int = 5
    max_one_off: float | None = None
    hold_prompt: str = "a person stands still."

    def __post_init__(self):
        if not 1 <= self.keep < self.span:
            raise ValueError(
                f"anchoring needs 1 <= keep < span, got keep={self.keep}, span={self.span}"
            )
        for name in ("switch_keep", "still_keep"):
            if not 1 <= getattr(self, name) <= self.keep:
                raise ValueError(
                    f"anchoring needs 1 <= {name} <= keep, got "
                    f"{name}={getattr(self, name)}, keep={self.keep}"
                )
        if self.max_one_off is not None and not self.max_one_off > 0:
            raise ValueError(f"anchoring needs max_one_off > 0 seconds, got {self.max_one_off}")

    def one_off_steps(self, longest: float, steps_per_second: float) -> int:
        """max_one_off in token steps, `longest` seconds (the bundle's) where it is None."""
        seconds = longest if self.max_one_off is None else self.max_one_off
        return max(1, round(seconds * steps_per_second))


def settles(text: str) -> bool:
    """Whether a prompt asks for something that ends, after which the stream holds: a one-off
    action (ONE_OFF), a count ("waves three times", "four steps") or a sequence ("then")."""
    words = plain_words(text)
    return (
        bool(_COUNTS.intersection(words))
        or any(w.isdigit() for w in words)
        or primitive_of(words) in ONE_OFF
    )


class Anchor:
    """One stream's re-anchoring: its last `keep` token steps, and whether it holds. The
    model may end its clip (TokenStream.allow_end; not while standing still): the stream
    then goes on with a fresh clip, of the prompt or, after a one-off, of the hold."""

    def __init__(
        self,
        anchoring: Anchoring,
        tokens: TokenStream,
        embed: Callable[[str], np.ndarray],
        text: str,
        one_off_steps: int,
    ):
        self.anchoring, self._tokens, self._embed = anchoring, tokens, embed
        self.one_off_steps = one_off_steps  # anchoring.one_off_steps for this bundle
        self.recent = np.zeros((0, tokens.generator.num_levels), np.int64)
        self.anchors = 0  # re-anchors and fresh clips so far
        self.fresh = 0  # of which fresh clips
        self.holding = False
        self.kind(text)

    def switch(self, text: str, embedding: np.ndarray) -> None:
        """A new prompt: a fresh clip under it at once, from the last `switch_keep` steps (the
        cache prefilled once, for those steps)."""
        self.holding = False
        self.kind(text)
        if len(self.recent):
            self._reanchor(self.anchoring.switch_keep, embedding)
        else:
            self._tokens.set_prompt(embedding)

    def continued(self, tokens: np.ndarray) -> None:
        """The stream goes on from these steps (MotionStream.continue_from): as at a switch,
        a fresh clip from the last `switch_keep` (kept whole, the end of a walk made the model
        end a jump asked for next at once, and stand)."""
        self.recent = np.asarray(tokens, np.int64)[-self.anchoring.keep :]
        self._reanchor(self.anchoring.switch_keep)

    def clip_ended(self) -> None:
        """The model ended its clip (never at step 0): a fresh one, of the prompt or, after a
        one-off, of the hold. Its first step is drawn next (mogo.generator.drawn_together)."""
        if self.one_off:
            self._hold()
        else:
            self._restart()

    def after(self, row: np.ndarray) -> np.ndarray:
        """The step's tokens once the token stream has drawn `row`: re-anchoring or settling
        where due."""
        self.recent = np.concatenate([self.recent, row[None]])[-self.anchoring.keep :]
        if self.one_off:
            if self._tokens.steps >= self.one_off_steps:
                self._hold()
        elif self._tokens.steps >= self.anchoring.span:  # its cache made with the round's
            self._reanchor(self.anchoring.still_keep if self.still else None, prefill=False)
        return row

    def kind(self, text: str) -> None:
        """What `text` asks for: a one-off (then the hold), standing still, and whether the
        model may end its clips."""
        self.one_off = settles(text)
        self.still = primitive_of(plain_words(text)) == STILL
        self._tokens.allow_end = not self.still

    def _hold(self) -> None:
        """A fresh clip of the hold prompt: one re-anchored from the end of a turn went on
        turning slowly."""
        hold = self.anchoring.hold_prompt
        self._restart()  # first: the prompt then has no held step to prefill
        self._tokens.set_prompt(self._embed(hold))
        self.holding = True
        self.kind(hold)

    def _restart(self) -> None:
        self._tokens.restart()
        self.anchors += 1
        self.fresh += 1

    def _reanchor(
        self, keep: int | None = None, embedding: np.ndarray | None = None, prefill: bool = True
    ) -> None:
        """A fresh clip from the last `keep` steps, under `embedding` where given (prefill:
        TokenStream.continue_from's)."""
        recent = self.recent[-(keep or self.anchoring.keep) :]
        self._tokens.continue_from(recent, embedding, prefill)
        self.anchors += 1
