"""mogo.stream_decoder on the shipped VQ decoder: streamed frames are the offline decode of the
same tokens, whatever the burst size, the push sizes and the length (around the lookahead and
the whole receptive field); the first frame comes as soon as its right context exists; the
buffer stays bounded; and the receptive field the manifest states is the decoder's own."""

import json
from types import SimpleNamespace

import numpy as np
import onnxruntime as ort
import pytest

from mogo import DEFAULT_BUNDLE, MotionGenerator
from mogo.stream_decoder import StreamingDecoder, push_many

# the receptive field as the manifest states it (the lengths below are chosen around it)
DECODER = json.loads((DEFAULT_BUNDLE / "manifest.json").read_text())["vq"]["decoder"]
LEFT, LOOKAHEAD = DECODER["left_context"], DECODER["lookahead"]


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


@pytest.fixture(scope="module")
def shipped(generator) -> StreamingDecoder:
    """The runtime's own streaming decoder of the shipped bundle: its session, graph names and
    sizes."""
    d = generator.streaming_decoder()
    assert (d.left_context, d.lookahead) == (LEFT, LOOKAHEAD)
    return d


def decoder(shipped, every=1) -> StreamingDecoder:
    return StreamingDecoder(
        shipped.session,
        left_context=LEFT,
        lookahead=LOOKAHEAD,
        codebook_size=shipped.codebook_size,
        ids_name=shipped.ids_name,
        features_name=shipped.features_name,
        every=every,
    )


def random_ids(shipped, n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, shipped.codebook_size, (n, shipped.levels))


def streamed(d: StreamingDecoder, ids: np.ndarray, chunk: int) -> list[np.ndarray]:
    """The frames each push returned, then the flush's."""
    return [d.push(ids[i : i + chunk]) for i in range(0, len(ids), chunk)] + [d.flush()]


LENGTHS = [
    1,
    LOOKAHEAD,
    LOOKAHEAD + 1,
    LOOKAHEAD + 2,
    LEFT + LOOKAHEAD + 1,
    LEFT + LOOKAHEAD + 2,
    2 * (LEFT + LOOKAHEAD) + 7,
]


@pytest.mark.parametrize("every", [1, 3, 8])
@pytest.mark.parametrize("chunk", [1, 5])
@pytest.mark.parametrize("length", LENGTHS)
def test_streamed_frames_are_the_offline_decode(generator, shipped, every, chunk, length):
    ids = random_ids(shipped, length, seed=length)
    d = decoder(shipped, every)
    offline = d.decode_offline(ids)
    frames = np.concatenate(streamed(d, ids, chunk))
    assert frames.shape == offline.shape == (length * generator.down_factor, shipped.feature_dim)
    np.testing.assert_allclose(frames, offline, atol=1e-5, rtol=0)


@pytest.mark.parametrize("every,chunk", [(1, 1), (8, 5)])
@pytest.mark.parametrize(
    "length,context", [(LOOKAHEAD + 2, LOOKAHEAD), (70, LOOKAHEAD), (70, 4), (5, LOOKAHEAD + 9)]
)
def test_a_flush_with_context_gives_the_offline_decode_of_stream_and_context_cut(
    shipped, every, chunk, length, context
):
    """A cut stream: its last frames see the tokens after the cut, not the end padding."""
    ids = random_ids(shipped, length + context, seed=length)
    d = decoder(shipped, every)
    head = ids[:length]
    pushed = [d.push(head[i : i + chunk]) for i in range(0, length, chunk)]
    frames = np.concatenate(pushed + [d.flush(ids[length:])])
    offline = d.decode_offline(ids)
    offline = offline[: length * len(offline) // len(ids)]  # the frames of the first `length`
    assert frames.shape == offline.shape
    np.testing.assert_allclose(frames, offline, atol=1e-5, rtol=0)
    assert d.pushed == d.emitted == d.buffered_tokens == 0


@pytest.mark.parametrize("every", [1, 8])
def test_the_first_frame_comes_once_its_lookahead_is_pushed_then_bursts_of_every(shipped, every):
    d = decoder(shipped, every)
    ids = random_ids(shipped, LOOKAHEAD + 1 + 3 * every)
    counts = [len(d.push(ids[i : i + 1])) for i in range(len(ids))]
    assert counts[:LOOKAHEAD] == [0] * LOOKAHEAD  # waiting for the first frame's right context
    assert counts[LOOKAHEAD] == 1  # token 0 has its lookahead: its frame at once
    burst = [0] * (every - 1) + [every]
    assert counts[LOOKAHEAD + 1 :] == burst * 3
    assert d.emitted == 1 + 3 * every and d.pushed == len(ids)


def test_a_push_of_many_tokens_returns_every_frame_that_became_final(shipped):
    d = decoder(shipped, every=8)
    assert len(d.push(random_ids(shipped, LOOKAHEAD + 5))) == 5
    assert len(d.push(random_ids(shipped, 2, seed=1))) == 0  # 2 < every since the last burst
    assert len(d.push(random_ids(shipped, 6, seed=2))) == 8


@pytest.mark.parametrize("every,chunk", [(1, 1), (8, 1), (8, 3), (5, 7)])
def test_the_buffer_stays_bounded(shipped, every, chunk):
    """At most left_context + lookahead + every - 1 tokens are held between calls, however
    long the stream."""
    d = decoder(shipped, every)
    ids = random_ids(shipped, 160)
    bound = LEFT + LOOKAHEAD + every - 1
    for i in range(0, len(ids), chunk):
        d.push(ids[i : i + chunk])
        assert d.buffered_tokens <= bound
    assert d.buffered_tokens >= LEFT + LOOKAHEAD  # ... and no less than the receptive field


def test_flush_starts_a_new_stream(shipped):
    d = decoder(shipped, every=8)
    ids = random_ids(shipped, 50)
    first = np.concatenate(streamed(d, ids, 4))
    assert d.pushed == d.emitted == d.buffered_tokens == 0
    second = np.concatenate(streamed(d, ids, 4))
    np.testing.assert_array_equal(first, second)


def test_push_many_gives_each_decoder_the_frames_of_its_own_push(shipped):
    """Streams of different ages pushed together, a token each a step: their windows (none
    due, first ones, bursts, full windows) decoded one call per length give each the frames
    of its own push."""
    starts = [0, 0, 3, 9, LOOKAHEAD + 2, 40]
    together = [decoder(shipped, every=8) for _ in starts]
    alone = [decoder(shipped, every=8) for _ in starts]
    ids = [random_ids(shipped, 100, seed=k) for k in range(len(starts))]
    made = 0
    for step in range(100):
        live = [k for k, start in enumerate(starts) if start <= step]
        rows = [ids[k][step - starts[k]][None] for k in live]
        got = push_many([together[k] for k in live], rows)
        for k, row, frames in zip(live, rows, got, strict=False):
            expected = alone[k].push(row)
            np.testing.assert_allclose(frames, expected, rtol=0, atol=1e-6)
            made += len(frames)
    assert made > 300


def test_push_many_needs_one_session(shipped):
    other = StreamingDecoder(WindowDecoder(LEFT, LOOKAHEAD, 1), LEFT, LOOKAHEAD, 7)
    ids = [random_ids(shipped, LOOKAHEAD + 1), np.zeros((LOOKAHEAD + 1, 2), np.int64)]
    with pytest.raises(ValueError, match="share one session"):
        push_many([decoder(shipped), other], ids)


def test_the_stated_receptive_field_holds(shipped):
    """Changing token j changes no frame before j - lookahead and none after j + left_context:
    what the streaming decoder relies on (a receptive field wider than the manifest says would
    make streamed frames differ from offline ones)."""
    d = decoder(shipped)
    ids = random_ids(shipped, 3 * (LEFT + LOOKAHEAD))
    base = d.decode_offline(ids)
    for j in (LEFT + LOOKAHEAD, len(ids) // 2):
        changed = ids.copy()
        changed[j] = (changed[j] + 1) % shipped.codebook_size
        moved = np.abs(d.decode_offline(changed) - base).max(axis=1)
        assert moved[: j - LOOKAHEAD].max() < 1e-6 and moved[j + LEFT + 1 :].max() < 1e-6
        assert moved[j] > 1e-3


def test_empty_input_and_bad_ids(shipped):
    d = decoder(shipped)
    levels, codes = shipped.levels, shipped.codebook_size
    assert d.decode_offline(np.zeros((0, levels), np.int64)).shape == (0, shipped.feature_dim)
    assert d.flush().shape == (0, shipped.feature_dim)
    with pytest.raises(ValueError, match="must lie in"):
        d.flush(np.full((2, levels), codes))
    for ids, message in [
        (np.full((2, levels), codes), "must lie in"),
        (np.full((2, levels), codes + 7), "must lie in"),
        (np.full((2, levels), -1), "must lie in"),
        (np.zeros((2, levels), np.float32), "must be integers"),
        (np.zeros((2, levels + 1), np.int64), rf"must be \(n, {levels}\)"),
        (np.zeros((2, levels - 1), np.int64), rf"must be \(n, {levels}\)"),
        (np.zeros(levels, np.int64), "must be"),
        (np.zeros((2, levels, 1), np.int64), rf"must be \(n, {levels}\)"),
    ]:
        with pytest.raises(ValueError, match=message):
            d.push(ids)
    with pytest.raises(ValueError, match="every must be >= 1"):
        decoder(shipped, every=0)
    with pytest.raises(ValueError, match="left_context, lookahead >= 0"):
        StreamingDecoder(shipped.session, -1, LOOKAHEAD, codes)


class WindowDecoder(ort.InferenceSession):
    """A stand-in VQ decoder in numpy with a known receptive field and `factor` frames per
    token (the temporal upsampling the shipped bundle lacks): the frames of token t are a
    fixed linear map of tokens t - left .. t + lookahead, zero-padded at the sequence edges,
    which is what a stack of convolutions computes. `extra` frames make the output length no
    whole multiple of the input's."""

    def __init__(self, left: int, lookahead: int, factor: int, extra: int = 0):  # no graph
        self.left, self.lookahead, self.factor, self.extra = left, lookahead, factor, extra
        self.weights = np.random.default_rng(9).normal(size=(left + lookahead + 1, 2, factor * 3))

    def get_inputs(self):
        return [SimpleNamespace(name="ids", shape=[1, "tokens", 2])]

    def get_outputs(self):
        return [SimpleNamespace(name="features", shape=[1, "frames", 3])]

    def run(self, names, feeds):
        ids = feeds["ids"][0] + 1.0  # + 1: token 0 differs from the padding
        padded = np.pad(ids, ((self.left, self.lookahead), (0, 0)))
        windows = np.stack([padded[t : t + len(self.weights)] for t in range(len(ids))])
        frames = np.einsum("twl,wlf->tf", windows, self.weights).reshape(-1, 3)
        return [np.concatenate([frames, frames[: self.extra]])[None].astype(np.float32)]


@pytest.mark.parametrize("factor", [2, 4])
@pytest.mark.parametrize("every,chunk,length", [(1, 1, 3), (1, 2, 20), (3, 5, 23), (4, 1, 9)])
def test_several_frames_per_token_stream_as_they_decode_offline(factor, every, chunk, length):
    """Bundles whose VQ upsamples in time: the factor is read off each decode, streamed frames
    are the offline ones, and the window's edges are where the stated receptive field says."""
    d = StreamingDecoder(WindowDecoder(3, 2, factor), 3, 2, 7, every=every)
    ids = np.random.default_rng(length).integers(0, 7, (length, 2))
    offline = d.decode_offline(ids)
    assert offline.shape == (length * factor, 3)
    np.testing.assert_allclose(np.concatenate(streamed(d, ids, chunk)), offline, rtol=1e-6)
    head = ids[: length - 2]
    pushed = [d.push(head[i : i + chunk]) for i in range(0, len(head), chunk)]
    cut = np.concatenate(pushed + [d.flush(ids[length - 2 :])])
    np.testing.assert_allclose(cut, offline[: (length - 2) * factor], rtol=1e-6)


def test_a_decoder_making_no_whole_number_of_frames_per_token_is_refused():
    d = StreamingDecoder(WindowDecoder(1, 1, 2, extra=1), 1, 1, 7)
    with pytest.raises(ValueError, match="made 7 frames from 3 tokens"):
        d.decode_offline(np.zeros((3, 2), np.int64))


def test_the_smallest_valid_decoder_is_accepted():
    """No left context, no lookahead (each token alone), one code: all valid; less is not."""
    d = StreamingDecoder(WindowDecoder(0, 0, 1), 0, 0, 1)
    ids = np.zeros((4, 2), np.int64)
    assert [len(d.push(ids[i : i + 1])) for i in range(4)] == [1, 1, 1, 1]
    assert d.buffered_tokens == 0
    with pytest.raises(ValueError, match="must lie in \\[0, 1\\)"):
        d.push(np.ones((1, 2), np.int64))
    for left, lookahead, codes in ((-1, 0, 1), (0, -1, 1), (0, 0, 0)):
        with pytest.raises(ValueError, match="left_context, lookahead >= 0 and codebook_size"):
            StreamingDecoder(WindowDecoder(0, 0, 1), left, lookahead, codes)
