"""Every way of making motion is the one re-anchored stream: generate past a clip's length,
play; and the stream's corners they rely on: the shipped re-anchoring, the one-off cap when
the model never ends a clip, continue_from on a re-anchored stream, frames read in part."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from mogo import Anchoring, MotionGenerator
from mogo.arguments import CutWarning
from mogo.generator import EMBEDDINGS_KEPT
from mogo.motion.features import facing_directions


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


def test_streams_re_anchor_with_the_shipped_defaults(generator):
    """The figures docs/long_streams.md measured: a change here is a change of behaviour."""
    shipped = Anchoring()
    assert (
        shipped.span,
        shipped.keep,
        shipped.switch_keep,
        shipped.still_keep,
        shipped.max_one_off,
        shipped.hold_prompt,
    ) == (80, 10, 1, 5, None, "a person stands still.")
    stream = generator.stream("a person walks forward.", seed=0)
    assert stream.anchor.one_off_steps == 196  # the bundle's longest clip: 9.8 s of 20 steps
    assert generator.stream("a person walks forward.", seed=0).anchor.anchoring == shipped


def test_a_one_off_the_model_never_ends_holds_at_max_one_off(generator):
    """Capped after exactly max_one_off seconds (the model ends no bow within 8 steps)."""
    cap = Anchoring(span=20, keep=5, max_one_off=0.4)
    stream = generator.stream("a person bows.", seed=0, anchoring=cap)
    assert stream.anchor.one_off_steps == 8
    for n in range(1, 8):
        stream.step()
        assert stream.tokens.steps == n and not stream.anchor.holding
    stream.step()
    assert stream.anchor.holding and stream.anchor.fresh == 1 and stream.tokens.steps == 0


def test_continue_from_on_a_re_anchored_stream_starts_a_fresh_clip_from_the_clips_end(generator):
    """As at a switch: the model sees the clip's last switch_keep steps, the anchor keeps its
    last `keep` for the next re-anchor, the decoder the whole clip (its left context)."""
    clip = generator.generate("a person walks forward.", seconds=5, seed=4)
    shipped = Anchoring()
    stream = generator.stream("a person jogs forward.", seed=9)
    stream.continue_from(clip)
    tokens = generator.encode_motion(clip)  # the clip's features encoded again
    assert np.array_equal(stream.anchor.recent, tokens[-shipped.keep :])
    assert stream.tokens.steps == shipped.switch_keep and stream.anchor.anchors == 1
    assert np.array_equal(stream.tokens.last, tokens[-1])
    assert stream.decoder.pushed == len(tokens)
    row = stream._next_tokens()
    assert np.array_equal(
        stream.anchor.recent, np.concatenate([tokens[1 - shipped.keep :], row[None]])
    )
    with pytest.raises(ValueError, match="before the first step"):
        stream.continue_from(clip)


ONE_OFFS = ["a person jumps.", "a person turns left."]


def done_within_two_seconds(generator, prompt: str, joints: np.ndarray) -> bool:
    """The jump (the pelvis well above where it stands) or the turn (over 45 degrees) in the
    first 2 s of `joints`."""
    joints = joints[: round(2 * generator.fps)]
    if "jumps" in prompt:
        return np.ptp(joints[:, 0, 1]) > 0.15
    facing = facing_directions(joints, generator.skeleton, facing_sigma=0)
    angle = np.degrees(np.unwrap(np.arctan2(facing[:, 0], facing[:, 2])))
    return angle[-1] - angle[0] > 45


@pytest.mark.parametrize("prompt", ONE_OFFS)
def test_a_one_off_after_continue_from_happens_within_two_seconds(generator, prompt):
    """Kept whole, the end of the walk made the model end the one-off at once, and stand."""
    for seed in range(3):
        walk = generator.generate("a person walks forward.", seconds=4, seed=seed)
        stream = generator.stream(prompt, seed=seed)
        stream.continue_from(walk)
        joints = np.array(list(stream.frames(round(2 * generator.fps))))
        assert done_within_two_seconds(generator, prompt, joints), f"seed {seed}: {prompt!r}"


@pytest.mark.parametrize("prompt", ONE_OFFS)
def test_a_one_off_after_a_switch_happens_within_two_seconds(generator, prompt):
    """From the switch's own frame on (`prompts`: where the new prompt takes over): the switch
    plays the new prompt, not the old one re-anchored."""
    for seed in range(3):
        stream = generator.stream("a person walks forward.", seed=seed)
        stream.advance(round(4 * generator.fps) // generator.down_factor)
        stream.set_prompt(prompt)
        stream.advance(round(3 * generator.fps) // generator.down_factor)
        motion = stream.finish()
        after = motion.joints[motion.prompts[1][0] :]
        assert done_within_two_seconds(generator, prompt, after), f"seed {seed}: {prompt!r}"


def test_a_step_after_frames_read_in_part_gives_the_unread_frames_first(generator):
    """frames() leaves part of a burst unread; the next step() returns them first, and the
    frames go on as from a stream read by step() alone (feet planted: their own lookahead)."""
    plain = generator.stream("a person walks forward.", seed=3)
    reference = []
    while sum(map(len, reference)) < 60:
        reference.append(plain.step())
    reference = np.concatenate(reference)
    stream = generator.stream("a person walks forward.", seed=3)
    read = list(stream.frames(limit=3))
    got = [np.array(read)]
    while sum(map(len, got)) < 60:
        got.append(stream.step())
    got = np.concatenate(got)
    assert len(got) > len(read) + 8  # steps brought new frames after the unread ones
    np.testing.assert_array_equal(got[:60], reference[:60])


def test_the_prompt_embedding_cache_stays_bounded_and_right():
    generator = MotionGenerator.load()  # its own cache
    prompts = [f"a person walks {k} steps." for k in range(EMBEDDINGS_KEPT + 20)]
    for prompt in prompts:
        generator._embedding(prompt)
    assert len(generator._embeddings) == EMBEDDINGS_KEPT
    assert prompts[0] not in generator._embeddings and prompts[-1] in generator._embeddings
    expected = generator.embed([prompts[0], prompts[-1]])
    np.testing.assert_array_equal(generator._embedding(prompts[0]), expected[0])  # again
    np.testing.assert_array_equal(generator._embedding(prompts[-1]), expected[1])  # kept
    assert len(generator._embeddings) == EMBEDDINGS_KEPT
    assert not generator._embedding(prompts[0]).flags.writeable  # shared by streams


def test_generate_longer_than_a_clip_is_the_stream_cut_to_length(generator):
    """Past the bundle's longest clip (9.8 s) a clip is the re-anchored stream, the same
    frames and tokens: its last frames too, planted with the feet's lookahead as the stream
    that goes on plants them."""
    seconds = 12.0
    motion = generator.generate("a person jogs forward.", seconds=seconds, seed=2)
    stream = generator.stream("a person jogs forward.", seed=2)
    stream.advance(round(seconds * generator.fps) // generator.down_factor)
    expected = stream.finish()
    assert stream.anchor.anchors >= 1
    assert len(motion.joints) == round(seconds * generator.fps)
    assert np.array_equal(motion.tokens, expected.tokens)
    np.testing.assert_array_equal(motion.joints, expected.joints)
    assert motion.prompts == [(0, "a person jogs forward.")]
    going_on = generator.stream("a person jogs forward.", seed=2).frames(len(motion.joints))
    np.testing.assert_array_equal(motion.joints, np.array(list(going_on)))


def test_play_is_the_stream_switched_at_each_entry(generator):
    """Every frame of a schedule, its last ones included, is the frame of a stream switched
    at the entries' steps."""
    schedule = [("a person walks forward", 3), ("a person turns left", 2)]
    motion = generator.play(schedule, seed=0)
    stream, chunks = generator.stream(schedule[0][0], seed=0), []
    for _ in range(round(3 * generator.fps) // generator.down_factor):
        chunks.append(stream.step())
    stream.set_prompt(schedule[1][0])
    while sum(map(len, chunks)) < len(motion.joints):
        chunks.append(stream.step())
    np.testing.assert_array_equal(motion.joints, np.concatenate(chunks)[: len(motion.joints)])


def test_a_clip_the_model_does_not_end_is_cut_at_the_cap_with_a_note(monkeypatch):
    generator = MotionGenerator.load()
    monkeypatch.setattr(generator, "defaults", replace(generator.defaults, max_seconds=1.0))
    with pytest.warns(CutWarning, match=r"did not end the motion within 1 s"):
        motion = generator.generate("a person walks forward.", seed=0)
    assert len(motion.joints) == generator.fps  # one second
    with warnings.catch_warnings():
        warnings.simplefilter("error", CutWarning)
        generator.generate("a person walks forward.", seconds=1.0, seed=0)  # asked: no note


def test_the_readmes_play_example_turns_left_for_seeds_0_to_7(generator):
    """A switch to a one-off action re-anchors under it at once: the turn happens (with the
    old prompt's context kept, half of these seeds did not turn)."""
    for seed in range(8):
        motion = generator.play(
            [("a person walks forward", 3), ("a person turns left", 2)], seed=seed
        )
        facing = facing_directions(motion.joints[60:], generator.skeleton, facing_sigma=0)
        angle = np.degrees(np.unwrap(np.arctan2(facing[:, 0], facing[:, 2])))
        assert angle[-1] - angle[0] > 45, f"seed {seed} turned {angle[-1] - angle[0]:.0f} deg"
