"""The public runtime on the default bundle shipped in the package: text -> motion, streams,
prompt switching, determinism, a held state that stays constant however long a stream runs,
and refusal of bad input."""

import hashlib
import shutil
import subprocess
import sys
import threading
from dataclasses import replace

import numpy as np
import pytest

from mogo.bundle import BundleError
from mogo.generator import DEFAULT_BUNDLE, STREAM_DECODE_EVERY, MotionGenerator
from mogo.motion.feet import LOOKAHEAD as FEET_LOOKAHEAD
from mogo.motion.skeleton import MAX_FRAMES
from mogo.sampling import Sampling


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


def test_generate_gives_a_motion_of_the_asked_length(generator):
    motion = generator.generate("a person walks forward.", seconds=2.5, seed=0)
    assert motion.joints.shape == (50, 22, 3) and motion.features.shape == (50, 263)
    assert motion.tokens.shape == (50, 6) and motion.fps == 20.0 and motion.seed == 0
    assert motion.prompts == [(0, "a person walks forward.")]
    assert np.all(np.isfinite(motion.joints))
    walked = motion.joints[-1, 0] - motion.joints[0, 0]
    assert walked[2] > 0.5  # the trained model walks forward (+Z), not in place


def test_the_model_can_end_the_motion_itself_and_batches_prompts(generator):
    motions = generator.generate_batch(
        ["a person jumps on the spot three times.", "someone waves."], seed=3
    )
    assert len(motions) == 2 and [m.seed for m in motions] == [3, 4]
    for motion in motions:
        assert 1 <= len(motion.joints) <= MAX_FRAMES


def test_same_seed_same_tokens_also_in_another_process(generator):
    tokens = generator.generate("a person runs backward.", seconds=1, seed=7).tokens
    again = generator.generate("a person runs backward.", seconds=1, seed=7).tokens
    other = generator.generate("a person runs backward.", seconds=1, seed=8).tokens
    assert np.array_equal(tokens, again) and not np.array_equal(tokens, other)
    script = (
        "import hashlib, numpy as np\n"
        "from mogo.generator import MotionGenerator\n"
        "t = MotionGenerator.load().generate('a person runs backward.', seconds=1, seed=7)"
        ".tokens\nprint(hashlib.sha256(np.ascontiguousarray(t).tobytes()).hexdigest())\n"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == hashlib.sha256(tokens.tobytes()).hexdigest()


def test_sessions_in_parallel_threads_do_not_affect_each_other(generator):
    prompts = ["a person walks forward.", "a person squats.", "someone claps.", "a man bows."]
    alone = [generator.generate(p, seconds=1.5, seed=k).tokens for k, p in enumerate(prompts)]
    together = [None] * len(prompts)

    def work(k):
        together[k] = generator.generate(prompts[k], seconds=1.5, seed=k).tokens

    threads = [threading.Thread(target=work, args=(k,)) for k in range(len(prompts))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert all(np.array_equal(a, b) for a, b in zip(alone, together, strict=False))


def test_streamed_frames_equal_the_offline_decode(generator):
    """The decoder's part (feet as decoded; planted feet: test_feet.py)."""
    lookahead = generator.manifest.vq.decoder.lookahead
    stream = generator.stream("a person jogs in a circle.", seed=2, plant_feet=False)
    streamed = np.concatenate([stream.step() for _ in range(100)])
    assert 100 - lookahead - STREAM_DECODE_EVERY < len(streamed) <= 100 - lookahead
    recorded = generator.stream("a person jogs in a circle.", seed=2, plant_feet=False)
    recorded.advance(100)
    motion = recorded.finish()  # the last frames too, their right context drawn past the cut
    longer = generator.stream("a person jogs in a circle.", seed=2, plant_feet=False)
    longer.advance(100 + lookahead)
    context = longer.finish().tokens
    assert np.array_equal(context[:100], motion.tokens)
    offline = generator.decode(context, [], frames=100, plant_feet=False)
    assert motion.joints.shape == offline.joints.shape == (100, 22, 3)
    assert np.array_equal(offline.tokens, motion.tokens)
    np.testing.assert_allclose(motion.joints, offline.joints, atol=1e-5)
    np.testing.assert_allclose(motion.features, offline.features, atol=1e-4)
    np.testing.assert_allclose(streamed, offline.joints[: len(streamed)], atol=1e-5)


def test_frames_iterator_and_lookahead(generator):
    """The decoder's lookahead and bursts (planted feet add theirs: test_feet.py)."""
    stream = generator.stream("a person walks forward.", seed=0, plant_feet=False)
    lookahead = generator.manifest.vq.decoder.lookahead
    assert all(len(stream.step()) == 0 for _ in range(lookahead))  # waiting for right context
    first = stream.step()
    assert len(first) == 1  # the first frame as soon as it can be, then bursts
    frames = list(stream.frames(limit=10))
    assert len(frames) == 10 and frames[0].shape == (22, 3)
    emitted = stream.frames_emitted
    assert emitted == 1 + 2 * STREAM_DECODE_EVERY  # 1 + 10 + 6 waiting for the next call
    following = stream.step()
    assert len(following) == 6 and stream.frames_emitted == emitted
    later = [stream.step() for _ in range(2 * STREAM_DECODE_EVERY)]
    # the same frames, each once, as from a stream read by step() alone
    plain = generator.stream("a person walks forward.", seed=0, plant_feet=False)
    steps = lookahead + 1 + 2 * STREAM_DECODE_EVERY + 1 + 2 * STREAM_DECODE_EVERY
    np.testing.assert_array_equal(
        np.concatenate([first, frames, following, *later]),
        np.concatenate([plain.step() for _ in range(steps)]),
    )
    assert len(list(plain.frames(limit=300))) == 300  # past CPython's cache of small ints


def test_prompt_switch_keeps_the_past_changes_the_future_without_a_jump(generator):
    steps, switch = 120, 60
    plain = generator.stream("a person walks forward.", seed=5)
    plain.advance(steps)
    plain = plain.finish()
    switched = generator.stream("a person walks forward.", seed=5)
    switched.advance(switch)
    switched.set_prompt("a person jumps on the spot.")
    switched.advance(steps - switch)
    switched = switched.finish()
    assert switched.prompts == [
        (0, "a person walks forward."),
        (switch, "a person jumps on the spot."),
    ]
    assert np.array_equal(switched.tokens[:switch], plain.tokens[:switch])
    assert not np.array_equal(switched.tokens[switch:], plain.tokens[switch:])
    lookahead = generator.manifest.vq.decoder.lookahead
    before = switch - lookahead  # frames not yet influenced by any token after the switch
    np.testing.assert_allclose(switched.joints[:before], plain.joints[:before], atol=1e-5)
    moves = np.abs(np.diff(switched.joints, axis=0)).max(axis=(1, 2))  # per-frame joint motion
    around = moves[switch - 3 : switch + 3]
    elsewhere = np.concatenate([moves[: switch - 3], moves[switch + 3 :]])
    assert around.max() <= elsewhere.max()


def test_a_schedule_plays_as_one_motion(generator):
    motion = generator.play([("a person walks forward.", 2.0), ("a person waves.", 1.5)], seed=1)
    assert len(motion.joints) == 70 and [f for f, _ in motion.prompts] == [0, 40]
    moves = np.abs(np.diff(motion.joints, axis=0)).max(axis=(1, 2))
    assert moves[37:43].max() <= np.delete(moves, np.s_[37:43]).max()  # no jump at the switch


def test_continue_from_goes_on_from_the_end_of_a_clip(generator):
    clip = generator.generate("a person walks forward.", seconds=3, seed=4)
    stream = generator.stream("a person turns left.", seed=9)
    stream.continue_from(clip)
    frames = np.array(list(stream.frames(limit=40)))
    assert frames.shape == (40, 22, 3)
    gap = np.abs(frames[0] - clip.joints[-1]).max()
    assert gap < 0.2, f"the continuation starts {gap:.2f} m away from the clip's last frame"
    with pytest.raises(ValueError, match="before the first step"):
        stream.continue_from(clip)


def _held_state(stream) -> tuple:
    """The sizes of everything a stream keeps between steps."""
    tokens = stream.tokens
    return (
        tuple(held.shape for cache in tokens.caches for held in cache),
        tokens.positions.shape,
        tokens.slot_tokens.shape,
        len(stream._unread),
        stream._record is None,
    )


@pytest.mark.parametrize("window", [None, 8], ids=["bundle-window", "window-8"])
def test_a_long_stream_holds_a_constant_state(generator, window):
    """Past the window every step replaces the oldest slot: the cache keeps the prefix and the
    latest `window` steps, nothing a stream holds grows, and the decoder keeps at most its
    receptive field. Four trips round the window show what 20,000 steps would. (Re-anchored,
    the default, a stream never fills the window: test_anchoring.)"""
    stream = generator.stream("a person jogs in a circle.", seed=11, window=window, anchoring=False)
    window = window or generator.defaults.window
    decoder = generator.manifest.vq.decoder
    most_buffered = decoder.left_context + decoder.lookahead + STREAM_DECODE_EVERY - 1
    steps, full = 4 * window + 3, None
    for n in range(1, steps + 1):
        stream.step()
        assert stream.decoder.buffered_tokens <= most_buffered
        if n > window:
            held = stream.tokens
            assert sorted(held.positions) == [0, *range(n - window, n)]
            assert full in (None, _held_state(stream)), f"the state grew at step {n}"
            full = _held_state(stream)
    assert all(shape[2] == 1 + window for shape in full[0])
    ready = steps - decoder.lookahead
    decoded = stream.frames_emitted + stream.feet.pending  # the feet hold some frames back
    assert ready - STREAM_DECODE_EVERY < decoded <= ready
    assert stream.feet.pending == min(decoded, FEET_LOOKAHEAD)


@pytest.mark.parametrize(
    "call,message",
    [
        (lambda g: g.generate(""), "the prompt is empty"),
        (lambda g: g.generate("   \n"), "the prompt is empty"),
        (lambda g: g.generate("walk", seconds=0), "seconds must be a positive number"),
        (lambda g: g.generate("walk", seconds=-2), "seconds must be a positive number"),
        (lambda g: g.generate("walk", seconds=float("nan")), "seconds must be a positive number"),
        (lambda g: g.generate("walk", seconds=1e6), "at most 600"),
        (lambda g: g.generate("walk", temperature=-1), "temperature must be >= 0"),
        (lambda g: g.generate("walk", top_k=-3), "top_k must be >= 0"),
        (lambda g: g.generate("walk", top_p=0), r"top_p must be in \(0, 1\]"),
        (lambda g: g.generate("walk", seed=-1), "seed must be >= 0, got -1"),
        (lambda g: g.generate_batch([]), "no prompt given"),
        (lambda g: g.generate_batch("walk"), "generate_batch takes a list of prompts"),
        (lambda g: g.play([]), "the schedule is empty"),
        (lambda g: g.stream(""), "the prompt is empty"),
    ],
)
def test_bad_input_is_refused_clearly(generator, call, message):
    with pytest.raises(ValueError, match=message):
        call(generator)


def test_sampling_is_one_object_or_its_fields_as_keywords(generator):
    assert generator.sampling() == Sampling.from_defaults(vars(generator.defaults))
    assert generator.sampling(top_k=5) == replace(generator.sampling(), top_k=5)
    assert generator.sampling(Sampling(temperature=0), top_p=0.5) == Sampling(0.0, 0, 0.5, 1.0)
    given = generator.generate("a person squats.", seconds=1, seed=3, sampling=Sampling(top_k=9))
    keywords = generator.generate("a person squats.", seconds=1, seed=3, top_k=9, top_p=1.0)
    assert np.array_equal(given.tokens, keywords.tokens)
    with pytest.raises(TypeError, match="unknown sampling option 'warmth'"):
        generator.generate("walk", warmth=2)


def test_unknown_characters_are_handled(generator):
    motion = generator.generate("a persön wälks ☃ forward!!", seconds=1, seed=0)
    assert np.all(np.isfinite(motion.joints))


def test_a_corrupted_or_missing_bundle_is_refused_naming_the_file(tmp_path):
    with pytest.raises(BundleError, match="no such bundle folder"):
        MotionGenerator.load(tmp_path / "nowhere")
    bundle = tmp_path / "bundle"
    shutil.copytree(DEFAULT_BUNDLE, bundle)
    original = (bundle / "level_0.onnx").read_bytes()
    damaged = bytearray(original)
    damaged[len(damaged) // 2] ^= 0xFF
    (bundle / "level_0.onnx").write_bytes(bytes(damaged))
    with pytest.raises(BundleError, match="level_0.onnx: sha256 does not match"):
        MotionGenerator.load(bundle)
    (bundle / "level_0.onnx").write_bytes(original)
    (bundle / "vq_decoder.onnx").unlink()
    with pytest.raises(BundleError, match="vq_decoder.onnx: missing"):
        MotionGenerator.load(bundle)


def test_the_default_bundle_runs_with_torch_unimportable(run_without_torch):
    result = run_without_torch(
        "from mogo.generator import MotionGenerator\n"
        "motion = MotionGenerator.load().generate('a person waves.', seconds=1, seed=0)\n"
        "print(motion.joints.shape)\n"
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "(20, 22, 3)"
