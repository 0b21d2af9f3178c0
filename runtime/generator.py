"""The public runtime: text in, motion out, on onnxruntime and numpy.

    generator = MotionGenerator.load()                    # the bundle shipped with the package
    motion = generator.generate("a person walks forward, then waves", seconds=6, seed=0)
    motion.save_bvh("walk.bvh")

    stream = generator.stream("a person jogs in a circle", seed=1)
    for frame in stream.frames():                          # (J, 3) joints, forever
        ...
        stream.set_prompt("a person jumps")                # from the next step on

Tokens come from the level graphs one step at a time (mogo.token_generator), frames
from the VQ decoder as soon as their right context exists (mogo.stream_decoder), joints
from the features with the root carried across chunks (mogo.motion.features.JointStream).
"""

from __future__ import annotations

import math
import os
import threading
import warnings
from collections import OrderedDict
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np
import onnxruntime as ort

from mogo._session import NamedGraph, check_types, graph_session
from mogo.align import Alignment, PromptAligner, RuleAligner
from mogo.anchoring import Anchor, Anchoring
from mogo.arguments import (
    CutWarning,
    ScheduleError,
    checked_bool,
    checked_int,
    checked_prompt,
    checked_schedule,
    checked_seconds,
    plural,
)
from mogo.bundle import Bundle, BundleError
from mogo.clip import Motion
from mogo.manifest import MAX_GENERATE_SECONDS, StepDecoderGraph, io_types
from mogo.motion.features import JointStream, joints_together
from mogo.motion.feet import SHORT, WINDOW, FootPlanter, planted, push_together
from mogo.motion.untrusted import checked_finite
from mogo.progress import Progress
from mogo.repertoire import Familiarity
from mogo.sampling import Sampling
from mogo.stream_decoder import StepDecoder, StreamingDecoder
from mogo.stream_state import StateError
from mogo.stream_state import read as read_state
from mogo.stream_state import write as write_state
from mogo.text_side import TextSide
from mogo.token_generator import (
    Stopped,
    TokenGenerator,
    TokenStream,
    prefill_together,
    step_together,
)

DEFAULT_BUNDLE = Path(__file__).parent / "default_bundle"
MAX_THREADS = 256  # more cores than a CPU has: beyond, the thread pools alone exhaust memory
STREAM_DECODE_EVERY = 8  # tokens per streaming decode: a window costs ~the same for 1 or 8
# (a low-latency stream decodes every token: waiting for 8 would undo most of what it gains)
EMBEDDINGS_KEPT = 256  # prompt embeddings kept for streams (a switch back encodes no text)


class MotionGenerator:
    """One loaded bundle. Sessions are shared: any number of streams, also in parallel
    threads, each with its own cache and random state.

    `threads`: the cores one generation may use. The level graphs of a step then run in that
    many groups at once, each on one core (on 2 cores this beat onnxruntime's own threads for
    every model size measured, docs/performance.md); the other graphs get that many
    intra-op threads. Tokens do not depend on it."""

    def __init__(self, bundle: Bundle, threads: int = 1):
        self.bundle = bundle
        manifest = self.manifest = bundle.manifest
        self.skeleton = manifest.skeleton()
        self.fps = manifest.fps
        self.defaults = manifest.defaults
        self.text = TextSide(bundle, threads)
        self.tokenizer, self.repertoire = self.text.tokenizer, self.text.repertoire
        levels = manifest.t2m.levels
        self.tokens = TokenGenerator(
            [bundle.path(g.file) for g in levels],
            levels,
            manifest.end_token,
            intra_op_threads=1,
            level_workers=threads,
        )
        for graph, session in zip(levels, self.tokens.sessions, strict=False):
            check_types(bundle.path(graph.file), session, io_types(manifest, graph))
        self.down_factor = manifest.vq.down_factor
        self._decoder = manifest.vq.decoder
        self._decoder_session = graph_session(
            bundle.path(self._decoder.file),
            self._decoder,
            threads,
            io_types(manifest, self._decoder),
        )
        # what low-latency streams decode with: the step graph, else the window graph; None: none
        self.low_latency_graph = manifest.vq.low_latency_step or manifest.vq.low_latency_decoder
        self._low_latency_session = (
            None
            if self.low_latency_graph is None
            else graph_session(
                bundle.path(self.low_latency_graph.file),
                self.low_latency_graph,
                1 if manifest.vq.low_latency_step else threads,  # a column a layer: too small
                io_types(manifest, self.low_latency_graph),
            )
        )
        self._vq_encoder = NamedGraph(bundle, manifest.vq.encoder, threads)
        self.codebook_size = manifest.vq.codebook_size
        self._embeddings: OrderedDict[str, np.ndarray] = OrderedDict()
        self._embeddings_lock = threading.Lock()

    @classmethod
    def load(cls, bundle_dir: str | os.PathLike | None = None, threads: int = 1) -> MotionGenerator:
        """Load and verify a bundle folder; None: the default bundle shipped with mogo."""
        if bundle_dir is None:
            if not (DEFAULT_BUNDLE / "manifest.json").is_file():
                raise BundleError(
                    f"no default bundle is installed at {DEFAULT_BUNDLE}; "
                    "pass the path of a bundle folder"
                )
            bundle_dir = DEFAULT_BUNDLE
        return cls(Bundle.load(bundle_dir), checked_int(threads, "threads", 1, MAX_THREADS))

    # -- text --------------------------------------------------------------------------------
    def embed(self, texts: Sequence[str]) -> np.ndarray:
        """Prompt embeddings (B, text_dim) float32."""
        return self.text.embed(texts)

    def _embedding(self, text: str) -> np.ndarray:
        """One prompt's embedding (text_dim,), read-only, the last EMBEDDINGS_KEPT kept:
        streams switch back and forth between few prompts, and every stream of a server
        starts from one."""
        with self._embeddings_lock:
            if text in self._embeddings:
                self._embeddings.move_to_end(text)
                return self._embeddings[text]
        embedding = self.embed([text])[0]
        embedding.flags.writeable = False
        with self._embeddings_lock:
            self._embeddings[text] = embedding
            if len(self._embeddings) > EMBEDDINGS_KEPT:
                self._embeddings.popitem(last=False)
        return embedding

    def vocabulary(self) -> set[str]:
        """The whole words of the tokenizer the model was trained with (what prompt alignment
        aims at)."""
        return self.text.vocabulary()

    def known(self, prompt: str) -> Familiarity | None:
        """How close `prompt` is to what the model was trained on (mogo.repertoire): the
        score, the threshold and the nearest training captions; None for a bundle without a
        repertoire (a text encoder trained with the model: see its PromptWarning instead)."""
        if self.repertoire is None:
            return None
        return self.text.familiarity(checked_prompt(prompt, "prompt"))

    def aligner(self, align: bool | PromptAligner) -> PromptAligner | None:
        """align=True: the rules on this bundle's vocabulary; an aligner: itself."""
        if isinstance(align, PromptAligner):
            return align
        if align is True:
            return RuleAligner(self.vocabulary(), self.defaults.max_seconds)
        if align is False or align is None:
            return None
        raise ValueError(f"align must be True, False or a PromptAligner, got {align!r}")

    # -- whole clips ---------------------------------------------------------------------------
    def generate(
        self,
        text: str,
        seconds: float | None = None,
        seed: int | None = None,
        sampling: Sampling | None = None,
        align: bool | PromptAligner = False,
        plant_feet: bool = True,
        stop=None,
        progress: bool = False,
        **options,
    ) -> Motion:
        """One prompt -> one Motion. seconds=None lets the model end the motion (at most the
        bundle's max_seconds: a CutWarning where it did not); longer than max_seconds, it is
        the first `seconds` of `stream(text, seed=seed)`, re-anchored (the model learnt clips
        of at most max_seconds: one clip that long drifts into other actions); seed=None
        draws a fresh seed, kept in Motion.seed so the result can be reproduced. `sampling`
        and the keyword `options`: see `sampling()`.
        align=True (or a PromptAligner) rewrites the prompt into caption-style steps (see
        mogo.align), played as one motion by `play`; the steps are kept in Motion.alignment.
        plant_feet=False keeps the joints as decoded (see mogo.motion.feet); the same for
        every method that makes motion. stop: a threading.Event another thread may set to
        end the work early (mogo.token_generator.Stopped is raised; `mogo serve` sets it when
        a client leaves). progress=True: a progress line on stderr while the token steps are
        drawn (minutes, for a long clip)."""
        sampling = self.sampling(sampling, **options)
        seconds = None if seconds is None else self._seconds(seconds)
        seed = checked_seed(seed)
        aligner = self.aligner(align)
        plant_feet = checked_bool(plant_feet, "plant_feet")
        text = checked_prompt(text) if aligner else self.read_prompt(text)
        return self._generate(
            text,
            seconds,
            seed,
            sampling,
            aligner,
            plant_feet,
            stop,
            checked_bool(progress, "progress"),
        )

    def _generate(
        self,
        text: str,
        seconds: float | None,
        seed: int,
        sampling: Sampling,
        aligner: PromptAligner | None,
        plant_feet: bool,
        stop=None,
        progress: bool = False,
    ) -> Motion:
        if aligner is not None:
            return self._play_aligned(
                aligner.align(text), seconds, seed, sampling, plant_feet, progress
            )
        max_steps = self._steps(self.defaults.max_seconds)
        if seconds is not None and self._steps(seconds) > max_steps:
            motion = self._play([(text, seconds)], seed, sampling, plant_feet, progress, stop)
            return self._cut(motion, round(seconds * self.fps))
        steps = None if seconds is None else self._steps(seconds)
        if steps is not None:  # a cut, not an end: the model goes on for the decoder's context
            steps += self._decoder.lookahead
        tokens = self.tokens.generate(
            self.embed([text])[0],
            steps,
            max_steps,
            sampling,
            seed,
            self.defaults.window,
            stop,
            progress,
        )
        if steps is None and len(tokens) == max_steps:
            warnings.warn(
                f"the model did not end the motion within "
                f"{self.defaults.max_seconds:g} s, its longest clip: cut there; ask "
                f"for seconds for longer motion",
                CutWarning,
                stacklevel=4,
            )
        frames = None if seconds is None else round(seconds * self.fps)
        return self.decode(tokens, [(0, text)], frames, seed, plant_feet)

    def generate_batch(
        self,
        texts: Sequence[str],
        seconds: float | None = None,
        seed: int | None = None,
        sampling: Sampling | None = None,
        align: bool | PromptAligner = False,
        plant_feet: bool = True,
        **options,
    ) -> list[Motion]:
        """`generate` for each prompt, in order: prompt k with seed + k (seed=None: one fresh
        seed for the batch), so any of them can be reproduced alone."""
        if isinstance(texts, str):
            raise ValueError("generate_batch takes a list of prompts; generate takes one")
        if not isinstance(texts, Iterable):
            raise TypeError(f"texts must be a list of prompts, got {type(texts).__name__}")
        if not (texts := list(texts)):
            raise ValueError("no prompt given")
        sampling = self.sampling(sampling, **options)
        seconds = None if seconds is None else self._seconds(seconds)
        seed = checked_seed(seed)
        aligner = self.aligner(align)
        plant_feet = checked_bool(plant_feet, "plant_feet")
        for k, text in enumerate(texts):  # not a comprehension: its own frame (Python 3.11)
            # would put a prompt's warning inside mogo instead of at the caller's line
            texts[k] = (
                checked_prompt(text, f"texts[{k}]")
                if aligner
                else self.read_prompt(text, f"texts[{k}]")
            )
        return [
            self._generate(text, seconds, seed + k, sampling, aligner, plant_feet)
            for k, text in enumerate(texts)
        ]

    def _play_aligned(
        self,
        alignment: Alignment,
        seconds: float | None,
        seed: int,
        sampling: Sampling,
        plant_feet: bool,
        progress: bool = False,
    ) -> Motion:
        if seconds is not None:
            alignment = alignment.scaled(seconds)
        motion = self._play(alignment.schedule(), seed, sampling, plant_feet, progress)
        motion.alignment = alignment
        return motion

    def play(
        self,
        schedule: Sequence[tuple[str, float]],
        seed: int | None = None,
        sampling: Sampling | None = None,
        plant_feet: bool = True,
        progress: bool = False,
        **options,
    ) -> Motion:
        """A list of (prompt, seconds) as one continuous motion, switching prompts on the
        fly: the same stream, so every switch is a smooth continuation. At most
        MAX_SCHEDULE_ENTRIES prompts and MAX_GENERATE_SECONDS in all; an entry's problem is a
        ScheduleError naming it. progress=True: a progress line on stderr while the token
        steps are drawn."""
        sampling = self.sampling(sampling, **options)
        seed = checked_seed(seed)
        plant_feet = checked_bool(plant_feet, "plant_feet")
        entries = checked_schedule(schedule)
        lengths = []
        for k, entry in enumerate(entries):
            try:
                lengths.append(self._seconds(entry[1]))
            except TypeError as error:  # which entry, for a long schedule
                raise TypeError(f"schedule[{k}]: {error}") from None
            except ValueError as error:
                raise ScheduleError(k, str(error)) from None
        if sum(lengths) > MAX_GENERATE_SECONDS:
            raise ScheduleError(
                None,
                f"the schedule's lengths add up to {sum(lengths):g} s; at "
                f"most {MAX_GENERATE_SECONDS:g} in one call (use a stream for "
                "longer motion)",
            )
        prompts = []
        for k, entry in enumerate(entries):
            try:
                prompts.append(self.read_prompt(entry[0], "prompt"))
            except TypeError as error:
                raise TypeError(f"schedule[{k}]: {error}") from None
            except ValueError as error:
                raise ScheduleError(k, str(error)) from None
        return self._play(
            list(zip(prompts, lengths, strict=False)),
            seed,
            sampling,
            plant_feet,
            checked_bool(progress, "progress"),
        )

    def _play(
        self,
        schedule: list[tuple[str, float]],
        seed: int,
        sampling: Sampling,
        plant_feet: bool,
        progress: bool = False,
        stop=None,
    ) -> Motion:
        """A schedule as one re-anchored stream (the stream `stream` makes), a switch per
        entry; `stop` as in `generate`."""
        stream = MotionStream(
            self, schedule[0][0], seed, sampling, self.defaults.window, plant_feet, Anchoring()
        )
        steps = [self._steps(seconds) for _, seconds in schedule]
        shown = Progress(sum(steps), "generating", enabled=progress, unit="steps")
        for k, ((prompt, _), count) in enumerate(zip(schedule, steps, strict=True)):
            if k:
                stream.switch_prompt(prompt)
            for _ in range(count):
                if stop is not None and stop.is_set():
                    raise Stopped("stopped")
                stream.advance(1)
                shown.update()
        shown.close()
        return stream.finish()

    def denormalised(self, normalised: np.ndarray) -> np.ndarray:
        """The decoder's normalised features in the bundle's units (clips and streams alike)."""
        return normalised * self.bundle.std + self.bundle.mean

    def decode(
        self,
        tokens: np.ndarray,
        prompts: list[tuple[int, str]],
        frames: int | None = None,
        seed: int | None = None,
        plant_feet: bool = True,
    ) -> Motion:
        """Token steps (n, L) -> Motion (features and joints), cut to `frames` when given.
        Steps past the cut are only the right context of the last kept frames (decoded
        without it, against the zero padding of an end, they collapse): Motion.tokens keeps
        the steps the kept frames come from. The feet are planted in the kept frames alone,
        the cut being the clip's end."""
        decoder = self.streaming_decoder()
        normalised = decoder.decode_offline(tokens)[:frames]
        features = self.denormalised(normalised)
        joints = JointStream(self.skeleton).push(features)
        if checked_bool(plant_feet, "plant_feet"):  # foot cleanup (issue 25)
            joints = planted(features, joints, self.skeleton)
        if frames is not None:
            tokens = tokens[: math.ceil(frames / self.down_factor)]
        return Motion(features, joints, self.fps, tokens, self.skeleton, prompts, seed)

    def _cut(self, motion: Motion, frames: int) -> Motion:
        """The first `frames` of a stream's Motion (its last token step may give more)."""
        if len(motion.joints) == frames:
            return motion
        return Motion(
            motion.features[:frames],
            motion.joints[:frames],
            motion.fps,
            motion.tokens[: math.ceil(frames / self.down_factor)],
            motion.skeleton,
            motion.prompts,
            motion.seed,
        )

    def encode_motion(self, motion: Motion) -> np.ndarray:
        """A clip's features -> its token steps (n, L), by the bundle's VQ encoder."""
        if not isinstance(motion, Motion):
            raise TypeError(
                f"motion must be a Motion (from generate, play or a stream's "
                f"finish), got {type(motion).__name__}"
            )
        features = np.asarray(motion.features, np.float32)
        if features.ndim != 2 or features.shape[1] != self.manifest.feature_dim:
            raise ValueError(
                f"motion features must be (T, {self.manifest.feature_dim}), got {features.shape}"
            )
        checked_finite(features, "motion features")
        usable = len(features) - len(features) % self.down_factor
        if usable < self.down_factor:
            raise ValueError(
                f"the motion has {plural(len(features), 'frame')}; at least "
                f"{self.down_factor} are needed"
            )
        normalised = (features[:usable] - self.bundle.mean) / self.bundle.std
        return self._vq_encoder.run(normalised[None])[0]

    # -- streams -------------------------------------------------------------------------------
    def stream(
        self,
        text: str,
        seed: int | None = None,
        sampling: Sampling | None = None,
        window: int | None = None,
        plant_feet: bool = True,
        anchoring: Anchoring | bool = True,
        low_latency: bool = False,
        **options,
    ) -> MotionStream:
        """An endless motion; see MotionStream. `sampling` and `options`: see `sampling()`.
        `anchoring`: True re-anchors the stream (mogo.anchoring: it keeps doing what the
        prompt says, one-off prompts settle into a hold), an Anchoring tunes it, False
        lets the model run on from step 0 (it drifts after a few seconds). `low_latency`:
        decode with the bundle's low-latency decoder (its frames wait a few tokens, not the
        centred decoder's 31: docs/model.md), every token."""
        sampling = self.sampling(sampling, **options)
        seed = checked_seed(seed)
        window = self.defaults.window if window is None else checked_int(window, "window", 1)
        if anchoring is True:
            anchoring = Anchoring()
        elif anchoring is False:
            anchoring = None
        elif not isinstance(anchoring, Anchoring):
            raise TypeError(
                f"anchoring must be True, False or an Anchoring, got {type(anchoring).__name__}"
            )
        low_latency = checked_bool(low_latency, "low_latency")
        if low_latency and self.low_latency_graph is None:
            raise ValueError(
                "this bundle has no low-latency decoder (manifest "
                "vq.low_latency_decoder); stream without low latency"
            )
        return MotionStream(
            self,
            self.read_prompt(text),
            seed,
            sampling,
            window,
            checked_bool(plant_feet, "plant_feet"),
            anchoring,
            low_latency,
        )

    def resume(self, state: str) -> MotionStream:
        """The stream `MotionStream.state()` was taken from, going on from there: the next
        frames are those the original made after it (on this machine, the same graphs). A
        state of another bundle, corrupted, truncated, hostile or of a newer format: one
        ValueError (mogo.stream_state.StateError) naming the problem. Costs a prefill and
        a step per token step since the stream's clip started or re-anchored (tens of ms)."""
        resumed = read_state(state, self)
        if resumed.low_latency and self.low_latency_graph is None:
            raise StateError(
                "the state is of a low-latency stream; this bundle has no such decoder"
            )
        stream = MotionStream(
            self,
            resumed.prompt,
            resumed.seed,
            resumed.sampling,
            resumed.window,
            resumed.plant_feet,
            resumed.anchoring,
            resumed.low_latency,
        )
        resumed.restore(stream)
        return stream

    def streaming_decoder(
        self, session: ort.InferenceSession | None = None, low_latency: bool = False
    ) -> StreamingDecoder:
        """`session`: another session of the bundle's decoder graph (None: this generator's);
        `low_latency`: the low-latency decoder's, decoding every token (a token a call where
        the bundle has its step graph)."""
        if low_latency and isinstance(self.low_latency_graph, StepDecoderGraph):
            window = self.manifest.vq.low_latency_decoder
            return StepDecoder(
                session or self._low_latency_session,
                self.low_latency_graph,
                window.left_context,
                self.codebook_size,
            )
        d, own = (
            (self.low_latency_graph, self._low_latency_session)
            if low_latency
            else (self._decoder, self._decoder_session)
        )
        return StreamingDecoder(
            session or own,
            d.left_context,
            d.lookahead,
            self.codebook_size,
            ids_name=d.inputs[0],
            features_name=d.outputs[0],
            every=1 if low_latency else STREAM_DECODE_EVERY,
        )

    def sampling(self, sampling: Sampling | None = None, **options) -> Sampling:
        """How a call draws its tokens: `sampling` (None: the bundle's defaults), with keyword
        options named as Sampling's fields (temperature=0, top_p=0.9, ...; None: not given)
        replacing single fields."""
        if sampling is None:
            sampling = Sampling.from_defaults(vars(self.defaults))
        if not isinstance(sampling, Sampling):
            raise TypeError(f"sampling must be a Sampling or None, got {type(sampling).__name__}")
        return sampling.updated(options)

    def _seconds(self, seconds: object) -> float:
        return checked_seconds(seconds, self.down_factor / self.fps, self.fps, MAX_GENERATE_SECONDS)

    def _steps(self, seconds: float) -> int:
        return max(1, math.ceil(round(seconds * self.fps) / self.down_factor))

    def read_prompt(self, text: object, name: str = "text") -> str:
        """A prompt checked where it enters the API (see mogo.text_side.TextSide.read)."""
        return self.text.read(text, name, stacklevel=4)


class MotionStream:
    """One endless motion: `step()` draws one token step and returns the frames that became
    final (joints (n, J, 3); none while the decoder waits for its right context, then bursts of
    STREAM_DECODE_EVERY). Memory and step time stay constant: the KV cache slides over the
    last `window` steps, or, re-anchored (`anchoring`, mogo.anchoring), holds at most its span.
    Planting the feet holds each frame back until the frames of its lookahead are decoded
    (mogo.motion.feet: 8 frames; 2 for a low-latency stream, whose decoder waits a few tokens,
    not 31)."""

    def __init__(
        self,
        generator: MotionGenerator,
        text: str,
        seed: int,
        sampling: Sampling,
        window: int | None,
        plant_feet: bool = True,
        anchoring: Anchoring | None = None,
        low_latency: bool = False,
        *,
        tokens: TokenGenerator | None = None,
        decoder_session: ort.InferenceSession | None = None,
    ):
        """`tokens`, `decoder_session`: other sessions of the bundle's graphs (the server's,
        mogo.serve.engine); None: the generator's."""
        self.generator = generator
        self.seed = seed
        self.prompts: list[tuple[int, str]] = [(0, text)]  # checked by the generator
        self.steps = 0  # token steps drawn
        self._lock = threading.RLock()  # set_prompt from another thread waits for a step
        self.tokens: TokenStream = (tokens or generator.tokens).start(
            generator._embedding(text), seed, sampling, window, allow_end=False
        )
        self.decoder = generator.streaming_decoder(decoder_session, low_latency=low_latency)
        self._joints = JointStream(generator.skeleton)
        self.feet = (  # issue 25
            FootPlanter(generator.skeleton, window=SHORT if low_latency else WINDOW)
            if plant_feet
            else None
        )
        self.frames_emitted = 0
        self._skip = 0
        self._unread = np.zeros((0, generator.skeleton.num_joints, 3), np.float32)
        self._record: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
        self.anchor = (
            None
            if anchoring is None
            else Anchor(
                anchoring,
                self.tokens,
                generator._embedding,
                text,
                anchoring.one_off_steps(
                    generator.defaults.max_seconds, generator.fps / generator.down_factor
                ),
            )
        )

    def step(self) -> np.ndarray:
        with self._lock:
            row = self._next_tokens()
            frames = self.emit(row[None], self.decoder.push(row[None]))
            if len(self._unread):
                frames, self._unread = np.concatenate([self._unread, frames]), self._unread[:0]
            return frames

    def frames(self, limit: int | None = None) -> Iterator[np.ndarray]:
        """Frames (J, 3) one by one, forever or `limit` of them. Frames decoded but not yet
        yielded (the decoder gives them in bursts) wait for the next frames() or step()."""
        limit = None if limit is None else checked_int(limit, "limit", 0)
        yielded = 0
        while limit is None or yielded < limit:
            if not len(self._unread):
                self._unread = self.step()
            while len(self._unread) and (limit is None or yielded < limit):
                frame, self._unread = self._unread[0], self._unread[1:]
                yielded += 1
                yield frame

    def set_prompt(self, text: str) -> None:
        """Switch the prompt from the next step on (exact: the cache is re-prefilled). Safe
        from another thread than the one reading frames: it waits for the step under way."""
        self.switch_prompt(self.generator.read_prompt(text))

    def switch_prompt(self, text: str) -> None:
        """`set_prompt` for a prompt already checked (a schedule's, a server client's)."""
        embedding = self.generator._embedding(text)
        with self._lock:
            if self.anchor is None:
                self.tokens.set_prompt(embedding)
            else:
                self.anchor.switch(text, embedding)
            self.prompts.append((self.frames_emitted + self._pending_frames(), text))

    def continue_from(self, motion: Motion) -> None:
        """Go on from the end of an existing clip (before the first step): its tokens become
        the decoder's left context, and the past the model sees (re-anchored: its last step,
        as at a switch, so that a one-off action asked for starts instead of being taken as
        done by the clip's end)."""
        if self.steps or self.tokens.steps:
            raise ValueError("continue_from must come before the first step of a stream")
        tokens = self.generator.encode_motion(motion)
        with self._lock:
            if self.anchor is None:
                self.tokens.continue_from(tokens)
            else:
                self.anchor.continued(tokens)
            final_together([self], [self.generator.denormalised(self.decoder.push(tokens))])
            self._skip = self._pending_frames()  # the clip's own last frames: not again

    def state(self) -> str:
        """Everything that keeps this stream going, as compact text (mogo.stream_state, a
        few KB): `MotionGenerator.resume(state)` goes on from here, also in another process
        or on another machine with the same bundle. Its first frame is frame
        `frames_emitted` (frames decoded but not yet read from frames() come first)."""
        with self._lock:
            return write_state(self)

    def advance(self, steps: int) -> None:
        """Draw `steps` token steps, keeping everything for `finish()`."""
        steps = checked_int(steps, "steps", 0)
        if self._record is None:
            self._record = []
        for _ in range(steps):
            self.step()

    def finish(self) -> Motion:
        """End the stream: the remaining frames and, if the stream was recorded by `advance`,
        the whole Motion. The stream is cut, not ended: it draws more steps, not kept, as the
        right context of its last frames (the decoder's lookahead, and the feet's before it),
        so they are the frames the stream would have emitted had it gone on."""
        g = self.generator
        levels = g.tokens.num_levels
        with self._lock:
            left = self._pending_frames() - self._skip  # the frames still to come out
            feet = self.lookahead_steps - self.decoder.lookahead
            drawn = [self._next_tokens() for _ in range(self.lookahead_steps)]
            ahead = np.reshape(drawn, (-1, levels))
            features = np.concatenate(
                [self.decoder.push(ahead[:feet]), self.decoder.flush(ahead[feet:])]
            )
            self.emit(np.zeros((0, levels), np.int64), features, limit=left)
        empty = (
            np.zeros((0, g.tokens.num_levels), np.int64),
            np.zeros((0, g.manifest.feature_dim), np.float32),
            np.zeros((0, g.skeleton.num_joints, 3), np.float32),
        )
        tokens, features, joints = (
            np.concatenate(column) for column in zip(empty, *(self._record or []), strict=False)
        )
        return Motion(features, joints, g.fps, tokens, g.skeleton, list(self.prompts), self.seed)

    @property
    def lookahead_steps(self) -> int:
        """Token steps drawn past a token before its frames are final: the decoder's
        lookahead and the foot planter's (one frame a token: a new stream's first frame comes at
        step this + 1)."""
        feet = 0 if self.feet is None else self.feet.lookahead
        return self.decoder.lookahead + math.ceil(feet / self.generator.down_factor)

    def _next_tokens(self) -> np.ndarray:
        return drawn_together([self])[0]

    def emit(
        self, tokens: np.ndarray, normalised: np.ndarray, limit: int | None = None
    ) -> np.ndarray:
        """The frames that became final from decoded rows (at most `limit`: `finish`)."""
        return emit_together([self], [tokens], [normalised], limit)[0]

    def _emit(
        self, tokens: np.ndarray, features: np.ndarray, joints: np.ndarray, limit: int | None
    ) -> np.ndarray:
        """`emit` of rows made final (features and joints, the feet planted where asked)."""
        skip = min(self._skip, len(joints))
        features, joints, self._skip = features[skip:], joints[skip:], self._skip - skip
        features, joints = features[:limit], joints[:limit]
        self.frames_emitted += len(joints)
        if self._record is not None:
            self._record.append((tokens, features.astype(np.float32), joints))
        return joints

    def _pending_frames(self) -> int:
        """Frames drawn as tokens but not yet emitted (the decoder's lookahead, and the
        frames the foot planter holds back)."""
        held = 0 if self.feet is None else self.feet.pending
        return (self.decoder.pushed - self.decoder.emitted) * self.generator.down_factor + held


def drawn_together(streams: Sequence[MotionStream]) -> list[np.ndarray]:
    """The next step's tokens (L,) of each stream, re-anchored where due: every stream's row
    in shared calls (mogo.token_generator.step_together), and the first steps of the fresh
    clips of those whose clips ended in a second."""
    rows = step_together([s.tokens for s in streams])
    ended = [k for k, row in enumerate(rows) if row is None and streams[k].anchor is not None]
    for k in ended:
        streams[k].anchor.clip_ended()
    for k, row in zip(ended, step_together([streams[k].tokens for k in ended]), strict=True):
        rows[k] = row
    for s in streams:
        s.steps += 1
    rows = [
        row if s.anchor is None else s.anchor.after(row)
        for s, row in zip(streams, rows, strict=True)
    ]
    prefill_together([s.tokens for s in streams if s.tokens.unfilled])  # the re-anchored
    return rows


def emit_together(
    streams: Sequence[MotionStream],
    tokens: list[np.ndarray],
    normalised: list[np.ndarray],
    limit: int | None = None,
) -> list[np.ndarray]:
    """`emit` of each stream's decoded rows: each stream's frames made final (at most `limit`
    each). The one path of a stream's frames, for one stream or a server's round."""
    features = [s.generator.denormalised(rows) for s, rows in zip(streams, normalised, strict=True)]
    return [
        s._emit(t, f, j, limit)
        for s, t, (f, j) in zip(streams, tokens, final_together(streams, features), strict=True)
    ]


def final_together(
    streams: Sequence[MotionStream], features: list[np.ndarray]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each stream's decoded rows (denormalised) in, its rows now final out with their joints,
    the feet planted where asked (the planter's lookahead later); streams of one skeleton. The
    joints of the streams with as many rows in one pass (mogo.motion.features.joints_together),
    the legs of the frames whose feet are planted in one pass (mogo.motion.feet.push_together):
    the numbers of one stream at a time."""
    joints: list[np.ndarray | None] = [None] * len(streams)
    alike: dict[int, list[int]] = {}  # streams by rows decoded
    for k, rows in enumerate(features):
        alike.setdefault(len(rows), []).append(k)
    for ks in alike.values():
        made = joints_together(
            [streams[k]._joints for k in ks], np.stack([features[k] for k in ks])
        )
        for k, rows in zip(ks, made, strict=True):
            joints[k] = rows
    final = list(zip(features, joints, strict=True))
    ks = [k for k, s in enumerate(streams) if s.feet is not None]  # those that plant feet
    made = push_together(
        [streams[k].feet for k in ks], [features[k] for k in ks], [joints[k] for k in ks]
    )
    for k, rows in zip(ks, made, strict=True):
        final[k] = rows
    return final


def checked_seed(seed: object) -> int:
    """The caller's seed, checked; None draws a fresh one (kept in Motion.seed)."""
    if seed is None:
        return int(np.random.SeedSequence().generate_state(1)[0])
    return checked_int(seed, "seed", 0)
