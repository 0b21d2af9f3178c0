"""Streaming VQ decoding: token ids go in as they are generated, motion features come out as
soon as each frame's receptive field is complete.

The VQ decoder is a stack of convolutions, so the frames of token t depend only on tokens
[t - left_context, t + lookahead]. Decoding a window of tokens gives exactly the offline
frames wherever that range lies inside the window, or the window edge is the sequence edge
(both then see the same zero padding): padding at an inner window edge only disturbs frames
within reach of it. So each push decodes one window (left context, new frames, lookahead) and
then forgets every token no later frame can reach: the cost per frame and the memory stay
constant however long the stream runs. A window costs about the same for one new token as for
a few, so with `every` = k it is decoded once k tokens are ready (the first frames still come
as soon as they can): k times fewer decodes, frames in bursts of k tokens.

Contexts are counted in tokens. With temporal downsampling a token decodes to several frames;
that factor is read off each decode (output length / input length), so any factor works.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
import onnxruntime as ort

from mogo._session import cpu_session
from mogo.manifest import StepDecoderGraph


class StreamingDecoder:
    """Decodes a growing stream of token ids (n, L) into normalised features (frames, D).

    `left_context` and `lookahead` are the decoder's receptive field in tokens (from
    the bundle manifest's vq.decoder, mogo.manifest.DecoderGraph); the default names
    are those mogo.export.onnx.vq_graphs writes. A session passed in is used as it is.
    """

    def __init__(
        self,
        session_or_path: ort.InferenceSession | str | os.PathLike,
        left_context: int,
        lookahead: int,
        codebook_size: int,
        *,
        ids_name: str = "ids",
        features_name: str = "features",
        intra_op_threads: int = 1,
        every: int = 1,
    ):
        if isinstance(session_or_path, ort.InferenceSession):
            self.session = session_or_path
        else:
            self.session = cpu_session(session_or_path, intra_op_threads)
        if min(left_context, lookahead) < 0 or codebook_size < 1:
            raise ValueError(
                f"need left_context, lookahead >= 0 and codebook_size >= 1, got "
                f"{left_context}, {lookahead}, {codebook_size}"
            )
        if every < 1:
            raise ValueError(f"every must be >= 1 token, got {every}")
        self.left_context, self.lookahead, self.every = left_context, lookahead, every
        self.codebook_size = codebook_size
        self.ids_name, self.features_name = ids_name, features_name
        self.levels = _static_last_dim(self.session.get_inputs(), ids_name)
        self.feature_dim = _static_last_dim(self.session.get_outputs(), features_name)
        self.reset()

    def reset(self) -> None:
        """Forget the stream and start a new one."""
        self._tokens = np.zeros((0, self.levels), np.int64)
        self._start = 0  # stream index of self._tokens[0]
        self.pushed = 0  # tokens pushed so far
        self.emitted = 0  # tokens whose frames were returned
        self._ready = 0  # tokens whose frames the window `feed` returned makes final

    @property
    def buffered_tokens(self) -> int:
        """Tokens held between calls: at most left_context + lookahead + every - 1."""
        return len(self._tokens)

    def push(self, ids: np.ndarray) -> np.ndarray:
        """Append ids (n, L); return the frames (frames, D) that became final, maybe none."""
        window = self.feed(ids)
        return self._none() if window is None else self.take(self._decode(window))

    def feed(self, ids: np.ndarray) -> np.ndarray | None:
        """`push` up to the decode: append ids (n, L) and return the window (tokens, L) to
        decode now, or None. Its decode goes to `take`: so a caller can decode the windows of
        many streams in one call (`push_many`)."""
        ids = self._checked(ids)
        self._tokens = np.concatenate([self._tokens, ids])
        self.pushed += len(ids)
        ready = self.pushed - self.lookahead
        if ready <= self.emitted or (self.emitted and ready - self.emitted < self.every):
            return None
        self._ready = ready
        return self._tokens

    def take(self, features: np.ndarray, cut: int = 0) -> np.ndarray:
        """`push` after the decode: the frames (frames, D) that became final, from the decode
        (frames, D) of the window `feed` returned, less `cut` tokens at each end (see
        `push_many`)."""
        ready = self._ready
        frames_per_token = len(features) // (len(self._tokens) - 2 * cut)
        first = (self.emitted - self._start - cut) * frames_per_token
        frames = features[first : first + (ready - self.emitted) * frames_per_token]
        self.emitted = ready
        keep_from = max(0, ready - self.left_context)
        self._tokens = self._tokens[keep_from - self._start :]
        self._start = keep_from
        return frames

    def flush(self, context: np.ndarray | None = None) -> np.ndarray:
        """End the stream: return its remaining frames and get ready for a new stream.
        `context`: token ids (n, L) that follow the end, the right context of the last frames
        (their own frames are not returned): a cut stream's last frames then are those of the
        offline decode of the stream and the context. Without it they see the end padding an
        offline decode of the stream alone sees, which collapses them when the motion does
        not end there."""
        if context is not None:
            self._tokens = np.concatenate([self._tokens, self._checked(context)])
        frames = self._emit(self.pushed)
        self.reset()
        return frames

    def decode_offline(self, ids: np.ndarray) -> np.ndarray:
        """Decode a whole sequence of ids (n, L) in one go."""
        return self._decode(self._checked(ids))

    def _emit(self, ready: int) -> np.ndarray:
        """Return the frames of tokens [emitted, ready) and drop the tokens no later frame
        needs. The buffer always starts at the first emitted token's left context, so it is
        exactly the window to decode."""
        if ready <= self.emitted:
            return self._none()
        self._ready = ready
        return self.take(self._decode(self._tokens))

    def _none(self) -> np.ndarray:
        return np.zeros((0, self.feature_dim), np.float32)

    def _decode(self, ids: np.ndarray) -> np.ndarray:
        if len(ids) == 0:
            return self._none()
        return self._decode_windows(ids[None])[0]

    def _decode_windows(
        self, windows: np.ndarray, session: ort.InferenceSession | None = None, cut: int = 0
    ) -> np.ndarray:
        """Windows (B, tokens, L) -> features (B, frames, D), one call; `session` decodes the
        windows less `cut` tokens at each end (see `push_many`)."""
        session = session or self.session
        (features,) = session.run([self.features_name], {self.ids_name: windows})
        tokens = windows.shape[1] - 2 * cut
        if features.shape[1] % tokens:
            raise ValueError(
                f"the decoder made {features.shape[1]} frames from {tokens} "
                "tokens, not a whole number per token"
            )
        return features

    def _checked(self, ids: np.ndarray) -> np.ndarray:
        ids = np.asarray(ids)
        if not np.issubdtype(ids.dtype, np.integer):
            raise ValueError(f"token ids must be integers, got dtype {ids.dtype}")
        if ids.ndim != 2 or ids.shape[1] != self.levels:
            raise ValueError(f"token ids must be (n, {self.levels}), got shape {ids.shape}")
        if ids.size and (ids.min() < 0 or ids.max() >= self.codebook_size):
            raise ValueError(
                f"token ids must lie in [0, {self.codebook_size}), got [{ids.min()}, {ids.max()}]"
            )
        return ids.astype(np.int64)


class StepDecoder(StreamingDecoder):
    """The low-latency decoder a token a call (mogo.export.onnx.vq_step_graph, the manifest's
    vq.low_latency_step): each token runs one column of every layer, where a window decode runs
    63, against a state that holds the layers' past inputs, and gives the window decoder's
    frames to a float rounding. Token rows are kept as StreamingDecoder keeps them (the
    last left_context + lookahead), so a stream restored from them (mogo.stream_state) rebuilds
    the state by replaying them, one token a call as they first ran: the same frames, bit for
    bit."""

    def __init__(
        self,
        session: ort.InferenceSession,
        graph: StepDecoderGraph,
        left_context: int,
        codebook_size: int,
    ):
        self.graph = graph
        super().__init__(
            session,
            left_context,
            graph.lookahead,
            codebook_size,
            ids_name=graph.inputs[0],
            features_name=graph.outputs[0],
        )

    def reset(self) -> None:
        super().reset()
        self._state = np.zeros((1, self.graph.state_size), np.float32)
        self._stepped = 0  # tokens the state has run (fewer than `pushed` after a restore)

    def push(self, ids: np.ndarray) -> np.ndarray:
        return _step_many([self], [ids])[0]

    def flush(self, context: np.ndarray | None = None) -> np.ndarray:
        """End the stream: its remaining frames, `context` (at least `lookahead` token rows that
        follow the end) being their right context; a step decoder has no end padding."""
        context = self._checked(
            np.zeros((0, self.levels), np.int64) if context is None else context
        )
        if self.pushed - self.emitted and len(context) < self.lookahead:
            raise ValueError(
                f"a step decoder ends with {self.lookahead} token rows of context, "
                f"got {len(context)}"
            )
        due = self.pushed - self.emitted
        frames = self.push(context)[:due]
        self.reset()
        return frames

    def decode_offline(self, ids: np.ndarray) -> np.ndarray:
        """Not for a step decoder, which has no end padding: decode whole clips with the
        decoder's window graph (the manifest's vq.low_latency_decoder)."""
        raise ValueError(
            "a step decoder decodes streams a token at a time; decode whole clips with "
            "the window graph (vq.low_latency_decoder)"
        )

    def _catch_up(self) -> None:
        """After a restore: run the kept token rows, as the stream first ran them."""
        if self._stepped == self.pushed:
            return
        self._state = np.zeros_like(self._state)
        self._stepped = self._start
        for row in self._tokens:
            _run_steps([self], row[None])

    def _taken(self, ids: np.ndarray, outputs: list[np.ndarray]) -> np.ndarray:
        """Account for `ids` pushed, their steps' `outputs`: the frames that became final."""
        first = self.pushed - self.lookahead  # the frame of the first of these steps
        self.pushed += len(ids)
        self._tokens = np.concatenate([self._tokens, ids])
        frames = [f for k, f in enumerate(outputs) if first + k >= self.emitted]
        self.emitted = max(self.emitted, self.pushed - self.lookahead)
        keep_from = max(0, self.emitted - self.left_context)
        self._tokens = self._tokens[keep_from - self._start :]
        self._start = keep_from
        return np.concatenate(frames) if frames else self._none()


def push_many(
    decoders: Sequence[StreamingDecoder],
    ids: Sequence[np.ndarray],
    interior: tuple[ort.InferenceSession, int] | None = None,
) -> list[np.ndarray]:
    """[decoder.push(i) for each decoder and its ids], the windows due decoded in one call per
    window length (decoders of one session): the decoder's convolutions keep batch rows
    apart, so each gets the frames of its own push. Streams in step share their window length
    (left context, `every` new tokens, lookahead). `interior`: (a session of the decoder
    graph that decodes a window less `cut` tokens at each end, cut) (mogo.serve.interior),
    for the windows whose new tokens lie `cut` tokens or more from both ends: every window of
    a stream past its first left context (the same frames to a float rounding)."""
    steps = [k for k, decoder in enumerate(decoders) if isinstance(decoder, StepDecoder)]
    stepped = _step_many([decoders[k] for k in steps], [ids[k] for k in steps])
    stepped = dict(zip(steps, stepped, strict=True))
    windows = [
        None if k in stepped else decoder.feed(i)
        for k, (decoder, i) in enumerate(zip(decoders, ids, strict=False))
    ]
    groups: dict[tuple[int, int], list[int]] = {}
    for k, (decoder, window) in enumerate(zip(decoders, windows, strict=False)):
        if window is not None:
            cut = 0 if interior is None else interior[1]
            if decoder.emitted - decoder._start < cut or decoder.lookahead < cut:
                cut = 0
            groups.setdefault((len(window), cut), []).append(k)
    frames = [stepped.get(k, decoder._none()) for k, decoder in enumerate(decoders)]
    for (_, cut), ks in groups.items():
        first = decoders[ks[0]]
        if any(decoders[k].session is not first.session for k in ks):
            raise ValueError("push_many needs decoders that share one session")
        decoded = first._decode_windows(
            np.stack([windows[k] for k in ks]), interior[0] if cut else None, cut
        )
        for k, features in zip(ks, decoded, strict=False):
            frames[k] = decoders[k].take(features, cut)
    return frames


def _step_many(decoders: list[StepDecoder], ids: list[np.ndarray]) -> list[np.ndarray]:
    """`push` for step decoders of one session: their rows stepped together, one call per row
    (each stream's state a row of the call's)."""
    ids = [d._checked(i) for d, i in zip(decoders, ids, strict=True)]
    if any(d.session is not decoders[0].session for d in decoders):
        raise ValueError("push_many needs step decoders that share one session")
    for d in decoders:
        d._catch_up()
    outputs: list[list[np.ndarray]] = [[] for _ in decoders]
    for depth in range(max(map(len, ids), default=0)):
        ks = [k for k, i in enumerate(ids) if depth < len(i)]
        features = _run_steps([decoders[k] for k in ks], np.stack([ids[k][depth] for k in ks]))
        for k, frame in zip(ks, features, strict=True):
            outputs[k].append(frame)
    return [d._taken(i, out) for d, i, out in zip(decoders, ids, outputs, strict=True)]


def _run_steps(group: list[StepDecoder], rows: np.ndarray) -> np.ndarray:
    """One call of the step graph: each decoder's token row (rows (B, L)) at its own position,
    its state a row of the call's; -> the frames (B, 1, D) of each position - lookahead."""
    names = group[0].graph.inputs
    feed = {
        names[0]: rows[:, None],
        names[1]: np.array([d._stepped for d in group]),
        names[2]: np.concatenate([d._state for d in group]),
    }
    features, states = group[0].session.run(None, feed)
    for row, d in enumerate(group):
        d._state, d._stepped = states[row : row + 1], d._stepped + 1
    return features


def _static_last_dim(args: list[ort.NodeArg], name: str) -> int:
    """The fixed size of the last axis of the graph input or output `name`."""
    shapes = {arg.name: arg.shape for arg in args}
    if name not in shapes:
        raise ValueError(f"the decoder graph has no {name!r}; it has {sorted(shapes)}")
    size = shapes[name][-1]
    if not isinstance(size, int):
        raise ValueError(f"the last axis of {name!r} must have a fixed size, got {size!r}")
    return size
