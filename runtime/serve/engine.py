"""The server's streams on one clock: who steps when, and the frames that come out.

A served stream is a MotionStream (re-anchored, mogo.anchoring), the same stream as
`mogo stream`'s: its level graphs are only made row-wise (mogo.serve.rowwise) so that streams
can share a call without their numbers mixing. Every stream is paced to real time on a shared
tick (one token step per frame, `fps` ticks a second), LEAD steps ahead so that its frames
leave before they are due. A new stream catches up at once (its first frame comes after the
decoder's lookahead), then steps on the shared ticks with all the others. Streams whose caches
have one layout share one call of each level graph (mogo.token_generator.step_together): a
re-anchored cache is the prefix and the steps since its clip started, so that is streams at
the same step of their clips. A stream takes a few extra steps (more lead, once) to join a
larger group a little ahead. The windows due are decoded in one call
(mogo.stream_decoder.push_many). Not thread-safe: the server calls it from one thread.
"""
from __future__ import annotations

import itertools
import math
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from mogo._session import graph_session
from mogo.anchoring import Anchoring
from mogo.generator import MotionGenerator, MotionStream
from mogo.motion.feet import LOOKAHEAD as FEET_LOOKAHEAD
from mogo.serve.interior import interior_session
from mogo.serve.rowwise import rowwise_graph
from mogo.stream_decoder import push_many
from mogo.token_generator import TokenGenerator, step_together

ALIGN_STEPS = 24  # extra steps a stream may take to join a larger group (1.2 s more lead)
SHARD_FROM = 16  # due streams from which a round runs as two shards: a second call of each
# level graph costs ~2 ms of CPU more a round, and below this one core keeps real time easily


class ServedStream(MotionStream):
    """One client's stream: a MotionStream on the engine's graphs, and its clock."""

    def __init__(self, engine: Engine, prompt: str, seed: int, sampling, start_tick: int,
                 plant_feet: bool):
        g = engine.generator
        # guided: alone on the bundle's own graphs, which quantise its two rows (conditional
        # and not) together, as MotionStream's do; the row-wise graphs would not
        super().__init__(g, prompt, seed, sampling, g.defaults.window, plant_feet, Anchoring(),
                         tokens=None if sampling.guided else engine.tokens,
                         decoder_session=engine.decoder_session)
        self.id = next(engine._ids)
        self.start_tick, self.extra = start_tick, 0

    @property
    def prompt(self) -> str:
        """The client's latest prompt."""
        return self.prompts[-1][1]


class Engine:
    """All live streams of a server over one MotionGenerator."""

    def __init__(self, generator: MotionGenerator, threads: int = 1,
                 tokens: TokenGenerator | None = None):
        """`tokens`: the bundle's level graphs made row-wise (mogo.serve.rowwise); None makes
        them."""
        self.generator = generator
        manifest = generator.manifest
        levels = manifest.t2m.levels
        if tokens is None:
            tokens = TokenGenerator([rowwise_graph(generator.bundle.path(g.file))
                                     for g in levels], levels, manifest.end_token,
                                    intra_op_threads=1,  # the shards run in parallel
                                    rows_apart=True)
        self.tokens = tokens
        self.fps = generator.fps
        decoder = manifest.vq.decoder
        # one thread a call: the shards fill the cores, and a second intra-op thread measured
        # ~30% more CPU a decode for no gain in time (the same features)
        path = generator.bundle.path(decoder.file)
        self.decoder_session = graph_session(path, decoder, 1)
        # full windows unpadded: ~half the CPU (None: a decoder it cannot cut, whole windows)
        self.interior = interior_session(path, decoder, self.decoder_session,
                                         generator.codebook_size)
        first_frame = decoder.lookahead + 1 + math.ceil(FEET_LOOKAHEAD / generator.down_factor)
        self.lead = first_frame + 2 * generator.streaming_decoder().every
        self.streams: dict[int, ServedStream] = {}
        self._pool = ThreadPoolExecutor(1, "mogo-shard") if threads > 1 else None
        self._ids = itertools.count(1)

    def shutdown(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)

    def tick(self, now: float) -> int:
        return math.floor(now * self.fps)

    def open(self, prompt: str, seed: int, sampling, now: float, plant_feet: bool = True
             ) -> ServedStream:
        """A new stream (prompt and sampling already checked by the caller)."""
        stream = ServedStream(self, prompt, seed, sampling, self.tick(now), plant_feet)
        self.streams[stream.id] = stream
        return stream

    def switch(self, stream: ServedStream, prompt: str) -> None:
        stream._switch_prompt(prompt)

    def close(self, stream: ServedStream) -> None:
        self.streams.pop(stream.id, None)

    def due(self, now: float) -> list[ServedStream]:
        """The streams behind their target at `now`, and those that take an extra step to
        share the calls of more streams (`_joins`)."""
        tick = self.tick(now)
        steps = Counter(s._tokens.steps for s in self.streams.values())
        due = []
        for stream in self.streams.values():
            target = self.lead + stream.extra + tick - stream.start_tick
            if stream.steps >= target and self._joins(stream, steps):
                stream.extra += 1  # one step beyond the clock: nearer to a larger group
                target += 1
            if stream.steps < target:
                due.append(stream)
        return due

    def _joins(self, stream: ServedStream, steps: Counter) -> bool:
        """Whether a step takes `stream` towards a larger group of streams at most
        ALIGN_STEPS ahead in their clips. Bounded: ALIGN_STEPS extra steps in a stream's life
        (so at most that much more lead)."""
        if stream.extra >= ALIGN_STEPS:
            return False
        n = stream._tokens.steps
        ahead = [(count, m) for m, count in steps.items() if n < m <= n + ALIGN_STEPS]
        return bool(ahead) and max(ahead)[0] >= steps[n]

    def round(self, due: list[ServedStream]) -> list[tuple[ServedStream, int, np.ndarray]]:
        """One step of each stream in `due`: (stream, index of its first new frame, joints
        (n, J, 3)) for each that made frames."""
        if self._pool is None or len(due) < SHARD_FROM:
            return self._step(due)
        # two shards, each its own calls, sampling and decoding, on two threads: onnxruntime
        # releases the GIL, so one shard's graphs run beside the other's Python. A stream's
        # numbers do not depend on its shard (rows never mix).
        half = len(due) // 2
        other = self._pool.submit(self._step, due[half:])
        return self._step(due[:half]) + other.result()

    def _step(self, due: list[ServedStream]) -> list[tuple]:
        """MotionStream.step for many streams: the token rows of one layout drawn in one call,
        the windows due decoded in one call."""
        rows = [stream._drawn(row) for stream, row in
                zip(due, step_together([stream._tokens for stream in due]))]
        decoded = push_many([s._decoder for s in due], [row[None] for row in rows],
                            self.interior)
        made = []
        for stream, row, features in zip(due, rows, decoded):
            first = stream.frames_emitted
            joints = stream._emit(row[None], features)
            if len(joints):
                made.append((stream, first, joints))
        return made
