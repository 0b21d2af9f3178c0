"""The server's streams on one clock: who steps when, and the frames that come out.

A served stream is a MotionStream (re-anchored, mogo.anchoring), the same stream as
`mogo stream`'s: its level graphs are only made row-wise (mogo.serve.rowwise) so that streams
can share a call without their numbers mixing. Every stream is paced to real time on a shared
tick (one token step per frame, `fps` ticks a second), LEAD steps ahead so that its frames
leave before they are due. A new stream catches up at once (its first frame comes after the
decoder's lookahead), then steps on the shared ticks with all the others. Streams whose caches
have one layout share one call of each level graph (mogo.token_generator.step_together): a
re-anchored cache is the prefix and the steps since its clip started, so that is streams at
the same step of their clips. A stream on its clock takes a step more to join a larger group
a little ahead, or waits a tick for one behind (its lead between LEAD and LEAD +
ALIGN_STEPS): fresh clips and holds start at the model's own times and scatter the streams
again and again. The windows due are decoded in one call
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
from mogo.stream_state import State
from mogo.token_generator import TokenGenerator, step_together

ALIGN_STEPS = 24  # extra lead a stream may take to join a larger group (1.2 s at most)
SHARD_FROM = 16  # due streams from which a round runs as two shards: a second call of each
# level graph costs ~2 ms of CPU more a round, and below this one core keeps real time easily


class ServedStream(MotionStream):
    """One client's stream: a MotionStream on the engine's graphs, and its clock."""

    def __init__(
        self,
        engine: Engine,
        prompt: str,
        seed: int,
        sampling,
        start_tick: int,
        plant_feet: bool,
        resumed: State | None = None,
    ):
        """`resumed`: a stream state (mogo.stream_state) to go on from, read and checked."""
        g = engine.generator
        # guided: alone on the bundle's own graphs, which quantise its two rows (conditional
        # and not) together, as MotionStream's do; the row-wise graphs would not
        super().__init__(
            g,
            prompt,
            seed,
            sampling,
            resumed.window if resumed else g.defaults.window,
            plant_feet,
            resumed.anchoring if resumed else Anchoring(),
            tokens=None if sampling.guided else engine.tokens,
            decoder_session=engine.decoder_session,
        )
        if resumed is not None:
            resumed.restore(self)
        self.id = next(engine._ids)
        self.start_tick, self.extra = start_tick, 0
        self.send_from = 0  # frames before this one are not sent (a resume's client has them)

    @property
    def prompt(self) -> str:
        """The client's latest prompt."""
        return self.prompts[-1][1]


class Engine:
    """All live streams of a server over one MotionGenerator."""

    def __init__(
        self, generator: MotionGenerator, threads: int = 1, tokens: TokenGenerator | None = None
    ):
        """`tokens`: the bundle's level graphs made row-wise (mogo.serve.rowwise); None makes
        them."""
        self.generator = generator
        manifest = generator.manifest
        levels = manifest.t2m.levels
        if tokens is None:
            tokens = TokenGenerator(
                [rowwise_graph(generator.bundle.path(g.file)) for g in levels],
                levels,
                manifest.end_token,
                intra_op_threads=1,  # the shards run in parallel
                rows_apart=True,
            )
        self.tokens = tokens
        self.fps = generator.fps
        decoder = manifest.vq.decoder
        # one thread a call: the shards fill the cores, and a second intra-op thread measured
        # ~30% more CPU a decode for no gain in time (the same features)
        path = generator.bundle.path(decoder.file)
        self.decoder_session = graph_session(path, decoder, 1)
        # full windows unpadded: ~half the CPU (None: a decoder it cannot cut, whole windows)
        self.interior = interior_session(
            path, decoder, self.decoder_session, generator.codebook_size
        )
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

    def open(
        self, prompt: str, seed: int, sampling, now: float, plant_feet: bool = True
    ) -> ServedStream:
        """A new stream (prompt and sampling already checked by the caller)."""
        stream = ServedStream(self, prompt, seed, sampling, self.tick(now), plant_feet)
        self.streams[stream.id] = stream
        return stream

    def restore(self, state: State) -> ServedStream:
        """A stream going on from `state` (its prompt checked by the caller), its cache made
        again (tens of ms: on any thread, the engine's goes on stepping); `resume` starts it."""
        return ServedStream(
            self, state.prompt, state.seed, state.sampling, 0, state.plant_feet, state
        )

    def resume(self, stream: ServedStream, now: float, send_from: int) -> None:
        """Start a restored stream, sending frames from `send_from` on: it catches up at once
        to where a stream of its steps would be, and past the frames its client has."""
        ahead = max(0, send_from - stream.frames_emitted) // self.generator.down_factor
        stream.start_tick = self.tick(now) - stream.steps - ahead
        stream.send_from = send_from
        self.streams[stream.id] = stream

    def switch(self, stream: ServedStream, prompt: str) -> None:
        stream.switch_prompt(prompt)

    def close(self, stream: ServedStream) -> None:
        self.streams.pop(stream.id, None)

    def due(self, now: float) -> list[ServedStream]:
        """The streams behind their target at `now`, and those that take an extra step to
        share the calls of more streams (`_joins`)."""
        tick = self.tick(now)
        steps = Counter(s.tokens.steps for s in self.streams.values())
        due = []
        for stream in self.streams.values():
            target = self.lead + stream.extra + tick - stream.start_tick
            if stream.steps >= target - 1:  # on its clock: it may move towards a group
                move = self._move(stream, steps, stream.steps >= target)
                stream.extra += move
                target += move
            if stream.steps < target:
                due.append(stream)
        return due

    def _move(self, stream: ServedStream, steps: Counter, idle: bool) -> int:
        """+1: a step beyond the clock (when `idle`) towards a larger group ahead in their
        clips; -1: a tick's wait (when due) for a larger group behind; 0: neither. The lead
        stays between `lead` and `lead` + ALIGN_STEPS: clips restart at the model's own
        times, so a stream moves again and again."""
        n = stream.tokens.steps
        if idle:
            room = range(n + 1, n + 1 + ALIGN_STEPS - stream.extra)
        else:
            room = range(n - stream.extra, n)
        larger = [count for m, count in steps.items() if m in room]
        if not larger or max(larger) < steps[n] + (0 if idle else 1):
            return 0
        return 1 if idle else -1

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
        rows = [
            stream.drawn(row)
            for stream, row in zip(
                due, step_together([stream.tokens for stream in due]), strict=False
            )
        ]
        decoded = push_many([s.decoder for s in due], [row[None] for row in rows], self.interior)
        made = []
        for stream, row, features in zip(due, rows, decoded, strict=False):
            first = stream.frames_emitted
            joints = stream.emit(row[None], features)
            if len(joints):
                made.append((stream, first, joints))
        return made
