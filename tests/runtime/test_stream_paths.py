"""The stream's corners every path relies on: the shipped re-anchoring, the one-off cap when
the model never ends a clip, continue_from on a re-anchored stream, frames read in part."""
import numpy as np
import pytest
from mogo import Anchoring, MotionGenerator
from mogo.generator import EMBEDDINGS_KEPT


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


def test_streams_re_anchor_with_the_shipped_defaults(generator):
    """The figures docs/long_streams.md measured: a change here is a change of behaviour."""
    shipped = Anchoring()
    assert (shipped.span, shipped.keep, shipped.switch_keep, shipped.still_keep,
            shipped.max_one_off, shipped.hold_prompt) == (80, 10, 1, 5, 196,
                                                          "a person stands still.")
    assert shipped.max_one_off == round(generator.defaults.max_seconds * generator.fps)
    assert generator.stream("a person walks forward.", seed=0).anchor.anchoring == shipped


def test_a_one_off_the_model_never_ends_holds_at_max_one_off(generator):
    """Capped after exactly max_one_off steps (the model ends no bow within 8)."""
    cap = Anchoring(span=20, keep=5, max_one_off=8)
    stream = generator.stream("a person bows.", seed=0, anchoring=cap)
    for n in range(1, cap.max_one_off):
        stream.step()
        assert stream._tokens.steps == n and not stream.anchor.holding
    stream.step()
    assert stream.anchor.holding and stream.anchor.fresh == 1 and stream._tokens.steps == 0


def test_continue_from_on_a_re_anchored_stream_keeps_the_clips_last_steps(generator):
    """A clip longer than the span: the first step re-anchors on the clip's end and the new
    step, like a stream that drew the clip itself."""
    clip = generator.generate("a person walks forward.", seconds=5, seed=4)
    shipped = Anchoring()
    assert len(clip.joints) > shipped.span
    stream = generator.stream("a person jogs forward.", seed=9)
    stream.continue_from(clip)
    tokens = generator.encode_motion(clip)  # the clip's features encoded again
    assert np.array_equal(stream.anchor.recent, tokens[-shipped.keep:])
    assert stream._tokens.steps == len(tokens)
    row = stream._next_tokens()
    assert stream.anchor.anchors == 1 and stream._tokens.steps == shipped.keep
    assert np.array_equal(stream.anchor.recent,
                          np.concatenate([tokens[1 - shipped.keep:], row[None]]))
    assert np.array_equal(stream._tokens.slot_tokens[1:], stream.anchor.recent[:-1])
    assert np.array_equal(stream._tokens.last, row)


def test_a_step_after_frames_read_in_part_gives_the_unread_frames_first(generator):
    """frames() leaves part of a burst unread; the step that decodes the next burst returns
    the unread frames, then the new ones (feet planted: their own lookahead)."""
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
    assert len(got) > len(read) + 8  # a step brought new frames after the unread ones
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
