"""The held-out paraphrase set: every primitive the semantic checks know has phrases, each
phrase names its action by one of its key words, and the sentences render for any params."""
import numpy as np

from mogo.bench.quality.paraphrases import KEY, PHRASES, caption_words, paraphrase, unseen_key_words
from mogo.bench.quality.semantic import CHECKS

PARAMS = dict(direction="left", turn=45, count=3, hand="both", foot="left", angle=-90,
              forward=True, seconds=2.5)


def test_every_primitive_has_phrases_each_with_a_key_word():
    assert set(PHRASES) == set(CHECKS) == set(KEY)
    for primitive, phrases in PHRASES.items():
        for phrase in phrases:
            assert any(key in phrase.split() for key in KEY[primitive]), phrase


def test_paraphrases_render_and_key_words_are_checked_against_training_words():
    rng = np.random.default_rng(0)
    for primitive in PHRASES:
        text = paraphrase(primitive, PARAMS, rng)
        assert "{" not in text and text.endswith(".") and "the both" not in text
    assert unseen_key_words(caption_words(["a person walks forward.", "she applauds."])) == \
        ["applauds"]
