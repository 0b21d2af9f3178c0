"""mogo.stream_decoder on the shipped VQ decoder: streamed frames are the offline decode of the
same tokens, whatever the burst size, the push sizes and the length (around the lookahead and
the whole receptive field); the first frame comes as soon as its right context exists; the
buffer stays bounded; and the receptive field the manifest states is the decoder's own."""
import json

import numpy as np
import onnxruntime as ort
import pytest

from mogo import DEFAULT_BUNDLE
from mogo.stream_decoder import StreamingDecoder

DECODER = json.loads((DEFAULT_BUNDLE / "manifest.json").read_text())["vq"]["decoder"]
LEFT, LOOKAHEAD, CODES = DECODER["left_context"], DECODER["lookahead"], DECODER["codebook_size"]


def test_this_file_imports_no_torch(run_without_torch):
    done = run_without_torch(f"import runpy\nrunpy.run_path({__file__!r})\n")
    assert done.returncode == 0, done.stderr


@pytest.fixture(scope="module")
def session():
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    return ort.InferenceSession(str(DEFAULT_BUNDLE / DECODER["file"]), options,
                                providers=["CPUExecutionProvider"])


def decoder(session, every=1) -> StreamingDecoder:
    return StreamingDecoder(session, LEFT, LOOKAHEAD, CODES, ids_name=DECODER["inputs"][0],
                            features_name=DECODER["outputs"][0], every=every)


def random_ids(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, CODES, (n, DECODER["levels"]))


def streamed(d: StreamingDecoder, ids: np.ndarray, chunk: int) -> list[np.ndarray]:
    """The frames each push returned, then the flush's."""
    return [d.push(ids[i:i + chunk]) for i in range(0, len(ids), chunk)] + [d.flush()]


LENGTHS = [1, LOOKAHEAD, LOOKAHEAD + 1, LOOKAHEAD + 2, LEFT + LOOKAHEAD + 1,
           LEFT + LOOKAHEAD + 2, 2 * (LEFT + LOOKAHEAD) + 7]


@pytest.mark.parametrize("every", [1, 3, 8])
@pytest.mark.parametrize("chunk", [1, 5])
@pytest.mark.parametrize("length", LENGTHS)
def test_streamed_frames_are_the_offline_decode(session, every, chunk, length):
    ids = random_ids(length, seed=length)
    d = decoder(session, every)
    offline = d.decode_offline(ids)
    frames = np.concatenate(streamed(d, ids, chunk))
    assert frames.shape == offline.shape == (length * DECODER["down_factor"],
                                             DECODER["feature_dim"])
    np.testing.assert_allclose(frames, offline, atol=1e-5, rtol=0)


@pytest.mark.parametrize("every", [1, 8])
def test_the_first_frame_comes_once_its_lookahead_is_pushed_then_bursts_of_every(session, every):
    d = decoder(session, every)
    ids = random_ids(LOOKAHEAD + 1 + 3 * every)
    counts = [len(d.push(ids[i:i + 1])) for i in range(len(ids))]
    assert counts[:LOOKAHEAD] == [0] * LOOKAHEAD  # waiting for the first frame's right context
    assert counts[LOOKAHEAD] == 1  # token 0 has its lookahead: its frame at once
    burst = [0] * (every - 1) + [every]
    assert counts[LOOKAHEAD + 1:] == burst * 3
    assert d.emitted == 1 + 3 * every and d.pushed == len(ids)


def test_a_push_of_many_tokens_returns_every_frame_that_became_final(session):
    d = decoder(session, every=8)
    assert len(d.push(random_ids(LOOKAHEAD + 5))) == 5
    assert len(d.push(random_ids(2, seed=1))) == 0  # 2 < every since the last burst
    assert len(d.push(random_ids(6, seed=2))) == 8


@pytest.mark.parametrize("every,chunk", [(1, 1), (8, 1), (8, 3), (5, 7)])
def test_the_buffer_stays_bounded(session, every, chunk):
    """At most left_context + lookahead + every - 1 tokens are held between calls, however
    long the stream."""
    d = decoder(session, every)
    ids = random_ids(160)
    bound = LEFT + LOOKAHEAD + every - 1
    for i in range(0, len(ids), chunk):
        d.push(ids[i:i + chunk])
        assert d.buffered_tokens <= bound
    assert d.buffered_tokens >= LEFT + LOOKAHEAD  # ... and no less than the receptive field


def test_flush_starts_a_new_stream(session):
    d = decoder(session, every=8)
    ids = random_ids(50)
    first = np.concatenate(streamed(d, ids, 4))
    assert d.pushed == d.emitted == d.buffered_tokens == 0
    second = np.concatenate(streamed(d, ids, 4))
    np.testing.assert_array_equal(first, second)


def test_the_stated_receptive_field_holds(session):
    """Changing token j changes no frame before j - lookahead and none after j + left_context:
    what the streaming decoder relies on (a receptive field wider than the manifest says would
    make streamed frames differ from offline ones)."""
    d = decoder(session)
    ids = random_ids(3 * (LEFT + LOOKAHEAD))
    base = d.decode_offline(ids)
    for j in (LEFT + LOOKAHEAD, len(ids) // 2):
        changed = ids.copy()
        changed[j] = (changed[j] + 1) % CODES
        moved = np.abs(d.decode_offline(changed) - base).max(axis=1)
        assert moved[:j - LOOKAHEAD].max() < 1e-6 and moved[j + LEFT + 1:].max() < 1e-6
        assert moved[j] > 1e-3


def test_empty_input_and_bad_ids(session):
    d = decoder(session)
    assert d.decode_offline(np.zeros((0, DECODER["levels"]), np.int64)).shape == (
        0, DECODER["feature_dim"])
    assert d.flush().shape == (0, DECODER["feature_dim"])
    levels = DECODER["levels"]
    for ids, message in [(np.full((2, levels), CODES), "must lie in"),
                         (np.full((2, levels), -1), "must lie in"),
                         (np.zeros((2, levels), np.float32), "must be integers"),
                         (np.zeros((2, levels + 1), np.int64), "must be"),
                         (np.zeros(levels, np.int64), "must be")]:
        with pytest.raises(ValueError, match=message):
            d.push(ids)
    with pytest.raises(ValueError, match="every must be >= 1"):
        decoder(session, every=0)
    with pytest.raises(ValueError, match="left_context, lookahead >= 0"):
        StreamingDecoder(session, -1, LOOKAHEAD, CODES)
