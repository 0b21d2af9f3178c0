"""The server's streams on one clock: who steps when, and the frames that come out.

A served stream is a MotionStream (re-anchored, mogo.anchoring), the same stream as
`mogo stream`'s: its level graphs are only rewritten (mogo.serve.pooled) so that streams at any
step of their clips share a call without their numbers mixing, their caches rows of one pool
(mogo.kv_pool). Every stream is paced to real time on a shared tick (one token step per frame,
`fps` ticks a second), its `lead` steps ahead so that its frames leave before they are due. A
new stream catches up at once (its first frame comes after the decoder's lookahead and the
feet's), in rounds shared with every other new stream and with the running streams; while
streams run, a round takes in only as many new ones as leave it about a tick long (`due`), so
a burst of arrivals does not hold the running ones back. What is due is decoded in one call
per decoder (mogo.stream_decoder.push_many): the centred one's windows, and the low-latency
one's tokens (its step graph) for streams that ask for it; the joints of a round's streams
come in one pass (mogo.generator.emit_together). With two threads a call's levels run in two
groups at once, every row in each (TokenGenerator level workers), so calls stay whole: each
has a fixed cost. Not thread-safe: the server calls it from one thread.
"""

from __future__ import annotations

import itertools
import math
import time

import numpy as np
from threadpoolctl import threadpool_limits

from mogo._session import graph_session
from mogo.anchoring import Anchoring
from mogo.generator import MotionGenerator, MotionStream, drawn_together, emit_together
from mogo.serve.interior import interior_session
from mogo.serve.pooled import pooled_levels, pooled_stages
from mogo.stream_decoder import push_many
from mogo.stream_state import State
from mogo.token_generator import TokenGenerator

ROUND_TICKS = 1.0  # with streams running, a round lasts about this many ticks at most: the
# streams catching up (new ones) share what the running ones leave of it
MIN_CATCH_UP = 4  # streams catching up in a round at the least, however busy the server


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
        low_latency: bool = False,
        resumed: State | None = None,
    ):
        """`resumed`: a stream state (mogo.stream_state) to go on from, read and checked;
        `low_latency`: decoded by the bundle's low-latency decoder (ValueError: it has none)."""
        g = engine.generator
        # guided: alone on the bundle's own graphs, which quantise its two rows (conditional
        # and not) together, as MotionStream's do; the row-wise graphs would not
        self.pooled = not sampling.guided
        tokens = engine.tokens if self.pooled else None
        if resumed is not None and self.pooled:  # its cache made in a pool of its own, off
            tokens = tokens.with_own_pool()  # the engine's thread; `resume` moves it in
        super().__init__(
            g,
            prompt,
            seed,
            sampling,
            resumed.window if resumed else g.defaults.window,
            plant_feet,
            resumed.anchoring if resumed else Anchoring(),
            low_latency,
            tokens=tokens,
            decoder_session=engine.decoder_session(low_latency),
        )
        if resumed is not None:
            resumed.restore(self)
        self.id = next(engine._ids)
        self.start_tick = start_tick
        self.send_from = 0  # frames before this one are not sent (a resume's client has them)
        self.low_latency = low_latency
        # its first frame after this many steps (its own decoder's and planter's lookahead),
        # then frames a burst (`every` steps) apart: two bursts more keep them ahead of time
        self.lead = self.lookahead_steps + 1 + 2 * self.decoder.every

    @property
    def prompt(self) -> str:
        """The client's latest prompt."""
        return self.prompts[-1][1]


def pooled_tokens(generator: MotionGenerator, signed: bool | None = None) -> TokenGenerator:
    """The bundle's level graphs pooled (mogo.serve.pooled) for an Engine, a call of one row on
    the generator's own (`alone`); `signed`: the pooled graphs' weights int8 or uint8 (None:
    int8 where this CPU multiplies them exactly, mogo.serve.rowwise; the bench compares both)."""
    levels = generator.manifest.t2m.levels
    return TokenGenerator(
        [pooled_stages(generator.bundle.path(g.file), signed) for g in levels],
        pooled_levels(levels),
        generator.manifest.end_token,
        intra_op_threads=1,  # the level groups run in parallel
        pooled=True,
        alone=generator.tokens.with_level_workers(1),  # its sessions: no second copy
    )


class Engine:
    """All live streams of a server over one MotionGenerator."""

    def __init__(
        self, generator: MotionGenerator, threads: int = 1, tokens: TokenGenerator | None = None
    ):
        """`tokens`: the bundle's level graphs pooled (`pooled_tokens`); None makes them.
        The engine's own pool over their sessions, a call's levels in `threads` groups."""
        self.generator = generator
        manifest = generator.manifest
        # numpy's BLAS on one thread while the engine runs: its level groups fill the cores, and
        # OpenBLAS's own workers, woken by the rounds' small products, spun beside them
        self._blas = threadpool_limits(1, user_api="blas")
        tokens = pooled_tokens(generator) if tokens is None else tokens
        self.tokens = tokens.with_own_pool().with_level_workers(threads)
        self.fps = generator.fps
        decoder = manifest.vq.decoder
        # one thread a call: the level groups fill the cores, and a second intra-op thread measured
        # ~30% more CPU a decode for no gain in time (the same features)
        path = generator.bundle.path(decoder.file)
        self._centred = graph_session(path, decoder, 1)
        # full windows unpadded: ~half the CPU (None: a decoder it cannot cut, whole windows)
        self.interior = interior_session(path, decoder, self._centred, generator.codebook_size)
        # its own session, only if the bundle has one: the graph MotionGenerator steps
        # low-latency streams with (a token a call where the bundle has it, else windows)
        low = generator.low_latency_graph
        self._low_latency = (
            None if low is None else graph_session(generator.bundle.path(low.file), low, 1)
        )
        self.streams: dict[int, ServedStream] = {}
        self._step_seconds: float | None = None  # wall time per stream step, rounds' mean
        self._ids = itertools.count(1)

    @property
    def low_latency(self) -> bool:
        """Whether this engine's bundle has a low-latency decoder (streams may ask for it)."""
        return self._low_latency is not None

    def decoder_session(self, low_latency: bool):
        """The session of the decoder a stream asks for: ValueError where there is none."""
        if not low_latency:
            return self._centred
        if self._low_latency is None:
            raise ValueError(
                "this server's bundle has no low-latency decoder (manifest "
                "vq.low_latency_decoder); stream without low latency"
            )
        return self._low_latency

    def shutdown(self) -> None:
        self.tokens.shutdown()
        self._blas.restore_original_limits()

    def tick(self, now: float) -> int:
        return math.floor(now * self.fps)

    def open(
        self,
        prompt: str,
        seed: int,
        sampling,
        now: float,
        plant_feet: bool = True,
        low_latency: bool = False,
    ) -> ServedStream:
        """A new stream (prompt and sampling already checked by the caller); ValueError for
        `low_latency` where the bundle has no such decoder."""
        stream = ServedStream(self, prompt, seed, sampling, self.tick(now), plant_feet, low_latency)
        self.streams[stream.id] = stream
        return stream

    def restore(self, state: State) -> ServedStream:
        """A stream going on from `state` (its prompt checked by the caller), its cache made
        again (tens of ms: on any thread, the engine's goes on stepping); `resume` starts it."""
        return ServedStream(
            self,
            state.prompt,
            state.seed,
            state.sampling,
            0,
            state.plant_feet,
            state.low_latency,
            state,
        )

    def resume(self, stream: ServedStream, now: float, send_from: int) -> None:
        """Start a restored stream, sending frames from `send_from` on: it catches up at once
        to where a stream of its steps would be, and past the frames its client has."""
        ahead = max(0, send_from - stream.frames_emitted) // self.generator.down_factor
        stream.start_tick = self.tick(now) - stream.steps - ahead
        stream.send_from = send_from
        if stream.pooled:
            stream.tokens.move_to(self.tokens)
        self.streams[stream.id] = stream

    def switch(self, stream: ServedStream, prompt: str) -> None:
        stream.switch_prompt(prompt)

    def close(self, stream: ServedStream) -> None:
        if self.streams.pop(stream.id, None) is not None and stream.pooled:
            self.tokens.pool.remove(stream.tokens)

    def due(self, now: float) -> list[ServedStream]:
        """The streams behind their target at `now` that the next round steps: every running
        one (its frames flowing), and of those catching up (no frame yet: new streams) the
        oldest, as many as fit beside them in a round of ROUND_TICKS. So a burst of arrivals
        catches up in the time the running streams leave, and they keep their clock."""
        tick = self.tick(now)
        behind = [s for s in self.streams.values() if s.steps < s.lead + tick - s.start_tick]
        if self._step_seconds is None or not any(s.frames_emitted for s in self.streams.values()):
            return behind  # an idle server: the whole burst at once
        running = [s for s in behind if s.frames_emitted]  # due now (or none: a round between)
        room = ROUND_TICKS / self.fps / self._step_seconds - len(running)
        catching_up = [s for s in behind if not s.frames_emitted]
        return running + catching_up[: max(MIN_CATCH_UP, int(room))]

    def round(self, due: list[ServedStream]) -> list[tuple[ServedStream, int, np.ndarray]]:
        """One step of each stream in `due`: (stream, index of its first new frame, joints
        (n, J, 3)) for each that made frames."""
        start = time.perf_counter()
        made = self._step(due)
        if due:  # a running mean, for `due`
            seconds = (time.perf_counter() - start) / len(due)
            last = self._step_seconds
            self._step_seconds = seconds if last is None else 0.8 * last + 0.2 * seconds
        return made

    def _step(self, due: list[ServedStream]) -> list[tuple]:
        """MotionStream.step for many streams: the token rows of one layout drawn in one call,
        the windows due decoded in one call per decoder."""
        rows = drawn_together(due)
        decoded = [None] * len(due)
        for low_latency, interior in ((False, self.interior), (True, None)):
            ks = [k for k, stream in enumerate(due) if stream.low_latency is low_latency]
            frames = push_many([due[k].decoder for k in ks], [rows[k][None] for k in ks], interior)
            for k, features in zip(ks, frames, strict=True):
                decoded[k] = features
        firsts = [stream.frames_emitted for stream in due]
        frames = emit_together(due, [row[None] for row in rows], decoded)
        return [
            (stream, first, joints)
            for stream, first, joints in zip(due, firsts, frames, strict=True)
            if len(joints)
        ]
