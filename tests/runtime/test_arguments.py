"""The public API refuses bad arguments where they enter it (mogo.arguments): a TypeError for a
wrong type and a ValueError for a wrong value, each naming the argument, never an error from
deep inside numpy or onnxruntime; prompts the model reads only in part give a PromptWarning."""

import warnings

import numpy as np
import pytest

from mogo import (
    Motion,
    MotionGenerator,
    PromptWarning,
    Sampling,
    UnfamiliarPromptWarning,
    UnknownPromptWarning,
)
from mogo.motion.skeleton import SMPL_22


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


@pytest.mark.parametrize(
    "call,message",
    [
        (lambda g: g.generate(None), "text must be a string .*got NoneType"),
        (lambda g: g.generate(5), "text must be a string .*got int"),
        (lambda g: g.generate(b"a person walks"), "text must be a string .*got bytes"),
        (lambda g: g.stream(None), "text must be a string .*got NoneType"),
        (lambda g: g.generate_batch(["a person walks.", 3]), r"texts\[1\] must be a string"),
        (lambda g: g.generate_batch(7), "texts must be a list of prompts, got int"),
        (lambda g: g.generate("walk", seconds="2"), "seconds must be a number, got str"),
        (lambda g: g.generate("walk", seconds=True), "seconds must be a number, got bool"),
        (lambda g: g.generate("walk", seed="3"), "seed must be an integer, got str"),
        (lambda g: g.generate("walk", seed=1.5), "seed must be an integer, got float"),
        (lambda g: g.generate("walk", sampling="greedy"), "sampling must be a Sampling or None"),
        (lambda g: g.generate("walk", temperature="hot"), "temperature must be a number, got str"),
        (lambda g: g.stream("walk", window="8"), "window must be an integer, got str"),
        (lambda g: g.play("a person walks"), "schedule must be a list of .* pairs, got str"),
        (lambda g: g.play(3), "schedule must be a list of .* pairs, got int"),
        (
            lambda g: g.play(["text"]),
            r"schedule\[0\] must be a \(prompt, seconds\) pair, got 'text'",
        ),
        (lambda g: g.play([("a", "x")]), r"schedule\[0\]: seconds must be a number, got str"),
        (
            lambda g: g.play([("a person walks.", 1), (None, 1)]),
            r"schedule\[1\]: prompt must be a string",
        ),
        (
            lambda g: g.stream("a person walks.", seed=0).continue_from([1, 2, 3]),
            "motion must be a Motion .*got list",
        ),
        (lambda g: g.encode_motion(np.zeros((40, 263))), "motion must be a Motion .*got ndarray"),
        (lambda g: g.embed("a person walks."), "texts must be a list of prompts, got one str"),
        (lambda g: next(g.stream("a person walks.").frames("3")), "limit must be an integer"),
        (lambda g: g.stream("a person walks.").advance(2.5), "steps must be an integer"),
        (
            lambda g: g.stream("a person walks.", anchoring=1),  # 1 == True, but is not True
            "anchoring must be True, False or an Anchoring, got int",
        ),
        (
            lambda g: g.stream("a person walks.", anchoring=0.0),
            "anchoring must be True, False or an Anchoring, got float",
        ),
    ],
)
def test_a_wrong_type_is_a_type_error_naming_the_argument(generator, call, message):
    with pytest.raises(TypeError, match=message):
        call(generator)


@pytest.mark.parametrize(
    "threads,error,message",
    [
        ("2", TypeError, "threads must be an integer, got str"),
        (1.5, TypeError, "threads must be an integer, got float"),
        (0, ValueError, "threads must be >= 1, got 0"),
        (2**70, ValueError, "threads must be at most 256"),  # was a pybind11 dump from onnxruntime
    ],
)
def test_load_checks_threads_before_reading_the_bundle(threads, error, message):
    with pytest.raises(error, match=message):
        MotionGenerator.load(threads=threads)


@pytest.mark.parametrize(
    "call,message",
    [
        (
            lambda g: g.generate("walk", seconds=0.01),
            r"seconds must be at least 0.05 \(one token step, 1 frame at 20 fps\), got 0.01",
        ),
        (lambda g: g.generate("walk", seconds=float("inf")), "seconds must be at most 600"),
        (lambda g: g.generate("walk", seconds=10**400), "seconds must be at most 600"),
        (lambda g: g.generate("walk", seed=-1), "seed must be >= 0, got -1"),
        (lambda g: g.stream("walk", window=0), "window must be >= 1, got 0"),
        (
            lambda g: g.play([("a person walks.", 1), ("a person jumps.", 0.01)]),
            r"schedule\[1\]: seconds must be at least 0.05",
        ),
        (
            lambda g: g.play([("a person walks.", 1), ("  ", 1)]),
            r"schedule\[1\]: the prompt is empty",
        ),
        (lambda g: g.generate("walk", guidance=float("nan")), "guidance must be finite, got nan"),
        (lambda g: g.generate("walk", top_k=-1), "top_k must be >= 0"),
        (
            lambda g: g.generate("walk", align=1),  # 1 == True, but is not True
            "align must be True, False or a PromptAligner, got 1",
        ),
        (
            lambda g: g.encode_motion(_clip(np.zeros((40, 263, 1)))),
            r"motion features must be \(T, 263\), got \(40, 263, 1\)",
        ),
        (
            lambda g: g.encode_motion(_clip(np.zeros((40, 264)))),
            r"motion features must be \(T, 263\), got \(40, 264\)",
        ),
        (
            lambda g: g.encode_motion(_clip(np.zeros((0, 263)))),
            "the motion has 0 frames; at least 1 are needed",
        ),
        (
            lambda g: g.encode_motion(_clip(np.zeros((40, 262)))),
            r"motion features must be \(T, 263\), got \(40, 262\)",
        ),
        (
            lambda g: g.encode_motion(_clip(np.zeros(263))),
            r"motion features must be \(T, 263\), got \(263,\)",
        ),
        (lambda g: next(g.stream("a person walks.").frames(-1)), "limit must be >= 0, got -1"),
        (lambda g: g.stream("a person walks.").advance(-1), "steps must be >= 0, got -1"),
        (
            lambda g: g.generate("walk", align=0),
            "align must be True, False or a PromptAligner, got 0",
        ),
    ],
)
def test_a_wrong_value_is_a_value_error_naming_the_argument(generator, call, message):
    with pytest.raises(ValueError, match=message):
        call(generator)


def _clip(features: np.ndarray) -> Motion:
    """A Motion carrying these features (only they are read when a clip is encoded)."""
    return Motion(
        features,
        np.zeros((len(features), 22, 3), np.float32),
        20.0,
        np.zeros((0, 6), np.int64),
        SMPL_22,
    )


def test_advancing_a_stream_by_zero_steps_draws_nothing(generator):
    stream = generator.stream("a person walks.", seed=0)
    stream.advance(0)
    assert list(stream.frames(0)) == []
    assert stream.finish().joints.shape[0] == 0


def test_a_clip_of_one_frame_is_encoded(generator):
    assert generator.encode_motion(_clip(np.zeros((1, 263)))).shape == (1, 6)


def test_numpy_numbers_are_taken_as_the_same_plain_numbers(generator):
    plain = generator.generate("a person jumps.", seconds=2, seed=4)
    numpy = generator.generate(
        "a person jumps.",
        seconds=np.float32(2),
        seed=np.int64(4),
        sampling=Sampling(top_p=np.float64(0.9)),
    )
    assert np.array_equal(plain.tokens, numpy.tokens) and len(numpy.joints) == 40


def test_the_shortest_length_is_one_token_step(generator):
    assert generator.generate("a person jumps.", seconds=0.05, seed=0).joints.shape == (1, 22, 3)
    played = generator.play([("a person walks.", 1), ("a person jumps.", 0.05)], seed=0)
    assert len(played.joints) == 21


@pytest.mark.parametrize(
    "prompt", ["🙂🙂", "一个人在走路", "xyzzy", "xyzzy plugh!", "...", "walked"]
)
def test_a_prompt_with_no_known_word_is_told_by_its_own_warning(old_generator, prompt):
    """The model makes one generic motion for it ('walked' is not in the vocabulary, only
    spelled out in letters): a warning of its own, which the command makes an error, and the
    way out (prompt alignment)."""
    g = old_generator
    for call in (
        lambda: g.generate(prompt, seconds=1),
        lambda: g.stream(prompt),
        lambda: g.generate_batch(["a person walks.", prompt], seconds=1),
        lambda: g.play([("a person walks.", 1), (prompt, 1)]),
    ):
        with pytest.warns(
            UnknownPromptWarning, match="the model knows no word of the prompt"
        ) as told:
            call()
        assert len(told) == 1 and repr(prompt) in str(told[0].message)
        assert "align" in str(told[0].message)
        assert told[0].filename == __file__  # told at the caller's line, not inside mogo


def test_unknown_words_are_named_by_a_warning_and_the_motion_is_made(old_generator):
    """Unknown: [UNK] (xyzzy, 🙂) or spelled out letter by letter (plugh: p ##l ##u ##g ##h),
    named without the punctuation around them."""
    with pytest.warns(
        PromptWarning,
        match=r"does not know 'xyzzy', '🙂', 'plugh': their "
        "meaning is lost",
    ) as told:
        motion = old_generator.generate(
            "a person walks xyzzy forward 🙂!! (plugh)", seconds=1, seed=0
        )
    assert len(motion.joints) == 20 and told[0].filename == __file__
    stream = old_generator.stream("a person walks forward.", seed=0)
    with pytest.warns(PromptWarning, match="does not know 'plugh'") as told:
        stream.set_prompt("a person plugh jumps.")
    assert told[0].filename == __file__


def test_a_prompt_past_the_text_encoders_length_is_told_where_it_is_cut(old_generator):
    limit = old_generator.manifest.text.max_length
    prompt = "a person walks forward, " * 12 + "then the person jumps and waves."
    with pytest.warns(PromptWarning) as told:
        motion = old_generator.generate(prompt, seconds=1, seed=0)
    message = str(told[0].message)
    tokens = len(old_generator.tokenizer.encode(prompt).ids)
    assert tokens == limit  # the encoder's own tokenizer cuts it, the count is the whole
    assert message.startswith(
        f"the prompt is {1 + 12 * 5 + 7} tokens long and the model reads "
        f"only {limit}: everything after 'walks forward, then the person' "
        "is ignored"
    )
    assert len(motion.joints) == 20 and told[0].filename == __file__


def test_a_prompt_far_from_the_repertoire_is_told_at_the_callers_line(generator):
    far = "the stock market fell sharply on tuesday"
    for call in (
        lambda: generator.generate(far, seconds=1),
        lambda: generator.stream(far),
        lambda: generator.generate_batch(["a person walks.", far], seconds=1),
        lambda: generator.play([("a person walks.", 1), (far, 1)]),
        lambda: generator.stream("a person walks.").set_prompt(far),
    ):
        with pytest.warns(UnfamiliarPromptWarning) as told:
            call()
        assert [w.filename for w in told] == [__file__]


def test_a_known_prompt_warns_of_nothing(generator):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        generator.generate("a person walks forward, then waves.", seconds=1, seed=0)
        generator.play([("a person walks.", 1), ("a person jumps.", 1)], seed=0)
