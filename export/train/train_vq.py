"""`mogo train vq`: the MoSA-VQ (mogo.export.models.vq) on random crops (or whole clips, batched by
length) of a HumanML3D-layout folder.

RUN/ holds
    checkpoint.pt   latest: weights, optimizer, step; "config" is the VQConfig as a dict
    best.pt         lowest validation MPJPE: weights and config (what `mogo train t2m` and
                    `mogo export` take)
    metrics.jsonl   train and val records

Validation decodes whole clips (as the runtime does, not crops), at most `--val-clips` of the
val split, and measures MPJPE on the recovered joints, root trajectory included. With
`--weight-average DECAY` it measures an exponential moving average of the weights, which is
what best.pt keeps; checkpoint.pt holds both.

Resuming is exact (same world size), as for `mogo train t2m`: batches depend only on
(seed, epoch) and every step reseeds torch from (seed, rank, step). Under torchrun, DDP keeps
the weights in step; the EMA codebooks are buffers, which DDP broadcasts from rank 0 before
every forward, so rank 0's codebook updates are the ones that stand.
"""
from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, replace
from pathlib import Path

import torch
from torch import Tensor, nn

from mogo.export.train.datasets import (HumanML3DFolder, MotionCropDataset, WholeClipBatches,
                                 whole_clip_features)
from mogo.export.train.options import VQTrainOptions
from mogo.export.train.training import (Process, WeightAverage, all_reduce_mean, batches,
                                  end_process, equal_length_groups, finish_together,
                                  format_duration, merge_recipe, previous_run,
                                  resumed_metrics_log, save_checkpoint, seed_everything,
                                  set_learning_rate, start_process, step_seed, steps_per_epoch,
                                  warmup_cosine, wrap_model)
from mogo.export.models.runs import read_vq_checkpoint, tokens_sha256, vq_checkpoint
from mogo.export.models.vq import MoSAVQ, VQConfig, reconstruction_metrics

PRESETS: dict[str, Callable[[], VQConfig]] = dict(
    tiny=VQConfig.tiny, cpu_default=VQConfig.cpu_default, paper=VQConfig.paper)
GRAD_CLIP = 1.0
# the recipe settings that change the model (None: the preset's value), for ablations
VQ_MODEL_SWITCHES = ("levels", "down_factor", "causal", "scale_bias", "decorrelation")


def train_vq(options: VQTrainOptions) -> None:
    """Train (or resume) a VQ run; under torchrun every process calls this, rank 0 writes."""
    options.check_intervals()
    if options.val_clips <= 0:
        raise ValueError(f"--val-clips must be positive, got {options.val_clips}")
    out = Path(options.out)
    if options.init is not None and options.resume:
        raise ValueError("--init starts a new run from trained weights; --resume continues a "
                         "run: pass one of them")
    state = previous_run(out, options.resume)
    given = {n: v for n, v in options.given().items() if n != "init"}
    init = None
    if options.init is not None:
        init, init_path = read_init(options.init)
        given = _recipe_of_init(given, init, init_path)
    recipe = merge_recipe(VQTrainOptions.recipe_defaults(), given, state)
    if recipe["preset"] not in PRESETS:
        raise ValueError(f"unknown config {recipe['preset']!r}; use {', '.join(PRESETS)}")
    if recipe["batch_size"] <= 0 or recipe["lr"] <= 0 or recipe["warmup"] < 0 \
            or recipe["crop_frames"] < 1:
        raise ValueError(f"need batch size > 0, lr > 0, warmup >= 0, crop frames >= 1, got "
                         f"{recipe['batch_size']}, {recipe['lr']}, {recipe['warmup']}, "
                         f"{recipe['crop_frames']}")
    folder = HumanML3DFolder(options.data)
    config = (VQConfig(**state["config"]) if state is not None
              else VQConfig(**init["config"]) if init is not None
              else vq_config(recipe, folder.feature_dim))
    if config.feature_dim != folder.feature_dim:
        raise ValueError(f"{options.init}: a VQ of {config.feature_dim} features; "
                         f"{folder.root} has {folder.feature_dim}")
    if recipe["tune"] not in ("all", "decoder"):
        raise ValueError(f"--tune must be all or decoder, got {recipe['tune']!r}")
    if recipe["tune"] == "decoder" and recipe["init"] is None:
        raise ValueError("--tune decoder fine-tunes a trained VQ: pass --init RUN")
    if init is not None and not init["ema"] and recipe["tune"] != "decoder":
        raise ValueError(f"--init {options.init}: a bundle keeps no codebook statistics to go "
                         "on training from; pass --tune decoder")
    if recipe["crop_frames"] % config.down_factor:
        raise ValueError(f"--crop-frames {recipe['crop_frames']} is not a multiple of the "
                         f"down factor {config.down_factor}")
    process = start_process(options.device)
    try:
        if state is None and init is not None:
            state = _fine_tuning_state(init, folder)
        _train(out, folder, config, recipe, state, options, process)
        finish_together(process)
    finally:
        end_process(process)


def read_init(path: Path) -> tuple[dict, Path]:
    """What `--init` starts from, with its path: a VQ run's checkpoint, or a bundle's VQ read
    back from its graphs (`vq_from_bundle`). A bundle's tokens are named by the
    tokens_sha256 its VQ was trained with, else by its encoder graph's sha256; "ema" is False
    for a bundle, which holds no EMA codebook statistics."""
    from mogo.bundle import MANIFEST

    path = Path(path)
    if not (path / MANIFEST).is_file():
        checkpoint = vq_checkpoint(path)
        return {**read_vq_checkpoint(checkpoint), "ema": True}, checkpoint
    from mogo.export.onnx.vq_graphs import vq_from_bundle

    model = vq_from_bundle(path)
    manifest = json.loads((path / MANIFEST).read_text())
    recipe = (manifest.get("training", {}).get("vq") or {}).get("recipe") or {}
    tokens = recipe.get("tokens_sha256") or \
        manifest["files"][manifest["vq"]["encoder"]["file"]]["sha256"]
    return dict(config=asdict(model.config), model=model.state_dict(), ema=False,
                recipe=dict(preset=recipe.get("preset", "cpu_default"),
                            tokens_sha256=tokens)), path


def _recipe_of_init(given: dict, init: dict, path: Path) -> dict:
    """A fine-tuning run keeps the model of the run it starts from: its preset and switches
    (a given switch that differs is refused); the training settings are the new run's."""
    fixed = {"preset": init["recipe"]["preset"],
             **{name: getattr(VQConfig(**init["config"]), name) for name in VQ_MODEL_SWITCHES}}
    for name, value in fixed.items():
        if given[name] is not None and given[name] != value:
            flag = "--config" if name == "preset" else f"--{name.replace('_', '-')}"
            raise ValueError(f"{flag} {given[name]} differs from {value} of --init {path}; a "
                             "fine-tuning run keeps the model it starts from")
    recipe = {**given, **fixed, "init": str(path.resolve())}
    if given["tune"] == "decoder":
        recipe["tokens_sha256"] = tokens_sha256(init, path)
    return recipe


def _fine_tuning_state(init: dict, folder: HumanML3DFolder) -> dict:
    """What _train takes from the --init checkpoint: its weights, at step 0, with the
    normalisation statistics of the data the new run trains and validates on."""
    statistics = {name: torch.as_tensor(value, dtype=torch.float32)
                  for name, value in (("mean", folder.mean), ("std", folder.std))}
    return dict(model={**init["model"], **statistics}, optimizer=None, step=0,
                best_val_mpjpe_mm=math.inf)


def vq_config(recipe: dict, feature_dim: int) -> VQConfig:
    """The preset with the recipe's model switches and the data's feature size."""
    switches = {name: recipe[name] for name in VQ_MODEL_SWITCHES if recipe[name] is not None}
    return replace(PRESETS[recipe["preset"]](), feature_dim=feature_dim, **switches)


def _train(out: Path, folder: HumanML3DFolder, config: VQConfig, recipe: dict,
           state: dict | None, options: VQTrainOptions, process: Process) -> None:
    seed, batch_size, steps = recipe["seed"], recipe["batch_size"], options.steps
    seed_everything(seed)
    model = MoSAVQ(config, folder.mean, folder.std)
    decoder_only = recipe.get("tune") == "decoder"
    if decoder_only:
        model.encoder.requires_grad_(False)
        model.quantizer.requires_grad_(False)
    ddp = wrap_model(model, process)
    optimizer = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad],
                                  lr=recipe["lr"], betas=(0.9, 0.99), weight_decay=0.0)
    step, best = 0, math.inf
    if state is not None:
        model.load_state_dict(state["model"])
        if state["optimizer"] is not None:
            optimizer.load_state_dict(state["optimizer"])
        step, best = state["step"], state["best_val_mpjpe_mm"]
    average = WeightAverage(model, recipe["weight_average"]) if recipe["weight_average"] else None
    if average is not None and state is not None and state.get("averaged_parameters"):
        average.parameters = state["averaged_parameters"]

    if recipe["whole_clips"]:  # items are batches already
        train_set = WholeClipBatches(folder, "train", batch_size, seed, config.down_factor)
        loader_batch, collate = 1, only_item
    else:
        train_set = MotionCropDataset(folder, "train", recipe["crop_frames"], seed)
        loader_batch, collate = batch_size, None
    val_clips = whole_clips(folder, "val", config.down_factor, options.val_clips)
    per_epoch = steps_per_epoch(train_set, loader_batch, process)
    epoch, done = divmod(step, max(per_epoch, 1))
    stream = batches(train_set, loader_batch, process, seed, collate, start_epoch=epoch)
    for _ in range(done):
        next(stream)
    log = resumed_metrics_log(out, step, process)
    extra = dict(recipe=recipe, data=str(folder.root.resolve()), world_size=process.world_size)
    if process.is_main:
        lookahead = "causal" if config.causal else "centred"
        if decoder_only:
            lookahead += " (fine-tuning the decoder alone)"
        print(f"vq: {sum(p.numel() for p in model.parameters()) / 1e6:.2f}M parameters, "
              f"{config.levels} levels of {config.codebook_size} codes, {lookahead} decoder; "
              f"{len(train_set.clips)} train clips, {len(val_clips)} val clips, {per_epoch} "
              f"steps an epoch; {process.world_size} process(es) on {process.device}; "
              f"{'resuming at' if step else 'starting at'} step {step} of {steps}", flush=True)

    device = process.device
    sums, count, window_start = None, 0, time.perf_counter()
    while step < steps:
        x = next(stream).to(device, non_blocking=True)
        torch.manual_seed(step_seed(seed, process.rank, step))
        lr = warmup_cosine(step, recipe["warmup"], steps, recipe["lr"], recipe["lr"] / 10)
        set_learning_rate(optimizer, lr)
        output = ddp(x, decoder_only=decoder_only)
        optimizer.zero_grad(set_to_none=True)
        output.losses["total"].backward()
        nn.utils.clip_grad_norm_(model.parameters(), GRAD_CLIP)
        optimizer.step()
        if average is not None:
            average.update(model)
        step += 1
        values = _train_values(output.losses, output.stats)
        sums = values if sums is None else sums + values
        count += 1

        if step % options.log_every == 0 or step == steps:
            rate = count / (time.perf_counter() - window_start)
            names = [*output.losses, *STAT_NAMES]
            values = all_reduce_mean(dict(zip(names, (sums / count).tolist())), process)
            log.write("train", step, lr=lr, **values, steps_per_s=round(rate, 3))
            if process.is_main:
                print(f"step {step}/{steps}  loss {values['total']:.4f}  recon "
                      f"{values['recon']:.4f}  joints {values['joints']:.4f}  perplexity "
                      f"{values['perplexity']:.0f}  lr {lr:.2e}  {rate:.2f} steps/s  "
                      f"eta {format_duration((steps - step) / rate)}", flush=True)
            sums, count, window_start = None, 0, time.perf_counter()
        if step % options.val_every == 0 or step == steps:
            if process.is_main:
                measured = model if average is None else average.averaged(model)
                metrics = reconstruction_metrics(measured, clip_batches(val_clips, device))
                improved = metrics["mpjpe_mm"] < best
                best = min(best, metrics["mpjpe_mm"])
                log.write("val", step, **metrics)
                print(f"val {step}  MPJPE {metrics['mpjpe_mm']:.1f} mm  feature L1 "
                      f"{metrics['feature_l1']:.4f}  by levels "
                      f"{' '.join(f'{v:.0f}' for v in metrics['mpjpe_mm_by_levels'])} mm"
                      f"{'  (averaged weights)' if average else ''}"
                      f"{'  (best)' if improved else ''}", flush=True)
                if improved:
                    save_checkpoint(out / "best.pt", measured, None, step, asdict(config),
                                    best_val_mpjpe_mm=best, **extra)
        if process.is_main and (step % options.checkpoint_every == 0 or step == steps):
            save_checkpoint(out / "checkpoint.pt", model, optimizer, step, asdict(config),
                            best_val_mpjpe_mm=best,
                            averaged_parameters=None if average is None else average.parameters,
                            **extra)


STAT_NAMES = ("perplexity", "usage", "dead_codes")


def only_item(items: list[Tensor]) -> Tensor:
    """The DataLoader collate of batches of one item that is a batch itself."""
    return items[0]


def _train_values(losses: dict[str, Tensor], stats: dict[str, Tensor]) -> Tensor:
    """What a training log line holds, kept on the device until the line is written (reading
    a value back each step would stall the GPU): every loss term, then STAT_NAMES: mean
    perplexity and usage, codes re-drawn."""
    return torch.stack([*(value.detach() for value in losses.values()),
                        stats["perplexity"].mean(), stats["usage"].mean(),
                        stats["dead_codes"].sum()])


def whole_clips(folder: HumanML3DFolder, split: str, down_factor: int,
                limit: int | None = None) -> list[Tensor]:
    """The first `limit` clips of a split, normalised, each (1, T, D) cut to whole tokens."""
    return [torch.from_numpy(clip.copy())[None]
            for clip in whole_clip_features(folder, split, down_factor, limit)]


def clip_batches(clips: list[Tensor], device: torch.device,
                 batch_size: int = 128) -> Iterator[Tensor]:
    """Clips (1, T, D) stacked into batches of equal T, so a whole split decodes in a few
    hundred calls."""
    for group in equal_length_groups([clip.shape[1] for clip in clips], batch_size):
        yield torch.cat([clips[i] for i in group]).to(device)
