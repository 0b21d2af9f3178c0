"""The token loop on onnxruntime: one session per level graph, a KV cache per stream.

One step = every level once, coarse to fine, at the next position: position 0 is the prompt
prefix (the first step is the prefill), position n >= 1 holds the tokens of step n - 1 and
predicts step n. Each level's presents are fed back as its pasts on the next step, untouched;
once the sliding window is full, the newest slot overwrites the oldest in place (every slot
carries its position, so slot order does not change the attention; with int8 graphs it changes
the rounding slightly, ~0.06 in logits of ~15), so no step copies the cache. The levels of
one step are independent (level l sees only earlier steps), so with several workers they run
concurrently, each on one core, and are sampled afterwards in level order. Guidance runs a
batch of two rows, conditional and unconditional. The rules (uniforms, end token, window) are
those of the torch reference `mogo.export.models.generate_torch.generate`, so both give the same
tokens.

Graph names come from the bundle manifest (mogo.manifest.Graph, written by
mogo.export.onnx.t2m_graphs), by role: the first five inputs are prompt, uncond, token_ids,
positions, past_positions, then past key/value pairs layer by layer; output 0 is the logits,
then the matching presents. The cache sizes (heads, head_dim) are the graph's own input shapes.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from mogo._session import graph_session
from mogo.kv_pool import KVPool, StagedSession
from mogo.manifest import BundleError, Graph
from mogo.motion.skeleton import MAX_FRAMES
from mogo.progress import Progress
from mogo.sampling import Sampling, choose_tokens, make_rng, step_uniforms

LEVEL_INPUTS = ["prompt", "uncond", "token_ids", "positions", "past_positions"]  # then the pasts
SHORT = 0.75  # pooled calls read a bucket's first slots alone where they use less than this
Cache = list[np.ndarray]  # one level: key, value, key, value, ... (batch, heads, slots, head_dim)


class Stopped(Exception):
    """`generate` was asked to stop by another thread (`mogo serve`, when a client leaves)."""


class TokenGenerator:
    """The level graphs of one model; `start` opens a stream on them (streams share sessions)."""

    def __init__(
        self,
        level_paths: Sequence[str | os.PathLike] | Sequence[Sequence[bytes]],
        graphs: Sequence[Graph],
        end_token: int,
        intra_op_threads: int = 1,
        level_workers: int = 1,
        pooled: bool = False,
        alone: TokenGenerator | None = None,
    ):
        """graphs[l]: the input and output names of level l (protocol order).
        level_workers > 1 runs the levels of a step in that many groups at once, balanced by
        layer count (each session then keeps `intra_op_threads`, best 1). pooled: each level
        the stages of mogo.serve.pooled (rows never mix, each row its own positions, new slots
        out, the pasts read in place): the streams keep their caches in one KVPool and share
        calls (`step_together`). alone: with pooled, the same model's graphs as exported, which
        a call of one row runs on instead: a stream's own cache's arithmetic, in about 2/3 of
        the row-wise stages' time at one row (no per-row quantisation, one call a level)."""
        if level_workers < 1:
            raise ValueError(f"level_workers must be >= 1, got {level_workers}")
        if len(level_paths) != len(graphs):
            raise ValueError(f"{len(level_paths)} graph files for {len(graphs)} graph entries")
        self.sessions = [
            StagedSession(path, graph, intra_op_threads)
            if pooled
            else graph_session(path, graph, intra_op_threads)
            for path, graph in zip(level_paths, graphs, strict=False)
        ]
        self.graphs = list(graphs)
        self.cache_shapes = [  # pooled: the graph's file names what its stages came from
            _cache_shape(session, graph.file if pooled else path)
            for session, path, graph in zip(self.sessions, level_paths, graphs, strict=False)
        ]
        self.end_token = end_token
        self.num_levels = len(graphs)
        self.num_classes = end_token + 1  # level 0's logits: every code and the end token
        self.pool = KVPool(self.cache_shapes) if pooled else None
        self.alone = alone
        self._spread_levels(level_workers)

    def with_level_workers(self, level_workers: int) -> TokenGenerator:
        """The same sessions (no second copy of the weights), levels spread over more or fewer
        workers."""
        if level_workers < 1:
            raise ValueError(f"level_workers must be >= 1, got {level_workers}")
        twin = copy.copy(self)
        twin._spread_levels(level_workers)
        return twin

    def with_own_pool(self) -> TokenGenerator:
        """The same sessions with a KVPool of its own (each server engine's, and a resumed
        stream's while its cache is made off the engine's thread)."""
        twin = copy.copy(self)
        twin.pool = KVPool(self.cache_shapes)
        return twin

    def shutdown(self) -> None:
        """End the threads of its level groups (the sessions stay with their other users)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)

    def _spread_levels(self, level_workers: int) -> None:
        self.level_groups = balanced_groups(
            [layers for layers, _, _ in self.cache_shapes], level_workers
        )
        self._pool = (
            ThreadPoolExecutor(len(self.level_groups) - 1, "mogo-level")
            if len(self.level_groups) > 1
            else None
        )

    def start(
        self,
        prompt_embedding: np.ndarray,
        seed: int = 0,
        sampling: Sampling = Sampling(),
        window: int | None = None,
        allow_end: bool = True,
    ) -> TokenStream:
        """A new stream; see `TokenStream`."""
        return TokenStream(self, prompt_embedding, seed, sampling, window, allow_end)

    def generate(
        self,
        prompt_embedding: np.ndarray,
        num_frames: int | None = None,
        max_frames: int = MAX_FRAMES,
        sampling: Sampling = Sampling(),
        seed: int = 0,
        window: int | None = None,
        stop=None,
        progress: bool = False,
    ) -> np.ndarray:
        """prompt_embedding (text_dim,) -> token ids (T, L) int64. num_frames given: exactly that
        many steps, the end token masked. None: until level 0 draws the end token or max_frames.
        stop: a threading.Event; once set, the next step raises Stopped. progress=True: a
        progress line on stderr (mogo.progress) as the steps are drawn."""
        stream = self.start(prompt_embedding, seed, sampling, window, num_frames is None)
        total = max_frames if num_frames is None else num_frames
        shown = Progress(total, "generating", enabled=progress, unit="steps")
        rows = []
        while len(rows) < total:
            if stop is not None and stop.is_set():
                raise Stopped("stopped")
            row = stream.step()
            if row is None:
                break
            rows.append(row)
            shown.update()
        shown.close()
        return np.array(rows, dtype=np.int64).reshape(-1, self.num_levels)

    def run(
        self,
        level: int,
        prompt: np.ndarray,
        uncond: np.ndarray,
        token_ids: np.ndarray,
        positions: np.ndarray,
        past_positions: np.ndarray,
        past: Cache,
        slots: np.ndarray | None = None,
    ) -> tuple[np.ndarray, Cache]:
        """One call of a level graph -> logits of the last position (batch, K[+1]), presents.
        Pooled graphs (mogo.serve.pooled) return the new slots only; their `positions` are
        (batch, seq), `past_positions` (batch, slots) hold the new slots' positions at `slots`
        (batch, seq) and MASKED where unused. Called as for the exported graphs (one vector of
        positions, `slots` None), the new slots follow the past."""
        graph = self.graphs[level]
        values = [prompt, uncond, token_ids, positions, past_positions, *past]
        if self.pool is not None:
            if slots is None:
                batch, held, new = len(prompt), len(past_positions), len(positions)
                slots = np.broadcast_to(np.arange(held, held + new), (batch, new))
                past_positions = np.broadcast_to(
                    np.concatenate([past_positions, positions]), (batch, held + new)
                )
                positions = np.broadcast_to(positions, (batch, new))
                past = [
                    np.concatenate(
                        [cache, np.zeros((*cache.shape[:2], new, cache.shape[3]))], 2
                    ).astype(np.float32)
                    for cache in past
                ]
            values = [prompt, uncond, token_ids, positions, past_positions, *past, slots]
        feed = dict(zip(graph.inputs, values, strict=True))  # one array per input, no more
        logits, *presents = self.sessions[level].run(list(graph.outputs), feed)
        return logits, presents

    def each_level(self, call: Callable[[int], tuple]) -> list[tuple]:
        """[call(level) for every level], the level groups run concurrently when there are
        several (onnxruntime releases the GIL while a graph runs)."""
        if self._pool is None:
            return [call(level) for level in range(self.num_levels)]

        def run_group(group: list[int]) -> list[tuple]:
            return [call(level) for level in group]

        others = [self._pool.submit(run_group, group) for group in self.level_groups[1:]]
        results = dict(zip(self.level_groups[0], run_group(self.level_groups[0]), strict=False))
        for group, future in zip(self.level_groups[1:], others, strict=False):
            results.update(zip(group, future.result(), strict=False))
        return [results[level] for level in range(self.num_levels)]

    def empty_cache(self, level: int, batch: int) -> Cache:
        """The past of a prefill: every layer's key and value with no slots."""
        layers, heads, head_dim = self.cache_shapes[level]
        empty = np.zeros((batch, heads, 0, head_dim), np.float32)
        return [empty] * (2 * layers)


class TokenStream:
    """One generation: its prompt, sampler state and cache. `step()` until it returns None.

    The cache holds slots at `positions` (absolute, shared by all levels), the prefix at slot 0.
    With `window` W, once it holds the prefix and W steps each new step replaces the oldest, so
    memory and step time stay constant; distances to the kept slots stay exact.
    allow_end=False forces the length (the caller stops): level 0 never draws the end token,
    which it otherwise may from the second step on.
    """

    def __init__(
        self,
        generator: TokenGenerator,
        prompt_embedding: np.ndarray,
        seed: int,
        sampling: Sampling,
        window: int | None,
        allow_end: bool,
    ):
        if window is not None and window < 1:
            raise ValueError(f"window must be >= 1 steps, got {window}")
        if generator.pool is not None and sampling.guided:
            raise ValueError("guided streams need the bundle's own level graphs, not pooled ones")
        self.generator, self.sampling = generator, sampling
        self.window, self.allow_end = window, allow_end
        self.rng = make_rng(seed)
        self.uncond = np.array([False, True][: 2 if sampling.guided else 1])
        self.prompt = self._batch(prompt_embedding)
        self.restart()

    def step(self) -> np.ndarray | None:
        """The tokens (L,) of the next step, or None once level 0 has drawn the end token.
        The first step is the prefill: the prompt prefix at position 0 predicts step 0."""
        return step_together([self])[0]

    def _drawn(self, logits: np.ndarray, uniforms: np.ndarray) -> np.ndarray | None:
        """The step's tokens, sampled from this stream's logits (rows, L, C); None (the stream
        ended) where level 0 drew the end token."""
        row = choose_tokens(
            logits[0],
            logits[1] if self.sampling.guided else None,
            uniforms,
            self.sampling,
            self._forbid(),
        )
        return self._ends(row)

    def _forbid(self) -> list[int | None]:
        """Per level, the token the step may not draw: the end token before the second step,
        or always where the caller sets the length."""
        g = self.generator
        return [None if self.allow_end and self.steps > 0 else g.end_token] + [None] * (
            g.num_levels - 1
        )

    def _ends(self, row: np.ndarray) -> np.ndarray | None:
        """`row`, or None (the stream ended) where level 0 drew the end token."""
        if row[0] == self.generator.end_token:
            self.ended = True
            return None
        return row

    def _took(self, row: np.ndarray) -> int:
        """The step drew `row`: the cache slot its call filled (at position `steps`, holding
        the previous step's tokens), appended or, with a full window, the oldest step's."""
        n = self.steps
        if self.window is not None and len(self.positions) == 1 + self.window:
            slot = self._oldest  # the prefix, slot 0, stays; slots are then in ring order
            self._oldest = slot % self.window + 1
            self.positions[slot], self.slot_tokens[slot] = n, self.last
            self.prefilled = len(self.positions)  # no longer made by steps from a prefill
        else:
            slot = len(self.positions)
            self.positions = np.append(self.positions, n)
            self.slot_tokens = np.concatenate([self.slot_tokens, self.last[None]])
        self.last, self.steps = row, n + 1
        return slot

    def set_prompt(self, prompt_embedding: np.ndarray) -> None:
        """Condition the following steps on a new prompt: one prefill of every cache slot, the
        prefix under the new prompt and the kept steps with their tokens, so the model then sees
        what it would if the stream had been those steps under that prompt (exactly with float
        graphs; int8 graphs round a little differently by slot order and prefill length)."""
        self.prompt = self._batch(prompt_embedding)
        if len(self.positions):  # before the first step there is nothing cached yet
            self._prefill()

    def continue_from(
        self,
        tokens: np.ndarray,
        prompt_embedding: np.ndarray | None = None,
        prefill: bool = True,
    ) -> None:
        """Take `tokens` (n, L) as the steps drawn so far (a clip to continue), in place of
        anything drawn before: the next step is step n, seeing them as its past; under
        `prompt_embedding` where given (a switch that re-anchors: one prefill, not two).
        prefill=False leaves the cache to `prefill_together` before the next step (a round's
        re-anchors share its calls)."""
        tokens = np.asarray(tokens, np.int64)
        L = self.generator.num_levels
        if tokens.ndim != 2 or tokens.shape[1] != L or len(tokens) == 0:
            raise ValueError(f"tokens to continue from must be (n >= 1, {L}), got {tokens.shape}")
        n = len(tokens)
        self.positions = np.arange(n, dtype=np.int64)
        self.slot_tokens = np.concatenate([np.zeros((1, L), np.int64), tokens[:-1]])
        self.last, self.steps, self.ended = tokens[-1], n, False
        if self.window is not None and n > 1 + self.window:
            keep = np.r_[0, n - self.window : n]
            self.positions, self.slot_tokens = self.positions[keep], self.slot_tokens[keep]
        self._oldest = 1
        if prompt_embedding is not None:
            self.prompt = self._batch(prompt_embedding)
        self.unfilled = True
        if prefill:
            self._prefill()

    def restart(self) -> None:
        """Forget every step drawn (not the random state): the next step is step 0 of a fresh
        clip under the prompt."""
        L = self.generator.num_levels
        self.positions = np.zeros(0, np.int64)  # (P,) position of every cache slot
        self.slot_tokens = np.zeros((0, L), np.int64)  # (P, L) the tokens each slot holds
        self.last = np.zeros(L, np.int64)  # tokens of the latest step (none yet: any valid id)
        self.steps = 0  # steps drawn
        self.ended = False
        self._oldest = 1  # with a full window: the slot the next step overwrites
        self.prefilled = 0  # leading slots the last prefill made (the others: one step each)
        self.unfilled = False  # slots set by continue_from, their cache not yet made
        self._keep(None)

    def _keep(self, caches: list[Cache] | None) -> None:
        """Hold `caches` (per level, the slots at `positions`; None: none) as the cache: the
        stream's own, or its row of the generator's pool."""
        g = self.generator
        if g.pool is not None:
            g.pool.store(self, caches)
        else:
            rows = len(self.uncond)
            self.caches = caches or [g.empty_cache(level, rows) for level in range(g.num_levels)]

    def move_to(self, generator: TokenGenerator) -> None:
        """Go on in `generator`'s pool (the same graphs): the cache moved from this stream's
        pool (a resumed served stream's, made off the server's thread) into it."""
        caches = self.generator.pool.caches(self)
        self.generator.pool.remove(self)
        self.generator = generator
        self._keep(caches)

    def _prefill(self) -> None:
        """Recompute every level's cache for the held slots under the current prompt."""
        prefill_together([self])

    def rebuild(self) -> None:
        """The cache of the held slots made again as it was made (a resumed stream,
        mogo.stream_state): the prefill of the first `prefilled`, then one step for each slot
        drawn since, so it holds the same numbers and the next draws are the same. After a
        full window's overwrites that history is gone: the whole window is prefilled (as at a
        prompt switch: close, not the same numbers with int8 graphs)."""
        g, positions, tokens = self.generator, self.positions, self.slot_tokens
        made = self.prefilled
        self.positions, self.slot_tokens = positions[:made], tokens[:made]
        rows = len(self.uncond)
        caches = (
            _prefilled_together([self])[0]
            if made
            else [g.empty_cache(level, rows) for level in range(g.num_levels)]
        )
        for k in range(made, len(positions)):
            caches = self._replayed(caches, tokens[k], positions[k : k + 1], positions[:k])
        self.positions, self.slot_tokens = positions, tokens
        self._keep(caches)

    def _replayed(
        self, caches: list[Cache], tokens: np.ndarray, position: np.ndarray, past: np.ndarray
    ) -> list[Cache]:
        """`caches` after one step's graph calls as the step made them, its tokens given, none
        drawn (pooled graphs return the new slot alone, which follows the past)."""
        outputs = self._call_levels(tokens, position, past, caches)
        if self.generator.pool is None:
            return [present for _, present in outputs]
        return [
            [np.concatenate([held, new], 2) for held, new in zip(cache, present, strict=True)]
            for cache, (_, present) in zip(caches, outputs, strict=True)
        ]

    def _call_levels(
        self,
        tokens: np.ndarray,
        position: np.ndarray,
        past: np.ndarray,
        caches: list[Cache],
        graphs: TokenGenerator | None = None,
    ) -> list[tuple]:
        """Every level graph once for this stream alone: the step at `position` fed `tokens`
        (L,), over the slots at `past` held in `caches` -> (logits, presents) per level.
        graphs: those to run (None: the stream's generator's)."""
        g = self.generator if graphs is None else graphs
        ids = np.repeat(tokens[None, None], len(self.uncond), axis=0)
        return g.each_level(
            lambda level: g.run(level, self.prompt, self.uncond, ids, position, past, caches[level])
        )

    def _batch(self, prompt_embedding: np.ndarray) -> np.ndarray:
        """(text_dim,) -> (B, text_dim) float32, one row per guidance branch."""
        prompt = np.asarray(prompt_embedding, np.float32).reshape(1, -1)
        return np.repeat(prompt, len(self.uncond), axis=0)


def step_together(streams: Sequence[TokenStream]) -> list[np.ndarray | None]:
    """One step of each stream (its tokens (L,), or None where it has ended). The one token
    loop: TokenStream.step is this for one stream. Streams on pooled graphs (the server's) share
    one call of each level graph per bucket of their pool (mogo.kv_pool), at any step of their
    clips; the rows never mix there, so a stream's tokens never depend on the others. Any other
    stream steps alone on its own cache."""
    drawn: list[np.ndarray | None] = [None] * len(streams)
    pooled: dict[int, list[int]] = {}
    for k, stream in enumerate(streams):
        if stream.ended:
            continue
        if stream.generator.pool is None:
            drawn[k] = _step_alone(stream)
        else:
            pooled.setdefault(id(stream.generator), []).append(k)
    for ks in pooled.values():
        for k, row in zip(ks, _step_pooled([streams[k] for k in ks]), strict=True):
            drawn[k] = row
    return drawn


def prefill_together(streams: Sequence[TokenStream]) -> None:
    """Each stream's cache made for its held slots under its prompt (`TokenStream._prefill`):
    streams on pooled graphs with the same slots in one call of each level graph (rows never
    mix there), any other alone (the bundle's graphs quantise a call's rows together)."""
    alike: dict[tuple, list[TokenStream]] = {}
    for s in streams:
        pooled = s.generator.pool is not None
        key = (id(s.generator), s.positions.tobytes()) if pooled else (id(s),)
        alike.setdefault(key, []).append(s)
    for group in alike.values():
        for s, caches in zip(group, _prefilled_together(group), strict=True):
            s._keep(caches)
            s.prefilled, s.unfilled = len(s.positions), False


def _prefilled_together(streams: list[TokenStream]) -> list[list[Cache]]:
    """Every level's cache for the held slots (the same for all) of each stream under its
    prompt, computed in one call of each level graph: each stream's rows of the presents."""
    g, positions = streams[0].generator, streams[0].positions
    token_ids = np.concatenate(
        [np.repeat(s.slot_tokens[None], len(s.uncond), axis=0) for s in streams]
    )
    rows = len(token_ids)
    outputs = g.each_level(
        lambda level: g.run(
            level,
            np.concatenate([s.prompt for s in streams]),
            np.concatenate([s.uncond for s in streams]),
            token_ids,
            positions,
            np.zeros(0, np.int64),
            g.empty_cache(level, rows),
        )
    )
    cuts = np.cumsum([len(s.uncond) for s in streams])
    return [
        [[present[cut - len(s.uncond) : cut] for present in presents] for _, presents in outputs]
        for s, cut in zip(streams, cuts, strict=True)
    ]


def _level_logits(g: TokenGenerator, outputs: list[tuple]) -> np.ndarray:
    """Every level's logits in one (rows, L, C) array, -inf past a level's classes."""
    rows = len(outputs[0][0])
    logits = np.full((rows, g.num_levels, g.num_classes), -np.inf, np.float32)
    for level, (level_logits, _) in enumerate(outputs):
        logits[:, level, : level_logits.shape[1]] = level_logits
    return logits


def _step_alone(s: TokenStream) -> np.ndarray | None:
    g = s.generator
    uniforms = step_uniforms(s.rng, g.num_levels)
    outputs = s._call_levels(s.last, np.array([s.steps], np.int64), s.positions, s.caches)
    row = s._drawn(_level_logits(g, outputs), uniforms)
    if row is not None:
        held = len(s.positions)
        slot = s._took(row)
        presents = [present for _, present in outputs]
        if len(s.positions) > held:
            s.caches = presents  # the past and the new slot, as the graph returns them
        else:  # a full window: the new slot replaces the oldest step's in place
            for cache, present in zip(s.caches, presents, strict=True):
                for held, new in zip(cache, present, strict=True):
                    held[:, :, slot] = new[:, :, -1]
    return row


def _pooled_call(
    g: TokenGenerator, group: list[TokenStream], bucket, rows
) -> tuple[list[tuple], bool]:
    """Every level graph once for `group`, whose caches lie at `rows` of `bucket`: each
    stream's new slot follows its slots in the call, as in its own cache. Returns the levels'
    outputs, and whether the call read the rows in place (so wrote the new slots there)."""
    if len(group) == 1 and g.alone is not None:
        return _alone_call(g.alone, group[0], bucket, rows), False
    prompt = np.concatenate([s.prompt for s in group])
    uncond = np.zeros(len(group), bool)
    token_ids = np.stack([s.last for s in group])[:, None]
    query = np.array([[s.steps] for s in group], np.int64)
    slots = np.array([[len(s.positions)] for s in group], np.int64)
    # where the group uses less than SHORT of its bucket (new streams, fresh clips), a copy
    # of just the slots used: a cache of n slots read as n, not padded to the bucket, rounds
    # as the stream's own cache does (padding to a multiple of 8 can change the last bit)
    used = int(slots.max()) + 1
    cut = slice(None) if used > SHORT * bucket.capacity else slice(0, used)
    keys = bucket.positions[rows, cut].copy()
    keys[np.arange(len(group)), slots[:, 0]] = query[:, 0]
    outputs = g.each_level(
        lambda level: g.run(
            level,
            prompt,
            uncond,
            token_ids,
            query,
            keys,
            # a run of rows, all slots: read in place, the new slots written there
            [np.ascontiguousarray(held[rows, :, cut]) for held in bucket.arrays[level]],
            slots,
        )
    )
    return outputs, isinstance(rows, slice) and cut == slice(None)


def _alone_call(alone: TokenGenerator, s: TokenStream, bucket, rows) -> list[tuple]:
    """Every level graph once for one pooled stream, on the graphs as exported (`alone`): its
    slots copied out of its row, as its own cache holds them, so the numbers of `_step_alone`.
    Returns the levels' logits and new slots (1, heads, 1, head_dim), as a pooled call does."""
    row = rows.start if isinstance(rows, slice) else rows[0]
    held = len(s.positions)
    caches = [
        [np.ascontiguousarray(array[row : row + 1, :, :held]) for array in level]
        for level in bucket.arrays
    ]
    outputs = s._call_levels(s.last, np.array([s.steps], np.int64), s.positions, caches, alone)
    return [
        (logits, [present[:, :, held:] for present in presents]) for logits, presents in outputs
    ]


def _step_pooled(members: list[TokenStream]) -> list[np.ndarray | None]:
    """One call of each level graph per pool bucket: the rows where they lie in the pool, each
    with its own positions; each stream samples its row, and its new slot goes into the pool."""
    g = members[0].generator
    pool = g.pool
    drawn: list[np.ndarray | None] = [None] * len(members)
    for s in members:
        pool.reserve(s, len(s.positions) + 1)
    for bucket, ks, rows in pool.groups(members):
        group = [members[k] for k in ks]
        uniforms = [step_uniforms(s.rng, g.num_levels) for s in group]
        called = [len(s.positions) for s in group]  # where each new slot went in the call
        outputs, in_place = _pooled_call(g, group, bucket, rows)
        sampled = _sampled_together(group, _level_logits(g, outputs), uniforms)
        took, slots, written = [], [], []
        for i, (k, s, row) in enumerate(zip(ks, group, sampled, strict=True)):
            drawn[k] = s._ends(row)
            if drawn[k] is not None:
                took.append(i)
                slots.append(s._took(drawn[k]))
                written.append(in_place and slots[-1] == called[i])  # not a full window's
        new = [[present[took] for present in presents] for _, presents in outputs]
        pool.write([group[i] for i in took], slots, new, written)
    return drawn


def _sampled_together(
    group: list[TokenStream], logits: np.ndarray, uniforms: list[np.ndarray]
) -> list[np.ndarray]:
    """Each stream's tokens (L,) from its logits (row i of (rows, L, C)): the streams of one
    Sampling in one choose_tokens call, which treats each row alone (the same tokens as one
    call per stream, in a few numpy calls for all)."""
    levels = logits.shape[1]
    rows: list[np.ndarray] = [None] * len(group)  # type: ignore[list-item]
    by_sampling: dict[Sampling, list[int]] = {}
    for i, s in enumerate(group):
        by_sampling.setdefault(s.sampling, []).append(i)
    for sampling, members in by_sampling.items():
        drawn = choose_tokens(
            logits[members].reshape(len(members) * levels, -1),
            None,
            np.concatenate([uniforms[i] for i in members]),
            sampling,
            [token for i in members for token in group[i]._forbid()],
        ).reshape(len(members), levels)
        for i, row in zip(members, drawn, strict=True):
            rows[i] = row
    return rows


def balanced_groups(layers: Sequence[int], groups: int) -> list[list[int]]:
    """Levels split into at most `groups` groups of about equal total layers (largest first,
    each to the lightest group), each group in level order; group 0 holds level 0."""
    loads: list[tuple[int, list[int]]] = [(0, []) for _ in range(min(groups, len(layers)))]
    for level in sorted(range(len(layers)), key=lambda l: -layers[l]):
        lightest = min(range(len(loads)), key=lambda k: loads[k][0])
        load, members = loads[lightest]
        loads[lightest] = (load + layers[level], members + [level])
    return sorted((sorted(members) for _, members in loads if members), key=lambda m: m[0])


def _cache_shape(session, path) -> tuple[int, int, int]:
    """(layers, heads, head_dim) of a level graph: its past inputs, key and value per layer,
    are (batch, heads, past, head_dim) with heads and head_dim fixed."""
    inputs = session.get_inputs()
    pasts = inputs[len(LEVEL_INPUTS) :]
    shape = pasts[0].shape if pasts else []
    if (
        not pasts
        or len(pasts) % 2
        or len(shape) != 4
        or not all(isinstance(size, int) for size in (shape[1], shape[3]))
    ):
        raise BundleError(
            f"{path}: not a level graph: expected key and value pairs of past "
            f"inputs (batch, heads, past, head_dim) after {LEVEL_INPUTS}"
        )
    return len(pasts) // 2, shape[1], shape[3]
