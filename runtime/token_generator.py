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
from mogo.manifest import BundleError, Graph
from mogo.motion.skeleton import MAX_FRAMES
from mogo.progress import Progress
from mogo.sampling import Sampling, choose_tokens, make_rng, step_uniforms

LEVEL_INPUTS = ["prompt", "uncond", "token_ids", "positions", "past_positions"]  # then the pasts
Cache = list[np.ndarray]  # one level: key, value, key, value, ... (batch, heads, slots, head_dim)


class Stopped(Exception):
    """`generate` was asked to stop by another thread (`mogo serve`, when a client leaves)."""


class TokenGenerator:
    """The level graphs of one model; `start` opens a stream on them (streams share sessions)."""

    def __init__(
        self,
        level_paths: Sequence[str | os.PathLike],
        graphs: Sequence[Graph],
        end_token: int,
        intra_op_threads: int = 1,
        level_workers: int = 1,
        rows_apart: bool = False,
    ):
        """graphs[l]: the input and output names of level l (protocol order).
        level_workers > 1 runs the levels of a step in that many groups at once, balanced by
        layer count (each session then keeps `intra_op_threads`, best 1). rows_apart: batch
        rows never mix inside the graphs (mogo.serve.rowwise), so streams may share a call
        (`step_together`); an int8 graph as exported quantises its whole batch at once."""
        if level_workers < 1:
            raise ValueError(f"level_workers must be >= 1, got {level_workers}")
        if len(level_paths) != len(graphs):
            raise ValueError(f"{len(level_paths)} graph files for {len(graphs)} graph entries")
        self.sessions = [
            graph_session(path, graph, intra_op_threads)
            for path, graph in zip(level_paths, graphs, strict=False)
        ]
        self.graphs = list(graphs)
        self.cache_shapes = [
            _cache_shape(session, path)
            for session, path in zip(self.sessions, level_paths, strict=False)
        ]
        self.end_token = end_token
        self.num_levels = len(graphs)
        self.num_classes = end_token + 1  # level 0's logits: every code and the end token
        self.rows_apart = rows_apart
        self._spread_levels(level_workers)

    def with_level_workers(self, level_workers: int) -> TokenGenerator:
        """The same sessions (no second copy of the weights), levels spread over more or fewer
        workers."""
        if level_workers < 1:
            raise ValueError(f"level_workers must be >= 1, got {level_workers}")
        twin = copy.copy(self)
        twin._spread_levels(level_workers)
        return twin

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
    ) -> tuple[np.ndarray, Cache]:
        """One call of a level graph -> logits of the last position (batch, K[+1]), presents."""
        graph = self.graphs[level]
        feed = dict(
            zip(
                graph.inputs,
                [prompt, uncond, token_ids, positions, past_positions, *past],
                strict=True,
            )
        )  # one array per input, no more
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

    @property
    def layout(self) -> tuple:
        """Streams with equal layouts query at one position over slots at the same positions,
        so they can share a call of each level graph (`step_together`)."""
        return self.steps, self.positions.tobytes()

    def _drawn(
        self, logits: np.ndarray, presents: list[Cache], uniforms: np.ndarray
    ) -> np.ndarray | None:
        """The step after its graph calls: tokens sampled from this stream's logits
        (rows, L, C), its cache moved on by `presents`."""
        g, n = self.generator, self.steps
        forbid = [None if self.allow_end and n > 0 else g.end_token] + [None] * (g.num_levels - 1)
        row = choose_tokens(
            logits[0], logits[1] if self.sampling.guided else None, uniforms, self.sampling, forbid
        )
        if row[0] == g.end_token:
            self.ended = True
            return None
        if self.window is not None and len(self.positions) == 1 + self.window:
            self._overwrite_oldest(presents, n)
        else:
            self.caches = presents
            self.positions = np.append(self.positions, n)
            self.slot_tokens = np.concatenate([self.slot_tokens, self.last[None]])
        self.last, self.steps = row, n + 1
        return row

    def set_prompt(self, prompt_embedding: np.ndarray) -> None:
        """Condition the following steps on a new prompt: one prefill of every cache slot, the
        prefix under the new prompt and the kept steps with their tokens, so the model then sees
        what it would if the stream had been those steps under that prompt (exactly with float
        graphs; int8 graphs round a little differently by slot order and prefill length)."""
        self.prompt = self._batch(prompt_embedding)
        if len(self.positions):  # before the first step there is nothing cached yet
            self._prefill()

    def continue_from(self, tokens: np.ndarray) -> None:
        """Take `tokens` (n, L) as the steps drawn so far (a clip to continue), in place of
        anything drawn before: the next step is step n, seeing them as its past."""
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
        self._prefill()

    def restart(self) -> None:
        """Forget every step drawn (not the random state): the next step is step 0 of a fresh
        clip under the prompt."""
        g, L = self.generator, self.generator.num_levels
        self.caches = [g.empty_cache(level, len(self.uncond)) for level in range(L)]
        self._group = None  # see _step_group
        self.positions = np.zeros(0, np.int64)  # (P,) position of every cache slot
        self.slot_tokens = np.zeros((0, L), np.int64)  # (P, L) the tokens each slot holds
        self.last = np.zeros(L, np.int64)  # tokens of the latest step (none yet: any valid id)
        self.steps = 0  # steps drawn
        self.ended = False
        self._oldest = 1  # with a full window: the slot the next step overwrites
        self.prefilled = 0  # leading slots the last prefill made (the others: one step each)

    def _prefill(self) -> None:
        """Recompute every level's cache for the held slots under the current prompt."""
        g = self.generator
        token_ids = np.repeat(self.slot_tokens[None], len(self.uncond), axis=0)
        none = np.zeros(0, np.int64)
        outputs = g.each_level(
            lambda level: g.run(
                level,
                self.prompt,
                self.uncond,
                token_ids,
                self.positions,
                none,
                g.empty_cache(level, len(self.uncond)),
            )
        )
        self.caches = [present for _, present in outputs]
        self._group = None
        self.prefilled = len(self.positions)

    def rebuild(self) -> None:
        """The cache of the held slots made again as it was made (a resumed stream,
        mogo.stream_state): the prefill of the first `prefilled`, then one step for each slot
        drawn since, so it holds the same numbers and the next draws are the same. After a
        full window's overwrites that history is gone: the whole window is prefilled (as at a
        prompt switch: close, not the same numbers with int8 graphs)."""
        g, positions, tokens = self.generator, self.positions, self.slot_tokens
        made = self.prefilled
        self.positions, self.slot_tokens = positions[:made], tokens[:made]
        if made:
            self._prefill()
        else:
            self.caches = [g.empty_cache(level, len(self.uncond)) for level in range(g.num_levels)]
        for k in range(made, len(positions)):
            self._replay(tokens[k], positions[k : k + 1], positions[:k])
        self.positions, self.slot_tokens, self._group = positions, tokens, None

    def _replay(self, tokens: np.ndarray, position: np.ndarray, past: np.ndarray) -> None:
        """One step's graph calls as `_step_group` made them, tokens given, none drawn."""
        g = self.generator
        ids = np.repeat(tokens[None, None], len(self.uncond), axis=0)
        outputs = g.each_level(
            lambda level: g.run(
                level, self.prompt, self.uncond, ids, position, past, self.caches[level]
            )
        )
        self.caches = [present for _, present in outputs]

    def _overwrite_oldest(self, presents: list[Cache], n: int) -> None:
        """Full window: the new slot (the last of every present) replaces the oldest step slot
        in place; the prefix slot 0 stays. Slots are then in ring order, oldest at _oldest."""
        slot = self._oldest
        for cache, present in zip(self.caches, presents, strict=False):
            for held, new in zip(cache, present, strict=False):
                held[:, :, slot] = new[:, :, -1]
        self.positions[slot] = n
        self.slot_tokens[slot] = self.last
        self._oldest = slot % self.window + 1
        self.prefilled = len(self.positions)  # no longer made by steps from a prefill

    def _batch(self, prompt_embedding: np.ndarray) -> np.ndarray:
        """(text_dim,) -> (B, text_dim) float32, one row per guidance branch."""
        prompt = np.asarray(prompt_embedding, np.float32).reshape(1, -1)
        return np.repeat(prompt, len(self.uncond), axis=0)


def step_together(streams: Sequence[TokenStream]) -> list[np.ndarray | None]:
    """One step of each stream (its tokens (L,), or None where it has ended): the streams of
    one layout share one call of each level graph, their rows stacked. The one token loop:
    TokenStream.step is this for one stream. Streams share a call only on graphs whose rows
    never mix (TokenGenerator.rows_apart), so a stream's tokens never depend on the others."""
    groups: dict[tuple, list[int]] = {}
    for k, stream in enumerate(streams):
        if not stream.ended:
            shared = stream.generator.rows_apart
            key = (id(stream.generator), stream.layout) if shared else id(stream)
            groups.setdefault(key, []).append(k)
    drawn: list[np.ndarray | None] = [None] * len(streams)
    for ks in groups.values():
        for k, row in zip(ks, _step_group([streams[k] for k in ks]), strict=False):
            drawn[k] = row
    return drawn


def _step_group(members: list[TokenStream]) -> list[np.ndarray | None]:
    g, first = members[0].generator, members[0]
    uniforms = [step_uniforms(s.rng, g.num_levels) for s in members]
    rows = np.cumsum([0] + [len(s.uncond) for s in members])

    def stacked(parts: list[np.ndarray]) -> np.ndarray:
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    prompt = stacked([s.prompt for s in members])
    uncond = stacked([s.uncond for s in members])
    token_ids = stacked([np.repeat(s.last[None, None], len(s.uncond), axis=0) for s in members])
    last = first._group  # the members of the last call and its presents, which hold the caches
    if last is not None and last[0] == members and all(s._group is last for s in members):
        caches = last[1]  # the same streams in the same order: their caches as they lie, no copy
    else:
        caches = [
            [stacked(parts) for parts in zip(*(s.caches[level] for s in members), strict=False)]
            for level in range(g.num_levels)
        ]
    position, past = np.array([first.steps], np.int64), first.positions
    outputs = g.each_level(
        lambda level: g.run(level, prompt, uncond, token_ids, position, past, caches[level])
    )
    logits = np.full((len(uncond), g.num_levels, g.num_classes), -np.inf, np.float32)
    for level, (level_logits, _) in enumerate(outputs):
        logits[:, level, : level_logits.shape[1]] = level_logits
    drawn = [
        s._drawn(logits[a:b], [[held[a:b] for held in present] for _, present in outputs], u)
        for s, a, b, u in zip(members, rows[:-1], rows[1:], uniforms, strict=False)
    ]
    group = (members, [present for _, present in outputs])
    for stream, row in zip(
        members, drawn, strict=False
    ):  # the presents are their caches (not a full window)
        took = row is not None and len(stream.positions) > len(past)
        stream._group = group if took and len(members) > 1 else None
    return drawn


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
    pasts = session.get_inputs()[len(LEVEL_INPUTS) :]
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
