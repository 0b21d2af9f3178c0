"""The action-reading benchmark on stand-ins: which texts it labels (a variant by its caption's
target), and that each head reads back actions it can tell apart."""

import numpy as np
import pytest

from mogo.bench.training.text_reading import centroid_head, labelled_texts, linear_head, vote_head
from mogo.export.models.sentence_encoder import CAPTIONS


def test_variants_take_their_captions_action_and_unknown_captions_are_left_out(tmp_path):
    texts = [
        "a person walks forward.",
        "someone claps twice.",
        "a man walks then claps.",
        "the nurse walks forward.",
        "someone trudges forward.",
    ]
    targets = np.array([[1, 0], [0, 1], [1, 1], [1, 0], [1, 0]], np.float32)
    sentences = np.arange(10, dtype=np.float32).reshape(5, 2)
    np.savez(
        tmp_path / CAPTIONS,
        train_text=np.array(texts),
        train_target=targets,
        train_sentence=sentences,
        train_variant=np.array([0, 0, 0, 1, 1], bool),
    )
    known = {
        "a person walks forward": ("walk", ("direction", "forward")),
        "someone claps twice": ("clap", ("count", 2)),
    }
    x, y = labelled_texts(tmp_path, known)
    assert y.tolist() == ["walk", "clap", "walk", "walk"]  # the caption of two actions is out
    assert np.array_equal(x, sentences[[0, 1, 3, 4]])


@pytest.mark.parametrize("head", [centroid_head, vote_head, linear_head])
def test_each_head_reads_back_actions_it_can_tell_apart(head):
    rng = np.random.default_rng(0)
    actions = ["clap", "walk", "wave"]
    axes = np.eye(8, dtype=np.float32)[:3]
    y = np.array(actions * 40)
    x = axes[[actions.index(a) for a in y]] + 0.1 * rng.standard_normal((120, 8), np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    read = head(x, y, actions)
    assert read(axes).tolist() == [0, 1, 2]
