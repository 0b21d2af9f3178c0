"""Our runtime passes the conformance vectors it wrote (runtime/web/conformance.json), by the
rule every port uses (mogo.export.onnx.conformance.compare_tokens); and that rule can fail."""

import json

import numpy as np
import pytest

from mogo.export.onnx.conformance import VECTORS, WORDS, anchoring_words, compare_tokens, run_tokens
from mogo.sampling import Sampling, choose_token, make_rng

VECTORS_DATA = json.loads(VECTORS.read_text())
TOLERANCES = VECTORS_DATA["tolerances"]


def test_the_file_is_small_and_plain_json():
    assert VECTORS.stat().st_size < 400_000
    assert VECTORS_DATA["format"] == "mogo-conformance"


@pytest.mark.parametrize("case", VECTORS_DATA["random"], ids=lambda c: str(c["seed"]))
def test_the_random_stream(case):
    assert make_rng(case["seed"]).random(len(case["uniforms"])).tolist() == case["uniforms"]


@pytest.mark.parametrize("case", VECTORS_DATA["sampler"], ids=lambda c: str(c["sampling"]))
def test_the_sampler(case):
    uncond = None if case["uncond"] is None else np.float32(case["uncond"])
    assert (
        choose_token(
            np.float32(case["cond"]),
            uncond,
            case["uniform"],
            Sampling(**case["sampling"]),
            case["forbid"],
        )
        == case["token"]
    )


@pytest.mark.parametrize("case", VECTORS_DATA["generate"], ids=lambda c: c["name"])
def test_generate(case, portable_generator):
    g = portable_generator
    for entry in case["schedule"]:
        embedding = g.embed([entry["prompt"]])[0]
        assert np.abs(embedding - entry["prompt_embedding"]).max() < TOLERANCES["prompt_embedding"]
    tokens = run_tokens(g.tokens, case)
    agreed, problem = compare_tokens(case, tokens, TOLERANCES)
    assert problem is None
    if agreed < case["steps"]:
        return
    prompts, start = [], 0  # the frame each prompt starts at: the token loop switched there
    for entry in case["schedule"]:
        prompts.append((start, entry["prompt"]))
        start += entry["steps"] * g.down_factor
    # the case's tokens decoded: a port's streaming decode gives the same frames
    motion = g.decode(tokens, prompts, case["frames"], plant_feet=False)
    assert np.abs(motion.joints - np.array(case["joints"])).max() < TOLERANCES["joints_m"]
    if "joints_planted" in case:
        planted = g.decode(tokens, prompts, case["frames"]).joints
        assert np.abs(planted - np.array(case["joints_planted"])).max() < TOLERANCES["joints_m"]
        assert np.abs(planted - motion.joints).max() > 0.01  # the feet did move


def test_a_wrong_token_is_caught_and_a_near_tie_forgiven():
    case = VECTORS_DATA["generate"][0]
    margins, gaps = np.array(case["margins"]), np.array(case["gaps"])
    sure = tuple(np.argwhere((margins > 0.01) & (gaps > 0.1))[0])
    tokens = np.array(case["tokens"])
    tokens[sure] = (tokens[sure] + 1) % 512
    agreed, problem = compare_tokens(case, tokens, TOLERANCES)
    assert agreed == sure[0] and f"step {sure[0]} level {sure[1]}" in problem
    for ties in (margins < TOLERANCES["tie_mass"], gaps < TOLERANCES["tie_logit"]):
        tie = tuple(np.argwhere(ties)[0])
        tokens = np.array(case["tokens"])
        tokens[tie] = (tokens[tie] + 1) % 512
        assert compare_tokens(case, tokens, TOLERANCES) == (tie[0], None)


def test_the_ports_anchoring_words_are_our_runtimes(portable_generator):
    """runtime/web/words.json is what mogo.align and mogo.anchoring say now (rewritten by
    `python -m mogo.export.onnx.conformance` when they change), and its tables, made from
    their public names, are their private ones."""
    from mogo import align, anchoring

    words = json.loads(WORDS.read_text())
    assert words == anchoring_words(portable_generator)
    assert words["verbs"] == {
        w: align._PRIMITIVE_OF[base]
        for w, base in align._BASE_OF.items()
        if align._PRIMITIVE_OF[base] is not None
    }
    assert set(words["counts"]) == anchoring._COUNTS
