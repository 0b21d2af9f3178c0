"""Streams stepped together give each stream exactly what it gives alone, and what the
runtime's own TokenStream gives before its window fills; with or without solo steps (the
steps before the window fills on the bundle's own graphs, one stream per call)."""
import numpy as np
import pytest

from mogo.serve.stepper import COMPACT_EVERY, Stepper

WINDOW = 12  # small, so that steps fall out of the window and dead slots are compacted
SOLO_STEPS = 7  # then batched warm-up steps, as in the server


@pytest.fixture(scope="module", params=["batched", "solo"])
def stepper(request, engine_parts, generator):
    solo = generator.tokens if request.param == "solo" else None
    return Stepper(engine_parts, WINDOW, generator.manifest.t2m.config["max_relative_distance"],
                   solo, SOLO_STEPS)


@pytest.fixture(scope="module")
def prompts(generator):
    return generator.embed(["a person walks forward", "a person jumps", "a person waves"])


def test_alone_it_gives_the_runtime_tokens_until_the_window_fills(stepper, generator, prompts):
    sampling = generator.sampling(None)
    reference = generator.tokens.start(prompts[0], 7, sampling, WINDOW, allow_end=False)
    stream = stepper.start(prompts[0], 7, sampling)
    for _ in range(WINDOW + 1):
        assert np.array_equal(stepper.step([stream])[0], reference.step())
        assert stream.solo is None or stream.steps < SOLO_STEPS  # then the batched layout


def test_solo_steps_are_the_runtime_stream_on_the_bundles_graphs(generator, engine_parts,
                                                                 prompts):
    stepper = Stepper(engine_parts, WINDOW, 64, solo=generator.tokens, solo_steps=WINDOW + 1)
    sampling = generator.sampling(None, top_k=40)
    reference = generator.tokens.start(prompts[0], 9, sampling, WINDOW, allow_end=False)
    stream = stepper.start(prompts[0], 9, sampling)
    for n in range(WINDOW + 1):
        if n == 4:
            stream.set_prompt(prompts[1])
            reference.set_prompt(prompts[1])
        assert stream.solo is not None
        assert np.array_equal(stepper.step([stream])[0], reference.step())


def run(stepper, generator, prompts, others: int, ahead: int, steps: int = 100) -> np.ndarray:
    """One stream's tokens (a switch included) while `others` streams run, `ahead` steps ahead;
    every other one guided (two rows)."""
    stream = stepper.start(prompts[0], 3, generator.sampling(None))
    crowd = [stepper.start(prompts[1 + k % 2], 10 + k, generator.sampling(None, guidance=1.0 + k % 2))
             for k in range(others)]
    for _ in range(ahead):
        stepper.step(crowd)
    drawn = []
    for n in range(steps):
        if n == 5:  # during the solo steps, if any
            stream.set_prompt(prompts[1])
        if n == 40:
            stream.set_prompt(prompts[2])
        if n == 70 and crowd:
            crowd[0].set_prompt(prompts[0])
        drawn.append(stepper.step([stream, *crowd])[0])
    return np.array(drawn)


@pytest.mark.parametrize("others, ahead", [(3, 0), (4, 5), (3, 4 * COMPACT_EVERY),
                                           (3, 2 * WINDOW + 3)])
def test_a_stream_draws_the_same_tokens_whatever_else_runs(stepper, generator, prompts,
                                                           others, ahead):
    """(3, 0): one shared call; (4, 5): warm-up at other steps; 4 * COMPACT_EVERY ahead: past
    warm-up, one shared call at other steps (virtual positions); 2 * WINDOW + 3: other phases,
    separate calls; dead slots and compaction on both sides."""
    assert 100 > WINDOW + 2 * COMPACT_EVERY
    alone = run(stepper, generator, prompts, 0, 0)
    assert np.array_equal(alone, run(stepper, generator, prompts, others, ahead))
