"""Re-anchored streams (mogo.anchoring): deterministic, frames equal to the offline decode of
their tokens across anchors and fresh clips, a held state bounded by the span, prompt switches
re-anchoring at once (test_generator's switch test checks there is no jump in the pose),
clips the model ends starting afresh, one-off prompts settling into the hold."""

import numpy as np
import pytest

from helpers import counted_prefills
from mogo import Anchoring, MotionGenerator
from mogo.anchoring import settles
from mogo.motion.features import facing_directions
from mogo.motion.feet import LOOKAHEAD as FEET_LOOKAHEAD

SMALL = Anchoring(span=20, keep=5, max_one_off=3.0)  # 60 steps


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


@pytest.mark.parametrize(
    "prompt,ends",
    [
        ("a person walks forward.", False),
        ("a person jogs backward.", False),
        ("someone waves with the right hand.", False),
        ("a person does jumping jacks.", False),
        ("a person spins to the left.", False),
        ("a person stands still.", False),
        ("a person claps.", False),
        ("a person sits down.", True),
        ("a person takes a seat.", True),
        ("a person bows.", True),
        ("a person turns left.", True),
        ("a person jumps.", True),
        ("someone kicks with the right foot.", True),
        ("a person waves three times.", True),
        ("a person walks forward for 4 steps.", True),
        ("a person walks, then waves.", True),
    ],
)
def test_prompts_that_end_are_told_from_those_that_go_on(prompt, ends):
    assert settles(prompt) is ends


def test_re_anchored_streams_are_deterministic_and_decode_like_their_tokens(generator):
    lookahead = generator.manifest.vq.decoder.lookahead
    runs = []
    for _ in range(2):
        stream = generator.stream("a person jogs forward.", seed=3, anchoring=SMALL)
        stream.advance(100)
        runs.append((stream.finish(), stream.anchor.anchors))
    (motion, anchors), (again, _) = runs
    ahead = lookahead + FEET_LOOKAHEAD  # steps finish() draws past the cut (down factor 1)
    assert anchors == (100 + ahead - SMALL.span) // (SMALL.span - SMALL.keep) + 1
    assert np.array_equal(motion.tokens, again.tokens)
    assert np.array_equal(motion.joints, again.joints)
    np.testing.assert_allclose(
        motion.joints, offline_past_the_cut(generator, motion, SMALL), atol=1e-5
    )
    plain = generator.stream("a person jogs forward.", seed=3, anchoring=False)
    plain.advance(100)
    tokens = plain.finish().tokens
    assert np.array_equal(tokens[: SMALL.span], motion.tokens[: SMALL.span])  # until the anchor
    assert not np.array_equal(tokens, motion.tokens)


def test_a_re_anchored_stream_holds_at_most_its_span(generator):
    stream = generator.stream("a person walks forward.", seed=1, anchoring=SMALL)
    for _ in range(5 * SMALL.span):
        stream.step()
        held = stream.tokens
        assert len(held.positions) <= SMALL.span + 1 and held.positions.max() < SMALL.span
        assert all(cache.shape[2] <= SMALL.span + 1 for level in held.caches for cache in level)
        assert len(stream.anchor.recent) == min(SMALL.keep, held.steps)


def test_a_switch_re_anchors_at_once_under_the_new_prompt(generator, monkeypatch):
    stream = generator.stream("a person walks forward.", seed=2, anchoring=SMALL)
    stream.advance(13)
    before = stream.anchor.anchors
    prefills = counted_prefills(monkeypatch)
    stream.set_prompt("a person waves with the right hand.")
    assert stream.anchor.anchors == before + 1
    assert len(prefills) == 1  # the cache made for the kept steps only, under the new prompt
    assert stream.tokens.steps == SMALL.switch_keep  # a fresh clip from the last step
    recent = stream.anchor.recent.copy()
    assert np.array_equal(recent, stream.finish().tokens[13 - SMALL.keep : 13])


def test_a_one_off_prompt_settles_into_a_fresh_clip_of_the_hold(generator, monkeypatch):
    stream = generator.stream("a person bows.", seed=0, anchoring=SMALL)
    assert stream.anchor.one_off and stream.tokens.allow_end and not stream.anchor.holding
    prefills = counted_prefills(monkeypatch)
    while not stream.anchor.holding and stream.steps <= stream.anchor.one_off_steps:
        before = len(prefills)
        stream.advance(1)
    assert len(prefills) == before  # a fresh clip of the hold: nothing held to prefill
    stream.advance(stream.anchor.one_off_steps + 1 - stream.steps)
    assert stream.anchor.holding and not stream.anchor.one_off and stream.anchor.fresh == 1
    assert not stream.tokens.allow_end  # the hold stands still: the model does not end it
    assert stream.tokens.steps <= SMALL.span
    stream.set_prompt("a person walks forward.")
    assert not stream.anchor.holding and not stream.anchor.one_off
    assert stream.tokens.allow_end  # a walk the model ends starts again


def test_standing_still_is_never_ended_and_re_anchors_from_its_last_still_keep_steps(generator):
    stream = generator.stream("a person stands still.", seed=5, anchoring=SMALL)
    assert stream.anchor.still and not stream.tokens.allow_end
    stream.advance(SMALL.span)
    assert stream.tokens.steps == SMALL.still_keep and stream.anchor.fresh == 0


def test_a_spin_the_model_ends_starts_again_and_keeps_turning(generator):
    """The model ends a spin after one turn (2 s, within the span): a fresh clip of it starts
    (re-anchored from the turn's standing end instead, the model stood). Frames still decode
    like the tokens across the fresh clips."""
    stream = generator.stream("a person spins to the left.", seed=0)
    stream.advance(200)
    motion = stream.finish()
    clip = generator.generate("a person spins to the left.", seed=0).tokens
    assert np.array_equal(motion.tokens[: len(clip)], clip)  # the first clip: generate's
    assert stream.anchor.fresh >= 3 and stream.anchor.fresh == stream.anchor.anchors
    facing = facing_directions(motion.joints[:200], generator.skeleton, facing_sigma=0)
    turned = np.degrees(np.ptp(np.unwrap(np.arctan2(facing[:, 0], facing[:, 2]))))
    assert turned > 3 * 360 - 90  # about 180 degrees a second, as the corpus spins
    np.testing.assert_allclose(
        motion.joints, offline_past_the_cut(generator, motion, Anchoring()), atol=1e-5
    )


def offline_past_the_cut(generator, motion, anchoring) -> np.ndarray:
    """`motion`'s frames decoded offline from its tokens and those that follow them, its
    last frames planted with the feet's lookahead as the stream going on plants them."""
    prompt, steps = motion.prompts[0][1], len(motion.tokens)
    longer = generator.stream(prompt, seed=motion.seed, anchoring=anchoring)
    longer.advance(steps + FEET_LOOKAHEAD + generator.manifest.vq.decoder.lookahead)
    context = longer.finish().tokens
    assert np.array_equal(context[:steps], motion.tokens)
    return generator.decode(context, [], frames=steps + FEET_LOOKAHEAD).joints[:steps]


def test_anchoring_arguments_are_checked(generator):
    with pytest.raises(ValueError, match="keep < span"):
        Anchoring(span=10, keep=10)
    with pytest.raises(ValueError, match="switch_keep <= keep"):
        Anchoring(keep=4, switch_keep=5)
    with pytest.raises(ValueError, match="still_keep <= keep"):
        Anchoring(keep=4, still_keep=0)
    with pytest.raises(TypeError, match="anchoring must be"):
        generator.stream("a person walks forward.", anchoring="yes")
