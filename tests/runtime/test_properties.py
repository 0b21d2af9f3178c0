"""Property-based tests (hypothesis) over the public API and the `mogo` command: whatever the
arguments, a call either works or fails the documented way (a TypeError or ValueError with a
one-line message; exit status 2 with exactly one `mogo: error:` line), never with another
exception, a numpy RuntimeWarning or a motion of the wrong length. Valid lengths stay at most
one second so that each example is fast."""

import contextlib
import io
import math
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mogo import Motion, MotionGenerator, PromptWarning
from mogo.cli import main

SETTINGS = settings(
    max_examples=60, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow]
)

WEIRD_FLOATS = st.sampled_from(
    [math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 5e-324, 1e-320, 1e-7, 1e300, -1e300, 2.0**63]
)
ODD_VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.text(max_size=4),
    st.binary(max_size=3),
    st.lists(st.integers(), max_size=2),
    st.just(10**400),
    st.sampled_from([np.float32(0.5), np.int64(3), np.float64(math.nan)]),
)
PROMPTS = st.one_of(
    st.sampled_from(
        [
            "a person walks forward.",
            "a person jumps.",
            "someone waves.",
            "xyzzy",
            "🙂",
            "一个人在走路",
            "...",
            "walked",
            "   ",
            "",
            "a person walks forward, " * 14 + "then jumps.",
        ]
    ),
    st.text(max_size=40),
    st.builds(lambda s: "a person walks " + s, st.text(max_size=20)),
    ODD_VALUES,
)
SECONDS = st.one_of(st.floats(min_value=0.0, max_value=1.0), WEIRD_FLOATS, ODD_VALUES)
SEEDS = st.one_of(st.integers(-3, 2**70), ODD_VALUES)
SAMPLING = st.fixed_dictionaries(
    {},
    optional={
        "temperature": st.one_of(st.floats(0, 3), WEIRD_FLOATS, ODD_VALUES),
        "top_k": st.one_of(st.integers(-3, 2**80), ODD_VALUES),
        "top_p": st.one_of(st.floats(0, 1.5), WEIRD_FLOATS, ODD_VALUES),
        "guidance": st.one_of(st.floats(-3, 5), WEIRD_FLOATS, ODD_VALUES),
    },
)


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


def works_or_refuses(call):
    """The call's result, or None when it raised a TypeError or ValueError with a one-line
    message; any warning but a PromptWarning fails the test."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = call()
        except (TypeError, ValueError) as error:
            assert str(error) and "\n" not in str(error), repr(error)
            result = None
    assert all(issubclass(w.category, PromptWarning) for w in caught), [
        str(w.message) for w in caught
    ]
    return result


def well_formed(motion, seconds=None, fps=20.0):
    assert isinstance(motion, Motion) and len(motion.joints) >= 1
    assert motion.joints.shape[1:] == (22, 3) and np.all(np.isfinite(motion.joints))
    if seconds is not None:
        assert len(motion.joints) == round(float(seconds) * fps)


@SETTINGS
@given(
    text=PROMPTS,
    seconds=SECONDS,
    seed=SEEDS,
    options=SAMPLING,
    align=st.sampled_from([False, False, True, None, "rules", 1]),
)
def test_generate_works_or_refuses(generator, text, seconds, seed, options, align):
    motion = works_or_refuses(
        lambda: generator.generate(text, seconds=seconds, seed=seed, align=align, **options)
    )
    if motion is not None:
        well_formed(motion, None if align is True else seconds)


@SETTINGS
@given(
    text=PROMPTS,
    seed=SEEDS,
    options=SAMPLING,
    frames=st.integers(1, 40),
    window=st.one_of(st.none(), st.integers(-2, 200), ODD_VALUES),
    switch=PROMPTS,
)
def test_stream_works_or_refuses(generator, text, seed, options, frames, window, switch):
    stream = works_or_refuses(lambda: generator.stream(text, seed=seed, window=window, **options))
    if stream is None:
        return
    first = list(stream.frames(frames))
    works_or_refuses(lambda: stream.set_prompt(switch))
    later = list(stream.frames(3))
    assert len(first) == frames and len(later) == 3
    assert all(f.shape == (22, 3) and np.all(np.isfinite(f)) for f in first + later)


ENTRIES = st.one_of(st.tuples(PROMPTS, SECONDS), st.lists(PROMPTS, max_size=3), PROMPTS)


@SETTINGS
@given(schedule=st.one_of(st.lists(ENTRIES, max_size=3), ODD_VALUES), seed=SEEDS, options=SAMPLING)
def test_play_works_or_refuses(generator, schedule, seed, options):
    motion = works_or_refuses(lambda: generator.play(schedule, seed=seed, **options))
    if motion is not None:
        assert isinstance(motion, Motion) and np.all(np.isfinite(motion.joints))


# -- the command -------------------------------------------------------------------------------
NUMBER_WORDS = st.one_of(
    st.sampled_from(
        [
            "nan",
            "inf",
            "-inf",
            "-1",
            "0",
            "0.01",
            "1e-320",
            "1e300",
            "1e400",
            "x",
            "",
            "0x10",
            "1_0",
            str(2**70),
            "-0",
            " 1",
            "0.5",
            "1",
            "2",
            "3",
        ]
    ),
    st.floats(0, 1).map(str),
    st.integers(-5, 50).map(str),
)
THREADS = st.sampled_from(["0", "-1", "1", "2", "x", "nan", "1.5", str(2**70)])  # no 50 cores
FLAGS = st.lists(
    st.one_of(
        st.tuples(
            st.sampled_from(["--temperature", "--top-k", "--top-p", "--guidance", "--seed"]),
            NUMBER_WORDS,
        ),
        st.tuples(st.just("--threads"), THREADS),
    ),
    max_size=4,
)
CLI_PROMPTS = st.one_of(
    st.sampled_from(
        [
            "a person walks forward.",
            "a person jumps.",
            "xyzzy",
            "a person walks xyzzy.",
            "",
            " ",
            "-x",
            "--seed",
        ]
    ),
    st.text(st.characters(blacklist_categories=["Cs", "Cc"]), max_size=30),
)


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(argv)
        except SystemExit as exit:  # argparse: --help never drawn, so its errors
            status = exit.code
    return status, out.getvalue(), err.getvalue()


TOLD = ("note: ", "generating: ", "writing: ")  # notes, and a long take's progress


def one_error_line_or_success(status: int, err: str) -> None:
    lines = err.splitlines()
    if status == 2:
        errors = [line for line in lines if line.startswith("mogo: error: ")]
        assert len(errors) == 1, err
        assert all(line.startswith(TOLD) for line in lines if line not in errors), err
    else:
        assert status == 0 and all(line.startswith(TOLD) for line in lines), (status, err)


@SETTINGS
@given(
    text=CLI_PROMPTS,
    seconds=NUMBER_WORDS,
    flags=FLAGS,
    extra=st.sampled_from(
        [
            [],
            [],
            ["--align", "rules"],
            ["--bundle", "/nonexistent"],
            ["--bvh-bone-translations"],
            ["--no-such-flag"],
            ["--seconds"],
        ]
    ),
)
def test_mogo_generate_works_or_says_one_line(text, seconds, flags, extra):
    with tempfile.TemporaryDirectory() as folder:
        argv = [
            "generate",
            text,
            "--seconds",
            seconds,
            "--out",
            folder,
            "--name",
            "m",
            *extra,
            *(word for flag in flags for word in flag),
        ]
        status, out, err = run_cli(argv)
        one_error_line_or_success(status, err)
        written = sorted(p.name for p in Path(folder).iterdir())
        assert written == (["m.bvh", "m.gif", "m.json", "m.npy"] if status == 0 else []), argv


@SETTINGS
@given(text=CLI_PROMPTS, frames=st.one_of(st.integers(1, 40).map(str), NUMBER_WORDS), flags=FLAGS)
def test_mogo_stream_works_or_says_one_line(text, frames, flags):
    if frames.strip().lstrip("+").isdigit() and int(frames) > 40:
        frames = "40"  # a stream without an end is not a test
    status, out, err = run_cli(
        ["stream", text, "--frames", frames, *(word for flag in flags for word in flag)]
    )
    one_error_line_or_success(status, err)
    if status == 0:
        assert len(out.splitlines()) == int(frames)
