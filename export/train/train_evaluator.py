"""`mogo train evaluator`: the text-motion evaluator (mogo.export.models.evaluator), trained
contrastively on the caption spans of a dataset, then exported for torch-free evaluation.

RUN/ holds
    tokenizer.json   trained on the training captions
    checkpoint.pt    latest: weights, optimizer, step, config, normalisation
    best.pt          highest validation R-precision (top 1, batches of 32): weights, config
    metrics.jsonl    train and val records
    evaluator/       the ONNX export of best.pt (`mogo.bench.quality.evaluator` loads it)

Resuming is exact, as for the other trainers: batches depend only on (seed, epoch) and every
step reseeds torch from (seed, rank, step).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tokenizers import Tokenizer
from torch import nn

from mogo.export.data.metrics import R_PRECISION_BATCH, matching_score, r_precision
from mogo.export.train.datasets import HumanML3DFolder, TextMotionDataset, collate_text_motion
from mogo.export.models.evaluator import Evaluator, EvaluatorConfig, export_evaluator
from mogo.export.train.recipes import EVALUATOR_RECIPE
from mogo.export.models.text_encoder import encode_captions, train_tokenizer
from mogo.export.train.train_t2m import make_optimizer
from mogo.export.train.training import (Process, RunOptions, all_reduce_mean, batches, begin_step,
                                  end_process, finish_together, format_duration,
                                  load_checkpoint, merge_recipe, previous_run,
                                  resumed_metrics_log, save_checkpoint, seed_everything,
                                  start_process, steps_per_epoch, wrap_model)
from mogo.motion.skeleton import MAX_FRAMES, MIN_FRAMES

GRAD_CLIP = 1.0
TOKENIZER = "tokenizer.json"
VOCAB = dict(tiny=100, cpu_default=4000)
PRESETS = dict(tiny=EvaluatorConfig.tiny, cpu_default=EvaluatorConfig)


@dataclass(kw_only=True)
class EvaluatorTrainOptions(RunOptions):
    val_spans: int = 1024  # validation spans embedded for R-precision (0: all)


def train_evaluator(options: EvaluatorTrainOptions) -> None:
    """Train (or resume) an evaluator run, then export its best.pt to RUN/evaluator."""
    options.check_intervals()
    out = Path(options.out)
    state = previous_run(out, options.resume)
    recipe = merge_recipe(EVALUATOR_RECIPE,
                          {name: getattr(options, name) for name in EVALUATOR_RECIPE},
                          None if state is None else state["config"])
    if recipe["preset"] not in PRESETS:
        raise ValueError(f"unknown config {recipe['preset']!r}; use {', '.join(PRESETS)}")
    folder = HumanML3DFolder(options.data)
    process = start_process(options.device)
    try:
        train_set = TextMotionDataset(folder, "train", MIN_FRAMES, MAX_FRAMES, recipe["seed"])
        val_set = TextMotionDataset(folder, "val", MIN_FRAMES, MAX_FRAMES, recipe["seed"])
        if state is None and process.is_main:
            out.mkdir(parents=True, exist_ok=True)
            captions = [span.caption for span in train_set.spans]
            train_tokenizer(captions, VOCAB[recipe["preset"]],
                            PRESETS[recipe["preset"]](0).max_length).save(str(out / TOKENIZER))
        if process.distributed:
            torch.distributed.barrier()
        tokenizer = Tokenizer.from_file(str(out / TOKENIZER))
        model_config = (EvaluatorConfig(**state["config"]["model"]) if state is not None else
                        replace(PRESETS[recipe["preset"]](tokenizer.get_vocab_size(),
                                                          folder.feature_dim),
                                max_frames=MAX_FRAMES))
        config = dict(model=asdict(model_config), recipe=recipe, tokenizer=TOKENIZER,
                      data=str(folder.root.resolve()), world_size=process.world_size,
                      mean=folder.mean.tolist(), std=folder.std.tolist())
        model = _train(out, config, state, options, process, tokenizer, train_set, val_set)
        if process.is_main:
            best = load_checkpoint(out / "best.pt")
            model.load_state_dict(best["model"])
            export_evaluator(model.eval(), tokenizer, folder.mean, folder.std, out / "evaluator",
                             training=dict(step=best["step"], data=config["data"],
                                           recipe=recipe, val=best["val"]))
            print(f"wrote {out / 'evaluator'} (best.pt of step {best['step']})", flush=True)
        finish_together(process)
    finally:
        end_process(process)


def _train(out: Path, config: dict, state: dict | None, options: EvaluatorTrainOptions,
           process: Process, tokenizer: Tokenizer, train_set: TextMotionDataset,
           val_set: TextMotionDataset) -> Evaluator:
    recipe = config["recipe"]
    seed, batch_size, steps = recipe["seed"], recipe["batch_size"], options.steps
    seed_everything(seed)
    model = Evaluator(EvaluatorConfig(**config["model"]))
    ddp = wrap_model(model, process)
    optimizer = make_optimizer(model, recipe["lr"])
    step, best = 0, -1.0
    if state is not None:
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        step, best = state["step"], state["best_r1"]
    per_epoch = steps_per_epoch(train_set, batch_size, process)
    epoch, done = divmod(step, max(per_epoch, 1))
    stream = batches(train_set, batch_size, process, seed, collate_text_motion, start_epoch=epoch)
    for _ in range(done):
        next(stream)
    log = resumed_metrics_log(out, step, process)
    if process.is_main:
        print(f"evaluator: {sum(p.numel() for p in model.parameters()) / 1e6:.2f}M parameters; "
              f"{len(train_set)} train / {len(val_set)} val spans, {per_epoch} steps an epoch; "
              f"{process.world_size} process(es) on {process.device}; "
              f"{'resuming at' if step else 'starting at'} step {step} of {steps}", flush=True)

    device = process.device
    sums, count, window_start = torch.zeros(2, device=device), 0, time.perf_counter()
    while step < steps:
        batch = next(stream)
        lr = begin_step(optimizer, recipe, step, steps, process.rank)
        ids, mask = encode_captions(tokenizer, batch["captions"])
        loss, accuracy = ddp(ids.to(device), mask.to(device), batch["motion"].to(device),
                             batch["lengths"].to(device))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), GRAD_CLIP)
        optimizer.step()
        step += 1
        sums += torch.stack([loss.detach(), accuracy])
        count += 1

        if step % options.log_every == 0 or step == steps:
            rate = count / (time.perf_counter() - window_start)
            values = all_reduce_mean(dict(zip(("loss", "batch_acc"), (sums / count).tolist())),
                                     process)
            log.write("train", step, lr=lr, **values, temperature=1 / model.log_scale.exp(),
                      steps_per_s=round(rate, 3))
            if process.is_main:
                print(f"step {step}/{steps}  loss {values['loss']:.4f}  in-batch top-1 "
                      f"{values['batch_acc']:.3f}  lr {lr:.2e}  {rate:.2f} steps/s  "
                      f"eta {format_duration((steps - step) / rate)}", flush=True)
            sums, count, window_start = torch.zeros_like(sums), 0, time.perf_counter()
        if step % options.val_every == 0 or step == steps:
            values = validate(model, val_set, tokenizer, options.val_spans, device)
            improved = values["r1"] > best
            best = max(best, values["r1"])
            log.write("val", step, **values)
            if process.is_main:
                print(f"val {step}  R-precision top-1/2/3 {values['r1']:.3f} / "
                      f"{values['r2']:.3f} / {values['r3']:.3f}  matching "
                      f"{values['matching']:.3f}{'  (best)' if improved else ''}", flush=True)
                if improved:
                    save_checkpoint(out / "best.pt", model, None, step, config, best_r1=best,
                                    val=values)
        if process.is_main and (step % options.checkpoint_every == 0 or step == steps):
            save_checkpoint(out / "checkpoint.pt", model, optimizer, step, config, best_r1=best)
    return model


@torch.no_grad()
def embed_spans(model: Evaluator, dataset: TextMotionDataset, tokenizer: Tokenizer,
                indices: list[int], device: torch.device, batch_size: int = 64
                ) -> tuple[np.ndarray, np.ndarray]:
    """(text, motion) embeddings of the dataset items `indices` (their epoch-0 windows)."""
    texts, motions = [], []
    for first in range(0, len(indices), batch_size):
        batch = collate_text_motion([dataset[i] for i in indices[first:first + batch_size]])
        ids, mask = encode_captions(tokenizer, batch["captions"])
        texts.append(model.embed_text(ids.to(device), mask.to(device)).cpu().numpy())
        motions.append(model.embed_motion(batch["motion"].to(device),
                                          batch["lengths"].to(device)).cpu().numpy())
    return np.concatenate(texts), np.concatenate(motions)


def validate(model: Evaluator, dataset: TextMotionDataset, tokenizer: Tokenizer, spans: int,
             device: torch.device) -> dict[str, float]:
    """R-precision top-1/2/3 (batches of 32, the protocol's, or all the spans when fewer; 20
    shuffles) and the matching distance on a fixed sample of `spans` validation spans (0: all),
    in eval mode."""
    model.eval()
    rng = np.random.default_rng(0)
    indices = sorted(rng.permutation(len(dataset))[:spans or len(dataset)].tolist())
    text, motion = embed_spans(model, dataset, tokenizer, indices, device)
    model.train()
    batch = min(R_PRECISION_BATCH, len(indices))
    precision = np.mean([r_precision(text, motion, rng, batch) for _ in range(20)], axis=0)
    return dict(r1=float(precision[0]), r2=float(precision[1]), r3=float(precision[2]),
                matching=matching_score(text, motion))
