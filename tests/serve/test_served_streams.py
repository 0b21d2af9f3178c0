"""Served streams on the engine's clock: a switch changes what a stream does, a burst of new
streams all start, the prompt-embedding cache stays bounded and right."""
import numpy as np
import pytest

pytest.importorskip("onnx")

from mogo.serve.engine import EMBEDDINGS_KEPT, Engine


def served(engine, prompts: dict[int, str], seed: int, steps: int) -> np.ndarray:
    """One stream's joints over `steps` token steps, the prompt switched at the steps given."""
    stream = engine.open(prompts[0], seed, engine.generator.sampling(None), 0.0)
    frames = []
    while stream.tokens.steps < steps:
        if stream.tokens.steps in prompts:
            engine.switch(stream, prompts[stream.tokens.steps])
        frames += [joints for _, _, joints in engine.round([stream])]
    engine.close(stream)
    return np.concatenate(frames)


def test_a_served_switch_changes_the_frames_after_it(generator, engine_parts):
    engine = Engine(generator, 1, tokens=engine_parts)
    walk = {0: "a person walks forward."}
    plain = served(engine, walk, 5, 120)
    switched = served(engine, walk | {60: "a person jumps on the spot."}, 5, 120)
    lookahead = generator.manifest.vq.decoder.lookahead
    before = 60 - lookahead - 8  # frames no token after the switch reaches (feet: 8 more)
    n = min(len(plain), len(switched))
    assert n > 70
    np.testing.assert_allclose(switched[:before], plain[:before], atol=1e-5)
    assert np.abs(switched[60:n] - plain[60:n]).max() > 0.1


def test_a_burst_of_new_streams_all_start(generator, engine_parts):
    """More new streams than a round's solo steps: each still reaches its first frame."""
    engine = Engine(generator, 1, tokens=engine_parts)
    sampling = generator.sampling(None)
    burst = [engine.open("a person walks forward.", k, sampling, 0.0) for k in range(25)]
    started, now = set(), 0.0
    while len(started) < len(burst) and now < 8.0:
        due = engine.due(now)
        started |= {stream.id for stream, _, _ in engine.round(due)} if due else set()
        now = round(now + (0 if due else 0.05), 6)
    assert started == {stream.id for stream in burst}


def test_the_prompt_embedding_cache_stays_bounded_and_right(generator, engine_parts):
    engine = Engine(generator, 1, tokens=engine_parts)
    prompts = [f"a person walks {k} steps." for k in range(EMBEDDINGS_KEPT + 20)]
    for prompt in prompts:
        engine.embedding(prompt)
    assert len(engine._embeddings) == EMBEDDINGS_KEPT
    expected = generator.embed([prompts[0], prompts[-1]])
    np.testing.assert_array_equal(engine.embedding(prompts[0]), expected[0])  # embedded again
    np.testing.assert_array_equal(engine.embedding(prompts[-1]), expected[1])  # still kept
    assert len(engine._embeddings) == EMBEDDINGS_KEPT
