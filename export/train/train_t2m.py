"""`mogo train t2m`: the RQHC-Transformer and its text encoder, trained jointly on the token
sequences of a trained MoSA-VQ.

RUN/ holds
    tokens/{train,val}.npz  every clip encoded once by the VQ (the whole clip), with the caption
                            spans cut in token units; reused while the VQ checkpoint's sha256,
                            the data folder and the span rule are unchanged
    tokenizer.json          trained on the training captions
    checkpoint.pt           latest: weights, optimizer, step, configs
    best.pt                 lowest validation loss: weights and configs
    metrics.jsonl           train and val records

Resuming is exact (same world size): batches depend only on (seed, epoch) (`training.batches`),
so a resumed run starts at epoch step // steps_per_epoch and skips the batches of that epoch
already done; and every step reseeds torch from (seed, rank, step), so dropout, prompt dropout
and token corruption do not depend on what ran before.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from tokenizers import Tokenizer
from torch import Tensor, nn

from mogo.export.train.datasets import HumanML3DFolder, TextMotionDataset, _EpochSeeded
from mogo.progress import Progress
from mogo.export.train.recipes import T2M_RECIPE
from mogo.export.models.t2m import T2M, T2MConfig
from mogo.export.models.text_encoder import (SmallTextEncoder, SmallTextEncoderConfig, encode_captions,
                                      train_tokenizer)
from mogo.export.train.training import (Process, RunOptions, all_reduce_mean, batches, end_process,
                                  equal_length_groups, finish_together, format_duration,
                                  load_checkpoint, merge_recipe, previous_run, resumed_metrics_log,
                                  save_checkpoint, seed_everything, set_learning_rate,
                                  start_process, step_seed, steps_per_epoch, warmup_cosine,
                                  wrap_model)
from mogo.export.train.train_vq import load_vq, vq_checkpoint
from mogo.export.models.vq import MoSAVQ, VQConfig
from mogo.bundle import file_sha256
from mogo.motion.skeleton import MAX_FRAMES, MIN_FRAMES

WEIGHT_DECAY = 0.1
GRAD_CLIP = 1.0
TOKENIZE_BATCH = 128
TOKENIZER = "tokenizer.json"
PRESETS: dict[str, Callable[[], T2MConfig]] = dict(
    tiny=T2MConfig.tiny, cpu_default=T2MConfig.cpu_default, paper=T2MConfig.paper)


# -- the VQ: the one place that knows how a VQ run is stored ---------------------------------

# -- the text encoder seam ---------------------------------------------------------------------

@dataclass(frozen=True)
class TextEncoderKind:
    """One kind of encoder behind the `TextEncoder` seam, so the loop never names a class:
    make_tokenizer(preset, training captions) for a new run; make_config(preset, prompt width
    the T2M takes, tokenizer) -> a plain dict saved in the checkpoint; build(config) -> the
    module (weights come from the checkpoint, or it is trained from its initialisation)."""
    make_tokenizer: Callable[[str, list[str]], Tokenizer]
    make_config: Callable[[str, int, Tokenizer], dict]
    build: Callable[[dict], nn.Module]


SMALL_VOCAB = dict(tiny=100, cpu_default=4000, paper=8000)


def _small_base(preset: str) -> SmallTextEncoderConfig:
    return SmallTextEncoderConfig.tiny(0) if preset == "tiny" else SmallTextEncoderConfig(0)


def _small_tokenizer(preset: str, captions: list[str]) -> Tokenizer:
    return train_tokenizer(captions, SMALL_VOCAB[preset], _small_base(preset).max_length)


def _small_config(preset: str, text_dim: int, tokenizer: Tokenizer) -> dict:
    return asdict(replace(_small_base(preset), vocab_size=tokenizer.get_vocab_size(),
                          width=text_dim))


def _small_build(config: dict) -> nn.Module:
    return SmallTextEncoder(SmallTextEncoderConfig(**config))


TEXT_ENCODERS = dict(small=TextEncoderKind(_small_tokenizer, _small_config, _small_build))


class TextToMotion(nn.Module):
    """Text encoder and T2M as one module: one DDP wrapper, one optimizer, one state_dict."""

    def __init__(self, text_encoder: nn.Module, t2m: T2M):
        super().__init__()
        self.text_encoder, self.t2m = text_encoder, t2m

    def forward(self, caption_ids: Tensor, caption_mask: Tensor, tokens: Tensor,
                lengths: Tensor) -> tuple[Tensor, Tensor]:
        """-> T2M.loss: (loss, per-level token accuracy (L,))."""
        return self.t2m.loss(self.text_encoder.encode(caption_ids, caption_mask), tokens, lengths)


def t2m_checkpoint(run_dir: str | Path) -> Path:
    """A T2M run's best.pt if it has one, else its checkpoint.pt."""
    run = Path(run_dir)
    best = run / "best.pt"
    return best if best.is_file() else run / "checkpoint.pt"


def load_t2m(run_dir: str | Path) -> tuple[T2M, nn.Module, Tokenizer]:
    """(T2M, text encoder, tokenizer) of a trained run, both models in eval mode."""
    run = Path(run_dir)
    path = t2m_checkpoint(run)
    state = load_checkpoint(path)
    config = state["config"]
    if not {"t2m", "text_encoder", "tokenizer"} <= set(config):
        raise ValueError(f"{path}: not a `mogo train t2m` checkpoint")
    model = _build_model(config["text_encoder"], T2MConfig(**config["t2m"]))
    model.load_state_dict(state["model"])
    model.eval()
    return model.t2m, model.text_encoder, Tokenizer.from_file(str(run / config["tokenizer"]))


def _build_model(text_encoder: dict, t2m_config: T2MConfig) -> TextToMotion:
    if text_encoder["kind"] not in TEXT_ENCODERS:
        raise ValueError(f"unknown text encoder {text_encoder['kind']!r}; known: "
                         f"{', '.join(TEXT_ENCODERS)}")
    return TextToMotion(TEXT_ENCODERS[text_encoder["kind"]].build(text_encoder["config"]),
                        T2M(t2m_config))


# -- tokens ------------------------------------------------------------------------------------

@torch.inference_mode()
def tokenize_split(folder: HumanML3DFolder, split: str, vq: MoSAVQ, key: dict,
                   device: torch.device) -> dict[str, np.ndarray]:
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
        x = torch.from_numpy(np.stack([raw[i][:lengths[i]] for i in batch])).to(device)
        ids = vq.encode((x - vq.mean) / vq.std).cpu().numpy().astype(np.int32)
        for i, clip_ids in zip(batch, ids):
            tokens[i] = clip_ids
        progress.update(len(batch))
    progress.close()
    offsets = np.cumsum([0] + [len(t) for t in tokens])
    return dict(tokens=np.concatenate(tokens), offsets=offsets.astype(np.int64),
                clip_ids=np.array(spans.ids, dtype=str),
                span_clip=np.array([s.clip for s in spans.spans], dtype=np.int64),
                span_start=np.array([s.start // down for s in spans.spans], dtype=np.int64),
                span_end=np.array([s.end // down for s in spans.spans], dtype=np.int64),
                captions=np.array([s.caption for s in spans.spans], dtype=str),
                **{name: np.array(value) for name, value in key.items()})


def read_tokens(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as arrays:
        return {name: arrays[name] for name in arrays.files}


def _cache_matches(path: Path, key: dict) -> bool:
    if not path.is_file():
        return False
    with np.load(path, allow_pickle=False) as arrays:
        return all(name in arrays.files and arrays[name].item() == value
                   for name, value in key.items())


def _write_tokens(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Through a temporary file: a run killed mid-write leaves no half cache."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    with partial.open("wb") as handle:
        np.savez(handle, **arrays)
    os.replace(partial, path)


class TokenSpans(_EpochSeeded):
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
        tokens = torch.from_numpy(c["tokens"][base + start:base + end].astype(np.int64))
        return dict(caption=str(c["captions"][index]), tokens=tokens)


def collate_tokens(batch: list[dict]) -> dict:
    """captions (list), tokens (B, Tmax, L) int64 padded with id 0, lengths (B,) int64."""
    lengths = torch.tensor([len(item["tokens"]) for item in batch], dtype=torch.long)
    tokens = torch.zeros(len(batch), int(lengths.max()), batch[0]["tokens"].shape[1],
                         dtype=torch.long)
    for row, item in enumerate(batch):
        tokens[row, :len(item["tokens"])] = item["tokens"]
    return dict(captions=[item["caption"] for item in batch], tokens=tokens, lengths=lengths)


# -- training ----------------------------------------------------------------------------------

@dataclass(kw_only=True)
class T2MTrainOptions(RunOptions):
    vq: Path
    text_encoder: str | None = None


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
        raise ValueError(f"{vq_path} is not the VQ checkpoint this run was trained on "
                         f"(sha256 differs); resume with that one or start a new run")
    t2m_config = (T2MConfig(**state["config"]["t2m"]) if state is not None
                  else _t2m_config(recipe["preset"], vq.config))
    process = start_process(options.device)
    try:
        if process.is_main:
            _prepare(out, folder, vq, recipe, vq_sha256, fresh=state is None,
                     device=process.device)
        if process.distributed:
            dist.barrier()
        config = dict(
            t2m=asdict(t2m_config), recipe=recipe, tokenizer=TOKENIZER,
            data=str(folder.root.resolve()), min_frames=MIN_FRAMES, max_frames=MAX_FRAMES,
            world_size=process.world_size,
            vq=dict(run=str(Path(options.vq).resolve()), checkpoint=str(vq_path.resolve()),
                    sha256=vq_sha256, down_factor=vq.config.down_factor))
        _train(out, config, state, options, process)
        finish_together(process)
    finally:
        end_process(process)


def _recipe(options: T2MTrainOptions, state: dict | None) -> dict:
    recipe = merge_recipe(T2M_RECIPE, {name: getattr(options, name) for name in T2M_RECIPE},
                          None if state is None else state["config"])
    if recipe["preset"] not in PRESETS:
        raise ValueError(f"unknown config {recipe['preset']!r}; use {', '.join(PRESETS)}")
    if recipe["text_encoder"] not in TEXT_ENCODERS:
        raise ValueError(f"unknown text encoder {recipe['text_encoder']!r}; use "
                         f"{', '.join(TEXT_ENCODERS)}")
    if recipe["batch_size"] <= 0 or recipe["lr"] <= 0 or recipe["warmup"] < 0:
        raise ValueError(f"need batch size > 0, lr > 0, warmup >= 0, got {recipe['batch_size']}, "
                         f"{recipe['lr']}, {recipe['warmup']}")
    return recipe


def _t2m_config(preset: str, vq: VQConfig) -> T2MConfig:
    """The preset with the VQ's codebook size; its number of levels must be the VQ's."""
    config = PRESETS[preset]()
    if config.num_levels != vq.levels:
        raise ValueError(f"config {preset} has {config.num_levels} levels but the VQ has "
                         f"{vq.levels}")
    return replace(config, codebook_size=vq.codebook_size)


def _prepare(out: Path, folder: HumanML3DFolder, vq: MoSAVQ, recipe: dict, vq_sha256: str,
             fresh: bool, device: torch.device) -> None:
    """Rank 0: the token caches (unless still valid) and, for a new run, the tokenizer."""
    key = dict(vq_sha256=vq_sha256, data=str(folder.root.resolve()), min_frames=MIN_FRAMES)
    for split in ("train", "val"):
        path = out / "tokens" / f"{split}.npz"
        if not _cache_matches(path, key):
            _write_tokens(path, tokenize_split(folder, split, vq, key, device))
    if fresh:
        captions = [str(c) for c in read_tokens(out / "tokens" / "train.npz")["captions"]]
        tokenizer = TEXT_ENCODERS[recipe["text_encoder"]].make_tokenizer(recipe["preset"],
                                                                         captions)
        tokenizer.save(str(out / TOKENIZER))


def make_optimizer(model: nn.Module, lr: float) -> torch.optim.AdamW:
    """AdamW with weight decay on the weights of linear layers only (not on norms, biases,
    embeddings, relative-position tables or learned prompt/level vectors)."""
    decayed = {id(m.weight) for m in model.modules() if isinstance(m, nn.Linear)}
    params = [p for p in model.parameters() if p.requires_grad]
    groups = [dict(params=[p for p in params if id(p) in decayed], weight_decay=WEIGHT_DECAY),
              dict(params=[p for p in params if id(p) not in decayed], weight_decay=0.0)]
    return torch.optim.AdamW(groups, lr=lr, betas=(0.9, 0.99))


def _train(out: Path, config: dict, state: dict | None, options: T2MTrainOptions,
           process: Process) -> None:
    recipe = config["recipe"]
    seed, batch_size, steps = recipe["seed"], recipe["batch_size"], options.steps
    kind = TEXT_ENCODERS[recipe["text_encoder"]]
    tokenizer = Tokenizer.from_file(str(out / TOKENIZER))
    t2m_config = T2MConfig(**config["t2m"])
    config["text_encoder"] = (state["config"]["text_encoder"] if state is not None else
                              dict(kind=recipe["text_encoder"],
                                   config=kind.make_config(recipe["preset"], t2m_config.text_dim,
                                                           tokenizer)))
    seed_everything(seed)
    model = _build_model(config["text_encoder"], t2m_config)
    ddp = wrap_model(model, process)
    optimizer = make_optimizer(model, recipe["lr"])
    step, best = 0, math.inf
    if state is not None:
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        step, best = state["step"], state["best_val_loss"]
        if state["config"]["world_size"] != process.world_size and process.is_main:
            print(f"note: the run started with {state['config']['world_size']} processes, now "
                  f"{process.world_size}: the batches differ from an uninterrupted run")

    max_tokens = MAX_FRAMES // config["vq"]["down_factor"]
    train_set = TokenSpans(read_tokens(out / "tokens" / "train.npz"), max_tokens, seed)
    val_set = TokenSpans(read_tokens(out / "tokens" / "val.npz"), max_tokens, seed)
    per_epoch = steps_per_epoch(train_set, batch_size, process)
    epoch, done = divmod(step, max(per_epoch, 1))  # batches() refuses a split under one batch
    stream = batches(train_set, batch_size, process, seed, collate_tokens, start_epoch=epoch)
    for _ in range(done):
        next(stream)
    log = resumed_metrics_log(out, step, process)
    if process.is_main:
        sizes = {name: sum(p.numel() for p in part.parameters()) / 1e6
                 for name, part in (("t2m", model.t2m), ("text encoder", model.text_encoder))}
        print(f"t2m: {sizes['t2m']:.2f}M parameters + text encoder {sizes['text encoder']:.2f}M; "
              f"{len(train_set)} train / {len(val_set)} val spans, {per_epoch} steps an epoch; "
              f"{process.world_size} process(es) on {process.device}; "
              f"{'resuming at' if step else 'starting at'} step {step} of {steps}", flush=True)

    device, L = process.device, t2m_config.num_levels
    sums, count, window_start = torch.zeros(1 + L, device=device), 0, time.perf_counter()
    while step < steps:
        batch = next(stream)
        torch.manual_seed(step_seed(seed, process.rank, step))
        lr = warmup_cosine(step, recipe["warmup"], steps, recipe["lr"], recipe["lr"] / 10)
        set_learning_rate(optimizer, lr)
        caption_ids, caption_mask = encode_captions(tokenizer, batch["captions"])
        loss, accuracy = ddp(caption_ids.to(device), caption_mask.to(device),
                             batch["tokens"].to(device), batch["lengths"].to(device))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), GRAD_CLIP)
        optimizer.step()
        step += 1
        sums += torch.cat([loss.detach()[None], accuracy])
        count += 1

        if step % options.log_every == 0 or step == steps:
            rate = count / (time.perf_counter() - window_start)
            values = all_reduce_mean(_named(sums / count), process)
            log.write("train", step, lr=lr, **values, steps_per_s=round(rate, 3))
            if process.is_main:
                print(f"step {step}/{steps}  {_summary(values)}  lr {lr:.2e}  "
                      f"{rate:.2f} steps/s  eta {format_duration((steps - step) / rate)}",
                      flush=True)
            sums, count, window_start = torch.zeros_like(sums), 0, time.perf_counter()
        if step % options.val_every == 0 or step == steps:
            values = validate(model, val_set, tokenizer, batch_size, process)
            improved = values["loss"] < best
            best = min(best, values["loss"])
            log.write("val", step, **values)
            if process.is_main:
                print(f"val {step}  {_summary(values)}{'  (best)' if improved else ''}",
                      flush=True)
                if improved:
                    save_checkpoint(out / "best.pt", model, None, step, config,
                                    best_val_loss=best)
        if process.is_main and (step % options.checkpoint_every == 0 or step == steps):
            save_checkpoint(out / "checkpoint.pt", model, optimizer, step, config,
                            best_val_loss=best)


@torch.no_grad()
def validate(model: TextToMotion, dataset: TokenSpans, tokenizer: Tokenizer, batch_size: int,
             process: Process) -> dict[str, float]:
    """Teacher-forced loss and per-level token accuracy over the whole split (eval mode: no
    dropout, prompt dropout or corruption), each rank taking every world_size-th span."""
    model.eval()
    device = process.device
    indices = list(range(process.rank, len(dataset), process.world_size))
    sums, count = torch.zeros(1 + model.t2m.config.num_levels, device=device), 0
    for first in range(0, len(indices), batch_size):
        batch = collate_tokens([dataset[i] for i in indices[first:first + batch_size]])
        caption_ids, caption_mask = encode_captions(tokenizer, batch["captions"])
        loss, accuracy = model(caption_ids.to(device), caption_mask.to(device),
                               batch["tokens"].to(device), batch["lengths"].to(device))
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
