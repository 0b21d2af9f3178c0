"""A level graph rewritten to return only the new cache slot computes what the row-wise graph
computes, to a float rounding, for a step with a past and for a prefill."""
import numpy as np
import pytest

pytest.importorskip("onnx")

from mogo.serve.newslot import newslot_graph  # noqa: E402
from mogo.serve.rowwise import rowwise_graph  # noqa: E402
from mogo.token_generator import TokenGenerator  # noqa: E402


def test_the_new_slot_and_the_same_logits(generator):
    levels = generator.manifest.t2m.levels[:2]
    whole = [rowwise_graph(generator.bundle.path(level.file)) for level in levels]
    before = TokenGenerator(whole, levels, generator.manifest.end_token)
    after = TokenGenerator([newslot_graph(graph) for graph in whole], levels,
                           generator.manifest.end_token)
    rng = np.random.default_rng(0)
    rows, slots = 3, 20
    prompt = np.repeat(generator.embed(["a person walks"]), rows, axis=0).astype(np.float32)
    uncond = np.array([False, True, False])
    tokens = rng.integers(0, 500, (rows, 1, generator.tokens.num_levels))
    past_positions = np.r_[0, 30, np.arange(2, slots)]  # one dead slot (after the query)
    for level in range(len(levels)):
        layers, heads, dim = before.cache_shapes[level]
        past = [rng.standard_normal((rows, heads, slots, dim)).astype(np.float32)
                for _ in range(2 * layers)]
        logits, presents = before.run(level, prompt, uncond, tokens, np.array([slots]),
                                      past_positions, past)
        new_logits, new_slots = after.run(level, prompt, uncond, tokens, np.array([slots]),
                                          past_positions, past)
        np.testing.assert_allclose(new_logits, logits, atol=1e-4)
        for present, slot in zip(presents, new_slots):
            assert slot.shape == (rows, heads, 1, dim)
            np.testing.assert_allclose(slot, present[:, :, -1:], atol=1e-5)
        prefill = np.repeat(tokens, 4, axis=1)
        none = np.zeros(0, np.int64)
        for a, b in zip(before.run(level, prompt, uncond, prefill, np.arange(4), none,
                                   before.empty_cache(level, rows))[1],
                        after.run(level, prompt, uncond, prefill, np.arange(4), none,
                                  after.empty_cache(level, rows))[1]):
            np.testing.assert_allclose(b, a, atol=1e-5)
