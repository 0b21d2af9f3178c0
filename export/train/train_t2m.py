"""`mogo train t2m`: the RQHC-Transformer and its text encoder, trained jointly on the token
sequences of a trained MoSA-VQ.

RUN/ holds
    tokens/{train,val}.npz  every clip encoded once by the VQ (the whole clip), with the caption
                            spans cut in token units; reused while the VQ checkpoint's sha256,
                            the data folder and the span rule are unchanged
    tokenizer.json          trained on the training captions (a sentence encoder's own)
    variants.json           with --variants: each training caption's variants (another subject,
                            another verb)
    checkpoint.pt           latest: weights, optimizer, step, configs
    best.pt                 lowest validation loss: weights and configs
    metrics.jsonl           train and val records

`T2MTrainer` plugs into the training loop (mogo.export.train.loop), which makes resuming exact:
dropout, prompt dropout and token corruption do not depend on what ran before.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from tokenizers import Tokenizer
from torch import Tensor, nn
from torch.utils.data import Dataset

from mogo.bundle import file_sha256
from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.export.models.runs import build_text_to_motion, load_vq, read_tokens, vq_checkpoint
from mogo.export.models.sentence_encoder import ENCODER_FILES
from mogo.export.models.t2m import T2MConfig, TextToMotion
from mogo.export.models.text_encoder import TEXT_ENCODERS, encode_captions
from mogo.export.models.vq import MoSAVQ, VQConfig
from mogo.export.train.datasets import EpochSeeded, TextMotionDataset
from mogo.export.train.loop import Run, Trainer, train_loop
from mogo.export.train.options import T2MTrainOptions
from mogo.export.train.training import (
    Process,
    all_reduce_mean,
    end_process,
    equal_length_groups,
    finish_together,
    make_optimizer,
    merge_recipe,
    previous_run,
    start_process,
)
from mogo.motion.skeleton import MAX_FRAMES, MIN_FRAMES
from mogo.progress import Progress

TOKENIZE_BATCH = 128
TOKENIZER = "tokenizer.json"
VARIANTS = "variants.json"
SENTENCE_VARIANTS = 0.25  # --variants' default with a sentence encoder
PRESETS: dict[str, Callable[[], T2MConfig]] = dict(
    tiny=T2MConfig.tiny, cpu_default=T2MConfig.cpu_default, paper=T2MConfig.paper
)


# -- tokens ------------------------------------------------------------------------------------


@torch.inference_mode()
def tokenize_split(
    folder: HumanML3DFolder, split: str, vq: MoSAVQ, key: dict, device: torch.device
) -> dict[str, np.ndarray]:
    """Encode every captioned clip of `split` whole (cut to a multiple of the VQ's down factor)
    and cut the caption spans (TextMotionDataset's: at least MIN_FRAMES) in token units.
    Plain arrays only: tokens (N, L) int32 of all clips end to end, offsets (clips + 1,),
    clip_ids, and per span: span_clip, span_start, span_end (tokens), captions; plus `key`."""
    spans = TextMotionDataset(folder, split, min_frames=MIN_FRAMES, max_frames=MAX_FRAMES)
    down = vq.config.down_factor
    vq = vq.to(device)
    raw = [folder.features(clip_id) for clip_id in spans.ids]  # normalised by the VQ's own
    lengths = [len(clip) - len(clip) % down for clip in raw]
    tokens: list[np.ndarray | None] = [None] * len(raw)
    progress = Progress(len(raw), f"tokenising {split}")
    for batch in equal_length_groups(lengths, TOKENIZE_BATCH):
        x = torch.from_numpy(np.stack([raw[i][: lengths[i]] for i in batch])).to(device)
        ids = vq.encode((x - vq.mean) / vq.std).cpu().numpy().astype(np.int32)
        for i, clip_ids in zip(batch, ids, strict=False):
            tokens[i] = clip_ids
        progress.update(len(batch))
    progress.close()
    offsets = np.cumsum([0] + [len(t) for t in tokens])
    return dict(
        tokens=np.concatenate(tokens),
        offsets=offsets.astype(np.int64),
        clip_ids=np.array(spans.ids, dtype=str),
        span_clip=np.array([s.clip for s in spans.spans], dtype=np.int64),
        span_start=np.array([s.start // down for s in spans.spans], dtype=np.int64),
        span_end=np.array([s.end // down for s in spans.spans], dtype=np.int64),
        captions=np.array([s.caption for s in spans.spans], dtype=str),
        **{name: np.array(value) for name, value in key.items()},
    )


def _cache_matches(path: Path, key: dict) -> bool:
    if not path.is_file():
        return False
    with np.load(path, allow_pickle=False) as arrays:
        return all(
            name in arrays.files and arrays[name].item() == value for name, value in key.items()
        )


def _write_tokens(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Through a temporary file: a run killed mid-write leaves no half cache."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    with partial.open("wb") as handle:
        np.savez(handle, **arrays)
    os.replace(partial, path)


class TokenSpans(EpochSeeded):
    """One item per caption span of a token cache; spans longer than `max_tokens` give a random
    window of `max_tokens` each epoch (TextMotionDataset's rule, in token units).
    Item: dict(caption=str, tokens=(T, L) int64 tensor)."""

    def __init__(self, cache: dict[str, np.ndarray], max_tokens: int, seed: int = 0):
        super().__init__(seed)
        self.cache, self.max_tokens = cache, max_tokens
        self._set_room(np.maximum(1, cache["span_end"] - cache["span_start"] - max_tokens + 1))

    def __len__(self) -> int:
        return len(self.cache["span_clip"])

    def __getitem__(self, index: int) -> dict:
        c = self.cache
        base = int(c["offsets"][c["span_clip"][index]])
        start, end = int(c["span_start"][index]), int(c["span_end"][index])
        if end - start > self.max_tokens:
            start += self._start(index)
            end = start + self.max_tokens
        tokens = torch.from_numpy(c["tokens"][base + start : base + end].astype(np.int64))
        return dict(caption=str(c["captions"][index]), tokens=tokens)


def collate_tokens(batch: list[dict]) -> dict:
    """captions (list), tokens (B, Tmax, L) int64 padded with id 0, lengths (B,) int64."""
    lengths = torch.tensor([len(item["tokens"]) for item in batch], dtype=torch.long)
    tokens = torch.zeros(
        len(batch), int(lengths.max()), batch[0]["tokens"].shape[1], dtype=torch.long
    )
    for row, item in enumerate(batch):
        tokens[row, : len(item["tokens"])] = item["tokens"]
    return dict(captions=[item["caption"] for item in batch], tokens=tokens, lengths=lengths)


# -- training ----------------------------------------------------------------------------------


def train_t2m(options: T2MTrainOptions) -> None:
    """Train (or resume) a T2M run; under torchrun every process calls this, rank 0 writes."""
    options.check_intervals()
    out = Path(options.out)
    state = previous_run(out, options.resume)
    recipe = _recipe(options, state)
    folder = HumanML3DFolder(options.data)
    vq_path = vq_checkpoint(options.vq)
    vq = load_vq(options.vq)
    vq_sha256 = file_sha256(vq_path)
    if state is not None and state["config"]["vq"]["sha256"] != vq_sha256:
        raise ValueError(
            f"{vq_path} is not the VQ checkpoint this run was trained on "
            f"(sha256 differs); resume with that one or start a new run"
        )
    t2m_config = (
        T2MConfig(**state["config"]["t2m"])
        if state is not None
        else _t2m_config(recipe["preset"], vq.config)
    )
    process = start_process(options.device)
    try:
        if process.is_main:
            _prepare(out, folder, vq, recipe, vq_sha256, fresh=state is None, device=process.device)
        if process.distributed:
            dist.barrier()
        config = dict(
            t2m=asdict(t2m_config),
            recipe=recipe,
            tokenizer=TOKENIZER,
            data=str(folder.root.resolve()),
            min_frames=MIN_FRAMES,
            max_frames=MAX_FRAMES,
            world_size=process.world_size,
            vq=dict(
                run=str(Path(options.vq).resolve()),
                checkpoint=str(vq_path.resolve()),
                sha256=vq_sha256,
                down_factor=vq.config.down_factor,
            ),
        )
        tokenizer = Tokenizer.from_file(str(out / TOKENIZER))
        config["text_encoder"] = (
            state["config"]["text_encoder"]
            if state is not None
            else dict(
                kind=recipe["text_encoder"],
                config=TEXT_ENCODERS[recipe["text_encoder"]].make_config(
                    recipe, t2m_config.text_dim, tokenizer
                ),
            )
        )
        train_loop(
            T2MTrainer(out, config, tokenizer, process),
            Run(out, options, recipe, config, state, process),
        )
        finish_together(process)
    finally:
        end_process(process)


def _recipe(options: T2MTrainOptions, state: dict | None) -> dict:
    recipe = merge_recipe(
        T2MTrainOptions.recipe_defaults(),
        options.given(),
        None if state is None else state["config"],
    )
    if recipe["preset"] not in PRESETS:
        raise ValueError(f"unknown config {recipe['preset']!r}; use {', '.join(PRESETS)}")
    if recipe["text_encoder"] not in TEXT_ENCODERS:
        raise ValueError(
            f"unknown text encoder {recipe['text_encoder']!r}; use {', '.join(TEXT_ENCODERS)}"
        )
    sentence = recipe["text_encoder"] == "sentence"
    if sentence:
        folder = recipe["sentence_encoder"]
        if folder is None or not all((Path(folder) / f).is_file() for f in ENCODER_FILES):
            raise ValueError(
                f"--text-encoder sentence needs --sentence-encoder DIR holding "
                f"{', '.join(ENCODER_FILES)} (got {folder})"
            )
        recipe["sentence_encoder"] = str(Path(folder).resolve())
    elif recipe["sentence_encoder"] is not None:
        raise ValueError("--sentence-encoder is for --text-encoder sentence")
    if recipe["variants"] is None:
        recipe["variants"] = SENTENCE_VARIANTS if sentence else 0.0
    if not 0.0 <= recipe["variants"] <= 1.0:
        raise ValueError(f"--variants is a share, between 0 and 1, got {recipe['variants']}")
    if recipe["batch_size"] <= 0 or recipe["lr"] <= 0 or recipe["warmup"] < 0:
        raise ValueError(
            f"need batch size > 0, lr > 0, warmup >= 0, got {recipe['batch_size']}, "
            f"{recipe['lr']}, {recipe['warmup']}"
        )
    return recipe


def _t2m_config(preset: str, vq: VQConfig) -> T2MConfig:
    """The preset with the VQ's codebook size; its number of levels must be the VQ's."""
    config = PRESETS[preset]()
    if config.num_levels != vq.levels:
        raise ValueError(
            f"config {preset} has {config.num_levels} levels but the VQ has {vq.levels}"
        )
    return replace(config, codebook_size=vq.codebook_size)


def caption_variants(captions: list[str], tokenizer: Tokenizer) -> dict[str, list[str]]:
    """Each distinct caption's variants: another subject (a kind of person), another verb of
    its primitive that no caption uses (mogo.export.train.train_text's, seed 0)."""
    from mogo.export.train.train_text import other_subjects, other_verbs

    texts = sorted(set(captions))
    known = {w for text in texts for w in text.replace(".", " ").replace(",", " ").split()}
    rng = np.random.default_rng(0)
    subjects, of_subject = other_subjects(texts, rng)
    verbs, of_verb = other_verbs(texts, known, rng)
    variants: dict[str, list[str]] = {}
    for variant, source in zip(
        subjects + verbs, np.concatenate([of_subject, of_verb]), strict=False
    ):
        variants.setdefault(texts[source], []).append(variant)
    return variants


def _prepare(
    out: Path,
    folder: HumanML3DFolder,
    vq: MoSAVQ,
    recipe: dict,
    vq_sha256: str,
    fresh: bool,
    device: torch.device,
) -> None:
    """Rank 0: the token caches (unless still valid) and, for a new run, the tokenizer."""
    key = dict(vq_sha256=vq_sha256, data=str(folder.root.resolve()), min_frames=MIN_FRAMES)
    for split in ("train", "val"):
        path = out / "tokens" / f"{split}.npz"
        if not _cache_matches(path, key):
            _write_tokens(path, tokenize_split(folder, split, vq, key, device))
    if fresh:
        captions = [str(c) for c in read_tokens(out / "tokens" / "train.npz")["captions"]]
        tokenizer = TEXT_ENCODERS[recipe["text_encoder"]].make_tokenizer(recipe, captions)
        tokenizer.save(str(out / TOKENIZER))
        if recipe["variants"]:
            (out / VARIANTS).write_text(json.dumps(caption_variants(captions, tokenizer)))


class T2MTrainer(Trainer):
    """The text encoder and T2M in the training loop: caption spans of the token caches,
    teacher-forced loss and per-level token accuracy."""

    best_name, metric = "best_val_loss", "loss"

    def __init__(self, out: Path, config: dict, tokenizer: Tokenizer, process: Process):
        self.out, self.config, self.tokenizer, self.process = out, config, tokenizer, process
        self.recipe = config["recipe"]
        share = self.recipe.get("variants", 0.0)  # runs from before variants had none
        self.variants = json.loads((out / VARIANTS).read_text()) if share else {}

    def build(self) -> TextToMotion:
        return build_text_to_motion(self.config["text_encoder"], T2MConfig(**self.config["t2m"]))

    def optimizer(self, model: nn.Module) -> torch.optim.Optimizer:
        return make_optimizer(model, self.recipe["lr"])

    def restored(self, model: nn.Module, state: dict | None) -> None:
        if hasattr(model.text_encoder, "remember"):  # a frozen sentence encoder
            captions = read_tokens(self.out / "tokens" / "train.npz")["captions"]
            texts = sorted(
                {str(c) for c in captions} | {v for vs in self.variants.values() for v in vs}
            )
            model.text_encoder.remember(self.tokenizer, texts)
        started = None if state is None else state["config"]["world_size"]
        if started is not None and started != self.process.world_size and self.process.is_main:
            print(
                f"note: the run started with {started} processes, now "
                f"{self.process.world_size}: the batches differ from an uninterrupted run"
            )

    def data(self) -> tuple[Dataset, int, Callable | None]:
        max_tokens = MAX_FRAMES // self.config["vq"]["down_factor"]
        self.train_set, self.val_set = (
            TokenSpans(
                read_tokens(self.out / "tokens" / f"{split}.npz"), max_tokens, self.recipe["seed"]
            )
            for split in ("train", "val")
        )
        return self.train_set, self.recipe["batch_size"], collate_tokens

    def banner(self, model: nn.Module, per_epoch: int) -> str:
        sizes = {
            name: sum(p.numel() for p in part.parameters()) / 1e6
            for name, part in (("t2m", model.t2m), ("text encoder", model.text_encoder))
        }
        return (
            f"t2m: {sizes['t2m']:.2f}M parameters + text encoder "
            f"{sizes['text encoder']:.2f}M; {len(self.train_set)} train / "
            f"{len(self.val_set)} val spans, {per_epoch} steps an epoch"
        )

    def step(self, model: nn.Module, batch: dict) -> tuple[Tensor, dict[str, Tensor]]:
        if self.variants:  # drawn from the step's seeded torch state: resuming stays exact
            draws = torch.rand(len(batch["captions"]), 2).tolist()
            batch = dict(
                batch,
                captions=[
                    others[int(pick * len(others))] if chance < self.recipe["variants"] else caption
                    for caption, (chance, pick) in zip(batch["captions"], draws, strict=False)
                    for others in [self.variants.get(caption) or [caption]]
                ],
            )
        loss, accuracy = _forward(model, self.tokenizer, batch, self.process.device)
        return loss, dict(
            loss=loss.detach(), **{f"acc_{level}": value for level, value in enumerate(accuracy)}
        )

    def train_line(self, values: dict[str, float]) -> str:
        return _summary(values)

    def validate(self, model: nn.Module) -> dict[str, float]:
        return validate(
            model, self.val_set, self.tokenizer, self.recipe["batch_size"], self.process
        )

    def val_line(self, values: dict[str, float]) -> str:
        return _summary(values)


def _forward(
    model: nn.Module, tokenizer: Tokenizer, batch: dict, device: torch.device
) -> tuple[Tensor, Tensor]:
    """-> TextToMotion's (loss, per-level token accuracy (L,)) of a `collate_tokens` batch."""
    caption_ids, caption_mask = encode_captions(tokenizer, batch["captions"])
    return model(
        caption_ids.to(device),
        caption_mask.to(device),
        batch["tokens"].to(device),
        batch["lengths"].to(device),
    )


@torch.no_grad()
def validate(
    model: TextToMotion,
    dataset: TokenSpans,
    tokenizer: Tokenizer,
    batch_size: int,
    process: Process,
) -> dict[str, float]:
    """Teacher-forced loss and per-level token accuracy over the whole split (eval mode: no
    dropout, prompt dropout or corruption), each rank taking every world_size-th span."""
    model.eval()
    device = process.device
    indices = list(range(process.rank, len(dataset), process.world_size))
    sums, count = torch.zeros(1 + model.t2m.config.num_levels, device=device), 0
    for first in range(0, len(indices), batch_size):
        batch = collate_tokens([dataset[i] for i in indices[first : first + batch_size]])
        loss, accuracy = _forward(model, tokenizer, batch, device)
        n = len(batch["captions"])
        sums += n * torch.cat([loss[None], accuracy])
        count += n
    model.train()
    totals = all_reduce_mean(dict(_named(sums), count=count), process)  # means of sums: ratios hold
    return {name: value / totals["count"] for name, value in totals.items() if name != "count"}


def _named(values: Tensor) -> dict[str, float]:
    """[loss, acc level 0, ..., acc level L-1] -> {"loss", "acc_0", ...}."""
    values = values.tolist()
    return dict(loss=values[0], **{f"acc_{level}": v for level, v in enumerate(values[1:])})


def _summary(values: dict[str, float]) -> str:
    accuracies = " ".join(f"{v:.3f}" for name, v in values.items() if name.startswith("acc_"))
    return f"loss {values['loss']:.4f}  acc {accuracies}"
