"""Resumable streams (mogo.stream_state): a resumed stream's frames equal the original's from
the state on, across switches, re-anchors, fresh clips, holds and guidance; states that are
not this bundle's, cut, altered, hostile or newer are refused with one line."""

import base64
import hashlib
import json
import zlib

import numpy as np
import pytest

from mogo import Anchoring, MotionGenerator
from mogo.stream_state import HEADER, MAGIC, MAX_STATE_CHARS, VERSION, StateError, _payload

SMALL = Anchoring(span=20, keep=5, max_one_off=2.0)  # 40 steps


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


def same_from_here(generator, stream, steps, switches=()):
    """Resume `stream` from its state now; both then step `steps` times (switching prompts at
    the given step offsets) and must emit the same frames."""
    resumed = generator.resume(stream.state())
    assert resumed.frames_emitted == stream.frames_emitted
    switches = dict(switches)
    for k in range(steps):
        if k in switches:
            stream.set_prompt(switches[k])
            resumed.set_prompt(switches[k])
        np.testing.assert_array_equal(resumed.step(), stream.step())
    np.testing.assert_array_equal(resumed.tokens.last, stream.tokens.last)
    assert resumed.prompts[-1] == stream.prompts[-1]
    return resumed


@pytest.mark.parametrize("taken_at", [0, 1, 23, 57])
def test_a_resumed_stream_makes_the_frames_the_original_would_have(generator, taken_at):
    stream = generator.stream("a person walks forward.", seed=4, anchoring=SMALL)
    for _ in range(taken_at):
        stream.step()
    same_from_here(generator, stream, 70, {10: "a person jumps.", 30: "a person waves."})
    assert stream.anchor.anchors >= 3  # re-anchors, a switch and the jump's hold on the way


def test_across_fresh_clips_holds_and_a_second_resume(generator):
    stream = generator.stream("a person sits down.", seed=2, anchoring=SMALL)
    for _ in range(30):
        stream.step()
    resumed = same_from_here(generator, stream, 30)
    assert stream.anchor.holding and stream.anchor.fresh >= 1
    same_from_here(generator, resumed, 20, {5: "a person spins to the left."})


def test_a_low_latency_stream_resumes_with_the_frames_its_feet_hold(generator):
    stream = generator.stream("a person walks forward.", seed=4, anchoring=SMALL, low_latency=True)
    for _ in range(9):
        stream.step()
    assert stream.feet.pending == stream.feet.lookahead == 2  # its short window's frames
    same_from_here(generator, stream, 40, {10: "a person jumps."})


def test_guided_unanchored_and_unplanted_streams_resume(generator):
    for options in (
        dict(guidance=2.0),
        dict(anchoring=False, window=16),  # its window overwritten: see the next test
        dict(plant_feet=False, temperature=0.5, top_k=20),
    ):
        stream = generator.stream("a person jogs in a circle.", seed=7, **options)
        for _ in range(12):
            stream.step()
        same_from_here(generator, stream, 40, {20: "a person claps."})


def test_an_overwritten_window_resumes_by_a_prefill(generator):
    """Past its window an unanchored stream's cache no longer comes from steps after a
    prefill: resuming prefills the window, as a switch does (close, not the same numbers
    with int8 graphs), and the stream goes on from the same step."""
    stream = generator.stream("a person walks.", seed=1, anchoring=False, window=8)
    for _ in range(20):
        stream.step()
    assert stream.tokens.prefilled == len(stream.tokens.positions) == 9
    resumed = generator.resume(stream.state())
    assert resumed.tokens.steps == stream.tokens.steps and resumed.steps == stream.steps
    assert len(resumed.step()) == len(stream.step())


def test_frames_decoded_but_not_yet_read_come_first(generator):
    stream = generator.stream("a person waves.", seed=3)
    frames = stream.frames()
    for _ in range(45):  # the first burst is 2 decodes' worth: some of it stays unread
        next(frames)
    assert len(stream._unread)
    resumed = generator.resume(stream.state())
    np.testing.assert_array_equal(
        np.array(list(resumed.frames(30))), np.array([next(frames) for _ in range(30)])
    )


def test_the_state_is_compact_text_well_within_the_limit(generator):
    stream = generator.stream("a person walks forward.", seed=0)
    for _ in range(100):
        stream.step()
    state = stream.state()
    assert isinstance(state, str) and state.isascii() and 1.5 * len(state) < MAX_STATE_CHARS
    assert len(state) < 20_000  # the foot planter's held-back frames are most of it
    unplanted = generator.stream("a person walks forward.", seed=0, plant_feet=False)
    for _ in range(100):
        unplanted.step()
    assert len(unplanted.state()) < 3_000


def reseal(state: str, change=None, version: int = VERSION, body: bytes | None = None) -> str:
    """`state` with its payload changed by `change` (a dict -> None) and a valid checksum:
    what anyone can write, since the checksum is no signature."""
    if body is None:
        payload = _payload(state)
        if change is not None:
            change(payload)
        body = zlib.compress(json.dumps(payload).encode())
    head = HEADER.pack(MAGIC, version, len(body), hashlib.sha256(body).digest())
    return base64.urlsafe_b64encode(head + body).decode().rstrip("=")


def bad(payload_change):
    return lambda state: reseal(state, payload_change)


def set_in(path, value):
    def change(payload):
        *outer, last = path
        for key in outer:
            payload = payload[key]
        payload[last] = value

    return change


@pytest.mark.parametrize(
    "damage,message",
    [
        (lambda s: s[: len(s) // 8 * 4], "truncated"),  # half, in whole base64 groups
        (lambda s: s[:40] + ("A" if s[40] != "A" else "B") + s[41:], "corrupted"),
        (lambda s: "x" * (MAX_STATE_CHARS + 1), "at most"),
        (lambda s: "!!not base64!!", "not base64"),
        (lambda s: base64.urlsafe_b64encode(b"hello world").decode(), "not a stream state"),
        (lambda s: reseal(s, version=VERSION + 1), "newer than this mogo reads"),
        (lambda s: reseal(s, body=zlib.compress(b"[" * 50000 + b"]" * 50000)), "not JSON"),
        (lambda s: reseal(s, body=zlib.compress(b"\0" * 10_000_000)), "inflates past"),
        (lambda s: reseal(s, body=b"not zlib"), "not zlib"),
        (bad(set_in(["bundle"], "0" * 64)), "another bundle"),
        (bad(set_in(["steps"], 10**300)), "'steps' must be an integer"),
        (bad(set_in(["steps"], "12")), "'steps' must be an integer"),
        (bad(set_in(["seed"], -1)), "'seed' must be an integer"),
        (bad(set_in(["rng"], [1, 2, 0, 0])), "not a PCG64 state"),
        (bad(set_in(["prompts"], [[0, 5]])), "'prompts[0]' must be [frame, prompt]"),
        (bad(set_in(["prompts"], [])), "'prompts' must be a list"),
        (bad(set_in(["sampling", "top_p"], 7)), "'sampling'"),
        (bad(set_in(["tokens", "slots"], "AAAA" * 10_000)), "'tokens.slots' must be at most"),
        (bad(set_in(["tokens", "last"], base64.b64encode(b"\xff\xff" * 6).decode())), "values"),
        (bad(set_in(["tokens", "steps"], 0)), "do not agree"),
        (bad(set_in(["decoder", "pushed"], 10**6)), "'decoder': its counts"),
        (
            bad(set_in(["feet", "pin"], base64.b64encode(np.full(12, np.nan).tobytes()).decode())),
            "finite",
        ),
        (bad(set_in(["feet", "flag"], [1, 0, 0, 0])), "'feet'"),
        (bad(set_in(["anchoring", "options", "span"], 10**9)), "anchoring.options.span"),
        (bad(set_in(["anchoring", "options", "keep"], 90)), "keep < span"),
        (bad(lambda payload: payload.pop("decoder")), "'decoder' is missing"),
    ],
)
def test_bad_states_are_refused_with_one_line_naming_the_problem(generator, damage, message):
    stream = generator.stream("a person walks forward.", seed=0)
    for _ in range(40):
        stream.step()
    with pytest.raises(StateError, match=None) as caught:
        generator.resume(damage(stream.state()))
    assert message in str(caught.value) and "\n" not in str(caught.value)
    assert isinstance(caught.value, ValueError)


def test_wrong_types_and_another_bundle(generator, old_generator):
    with pytest.raises(StateError, match="a stream state is text, got bytes"):
        generator.resume(b"MOGO")
    state = old_generator.stream("a person walks.", seed=0).state()
    with pytest.raises(StateError, match="another bundle"):
        generator.resume(state)
