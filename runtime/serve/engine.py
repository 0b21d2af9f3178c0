"""The server's streams on one clock: who steps when, and the frames that come out.

Every stream is paced to real time on a shared tick (one token step per frame, `fps` ticks a
second), LEAD steps ahead so that its frames leave before they are due. A new stream catches
up at once (its first frame comes after the decoder's lookahead), then steps on the shared
ticks with all the others. Until its first frame a stream steps alone on the bundle's own
level graphs (cheapest for one row, so the first frame waits on no batch); then streams share
a call when their caches have one layout (mogo.serve.stepper): at the same step during
warm-up, at the same phase after it. A stream takes a few extra steps (more lead, once) to
join a larger group: a warm-up cohort a little ahead, or the common phase, so that past
warm-up one call of each level graph serves them all. Not thread-safe: the server calls it
from one thread.
"""
from __future__ import annotations

import itertools
import math
from concurrent.futures import ThreadPoolExecutor
from collections import Counter, OrderedDict

import numpy as np

from mogo._session import graph_session
from mogo.generator import MotionGenerator
from mogo.motion.features import JointStream
from mogo.motion.feet import LOOKAHEAD as FEET_LOOKAHEAD
from mogo.motion.feet import FootPlanter
from mogo.serve.interior import interior_session
from mogo.serve.newslot import newslot_graph
from mogo.serve.rowwise import rowwise_graph
from mogo.serve.stepper import COMPACT_EVERY, BatchedStream, Stepper
from mogo.stream_decoder import push_many
from mogo.token_generator import TokenGenerator

ALIGN_STEPS = 24  # extra steps a stream may take to join a larger group (1.2 s more lead)
# new streams' solo steps a round (each takes its share, at least one): a lone new stream
# reaches its first frame in two rounds, and a burst of new streams holds up the frames of the
# running ones by about this many one-row steps a round (~20 ms), not by all of theirs
SOLO_STEPS_A_ROUND = 20
SHARD_FROM = 16  # due streams from which a round runs as two shards: a second call of each
# level graph costs ~2 ms of CPU more a round, and below this one core keeps real time easily
EMBEDDINGS_KEPT = 256  # prompt embeddings cached (switching back costs no text encoding)


class ServedStream:
    """One client's stream: tokens (a BatchedStream), its decoder, joints and feet, its
    clock."""

    def __init__(self, engine: Engine, prompt: str, seed: int, sampling, start_tick: int,
                 plant_feet: bool):
        g = engine.generator
        self.id = next(engine._ids)
        self.prompt, self.seed = prompt, seed
        self.tokens: BatchedStream = engine.stepper.start(engine.embedding(prompt), seed,
                                                          sampling)
        self.decoder = g.streaming_decoder(engine.decoder_session)
        self.joints = JointStream(g.skeleton)
        self.feet = FootPlanter(g.skeleton) if plant_feet else None
        self.start_tick, self.extra = start_tick, 0
        self.frames_sent = 0
        self.no_frames = np.zeros((0, g.skeleton.num_joints, 3), np.float32)

    def push(self, row: np.ndarray, bundle) -> np.ndarray:
        """The frames (n, J, 3) that the new token step made final."""
        return self.move(self.decoder.push(row[None]), bundle)

    def move(self, features: np.ndarray, bundle) -> np.ndarray:
        """The frames (n, J, 3) of decoded features (n, D), normalised, made final."""
        if not len(features):  # 7 of every 8 steps: nothing decoded, nothing to move on
            return self.no_frames
        features = features * bundle.std + bundle.mean
        joints = self.joints.push(features)
        if self.feet is not None:
            features, joints = self.feet.push(features, joints)
        self.frames_sent += len(joints)
        return joints


class Engine:
    """All live streams of a server over one MotionGenerator."""

    def __init__(self, generator: MotionGenerator, threads: int = 1,
                 tokens: TokenGenerator | None = None):
        """`tokens`: the bundle's level graphs made row-wise (mogo.serve.rowwise) and returning
        only the new cache slot (mogo.serve.newslot); None makes them."""
        self.generator = generator
        manifest = generator.manifest
        levels = manifest.t2m.levels
        if tokens is None:
            tokens = TokenGenerator([newslot_graph(rowwise_graph(generator.bundle.path(g.file)))
                                     for g in levels], levels, manifest.end_token,
                                    intra_op_threads=1)  # the shards run in parallel
        window = manifest.defaults.window
        if window is None:  # an unbounded cache: every stream would grow without end
            raise ValueError("mogo serve needs a bundle with a KV window (defaults.window)")
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
        self.stepper = Stepper(tokens, window, manifest.t2m.config["max_relative_distance"],
                               solo=generator.tokens.with_level_workers(threads),
                               solo_steps=min(first_frame, window + 1))
        self.streams: dict[int, ServedStream] = {}
        self._pool = ThreadPoolExecutor(1, "mogo-shard") if threads > 1 else None
        self._ids = itertools.count(1)
        self._embeddings: OrderedDict[str, np.ndarray] = OrderedDict()

    def shutdown(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)

    def tick(self, now: float) -> int:
        return math.floor(now * self.fps)

    def embedding(self, prompt: str) -> np.ndarray:
        if prompt not in self._embeddings:
            self._embeddings[prompt] = self.generator.embed([prompt])[0]
            if len(self._embeddings) > EMBEDDINGS_KEPT:
                self._embeddings.popitem(last=False)
        self._embeddings.move_to_end(prompt)
        return self._embeddings[prompt]

    def open(self, prompt: str, seed: int, sampling, now: float, plant_feet: bool = True
             ) -> ServedStream:
        """A new stream (prompt and sampling already checked by the caller)."""
        stream = ServedStream(self, prompt, seed, sampling, self.tick(now), plant_feet)
        self.streams[stream.id] = stream
        return stream

    def switch(self, stream: ServedStream, prompt: str) -> None:
        stream.tokens.set_prompt(self.embedding(prompt))
        stream.prompt = prompt

    def close(self, stream: ServedStream) -> None:
        self.streams.pop(stream.id, None)

    def due(self, now: float) -> list[ServedStream]:
        """The streams behind their target at `now`, and those that take an extra step to
        share the calls of more streams (`_joins`)."""
        tick = self.tick(now)
        keys = Counter(s.tokens.key for s in self.streams.values())
        due = []
        for stream in self.streams.values():
            target = self.lead + stream.extra + tick - stream.start_tick
            if stream.tokens.steps >= target and self._joins(stream, keys):
                stream.extra += 1  # one step beyond the clock: nearer to a larger group
                target += 1
            if stream.tokens.steps < target:
                due.append(stream)
        return due

    def _joins(self, stream: ServedStream, keys: Counter) -> bool:
        """Whether a step takes `stream` towards a larger group of streams: in warm-up, one at
        most ALIGN_STEPS ahead; past it, the most common phase. Bounded: ALIGN_STEPS extra
        steps in warm-up, COMPACT_EVERY more past it (so at most that much more lead)."""
        kind, value = key = stream.tokens.key
        bound = ALIGN_STEPS + (COMPACT_EVERY if kind == "steady" else 0)
        if kind == "solo" or stream.extra >= bound:
            return False
        if kind == "steady":
            phases = Counter({k[1]: n for k, n in keys.items() if k[0] == "steady"})
            return phases.most_common(1)[0][0] != value
        ahead = [(n, k[1]) for k, n in keys.items()
                 if k[0] == "warm" and value < k[1] <= value + ALIGN_STEPS]
        return bool(ahead) and max(ahead)[0] >= keys[key]

    def round(self, due: list[ServedStream]) -> list[tuple[ServedStream, int, np.ndarray]]:
        """One step of each stream in `due`: (stream, index of its first new frame, joints
        (n, J, 3)) for each that made frames."""
        if self._pool is None or len(due) < SHARD_FROM:
            return self._step(due)
        # two shards, each its own calls, sampling and decoding, on two threads: onnxruntime
        # releases the GIL, so one shard's graphs run beside the other's Python. A stream's
        # numbers do not depend on its shard (rows never mix); halves in a stable order keep
        # each shard's batch from the last round (no copy).
        half = len(due) // 2
        other = self._pool.submit(self._step, due[half:])
        return self._step(due[:half]) + other.result()

    def _step(self, due: list[ServedStream]) -> list[tuple]:
        bundle, made = self.generator.bundle, []
        batched = [s for s in due if s.tokens.solo is None]
        solo = [s for s in due if s.tokens.solo is not None]
        for stream in solo:  # a round's solo steps shared among the new streams
            made.append((stream, stream.frames_sent,
                         self._solo_steps(stream, max(1, SOLO_STEPS_A_ROUND // len(solo)))))
        rows = self.stepper.step([s.tokens for s in batched])
        # the windows due decoded in one call (streams in step share their window length)
        decoded = push_many([s.decoder for s in batched], [row[None] for row in rows],
                            self.interior)
        for stream, features in zip(batched, decoded):
            first = stream.frames_sent
            made.append((stream, first, stream.move(features, bundle)))
        return [(stream, first, joints) for stream, first, joints in made if len(joints)]

    def _solo_steps(self, stream: ServedStream, steps: int) -> np.ndarray:
        """Up to `steps` of a new stream's solo steps (mogo.serve.stepper), back to back: its
        clock asks for them all at once (it starts `lead` steps behind)."""
        joints = [stream.no_frames]
        for _ in range(steps):
            if stream.tokens.solo is None:
                break
            joints.append(stream.push(stream.tokens.step_solo(), self.generator.bundle))
        return np.concatenate(joints)
