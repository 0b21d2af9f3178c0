"""What every training run shares: the process group, seeds, batches, the learning-rate
schedule, checkpoints and the JSONL metrics log.

One code path serves a single process and `torchrun --nproc_per_node N`: torchrun sets
RANK / WORLD_SIZE / LOCAL_RANK, and then each process joins the group (gloo on CPU, nccl on
CUDA), sees its own shard of every epoch, and only rank 0 writes files.
"""

from __future__ import annotations

import copy
import json
import math
import os
import random
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, Dataset, DistributedSampler

from mogo.export.models.runs import CHECKPOINT_FORMAT, load_checkpoint

GPU_LOADER_WORKERS = 3
WEIGHT_DECAY = 0.1  # of make_optimizer


@dataclass(frozen=True)
class Process:
    rank: int
    world_size: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1


def start_process(device: str = "auto") -> Process:
    """This process's place in the run; joins the process group when launched by torchrun."""
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError("--device cuda was asked for, but torch sees no CUDA device")
    if device not in ("cpu", "cuda") and not device.startswith("cuda:"):
        raise ValueError(f"unknown device {device!r}; use auto, cpu or cuda")
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    if world_size > 1:
        if device.startswith("cuda"):
            local_rank = int(os.environ.get("LOCAL_RANK", "0"))
            torch.cuda.set_device(local_rank)
            device = f"cuda:{local_rank}"
        dist.init_process_group("nccl" if device.startswith("cuda") else "gloo")
    if device.startswith("cuda"):
        torch.backends.cuda.matmul.allow_tf32 = True  # fp32 weights, TF32 matrix products
        torch.backends.cudnn.allow_tf32 = True
    return Process(rank, world_size, torch.device(device))


def finish_together(process: Process) -> None:
    """After a run completes: a rank tearing gloo down while another still works (rank 0
    writing its last checkpoint) can abort the process, so every rank waits here first."""
    if process.distributed:
        dist.barrier()


def end_process(process: Process) -> None:
    if process.distributed and dist.is_initialized():
        dist.destroy_process_group()


def seed_everything(seed: int) -> None:
    """The same seed on every rank: identical initial weights without a broadcast."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def wrap_model(model: nn.Module, process: Process) -> nn.Module:
    """DistributedDataParallel when there are several processes, the model itself otherwise."""
    model.to(process.device)
    if not process.distributed:
        return model
    device_ids = [process.device.index] if process.device.type == "cuda" else None
    return nn.parallel.DistributedDataParallel(model, device_ids=device_ids)


def unwrap_model(model: nn.Module) -> nn.Module:
    return model.module if isinstance(model, nn.parallel.DistributedDataParallel) else model


def batches(
    dataset: Dataset,
    batch_size: int,
    process: Process,
    seed: int,
    collate_fn: Callable | None = None,
    start_epoch: int = 0,
) -> Iterator:
    """Endless shuffled batches, this rank's shard of each epoch. The order depends only on
    (seed, epoch), so a resumed run sees the batches it would have seen."""
    if len(dataset) < batch_size * process.world_size:
        raise ValueError(
            f"the training split has {len(dataset)} items, fewer than one batch "
            f"of {batch_size} per process ({process.world_size} processes)"
        )
    sampler = DistributedSampler(
        dataset,
        num_replicas=process.world_size,
        rank=process.rank,
        shuffle=True,
        seed=seed,
        drop_last=True,
    )
    on_gpu = process.device.type == "cuda"  # there, workers assemble batches while it computes
    loader = DataLoader(
        dataset,
        batch_size=batch_size,
        sampler=sampler,
        drop_last=True,
        collate_fn=collate_fn,
        num_workers=min(GPU_LOADER_WORKERS, os.cpu_count() or 1) if on_gpu else 0,
        pin_memory=on_gpu,
    )
    epoch = start_epoch
    while True:
        sampler.set_epoch(epoch)
        if hasattr(dataset, "set_epoch"):
            dataset.set_epoch(epoch)
        yield from loader
        epoch += 1


def equal_length_groups(lengths: list[int], batch_size: int) -> Iterator[list[int]]:
    """Indices of items of equal length, at most `batch_size` a group: whole clips batched
    without padding (padding would change what the convolutions see at the ends)."""
    by_length: dict[int, list[int]] = {}
    for index, length in enumerate(lengths):
        by_length.setdefault(length, []).append(index)
    for same in by_length.values():
        for first in range(0, len(same), batch_size):
            yield same[first : first + batch_size]


class WeightAverage:
    """An exponential moving average of a model's trained parameters (Polyak averaging):
    after every step, average <- decay * average + (1 - decay) * weights. It averages out the
    noise of the steps, which a quantity integrated over a clip, as the root trajectory is from
    per-frame velocities, is most sensitive to. Starts at the model's weights."""

    def __init__(self, model: nn.Module, decay: float):
        if not 0 < decay < 1:
            raise ValueError(f"the weight average's decay must be in (0, 1), got {decay}")
        self.decay = decay
        self.parameters = {
            name: p.detach().clone()
            for name, p in unwrap_model(model).named_parameters()
            if p.requires_grad
        }

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        for name, p in unwrap_model(model).named_parameters():
            if name in self.parameters:
                self.parameters[name].lerp_(p, 1 - self.decay)

    def averaged(self, model: nn.Module) -> nn.Module:
        """A copy of the model (buffers and untrained parameters as they are) holding the
        averaged parameters."""
        averaged = copy.deepcopy(unwrap_model(model))
        averaged.load_state_dict({**averaged.state_dict(), **self.parameters})
        return averaged


def steps_per_epoch(dataset: Dataset, batch_size: int, process: Process) -> int:
    return len(dataset) // process.world_size // batch_size


def warmup_cosine(step: int, warmup: int, total: int, peak: float, final: float) -> float:
    """Linear warm-up to `peak` over `warmup` steps, then cosine decay to `final` at `total`."""
    if step < warmup:
        return peak * (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, total - warmup))
    return final + 0.5 * (peak - final) * (1 + math.cos(math.pi * progress))


def begin_step(
    optimizer: torch.optim.Optimizer, recipe: dict, step: int, steps: int, rank: int
) -> float:
    """Before a training step: reseed torch (`step_seed`) and set the warm-up-cosine learning
    rate of the recipe (peak recipe["lr"], down to a tenth); -> the rate."""
    torch.manual_seed(step_seed(recipe["seed"], rank, step))
    lr = warmup_cosine(step, recipe["warmup"], steps, recipe["lr"], recipe["lr"] / 10)
    set_learning_rate(optimizer, lr)
    return lr


def set_learning_rate(optimizer: torch.optim.Optimizer, lr: float) -> None:
    for group in optimizer.param_groups:
        group["lr"] = lr


def make_optimizer(model: nn.Module, lr: float) -> torch.optim.AdamW:
    """AdamW with weight decay on the weights of linear layers only (not on norms, biases,
    embeddings, relative-position tables or learned prompt/level vectors)."""
    decayed = {id(m.weight) for m in model.modules() if isinstance(m, nn.Linear)}
    params = [p for p in model.parameters() if p.requires_grad]
    groups = [
        dict(params=[p for p in params if id(p) in decayed], weight_decay=WEIGHT_DECAY),
        dict(params=[p for p in params if id(p) not in decayed], weight_decay=0.0),
    ]
    return torch.optim.AdamW(groups, lr=lr, betas=(0.9, 0.99))


def save_checkpoint(
    path: Path,
    model: nn.Module,
    optimizer: torch.optim.Optimizer | None,
    step: int,
    config: dict,
    **extra,
) -> None:
    """Tensors, numbers, strings and containers only, so `load_checkpoint` can refuse anything
    else (weights_only=True). Written to a temporary file and renamed: a run killed mid-save
    keeps its previous checkpoint."""
    state = dict(
        format=CHECKPOINT_FORMAT,
        step=step,
        config=config,
        model=unwrap_model(model).state_dict(),
        optimizer=optimizer.state_dict() if optimizer is not None else None,
        torch_rng=torch.get_rng_state(),
        **extra,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    torch.save(state, partial)
    os.replace(partial, path)


class MetricsLog:
    """One JSON object per line in RUN/metrics.jsonl (rank 0 only); appends, so a resumed run
    continues the same log."""

    def __init__(self, path: Path, enabled: bool = True):
        self.path = Path(path)
        self.enabled = enabled
        self.start = time.perf_counter()
        if enabled:
            self.path.parent.mkdir(parents=True, exist_ok=True)

    def write(self, kind: str, step: int, **values: float) -> None:
        if not self.enabled:
            return
        record = dict(
            kind=kind,
            step=step,
            seconds=round(time.perf_counter() - self.start, 3),
            **{k: _plain(v) for k, v in values.items()},
        )
        with self.path.open("a") as log:
            log.write(json.dumps(record) + "\n")


def previous_run(out: Path, resume: bool) -> dict | None:
    """The state of the run in `out` to resume, or None for a new run (which `out` must not
    already hold)."""
    checkpoint = Path(out) / "checkpoint.pt"
    if resume:
        if not checkpoint.is_file():
            raise FileNotFoundError(f"--resume: no checkpoint at {checkpoint}")
        return load_checkpoint(checkpoint)
    if checkpoint.exists():
        raise ValueError(f"{out} already holds a run; pass --resume or choose a new --out")
    return None


def merge_recipe(defaults: dict, given: dict, state: dict | None) -> dict:
    """What defines a run: `defaults` for a new run, the run's own recipe (state["recipe"])
    on resume, with the values `given` (None: not given) on top. A resumed run keeps its
    settings, so a given value that differs from it is refused; a run from before a setting
    existed had its default."""
    base = defaults if state is None else {**defaults, **state["recipe"]}
    recipe = dict(base)
    for name, value in given.items():
        if value is None:
            continue
        if state is not None and value != base[name]:
            raise ValueError(
                f"--{name.replace('_', '-')} {value} differs from the run's "
                f"{base[name]}; a resumed run keeps its settings"
            )
        recipe[name] = value
    return recipe


def step_seed(seed: int, rank: int, step: int) -> int:
    """Every step reseeds torch from (seed, rank, step), so that dropout and other training
    noise do not depend on what ran before: a resumed run is exact."""
    return int(np.random.SeedSequence([seed, rank, step]).generate_state(1)[0])


def resumed_metrics_log(out: Path, step: int, process: Process) -> MetricsLog:
    """The run's MetricsLog, without records after `step` (left by a run killed between logging
    and its next checkpoint), so a resumed log reads as one uninterrupted run."""
    path = Path(out) / "metrics.jsonl"
    if process.is_main and path.is_file():
        kept = [
            line
            for line in path.read_text().splitlines()
            if line.strip() and json.loads(line)["step"] <= step
        ]
        path.write_text("".join(line + "\n" for line in kept))
    return MetricsLog(path, enabled=process.is_main)


def format_duration(seconds: float) -> str:
    seconds = int(seconds)
    if seconds >= 3600:
        return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
    return f"{seconds // 60}m{seconds % 60:02d}s" if seconds >= 60 else f"{seconds}s"


def all_reduce_mean(values: dict[str, float], process: Process) -> dict[str, float]:
    """The mean of each value over all ranks (for logging losses and validation metrics)."""
    if not process.distributed:
        return values
    names = sorted(values)
    tensor = torch.tensor(
        [float(values[n]) for n in names], dtype=torch.float64, device=process.device
    )
    dist.all_reduce(tensor)
    return {n: float(v) / process.world_size for n, v in zip(names, tensor.tolist(), strict=False)}


def _plain(value):
    if isinstance(value, torch.Tensor):
        return value.item() if value.numel() == 1 else value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value
