"""mogo.token_generator on the shipped bundle, against the contracts its docstrings state: the
uniforms of the seed mapping, the end token, the sliding window (the cache holds the prompt
prefix and the last `window` steps, each slot at its own position with its own tokens, never
more), prompt switches after the window has wrapped, continue_from and restart.

A reference for "the model sees exactly these slots": one prefill of the held slots under a
prompt, then the step's own position on that cache, computed here from the rules (position 0
the prompt prefix, position p >= 1 the tokens of step p - 1, the prefix and the last `window`
steps held) and not from the stream's bookkeeping. A stream that has just re-prefilled its
cache (set_prompt, continue_from) must give those logits. (A stream that only slid its window
need not: its kept slots were computed when older steps were still visible.)"""

import copy
import json
import threading
from types import SimpleNamespace

import numpy as np
import pytest

import mogo.token_generator as token_loop
from mogo import DEFAULT_BUNDLE, MotionGenerator, Sampling
from mogo.manifest import BundleError
from mogo.token_generator import LEVEL_INPUTS, TokenGenerator, _cache_shape, balanced_groups

PROMPTS = ["a person walks forward.", "a person jumps on the spot.", "someone waves."]
TOP_P = Sampling(top_p=0.9)
GUIDED = Sampling(top_p=0.9, guidance=2.0)
SAME_CACHE = 2e-4  # logits of two prefills of the same slots (slot order may differ)


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


@pytest.fixture(scope="module")
def tokens(generator):
    return generator.tokens


@pytest.fixture(scope="module")
def embeddings(generator):
    return generator.embed(PROMPTS)


@pytest.fixture
def draws(monkeypatch):
    """Every call of the sampler from the token loop: its logits, uniforms and forbidden ids."""
    calls = []
    choose = token_loop.choose_tokens

    def recording(cond, uncond, uniforms, sampling, forbid=None):
        calls.append(
            dict(
                cond=cond.copy(),
                uncond=None if uncond is None else uncond.copy(),
                uniforms=uniforms.copy(),
                forbid=forbid,
            )
        )
        return choose(cond, uncond, uniforms, sampling, forbid)

    monkeypatch.setattr(token_loop, "choose_tokens", recording)
    return calls


def run(stream, steps: int) -> np.ndarray:
    return np.array([stream.step() for _ in range(steps)]).reshape(steps, -1)


def expected_logits(tokens, embedding, steps, window, guided=False, slot_order=None) -> np.ndarray:
    """Logits (B, L, K + 1) of step n = len(steps) >= 1, -inf padded like the loop pads them,
    from a cache that holds exactly the prefix and the last `window` steps (see the module
    docstring), in position order or in `slot_order` (the same positions, as a stream whose
    window has wrapped holds them: the shipped int8 graphs' logits depend on slot order by up
    to ~0.06, their quantised kernels' rounding, where float graphs' do not)."""
    n, L = len(steps), tokens.num_levels
    first = 1 if window is None else max(1, n - window)
    held = np.r_[0, first:n].astype(np.int64)
    if slot_order is not None:
        assert sorted(slot_order) == held.tolist()
        held = np.asarray(slot_order, np.int64)
    at = np.concatenate([np.zeros((1, L), np.int64), steps])  # position p: tokens of step p - 1
    flags = np.array([False, True][: 2 if guided else 1])
    prompt = np.repeat(np.asarray(embedding, np.float32)[None], len(flags), axis=0)
    out = np.full((len(flags), L, tokens.num_classes), -np.inf, np.float32)
    for level in range(L):
        _, cache = tokens.run(
            level,
            prompt,
            flags,
            np.repeat(at[held][None], len(flags), 0),
            held,
            np.zeros(0, np.int64),
            tokens.empty_cache(level, len(flags)),
        )
        logits, _ = tokens.run(
            level,
            prompt,
            flags,
            np.repeat(at[n][None, None], len(flags), 0),
            np.array([n]),
            held,
            cache,
        )
        out[:, level, : logits.shape[1]] = logits
    return out


def drawn_logits(call) -> np.ndarray:
    return np.stack([call["cond"]] + ([] if call["uncond"] is None else [call["uncond"]]))


def assert_holds_prefix_and_last_steps(stream, steps: np.ndarray, window) -> None:
    """The stream's cache: slot 0 the prefix, then one slot per kept step at its position with
    the tokens that position holds, no other slot; every level's keys and values that long."""
    n, L = len(steps), stream.generator.num_levels
    first = 1 if window is None else max(1, n - window)
    assert stream.positions[0] == 0
    assert sorted(stream.positions.tolist()) == [0, *range(first, n)]
    at = np.concatenate([np.zeros((1, L), np.int64), steps])
    assert np.array_equal(stream.slot_tokens, at[stream.positions])
    assert np.array_equal(stream.last, steps[-1])
    assert all(
        array.shape[2] == len(stream.positions) for cache in stream.caches for array in cache
    )


# -- the seed mapping and the end token ----------------------------------------------------------
@pytest.mark.parametrize("sampling", [TOP_P, Sampling(temperature=0), GUIDED])
def test_each_step_draws_the_next_uniforms_of_the_seed_whatever_the_settings(
    tokens, embeddings, draws, sampling
):
    stream = tokens.start(embeddings[0], seed=77, sampling=sampling, allow_end=False)
    run(stream, 12)
    expected = np.random.Generator(np.random.PCG64(77)).random((12, tokens.num_levels))
    assert np.array_equal(np.array([d["uniforms"] for d in draws]), expected)


def test_the_same_seed_gives_the_same_tokens_another_seed_others(tokens, embeddings):
    first = run(tokens.start(embeddings[0], seed=3, sampling=TOP_P, allow_end=False), 20)
    again = run(tokens.start(embeddings[0], seed=3, sampling=TOP_P, allow_end=False), 20)
    other = run(tokens.start(embeddings[0], seed=4, sampling=TOP_P, allow_end=False), 20)
    assert np.array_equal(first, again) and not np.array_equal(first, other)
    assert np.array_equal(
        first, tokens.generate(embeddings[0], num_frames=20, sampling=TOP_P, seed=3)
    )
    seed_0 = tokens.generate(embeddings[0], num_frames=4, sampling=TOP_P, seed=0)
    assert np.array_equal(tokens.generate(embeddings[0], num_frames=4, sampling=TOP_P), seed_0)
    assert np.array_equal(
        run(tokens.start(embeddings[0], sampling=TOP_P, allow_end=False), 4), seed_0
    )
    spread = tokens.with_level_workers(2)  # levels run concurrently: the same tokens
    assert np.array_equal(
        first, spread.generate(embeddings[0], num_frames=20, sampling=TOP_P, seed=3)
    )


def test_guided_steps_feed_the_sampler_both_branches_of_the_same_cache(tokens, embeddings, draws):
    """With guidance the loop runs a conditional and an unconditional row; right after
    continue_from both are the reference logits of their branch."""
    steps = run(tokens.start(embeddings[1], seed=5, sampling=TOP_P, allow_end=False), 9)
    stream = tokens.start(embeddings[1], seed=5, sampling=GUIDED, allow_end=False)
    stream.continue_from(steps)
    stream.step()
    expected = expected_logits(tokens, embeddings[1], steps, None, guided=True)
    np.testing.assert_allclose(drawn_logits(draws[-1]), expected, atol=SAME_CACHE, rtol=0)
    finite = np.isfinite(expected[0])
    assert np.abs(expected[0][finite] - expected[1][finite]).max() > 0.1


@pytest.fixture
def end_always_wins(tokens, monkeypatch):
    """The level graphs with level 0's end token made certain."""
    forward = tokens.run

    def run_level(level, *inputs):
        logits, presents = forward(level, *inputs)
        if level == 0:
            logits = logits.copy()
            logits[:, tokens.end_token] = 1e4
        return logits, presents

    monkeypatch.setattr(tokens, "run", run_level)


def test_the_end_token_may_end_a_stream_from_its_second_step(
    tokens, embeddings, end_always_wins, monkeypatch
):
    stream = tokens.start(embeddings[0], seed=0, sampling=TOP_P)
    first = stream.step()
    assert first is not None and first[0] != tokens.end_token  # never an empty motion
    assert stream.step() is None
    assert tokens.generate(embeddings[0], sampling=TOP_P).shape == (1, tokens.num_levels)

    def no_more(*args):
        raise AssertionError("an ended stream ran a level graph")

    monkeypatch.setattr(tokens, "run", no_more)
    assert stream.step() is None and stream.step() is None  # ended for good, nothing drawn


@pytest.mark.parametrize("length", [6, 257])
def test_a_forced_length_never_draws_the_end_token(tokens, embeddings, end_always_wins, length):
    """Exactly `length` steps, also past 256 (12.8 s), where a count compared by identity
    instead of value would run on: CPython caches small ints only."""
    steps = tokens.generate(embeddings[0], num_frames=length, sampling=TOP_P)
    assert steps.shape == (length, tokens.num_levels)
    assert not np.any(steps[:, 0] == tokens.end_token)


# -- the sliding window ----------------------------------------------------------------------------
@pytest.mark.parametrize("window", [1, 5])
def test_the_window_holds_the_prefix_and_the_last_steps_at_every_step(tokens, embeddings, window):
    stream = tokens.start(embeddings[0], seed=2, sampling=TOP_P, window=window, allow_end=False)
    steps = np.zeros((0, tokens.num_levels), np.int64)
    for _ in range(3 * window + 4):
        steps = np.concatenate([steps, stream.step()[None]])
        assert_holds_prefix_and_last_steps(stream, steps, window)
        assert len(stream.positions) <= 1 + window


@pytest.mark.parametrize("window,length", [(128, 300), (256, 290)])
def test_the_window_bounds_the_cache_of_a_long_stream(tokens, embeddings, window, length):
    """The shipped window, and one past 255 steps (where a length compared by identity, not
    value, would never count as full: CPython caches small ints only)."""
    stream = tokens.start(embeddings[0], seed=2, sampling=TOP_P, window=window, allow_end=False)
    steps = run(stream, length)
    assert len(stream.positions) == window + 1
    assert_holds_prefix_and_last_steps(stream, steps, window)


@pytest.fixture
def past_lengths(tokens, monkeypatch):
    """How many past slots each level graph call was given."""
    lengths = []
    forward = tokens.run

    def run_level(level, prompt, uncond, token_ids, positions, past_positions, past):
        lengths.append(len(past_positions))
        return forward(level, prompt, uncond, token_ids, positions, past_positions, past)

    monkeypatch.setattr(tokens, "run", run_level)
    return lengths


def test_generate_and_stream_slide_the_bundles_window(generator, past_lengths):
    window = json.loads((DEFAULT_BUNDLE / "manifest.json").read_text())["defaults"]["window"]
    steps = window + 30
    generator.generate(PROMPTS[0], seconds=steps / generator.fps, seed=1)
    assert max(past_lengths) == 1 + window
    past_lengths.clear()
    generator.stream(PROMPTS[0], seed=1, anchoring=False).advance(steps)
    assert max(past_lengths) == 1 + window
    past_lengths.clear()
    generator.stream(PROMPTS[0], seed=1, window=7, anchoring=False).advance(20)
    assert max(past_lengths) == 1 + 7


@pytest.mark.parametrize("window", [0, -1])
def test_an_empty_window_is_refused(generator, tokens, embeddings, window):
    with pytest.raises(ValueError, match="window must be >= 1"):
        tokens.start(embeddings[0], window=window)
    with pytest.raises(ValueError, match="window must be >= 1"):
        generator.stream(PROMPTS[0], seed=0, window=window)


# -- prompt switches -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "window,switch",
    [
        (5, 1),
        (5, 5),
        (5, 6),
        (5, 7),
        (5, 9),
        (5, 13),
        (128, 129),
        (128, 140),
        (128, 200),
        (128, 257),
    ],
)
@pytest.mark.parametrize("sampling", [TOP_P, GUIDED], ids=["plain", "guided"])
def test_a_prompt_switch_reprefills_the_held_slots_at_their_positions(
    tokens, embeddings, draws, window, switch, sampling
):
    """After `switch` steps under prompt A (past the window: the slots are in ring order), then
    set_prompt(B): the cache holds the prefix and the last `window` steps, and the next step
    sees exactly them under B."""
    stream = tokens.start(embeddings[0], seed=8, sampling=sampling, window=window, allow_end=False)
    steps = run(stream, switch)
    stream.set_prompt(embeddings[1])
    assert_holds_prefix_and_last_steps(stream, steps, window)
    slot_order = stream.positions.tolist()
    after = run(stream, 3)
    expected = expected_logits(tokens, embeddings[1], steps, window, sampling.guided, slot_order)
    np.testing.assert_allclose(drawn_logits(draws[switch]), expected, atol=SAME_CACHE, rtol=0)
    assert_holds_prefix_and_last_steps(stream, np.concatenate([steps, after]), window)


@pytest.mark.parametrize("window,switch", [(5, 3), (5, 6), (5, 8), (5, 13), (128, 129), (128, 257)])
@pytest.mark.parametrize("sampling", [TOP_P, GUIDED], ids=["plain", "guided"])
def test_a_switched_stream_goes_on_as_a_fresh_stream_continued_from_its_steps(
    tokens, embeddings, draws, window, switch, sampling
):
    """set_prompt(B) after `switch` steps, then the same steps as a stream started under B,
    continued from those steps, with the same random state. (Switch points where the ring is
    in position order, or small: elsewhere the int8 graphs' slot-order rounding may flip a
    draw, see expected_logits.)"""
    stream = tokens.start(embeddings[0], seed=8, sampling=sampling, window=window, allow_end=False)
    steps = run(stream, switch)
    fresh = tokens.start(embeddings[1], seed=8, sampling=sampling, window=window, allow_end=False)
    fresh.continue_from(steps)
    fresh.rng = copy.deepcopy(stream.rng)
    stream.set_prompt(embeddings[1])
    draws.clear()
    after = run(stream, 4)
    assert np.array_equal(after, run(fresh, 4))
    for switched, fresh_draw in zip(draws[:4], draws[4:], strict=False):
        np.testing.assert_allclose(
            drawn_logits(switched), drawn_logits(fresh_draw), atol=SAME_CACHE, rtol=0
        )


def test_a_prompt_set_before_the_first_step_is_the_prompt_of_the_prefill(tokens, embeddings):
    stream = tokens.start(embeddings[0], seed=4, sampling=TOP_P, allow_end=False)
    stream.set_prompt(embeddings[2])
    started = tokens.start(embeddings[2], seed=4, sampling=TOP_P, allow_end=False)
    assert np.array_equal(run(stream, 10), run(started, 10))


# -- continue_from ---------------------------------------------------------------------------------
@pytest.mark.parametrize("length", [1, 2, 5, 6, 7, 8, 16])
def test_continue_from_keeps_the_prefix_and_the_last_window_steps(
    tokens, embeddings, draws, length
):
    """window 5: a clip of n steps leaves the prefix and steps n-5 .. n-1 in the cache (n - 1 of
    them below that), the next step is step n; then the window slides on from there."""
    window = 5
    steps = run(tokens.start(embeddings[2], seed=6, sampling=TOP_P, allow_end=False), length)
    stream = tokens.start(embeddings[0], seed=1, sampling=TOP_P, window=window, allow_end=False)
    run(stream, 3)  # drawn before: forgotten
    stream.continue_from(steps)
    assert stream.steps == length
    assert_holds_prefix_and_last_steps(stream, steps, window)
    draws.clear()
    more = run(stream, 2 * window + 1)
    expected = expected_logits(tokens, embeddings[0], steps, window)
    np.testing.assert_allclose(drawn_logits(draws[0]), expected, atol=SAME_CACHE, rtol=0)
    assert_holds_prefix_and_last_steps(stream, np.concatenate([steps, more]), window)


def test_continue_from_without_a_window_keeps_every_step(tokens, embeddings, draws):
    steps = run(tokens.start(embeddings[2], seed=6, sampling=TOP_P, allow_end=False), 12)
    stream = tokens.start(embeddings[0], seed=1, sampling=TOP_P, allow_end=False)
    stream.continue_from(steps)
    assert_holds_prefix_and_last_steps(stream, steps, None)
    stream.step()
    np.testing.assert_allclose(
        drawn_logits(draws[-1]),
        expected_logits(tokens, embeddings[0], steps, None),
        atol=SAME_CACHE,
        rtol=0,
    )


def test_continue_from_refuses_what_is_not_a_clip_of_steps(tokens, embeddings):
    stream = tokens.start(embeddings[0], seed=0)
    L = tokens.num_levels
    for bad in (
        np.zeros((0, L), np.int64),
        np.zeros((3, L - 1), np.int64),
        np.zeros((3, L + 1), np.int64),
        np.zeros(L),
        np.zeros((3, L, 1), np.int64),
    ):
        with pytest.raises(ValueError, match="tokens to continue from"):
            stream.continue_from(bad)


def test_restart_forgets_every_step_drawn(tokens, embeddings):
    """After restart the stream is a fresh clip under its prompt: greedy, the same steps as a
    stream just started (whatever it drew before and whatever its random state)."""
    greedy = Sampling(temperature=0)
    stream = tokens.start(embeddings[1], seed=3, sampling=greedy, window=5, allow_end=False)
    run(stream, 9)  # past the window: the slots in ring order
    stream.restart()
    assert stream.steps == 0 and len(stream.positions) == 0
    started = tokens.start(embeddings[1], seed=8, sampling=greedy, window=5, allow_end=False)
    assert np.array_equal(run(stream, 8), run(started, 8))


# -- the rest of the loop's promises ---------------------------------------------------------------
def test_a_batched_prompt_embeds_as_the_same_prompt_alone(generator):
    """The attention mask: padding a short prompt to a long one's length changes nothing."""
    short, long = "a man bows.", "a person walks forward slowly, turns around and waves twice."
    together = generator.embed([short, long])
    np.testing.assert_allclose(together[0], generator.embed([short])[0], atol=1e-5, rtol=0)
    np.testing.assert_allclose(together[1], generator.embed([long])[0], atol=1e-5, rtol=0)


def test_the_level_graphs_are_read_as_the_model_config_states(generator, tokens):
    """The cache shape (layers, heads, head_dim) read off each graph's past inputs is the
    t2m config's; level 0 scores every code and the end token."""
    config = generator.manifest.t2m.config
    assert tokens.cache_shapes == [
        (layers, heads, config["head_dim"])
        for layers, heads in zip(config["layers"], config["heads"], strict=False)
    ]
    assert tokens.num_classes == config["codebook_size"] + 1
    logits, _ = tokens.run(
        0,
        np.zeros((1, config["text_dim"]), np.float32),
        np.array([False]),
        np.zeros((1, 1, tokens.num_levels), np.int64),
        np.array([0]),
        np.zeros(0, np.int64),
        tokens.empty_cache(0, 1),
    )
    assert logits.shape == (1, tokens.num_classes)


def test_level_workers_are_checked_where_the_graphs_are_opened(generator, tokens, embeddings):
    levels = generator.manifest.t2m.levels
    paths = [generator.bundle.path(graph.file) for graph in levels]
    with pytest.raises(ValueError, match="5 graph files for 6 graph entries"):
        TokenGenerator(paths[:5], levels, generator.manifest.end_token)
    with pytest.raises(ValueError, match="7 graph files for 6 graph entries"):
        TokenGenerator(paths + paths[:1], levels, generator.manifest.end_token)
    for make in (
        lambda: TokenGenerator(paths, levels, generator.manifest.end_token, level_workers=0),
        lambda: tokens.with_level_workers(0),
    ):
        with pytest.raises(ValueError, match="level_workers must be >= 1, got 0"):
            make()
    assert tokens.with_level_workers(1).level_groups == [list(range(6))]
    assert TokenGenerator(paths, levels, generator.manifest.end_token).level_groups == [
        list(range(6))
    ]  # one worker unless asked
    two = TokenGenerator(paths, levels, generator.manifest.end_token, level_workers=2)
    assert two.level_groups == [[0, 3, 5], [1, 2, 4]]  # by the config's layers, 4 3 2 2 1 1
    threads = {}
    run_level = two.run

    def recording(level, *args):
        threads.setdefault(level, set()).add(threading.get_ident())
        return run_level(level, *args)

    two.run = recording
    assert np.array_equal(
        two.generate(embeddings[1], num_frames=6, seed=1),
        tokens.generate(embeddings[1], num_frames=6, seed=1),
    )
    here = {threading.get_ident()}  # group 0 on the caller's thread, group 1 on a worker
    assert all(threads[level] == here for level in (0, 3, 5))
    assert all(threads[level].isdisjoint(here) for level in (1, 2, 4))


@pytest.mark.parametrize(
    "pasts,problem",
    [
        ([[1, 4, "past", 8]] * 4, None),
        ([[1, 4, "past", 8]] * 3, "odd"),
        ([], "no pasts"),
        ([[1, 4, "past", 8]], "a key without its value"),
        ([[1, 4, 8]] * 4, "three axes"),
        ([[1, 4, "past", 8, 1]] * 2, "five axes"),
        ([[1, "heads", "past", 8]] * 2, "heads not fixed"),
        ([[1, 4, "past", "dim"]] * 2, "head_dim not fixed"),
    ],
)
def test_a_graph_without_key_and_value_pairs_of_pasts_is_no_level_graph(pasts, problem):
    inputs = [SimpleNamespace(name=name, shape=[1]) for name in LEVEL_INPUTS]
    inputs += [SimpleNamespace(name=f"past_{i}", shape=shape) for i, shape in enumerate(pasts)]
    session = SimpleNamespace(get_inputs=lambda: inputs)
    if problem is None:
        assert _cache_shape(session, "level_0.onnx") == (2, 4, 8)
    else:
        with pytest.raises(BundleError, match="level_0.onnx: not a level graph"):
            _cache_shape(session, "level_0.onnx")


def test_level_groups_balance_layers_and_group_0_holds_level_0():
    assert balanced_groups([4, 3, 2, 2, 1, 1], 2) == [[0, 3, 5], [1, 2, 4]]
    assert balanced_groups([4, 3, 2, 2, 1, 1], 1) == [[0, 1, 2, 3, 4, 5]]
    assert balanced_groups([1, 1], 5) == [[0], [1]]
    assert balanced_groups([1, 5, 1], 2) == [[0, 2], [1]]
    assert balanced_groups([1, 1, 4], 2) == [[0, 1], [2]]  # the heaviest placed first
