"""Golden outputs of the shipped bundle: fixed prompts and seeds through generate (sampled,
greedy, top-k, guided, model-ended, batched, past the sliding window), play with a prompt
switch, a stream switching prompt at frame 30, one past its window (not re-anchored) and one
re-anchored past its span, and continue_from, each pinned by the sha256 of the exact bytes of
its tokens (int64) and joints (float32). Any change to sampling, seeding, the token loop,
decoding or the joints shows here.

golden.json was first recorded from the code before issue 17's restructure (commit c41cff4,
then `mogo.runtime.generator`), so this test is that restructure's "same bundle, prompt and
seed give byte-identical tokens and motion". After a deliberate change of the model or of what
a seed draws, re-record it and say why in the commit (issue 25 did, for the joints alone: feet
are planted by default; the *_feet_as_decoded cases keep the bytes from before it; issue 19
did for streams past their first anchor, re-anchored by default, and again for the
re-anchored stream cases when the model could end a stream's clip to start a fresh one: such
a stream draws differently from its first step):

    python tests/runtime/test_golden.py --record

Two processes on one machine give identical bytes. Another CPU may round the decoder's floats
differently: the tokens then still match and the message says only the joints moved.
"""
import hashlib
import json
import platform
import sys
from pathlib import Path

import numpy as np
import pytest

from mogo import DEFAULT_BUNDLE, MotionGenerator

GOLDEN = Path(__file__).with_name("golden.json")
RECORDED = json.loads(GOLDEN.read_text()) if GOLDEN.exists() else {"cases": {}}

# name: prompt, seconds (None: the model ends it), seed, sampling options
GENERATE = {
    "walk_2s_seed0": ("a person walks forward.", 2.0, 0, {}),
    "walk_3s_seed7": ("a person walks forward.", 3.0, 7, {}),
    "wave_2.5s_seed1": ("someone waves with the right hand.", 2.5, 1, {}),
    "jump_2s_seed3": ("a person jumps on the spot three times.", 2.0, 3, {}),
    "run_back_3s_greedy": ("a person runs backward.", 3.0, 2, dict(temperature=0.0)),
    "squat_2.5s_top_k": ("a person squats down and stands up.", 2.5, 5,
                         dict(temperature=0.8, top_k=40, top_p=1.0)),
    "circle_3s_guided": ("a person walks in a circle.", 3.0, 11, dict(guidance=2.0)),
    "turn_8s_past_the_window": ("a person walks forward, then turns around.", 8.0, 4, {}),
    "wave_model_ended": ("someone waves.", None, 3, {}),
}


def digest(array: np.ndarray) -> str:
    """sha256 of the dtype, shape and exact bytes."""
    array = np.ascontiguousarray(array)
    return hashlib.sha256(f"{array.dtype.str}{array.shape}".encode() + array.tobytes()).hexdigest()


def pinned(joints: np.ndarray, tokens: np.ndarray | None = None, prompts=None) -> dict:
    case = {"frames": len(joints), "joints": digest(joints)}
    if tokens is not None:
        case.update(steps=len(tokens), tokens=digest(tokens))
    if prompts is not None:
        case["prompts"] = [[int(frame), text] for frame, text in prompts]
    return case


def outputs(generator) -> dict[str, dict]:
    """Every golden case on `generator`, through the public API only (the same calls work on
    the code before the restructure)."""
    cases = {}
    for name, (prompt, seconds, seed, options) in GENERATE.items():
        motion = generator.generate(prompt, seconds=seconds, seed=seed, **options)
        cases[f"generate/{name}"] = pinned(motion.joints, motion.tokens)
    batch_prompts = ["a person walks forward.", "a person sits down."]
    batch = generator.generate_batch(batch_prompts, seconds=2.0, seed=9)
    for k, motion in enumerate(batch):
        cases[f"generate/batch_{k}"] = pinned(motion.joints, motion.tokens)
    played = generator.play([("a person walks forward.", 2.0), ("a person waves.", 1.5)],
                            seed=1)
    cases["play/walk_then_wave"] = pinned(played.joints, played.tokens, played.prompts)
    stream = generator.stream("a person jogs in a circle.", seed=2)
    frames = list(stream.frames(30))
    stream.set_prompt("a person jumps on the spot.")
    frames += list(stream.frames(30))
    cases["stream/60_frames_switch_at_30"] = pinned(np.array(frames), prompts=stream.prompts)
    stream = generator.stream("a person walks forward.", seed=6, anchoring=False)
    stream.advance(140)  # past the 128-step window: its slots are in ring order
    stream.set_prompt("a person turns around and walks back.")
    stream.advance(20)
    wrapped = stream.finish()
    cases["stream/switch_after_the_window_wrapped"] = pinned(wrapped.joints, wrapped.tokens,
                                                             wrapped.prompts)
    # plant_feet=False: the joints as decoded, the bytes recorded before feet were planted
    # (and before streams were re-anchored)
    raw = generator.generate("a person walks forward.", seconds=2.0, seed=0, plant_feet=False)
    cases["generate/walk_2s_seed0_feet_as_decoded"] = pinned(raw.joints, raw.tokens)
    stream = generator.stream("a person jogs in a circle.", seed=2, plant_feet=False,
                              anchoring=False)
    frames = list(stream.frames(30))
    stream.set_prompt("a person jumps on the spot.")
    frames += list(stream.frames(30))
    cases["stream/60_frames_switch_at_30_feet_as_decoded"] = pinned(np.array(frames),
                                                                    prompts=stream.prompts)
    stream = generator.stream("a person walks forward.", seed=6)
    stream.advance(140)  # fresh clips where the model ends one, re-anchored (mogo.anchoring)
    anchored = stream.finish()
    cases["stream/re_anchored_140_steps"] = pinned(anchored.joints, anchored.tokens)
    clip = generator.generate("a person walks forward.", seconds=3.0, seed=4)
    cases["continue_from/encoded_clip"] = {"tokens": digest(generator.encode_motion(clip))}
    stream = generator.stream("a person turns left.", seed=9)
    stream.continue_from(clip)
    cases["continue_from/40_frames"] = pinned(np.array(list(stream.frames(40))))
    return cases


def model_sha256() -> str:
    """The shipped model: every file of the default bundle but its manifest (whose form may
    change while the model stays), by name and content."""
    digest = hashlib.sha256()
    for path in sorted(Path(DEFAULT_BUNDLE).iterdir()):
        if path.name != "manifest.json":
            digest.update(path.name.encode() + hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def record() -> None:
    """Write golden.json from the code that runs this (see the module docstring)."""
    import onnxruntime

    document = {"model_sha256": model_sha256(),
                "recorded_with": {"numpy": np.__version__, "onnxruntime": onnxruntime.__version__,
                                  "machine": platform.machine(), "python": platform.python_version()},
                "cases": outputs(MotionGenerator.load())}
    GOLDEN.write_text(json.dumps(document, indent=1) + "\n")
    print(f"wrote {len(document['cases'])} cases to {GOLDEN}")


@pytest.fixture(scope="module")
def computed():
    return outputs(MotionGenerator.load())


def test_the_golden_file_is_of_the_shipped_model():
    assert RECORDED.get("model_sha256") == model_sha256(), (
        "the default bundle's model files changed: re-record golden.json (module docstring)")


def test_every_case_is_recorded(computed):
    assert sorted(computed) == sorted(RECORDED["cases"])


@pytest.mark.parametrize("name", sorted(RECORDED["cases"]))
def test_same_bundle_prompt_and_seed_give_the_recorded_bytes(computed, name):
    got, want = computed[name], RECORDED["cases"][name]
    same_tokens = got.get("tokens") == want.get("tokens")
    assert got == want, (f"{name}: {'only the joints' if same_tokens else 'the tokens'} "
                         f"changed: {got} != {want}")


if __name__ == "__main__":
    if sys.argv[1:] != ["--record"]:
        sys.exit(f"usage: python {sys.argv[0]} --record")
    record()
