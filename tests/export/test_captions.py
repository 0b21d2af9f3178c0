import re

import numpy as np
import pytest

from mogo.export.data.animator import PRIMITIVES, Segment, sample_segment
from mogo.export.data.caption_templates import JOINERS, POOLS, SUBJECTS, TEMPLATES
from mogo.export.data.captions import (
    caption_program,
    caption_segment,
    conjugate,
    count_noun,
    render,
    templates,
    times_word,
)

DRAWS = 300  # random segments per template: enough to meet every param combination it fits


def _well_formed(phrase: str) -> None:
    assert not re.search(r"[{}<>#]|\s\s|\s[,.]", phrase), phrase
    assert phrase == phrase.strip() and phrase


def test_every_primitive_has_templates_in_both_pools():
    assert set(TEMPLATES) == set(PRIMITIVES)
    for primitive in PRIMITIVES:
        train, heldout = templates(primitive, "train"), templates(primitive, "heldout")
        assert train and heldout, primitive
        assert not {t.id for t in train} & {t.id for t in heldout}
        assert len(heldout) <= len(train) / 2, primitive


def test_template_ids_are_unique():
    distinct = {id(t): t for ts in TEMPLATES.values() for t in ts}.values()
    ids = [t.id for t in distinct] + [j.id for j in JOINERS]
    assert len(ids) == len(set(ids))


@pytest.mark.parametrize("primitive", sorted(PRIMITIVES))
def test_every_template_renders_for_random_params(primitive):
    rng = np.random.default_rng(0)
    segments = [sample_segment(primitive, rng) for _ in range(DRAWS)]
    for template in TEMPLATES[primitive]:
        fitting = [s for s in segments if template.fits(s.params)]
        assert fitting, f"{template.id} fits none of {DRAWS} random {primitive} segments"
        for segment in fitting[:20]:
            for subject in SUBJECTS:
                finite, gerund = render(template, primitive, segment.params, rng, subject)
                _well_formed(finite)
                _well_formed(gerund)
                assert finite.split()[0] != gerund.split()[0]


@pytest.mark.parametrize("pool", POOLS)
def test_program_captions_are_humanml3d_style(pool):
    rng = np.random.default_rng(1)
    names = sorted(PRIMITIVES)
    for _ in range(200):
        segments = [
            sample_segment(names[int(rng.integers(len(names)))], rng)
            for _ in range(int(rng.integers(1, 4)))
        ]
        sentence = caption_program(segments, rng, pool)
        _well_formed(sentence.text[:-1])
        assert sentence.text.endswith(".") and sentence.text[0].islower()
        assert len(sentence.template_ids) == 2 * len(segments) - 1
        by_id = {t.id: t for ts in TEMPLATES.values() for t in ts} | {j.id: j for j in JOINERS}
        assert all(by_id[i].heldout == (pool == "heldout") for i in sentence.template_ids)


def test_pools_give_disjoint_phrasings():
    rng = np.random.default_rng(2)
    segment = Segment("bow", {})
    train = {caption_segment(segment, rng, "train").template_ids for _ in range(100)}
    heldout = {caption_segment(segment, rng, "heldout").template_ids for _ in range(100)}
    assert train and heldout and not train & heldout
    with pytest.raises(ValueError, match="pool"):
        caption_segment(segment, rng, "test")


def _captions(segment: Segment, n: int = 60) -> list[str]:
    rng = np.random.default_rng(3)
    return [caption_segment(segment, rng, pool).text for pool in POOLS for _ in range(n)]


@pytest.mark.parametrize(
    "primitive,param",
    [("wave", "hand"), ("raise_arms", "hand"), ("punch", "hand"), ("kick", "foot")],
)
@pytest.mark.parametrize("side", ["left", "right"])
def test_captions_name_the_right_limb(primitive, param, side):
    rng = np.random.default_rng(4)
    params = dict(sample_segment(primitive, rng).params, **{param: side})
    other = "right" if side == "left" else "left"
    for text in _captions(Segment(primitive, params)):
        assert re.search(rf"\b{side}\b", text) and not re.search(rf"\b{other}\b", text), text


@pytest.mark.parametrize("direction", ["left", "right"])
def test_spin_and_turn_captions_name_the_direction(direction):
    clockwise = "counterclockwise" if direction == "left" else "clockwise"
    for text in _captions(Segment("spin", {"direction": direction})):
        assert re.search(rf"\b({direction}|{clockwise})\b", text), text
    sign = 1 if direction == "left" else -1
    for text in _captions(Segment("turn", {"angle": sign * 90})):
        assert re.search(rf"\b({direction}|{clockwise})\b", text), text


@pytest.mark.parametrize("gait", ["walk", "jog", "run"])
@pytest.mark.parametrize("direction", ["forward", "backward", "left", "right"])
def test_locomotion_captions_name_the_direction(gait, direction):
    rng = np.random.default_rng(5)
    params = dict(sample_segment(gait, rng).params, direction=direction, turn=0)
    words = {
        "forward": r"forwards?|ahead",
        "backward": r"backwards?|backs up",
        "left": r"left|leftward",
        "right": r"right|rightward",
    }[direction]
    for text in _captions(Segment(gait, params)):
        assert re.search(rf"\b({words})\b", text), text


def test_locomotion_captions_name_the_curve():
    rng = np.random.default_rng(6)
    params = dict(sample_segment("walk", rng).params, direction="forward", turn=90)
    for text in _captions(Segment("walk", params)):
        assert re.search(r"\bleft\b", text) and not re.search(r"\bright\b", text), text


def test_counts_are_words():
    assert [times_word(n) for n in (1, 2, 3)] == ["once", "twice", "three times"]
    assert count_noun(1, "squat") == "a squat"
    assert count_noun(3, "right punch") == "three right punches"
    rng = np.random.default_rng(7)
    params = dict(sample_segment("clap", rng).params, count=2)
    for text in _captions(Segment("clap", params)):
        assert re.search(r"\b(twice|two)\b", text), text


def test_conjugation():
    assert [conjugate(v, "s") for v in ("walk", "punch", "do", "carry")] == [
        "walks",
        "punches",
        "does",
        "carries",
    ]
    assert [conjugate(v, "ing") for v in ("jog", "wave", "squat", "walk")] == [
        "jogging",
        "waving",
        "squatting",
        "walking",
    ]
