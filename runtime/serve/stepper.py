"""Many token streams advanced together: one call of each level graph for all streams whose
caches share a layout (the engine of `mogo serve`).

The level graphs take a batch axis, but one `positions` and one `past_positions` for the whole
batch, and attention depends on positions only through their differences, clipped at the
model's max_relative_distance R (plus `position == 0`, which marks the prompt prefix). So rows
can share a call when every cache slot of theirs lies at the same distance from the query.
Each stream keeps its cache in one layout, the same whatever else runs:

    [prefix | d dead slots | live steps, oldest first]

Once the window W is full, the step that falls out of it is not removed (that is a copy of the
whole cache) but marked dead: given a position after the query, attention masks it exactly.
Every COMPACT_EVERY steps the dead slots are dropped in one copy. The layout lives in arrays of
a fixed 1 + W + COMPACT_EVERY slots, the free ones at the end marked dead too: the level graphs
(rewritten by mogo.serve.newslot) return only the new slot, which is written in place, so no
other step copies a cache. A stream at step n holds d = f(n) dead slots, so two streams can
share a call when they are at the same step (warm-up: n < max(W + 1, R)) or, past warm-up, at
the same n mod COMPACT_EVERY: the prefix is then beyond R from the query for both, and the
call uses one set of virtual positions with the same distances. The server keeps streams on
one phase (mogo.serve.engine), so past warm-up they all share one call. Rows never mix inside
a graph (int8 graphs are made row-wise first, mogo.serve.rowwise), and a stream's layout
depends only on its own steps, so its tokens do not depend on what else runs. Sampling is
the runtime's, row for row (mogo.sampling).

Until its window fills (its first W + 1 steps) a stream's layout is also the runtime's
TokenStream's, so a Stepper given `solo` level graphs (the bundle's own, as exported) runs a
stream's first `solo_steps` steps on a TokenStream of its own, one row per call: far cheaper
than a one-row call of the row-wise graphs, so a new stream gets its first frame without
waiting on a batch; then its cache is copied once into the batched arrays. (Batched warm-up
cohorts cost less per step than solo steps, so solo steps stop there.) Where a stream switches
path is its own step count, so this too is the same whatever else runs.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mogo.sampling import Sampling, choose_tokens, make_rng, step_uniforms
from mogo.token_generator import TokenGenerator, TokenStream

COMPACT_EVERY = 8  # steps between copies that drop dead cache slots


class BatchedStream:
    """One stream of a Stepper: prompt rows, sampler, the tokens of its cache slots. Its
    cache lives in rows [row, row + rows) of the arrays of `batch` (a _Batch)."""

    def __init__(self, stepper: Stepper, embedding: np.ndarray, seed: int, sampling: Sampling):
        self.stepper, self.sampling, self.rng = stepper, sampling, make_rng(seed)
        self.uncond = np.array([False, True][:2 if sampling.guided else 1])
        self.prompt = self._rows(embedding)
        L = stepper.tokens.num_levels
        self.last = np.zeros(L, np.int64)  # tokens of the latest step (none yet: any valid id)
        self.steps = 0
        self.dead = 0  # dead slots right after the prefix
        self.live: list[int] = []  # positions of the live slots, the prefix (0) first
        self.slot_tokens = np.zeros((0, L), np.int64)  # tokens of every slot, layout order
        self.batch: _Batch | None = None
        self.row = 0
        self.solo: TokenStream | None = None  # its first solo_steps steps, if any
        if stepper.solo is not None:
            self.solo = stepper.solo.start(embedding, seed, sampling, stepper.window,
                                           allow_end=False)

    @property
    def key(self) -> tuple:
        """Streams with equal keys have caches of one layout, at the same distances (a solo
        stream shares with none)."""
        if self.solo is not None:
            return ("solo", id(self))
        if self.steps < self.stepper.steady_from:
            return ("warm", self.steps)
        return ("steady", self.dead)

    def set_prompt(self, embedding: np.ndarray) -> None:
        """Condition the following steps on a new prompt: every held slot is recomputed under
        it (as mogo.token_generator.TokenStream.set_prompt does), in this stream's layout."""
        self.prompt = self._rows(embedding)
        if self.solo is not None:
            self.solo.set_prompt(embedding)
            return
        if not self.steps:
            return
        g = self.stepper.tokens
        n = self.steps
        positions = np.array([0] + [n + 1] * self.dead + self.live[1:], np.int64)
        token_ids = np.repeat(self.slot_tokens[None], len(self.uncond), axis=0)
        none = np.zeros(0, np.int64)
        outputs = g.each_level(lambda level: g.run(
            level, self.prompt, self.uncond, token_ids, positions, none,
            g.empty_cache(level, len(self.uncond))))
        self.batch, self.row = _Batch([self], self.stepper.held([p for _, p in outputs])), 0

    def step_solo(self) -> np.ndarray:
        """The next step on the stream's own TokenStream; the last solo step hands its state
        over to the batched layout (the same before the window fills: prefix, every step)."""
        solo = self.solo
        drawn = solo.step()
        self.steps += 1
        if self.steps == self.stepper.solo_steps:
            self.live = [int(p) for p in solo.positions]
            self.slot_tokens, self.last, self.rng = solo.slot_tokens, solo.last, solo.rng
            self.batch, self.row = _Batch([self], self.stepper.held(solo.caches)), 0
            self.solo = None
        return drawn

    def cache(self, level: int) -> list[np.ndarray]:
        rows = slice(self.row, self.row + len(self.uncond))
        return [held[rows] for held in self.batch.caches[level]]

    def _rows(self, embedding: np.ndarray) -> np.ndarray:
        prompt = np.asarray(embedding, np.float32).reshape(1, -1)
        return np.repeat(prompt, len(self.uncond), axis=0)


class _Batch:
    """Cache arrays (per level, per layer (rows, heads, slots, head_dim)) of streams in order."""

    def __init__(self, members: list[BatchedStream], caches: list[list[np.ndarray]]):
        self.members, self.caches = members, caches


class Stepper:
    """Level graphs shared by any number of BatchedStreams; `step` advances a set of them."""

    def __init__(self, tokens: TokenGenerator, window: int, max_relative_distance: int,
                 solo: TokenGenerator | None = None, solo_steps: int = 0):
        """`tokens`: level graphs that return only the new cache slot (mogo.serve.newslot);
        `solo`: level graphs for each stream's first `solo_steps` steps (1 to window + 1), one
        stream per call (see the module docstring); None batches every step."""
        if window < 1:
            raise ValueError(f"window must be >= 1 steps, got {window}")
        if solo is not None and not 1 <= solo_steps <= window + 1:
            raise ValueError(f"solo_steps must be 1 to window + 1 = {window + 1}, got "
                             f"{solo_steps}")
        self.tokens, self.window = tokens, window
        self.solo, self.solo_steps = solo, solo_steps
        self.slots = 1 + window + COMPACT_EVERY  # the cache arrays' size: see _advance
        self.steady_from = max(window + 1, max_relative_distance)  # see the module docstring

    def start(self, embedding: np.ndarray, seed: int, sampling: Sampling) -> BatchedStream:
        return BatchedStream(self, embedding, seed, sampling)

    def step(self, streams: Sequence[BatchedStream]) -> list[np.ndarray]:
        """One token step of each stream (tokens (L,) each, in order): one call per level for
        every group of streams with the same key."""
        groups: dict[tuple, list[BatchedStream]] = {}
        rows = {}
        for stream in streams:
            if stream.solo is not None:
                rows[id(stream)] = stream.step_solo()
            else:
                groups.setdefault(stream.key, []).append(stream)
        for members in groups.values():
            rows.update(zip(map(id, members), self._step_group(members)))
        return [rows[id(stream)] for stream in streams]

    def _step_group(self, members: list[BatchedStream]) -> list[np.ndarray]:
        g, first = self.tokens, members[0]
        n, uniforms = first.steps, [step_uniforms(s.rng, g.num_levels) for s in members]
        if n < self.steady_from:  # real positions, shared by streams at the same step
            past = [0] + [n + 1] * first.dead + first.live[1:] if n else []
            query = n
        else:  # the same distances for every stream: live steps 1..W back, the prefix beyond R
            query = self.steady_from
            past = [0] + [query + 1] * first.dead + list(range(query - self.window, query))
        past += [query + 1] * (self.slots - len(past))  # free slots: dead
        prompt = np.concatenate([s.prompt for s in members])
        uncond = np.concatenate([s.uncond for s in members])
        token_ids = np.concatenate([np.repeat(s.last[None, None], len(s.uncond), axis=0)
                                    for s in members])
        caches = self._caches(members)
        outputs = g.each_level(lambda level: g.run(
            level, prompt, uncond, token_ids, np.array([query], np.int64),
            np.array(past, np.int64), caches[level]))
        logits = np.full((len(uncond), g.num_levels, g.num_classes), -np.inf, np.float32)
        for level, (level_logits, _) in enumerate(outputs):
            logits[:, level, :level_logits.shape[1]] = level_logits
        tokens = self._sample(members, logits, uniforms)
        self._advance(members, caches, [present for _, present in outputs], tokens)
        return tokens

    def _sample(self, members: list[BatchedStream], logits: np.ndarray,
                uniforms: list[np.ndarray]) -> list[np.ndarray]:
        """Each member's tokens (L,) from its rows of logits (B, L, C): one choose_tokens call
        for all members with the same sampling (its arithmetic is row by row)."""
        g = self.tokens
        first_rows = np.cumsum([0] + [len(s.uncond) for s in members])
        groups: dict[Sampling, list[int]] = {}
        for k, stream in enumerate(members):
            groups.setdefault(stream.sampling, []).append(k)
        tokens: list[np.ndarray] = [np.zeros(0)] * len(members)
        for sampling, ks in groups.items():
            rows = first_rows[ks]
            cond = logits[rows].reshape(-1, logits.shape[2])
            uncond = logits[rows + 1].reshape(cond.shape) if sampling.guided else None
            forbid = ([g.end_token] + [None] * (g.num_levels - 1)) * len(ks)  # endless streams
            drawn = choose_tokens(cond, uncond, np.concatenate([uniforms[k] for k in ks]),
                                  sampling, forbid).reshape(len(ks), g.num_levels)
            for k, row in zip(ks, drawn):
                tokens[k] = row
        return tokens

    def _caches(self, members: list[BatchedStream]) -> list[list[np.ndarray]]:
        """The members' caches as one batch: the arrays of the last call when it held exactly
        these streams in this order (no copy), else their rows joined."""
        g = self.tokens
        if members[0].batch is None:  # before the first step: every slot free
            rows = sum(len(s.uncond) for s in members)
            return self.held([g.empty_cache(level, rows) for level in range(g.num_levels)])
        batch = members[0].batch
        if batch.members == members and all(s.batch is batch for s in members):
            return batch.caches
        return [[np.concatenate(parts) for parts in zip(*(s.cache(level) for s in members))]
                for level in range(g.num_levels)]

    def held(self, caches: list[list[np.ndarray]]) -> list[list[np.ndarray]]:
        """Caches (per level, per layer (rows, heads, slots, head_dim)) in arrays of
        `self.slots` slots. Free slots are masked, so they add exactly nothing as long as they
        are finite: zero here, stale slots after a compaction."""
        def widened(cache: np.ndarray) -> np.ndarray:
            rows, heads, slots, dim = cache.shape
            out = np.zeros((rows, heads, self.slots, dim), np.float32)
            out[:, :, :slots] = cache
            return out
        return [[widened(cache) for cache in level] for level in caches]

    def _advance(self, members: list[BatchedStream], caches: list[list[np.ndarray]],
                 presents: list[list[np.ndarray]], tokens: list[np.ndarray]) -> None:
        """The new slot (each present) is written after the members' held slots, in place;
        the step leaving the window stays where it is, now dead (dead slots lie right after
        the prefix); once there are COMPACT_EVERY of them the live slots move over them in one
        copy. Members share their layout (it is part of the key). Held slots never pass
        1 + W + COMPACT_EVERY: the prefix, 7 dead, W live and the new one at most."""
        first = members[0]
        used = len(first.live) + first.dead
        dead = first.dead + (len(first.live) == 1 + self.window)
        compact = dead == COMPACT_EVERY
        for level, new in zip(caches, presents):
            for cache, slot in zip(level, new):
                cache[:, :, used] = slot[:, :, -1]
                if compact:
                    cache[:, :, 1:1 + self.window] = cache[:, :, 1 + dead:1 + dead + self.window]
        batch, row = _Batch(list(members), caches), 0
        for stream, drawn in zip(members, tokens):
            live = stream.live + [stream.steps]
            slots = np.concatenate([stream.slot_tokens, stream.last[None]])
            if len(live) > 1 + self.window:
                live = [0] + live[2:]
            if compact:
                slots = np.concatenate([slots[:1], slots[1 + dead:]])
            stream.live, stream.slot_tokens, stream.dead = live, slots, 0 if compact else dead
            stream.batch, stream.row = batch, row
            stream.steps, stream.last = stream.steps + 1, drawn
            row += len(stream.uncond)
