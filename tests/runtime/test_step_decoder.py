"""The shipped low-latency decoder stepped a token a call (mogo.stream_decoder.StepDecoder):
the window decoder's frames, whatever the chunking, and the same frames after a restore."""

import numpy as np
import pytest

from mogo import MotionGenerator
from mogo.stream_decoder import StepDecoder, StreamingDecoder, push_many


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load(threads=1)


def _ids(generator, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, generator.codebook_size, (n, generator.tokens.num_levels))


def _window(generator) -> StreamingDecoder:
    graph = generator.manifest.vq.low_latency_decoder
    path = generator.bundle.path(graph.file)
    return StreamingDecoder(path, graph.left_context, graph.lookahead, generator.codebook_size)


def test_its_frames_are_the_window_decoders(generator):
    ids = _ids(generator, 90)
    step = generator.streaming_decoder(low_latency=True)
    assert isinstance(step, StepDecoder) and step.lookahead == 2
    stepped = np.concatenate([step.push(row[None]) for row in ids])
    offline = _window(generator).decode_offline(ids)
    assert stepped.shape == (88, generator.manifest.feature_dim)
    np.testing.assert_allclose(stepped, offline[:88], atol=1e-4)  # fp rounding, normalised


def test_any_chunking_gives_the_same_frames(generator):
    ids = _ids(generator, 70, seed=1)
    one = generator.streaming_decoder(low_latency=True)
    frames = np.concatenate([one.push(row[None]) for row in ids])
    chunked, parts, start = generator.streaming_decoder(low_latency=True), [], 0
    for size in (1, 5, 0, 17, 2, 45):
        parts.append(chunked.push(ids[start : start + size]))
        start += size
    np.testing.assert_array_equal(np.concatenate(parts), frames)


def test_a_restored_decoder_replays_its_rows_to_the_same_frames(generator):
    ids = _ids(generator, 150, seed=2)
    original = generator.streaming_decoder(low_latency=True)
    original.push(ids[:100])
    restored = generator.streaming_decoder(low_latency=True)  # as mogo.stream_state restores
    restored._tokens, restored._start = original._tokens.copy(), original._start
    restored.pushed, restored.emitted = original.pushed, original.emitted
    assert len(restored._tokens) == restored.left_context + restored.lookahead
    np.testing.assert_array_equal(restored.push(ids[100:]), original.push(ids[100:]))


def test_flush_ends_with_the_frames_of_the_stream_that_goes_on(generator):
    ids = _ids(generator, 40, seed=3)
    going_on = generator.streaming_decoder(low_latency=True).push(ids)
    cut = generator.streaming_decoder(low_latency=True)
    frames = np.concatenate([cut.push(ids[:30]), cut.flush(ids[30:32])])
    np.testing.assert_array_equal(frames, going_on[:30])
    assert cut.pushed == 0  # ready for a new stream
    short = generator.streaming_decoder(low_latency=True)
    short.push(ids[:10])
    with pytest.raises(ValueError, match="ends with 2 token rows of context, got 1"):
        short.flush(ids[10:11])


def test_many_streams_step_in_one_call_as_each_alone(generator):
    streams = [generator.streaming_decoder(low_latency=True) for _ in range(3)]
    alone = [generator.streaming_decoder(low_latency=True) for _ in range(3)]
    rows = [_ids(generator, 12, seed=10 + k) for k in range(3)]
    together = [[] for _ in streams]
    for t in range(12):
        live = [k for k in range(3) if t < 4 + 4 * k]  # streams that stop at different steps
        frames = push_many([streams[k] for k in live], [rows[k][t : t + 1] for k in live])
        for k, f in zip(live, frames, strict=True):
            together[k].append(f)
    for k in range(3):
        expected = alone[k].push(rows[k][: 4 + 4 * k])
        np.testing.assert_allclose(np.concatenate(together[k]), expected, atol=1e-5)


def test_whole_clips_decode_with_the_window_graph_not_the_step_graph(generator):
    from mogo.bench.quality.evaluate import reconstruct

    with pytest.raises(ValueError, match="decode whole clips with the window graph"):
        generator.streaming_decoder(low_latency=True).decode_offline(_ids(generator, 10))
    features = generator.generate("a person walks forward.", seconds=2, seed=0).features
    centred, low = (reconstruct(generator, [features], low_latency=b)[0] for b in (False, True))
    assert low.shape == centred.shape == features.shape
    scale = np.abs(features).mean()  # both decoders reconstruct the clip, neither exactly
    assert np.abs(low - features).mean() < 0.2 * scale and not np.array_equal(low, centred)
