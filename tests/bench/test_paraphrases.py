"""The paraphrase phrasebooks: every primitive of corpus v1 (the shipped model's, each with a
semantic check; the books were written before corpus v2) has phrases, each
phrase names its action by one of its key words, no key word is a word of the shipped
model's training captions, and the sentences render for any params."""

import re

import numpy as np
import pytest

from mogo.bench.quality.paraphrases import (
    BLIND,
    FRESH,
    LATE,
    PHRASEBOOKS,
    UNSEEN,
    caption_words,
    paraphrase,
    unseen_key_words,
)
from mogo.bench.quality.semantic import CHECKS
from mogo.export.data.animator import CORPORA
from mogo.generator import MotionGenerator

PARAMS = dict(
    direction="left",
    turn=45,
    count=3,
    hand="both",
    foot="left",
    angle=-90,
    forward=True,
    seconds=2.5,
)


@pytest.mark.parametrize("book", PHRASEBOOKS, ids=lambda b: b.name)
def test_every_primitive_has_phrases_each_with_an_unseen_key_word(book):
    assert set(book.phrases) == set(CORPORA["v1"]) == set(book.keys) and set(CHECKS) >= set(
        book.keys
    )
    for primitive, phrases in book.phrases.items():
        for phrase in phrases:
            assert set(re.findall(r"[a-z]+", phrase)) & set(book.keys[primitive]), phrase
    # the trained tokenizer's words are the words of the training captions
    assert unseen_key_words(MotionGenerator.load().vocabulary(), book) == []


@pytest.mark.parametrize("book", PHRASEBOOKS, ids=lambda b: b.name)
def test_paraphrases_render(book):
    rng = np.random.default_rng(0)
    for primitive in book.phrases:
        text = paraphrase(primitive, PARAMS, rng, book)
        assert "{" not in text and text.endswith(".") and "the both" not in text
        assert text.startswith(book.subjects)


def test_key_words_are_checked_against_training_words():
    assert unseen_key_words(caption_words(["a person walks forward.", "she applauds."])) == [
        "applauds"
    ]


@pytest.mark.parametrize("book", [FRESH, UNSEEN, LATE, BLIND], ids=lambda b: b.name)
def test_the_later_subjects_are_not_among_the_adapters_people(book):
    from mogo.export.data.wordnet_people import PEOPLE

    assert not {s.split()[-1] for s in book.subjects} & set(PEOPLE)
