"""`mogo export text --text RUN --bundle OLD --out NEW`: OLD with a pretrained sentence encoder as
its text side (a `mogo train text` run: all-MiniLM-L6-v2 and the adapter onto OLD's prompt
space), and the repertoire it reports prompts against. OLD's own text encoder and tokenizer
stay, renamed (`text.trained`): the runtime reads with them the prompts whose every word they
know, exactly as the level graphs were trained. Every file is copied byte for byte; nothing
is retrained, so OLD's training runs are not needed.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tokenizers import Tokenizer

from mogo.align import plain_words, primitive_of
from mogo.bundle import Bundle, write_manifest
from mogo.export.data.outside_repertoire import CALIBRATION, INSIDE
from mogo.export.models.runs import load_checkpoint
from mogo.export.models.sentence_encoder import (
    CAPTIONS,
    ENCODER,
    MAX_LENGTH,
    Adapter,
    MiniLM,
    SentenceEmbedder,
    SentenceTower,
    sentence_tokenizer,
    variant_rows,
)
from mogo.export.onnx.bundle import new_folder
from mogo.export.onnx.text_graph import export_sentence_text_graph
from mogo.manifest import (
    SENTENCE_ENCODER,
    Graph,
    Manifest,
    Pretrained,
    Repertoire,
    Text,
    TrainedEncoder,
    TrainingRun,
)
from mogo.repertoire import what_it_says

TRAINED, TRAINED_TOKENIZER = "trained_text_encoder.onnx", "trained_tokenizer.json"
REPERTOIRE_SIZE = 2048  # training captions kept, about (kept_captions)
CHECK_CAPTIONS = 256  # val captions the int8 graph is compared with the fp32 reference on


def replace_text_side(text_run: Path, bundle_dir: Path, out: Path) -> Manifest:
    """The new bundle (see the module's docstring); returns its manifest."""
    old = Bundle.load(bundle_dir)
    manifest = old.manifest
    if manifest.text.sentence_encoder:
        raise ValueError(f"{bundle_dir} already has a sentence encoder")
    run, best = Path(text_run), load_checkpoint(Path(text_run) / "best.pt")
    captions = np.load(run / CAPTIONS)
    _check_targets(old, captions)
    out = new_folder(out)
    kept = {manifest.text.tokenizer: TRAINED_TOKENIZER, manifest.text.encoder.file: TRAINED}
    for name in manifest.files:  # the old text side under new names, every other file as it is
        shutil.copy2(old.path(name), out / kept.get(name, name))
    sentence_tokenizer(run / ENCODER).save(str(out / "tokenizer.json"))
    config = best["config"]
    graph, pretrained = _sentence_graph(run, best, out, captions)
    texts, sentences = own_captions(captions, "train")
    targets = captions["train_target"][~variant_rows(captions, "train")]
    repertoire = write_repertoire(
        out,
        run / ENCODER,
        [str(t) for t in texts],
        sentences,
        own_captions(captions, "val")[1],
        targets,
    )
    trained_encoder = TrainedEncoder(
        TRAINED_TOKENIZER, replace(manifest.text.encoder, file=TRAINED)
    )
    text = Text(
        tokenizer="tokenizer.json",
        max_length=MAX_LENGTH,
        kind=SENTENCE_ENCODER,
        encoder=graph,
        pretrained=pretrained,
        repertoire=repertoire,
        trained=trained_encoder,
    )
    storage = manifest.fp16_storage
    if storage is not None:  # the new text graph is int8 as published; the old one is fp16
        storage = replace(storage, files=tuple(sorted(kept.get(f, f) for f in storage.files)))
    trained = TrainingRun(
        step=best["step"],
        recipe=config["recipe"],
        data=config["data"],
        best_val_loss=best["best_val_error"],
    )
    return write_manifest(
        out,
        replace(
            manifest,
            text=text,
            fp16_storage=storage,
            training={**manifest.training, "text": trained},
        ),
    )


def _sentence_graph(run: Path, best: dict, out: Path, captions) -> tuple[Graph, Pretrained]:
    """The run's encoder and adapter joined into out/text_encoder.onnx, and what the manifest
    says of the pretrained encoder (its provenance, the int8 graph's cosine to fp32)."""
    config = best["config"]
    adapter = Adapter(config["in_dim"], config["out_dim"], config["recipe"]["hidden"])
    adapter.load_state_dict(best["model"])
    graph = export_sentence_text_graph(
        run / ENCODER / "model.onnx", adapter.eval(), out / "text_encoder.onnx"
    )
    provenance = json.loads((run / ENCODER / "provenance.json").read_text())
    return graph, Pretrained(
        **provenance,
        reference_min_cosine=_reference_cosine(
            run / ENCODER, out, [str(t) for t in captions["val_text"][:CHECK_CAPTIONS]]
        ),
    )


def _check_targets(old: Bundle, captions) -> None:
    """The run's targets must be this bundle's own prompt embeddings."""
    from mogo.generator import MotionGenerator

    texts = [str(t) for t in captions["val_text"][:32]]
    if not np.allclose(MotionGenerator(old).embed(texts), captions["val_target"][:32], atol=1e-4):
        raise ValueError("the text run was trained on another bundle's prompt embeddings")


@torch.no_grad()
def _reference_cosine(encoder: Path, out: Path, texts: list[str]) -> float:
    """The lowest cosine between the shipped graph's sentence embeddings and the fp32
    reference's (MiniLM in torch from the published safetensors) on `texts`."""
    from mogo._session import cpu_session

    tokenizer = Tokenizer.from_file(str(out / "tokenizer.json"))
    tokenizer.enable_padding()
    encoded = tokenizer.encode_batch(texts)
    ids = np.array([e.ids for e in encoded], np.int64)
    mask = np.array([e.attention_mask for e in encoded], np.int64)
    shipped = cpu_session(out / "text_encoder.onnx", 2).run(
        ["sentence_embedding"], dict(token_ids=ids, attention_mask=mask)
    )[0]
    reference = MiniLM.load(encoder)(torch.from_numpy(ids), torch.from_numpy(mask)).numpy()
    return round(float(np.min(np.sum(shipped * reference, axis=1))), 5)


def sentence_text_side(out: Path, tower: SentenceTower, train: list[str], val: list[str]) -> Text:
    """The text side of a model conditioned on a sentence encoder (`mogo train t2m
    --text-encoder sentence`): the encoder's graph and the trained projection as one graph, its
    tokenizer, its provenance and the repertoire of the training captions (`train`; `val`
    calibrates its threshold). One encoder, the one the level graphs were trained on: no
    adapter, no second encoder, nothing to route between."""
    folder = tower.folder
    if not (folder / "model.safetensors").is_file():
        raise ValueError(
            f"{folder}: no model.safetensors (and config.json), the fp32 reference "
            "the shipped graph is checked against"
        )
    sentence_tokenizer(folder).save(str(out / "tokenizer.json"))
    graph = export_sentence_text_graph(
        folder / "model.onnx", tower.projection.eval(), out / "text_encoder.onnx"
    )
    provenance = json.loads((folder / "provenance.json").read_text())
    pretrained = Pretrained(
        **provenance, reference_min_cosine=_reference_cosine(folder, out, val[:CHECK_CAPTIONS])
    )
    embedder = SentenceEmbedder(folder)
    train = sorted(set(train))
    repertoire = write_repertoire(
        out, folder, train, embedder.embed(train), embedder.embed(sorted(set(val)))
    )
    return Text(
        tokenizer="tokenizer.json",
        max_length=MAX_LENGTH,
        kind=SENTENCE_ENCODER,
        encoder=graph,
        pretrained=pretrained,
        repertoire=repertoire,
    )


def write_repertoire(
    out: Path,
    encoder: Path,
    texts: list[str],
    sentences: np.ndarray,
    val_sentences: np.ndarray,
    prompts: np.ndarray | None = None,
) -> Repertoire:
    """The training captions kept (`kept_captions` of `texts` and their unit `sentences`), with
    `prompts` (their prompt embeddings by the encoder the level graphs were trained with, where
    that is not the sentence encoder), and the threshold that best separates the val captions
    and INSIDE from CALIBRATION (each of the three counted as a third)."""
    kept = kept_captions(texts, sentences)
    np.save(out / "repertoire.npy", sentences[kept].astype(np.float16))
    if prompts is not None:
        np.save(out / "repertoire_prompts.npy", prompts[kept].astype(np.float16))
    (out / "repertoire.json").write_text(json.dumps([texts[k] for k in kept], indent=0))
    known = sentences[kept].astype(np.float16).astype(np.float32)
    embedder = SentenceEmbedder(encoder)
    val = nearest_cosine(val_sentences, known)
    inside = nearest_cosine(embedder.embed(list(INSIDE)), known)
    outside = nearest_cosine(embedder.embed(list(CALIBRATION)), known)
    threshold, accepted, refused = calibrate([val, inside], outside)
    return Repertoire(
        embeddings="repertoire.npy",
        captions="repertoire.json",
        prompts=None if prompts is None else "repertoire_prompts.npy",
        threshold=threshold,
        held_out_accepted=accepted,
        outside_refused=refused,
    )


def own_captions(captions, split: str) -> tuple[np.ndarray, np.ndarray]:
    """(texts, sentence embeddings) of a split's captions, without the variants the adapter
    also trained on (mogo.export.train.train_text: other subjects, other verbs)."""
    own = ~variant_rows(captions, split)
    return captions[f"{split}_text"][own], captions[f"{split}_sentence"][own]


def nearest_cosine(sentences: np.ndarray, known: np.ndarray) -> np.ndarray:
    return np.max(sentences @ known.T, axis=1)


def calibrate(inside: list[np.ndarray], outside: np.ndarray) -> tuple[float, float, float]:
    """The threshold with the fewest errors, each set weighted as a share of its own size
    (the `inside` sets accepted at >= threshold, `outside` refused below it); -> (threshold,
    share of all the inside prompts accepted, share of outside refused). Midway between
    neighbouring scores."""
    scores = np.unique(np.concatenate([*inside, outside]))
    candidates = (scores[1:] + scores[:-1]) / 2
    rates = [[np.mean(group >= t) for group in inside] + [np.mean(outside < t)] for t in candidates]
    best = int(np.argmax([sum(r) for r in rates]))
    accepted = np.mean(np.concatenate(inside) >= candidates[best])
    return (
        round(float(candidates[best]), 4),
        round(float(accepted), 4),
        round(float(rates[best][-1]), 4),
    )


def kept_captions(texts: list[str], sentences: np.ndarray) -> np.ndarray:
    """Indices (sorted) of about REPERTOIRE_SIZE of `texts` that cover them all, medoids of
    their unit `sentences`: half of them captions of one action, half of several, so that a
    short prompt finds a short caption. The captions of one action are covered group by group
    of their action (the rule aligner's reading of their verb) and what they say (sides, ways,
    counts: mogo.repertoire.what_it_says), each group in proportion to its size and by one at
    least: medoids of the sentence space alone kept "claps four times" and "claps five times"
    and no other count of claps, and a prompt that says "twice" could not be played as
    twice."""
    says = [what_it_says(text) for text in texts]
    single = np.array([said["steps"] == {1} for said in says])
    groups: dict[tuple, list[int]] = {}
    for index in np.flatnonzero(single):
        action = primitive_of(plain_words(texts[index]))
        groups.setdefault((action, frozenset(says[index].items())), []).append(index)
    half = REPERTOIRE_SIZE // 2
    shares = [(np.flatnonzero(~single), half)] + [
        (np.array(rows), max(1, round(half * len(rows) / single.sum()))) for rows in groups.values()
    ]
    return np.sort(
        np.concatenate(
            [
                rows[medoids(sentences[rows], min(share, len(rows)))]
                for rows, share in shares
                if len(rows)
            ]
        )
    )


def medoids(points: np.ndarray, k: int, iterations: int = 8, seed: int = 0) -> np.ndarray:
    """Indices of `k` points that cover unit `points`: spherical k-means, then each cluster's
    point nearest its centre (sorted)."""
    rng = np.random.default_rng(seed)
    centres = points[rng.choice(len(points), k, replace=False)]
    for _ in range(iterations):
        assigned = np.argmax(points @ centres.T, axis=1)
        sums = np.zeros_like(centres)
        np.add.at(sums, assigned, points)
        norms = np.linalg.norm(sums, axis=1, keepdims=True)
        centres = np.where(norms > 0, sums / np.maximum(norms, 1e-9), centres)
    similarity = points @ centres.T
    return np.unique(np.argmax(similarity, axis=0))
