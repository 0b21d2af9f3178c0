"""The one training loop: `train_loop` runs a `Trainer` (the VQ's, the T2M's, the evaluator's),
which brings its model, its step (the loss) and its validation; the loop owns the rest. It
seeds, builds and wraps the model (DDP under torchrun), restores a run from its checkpoint and
skips the batches its epoch already saw, sets the warm-up-cosine learning rate, clips the
gradients, logs to RUN/metrics.jsonl, validates every `--val-every` steps (keeping the best
model in best.pt) and writes RUN/checkpoint.pt every `--checkpoint-every` steps. With
`--max-minutes` it stops early once past that wall time, validated and checkpointed.

Resuming is exact (same world size): batches depend only on (seed, epoch) (`batches`), and
every step reseeds torch from (seed, rank, step) (`begin_step`), so dropout and other training
noise do not depend on what ran before.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor, nn
from torch.utils.data import Dataset

from mogo.export.train.options import RunOptions
from mogo.export.train.training import (
    MetricsLog,
    Process,
    all_reduce_mean,
    batches,
    begin_step,
    format_duration,
    resumed_metrics_log,
    save_checkpoint,
    seed_everything,
    steps_per_epoch,
    wrap_model,
)

GRAD_CLIP = 1.0  # the largest gradient norm of a step


class Trainer:
    """What one kind of model brings to the loop. `best_name` is the checkpoint key of the best
    validation score so far, `metric` the validation value it is, `worst` its value before any
    validation. The methods without a body here are the trainer's to write."""

    best_name: str
    metric: str
    higher_is_better = False
    worst = math.inf

    def build(self) -> nn.Module:
        """A new model, built after the run's seed is set (its initial weights)."""
        raise NotImplementedError

    def optimizer(self, model: nn.Module) -> torch.optim.Optimizer:
        raise NotImplementedError

    def restored(self, model: nn.Module, state: dict | None) -> None:
        """After the weights (and optimizer) came from the run's state (None: a new run)."""

    def data(self) -> tuple[Dataset, int, Callable | None]:
        """The training items, how many make a batch, the collate function (None: default)."""
        raise NotImplementedError

    def banner(self, model: nn.Module, per_epoch: int) -> str:
        """The start of the run's first line: the model and its data."""
        raise NotImplementedError

    def step(self, model: nn.Module, batch) -> tuple[Tensor, dict[str, Tensor]]:
        """(loss, the values a training log line averages, each a detached scalar tensor)."""
        raise NotImplementedError

    def stepped(self, model: nn.Module) -> None:
        """After every optimizer step."""

    def train_line(self, values: dict[str, float]) -> str:
        raise NotImplementedError

    def train_extras(self, model: nn.Module) -> dict:
        """Values a training record holds besides the averaged ones."""
        return {}

    def validate(self, model: nn.Module) -> dict[str, float] | None:
        """The validation values (called on every rank; None where a rank measures nothing)."""
        raise NotImplementedError

    def val_line(self, values: dict[str, float]) -> str:
        raise NotImplementedError

    def kept(self, model: nn.Module) -> nn.Module:
        """What best.pt keeps of the model validated."""
        return model

    def checkpoint_extras(self, values: dict[str, float] | None) -> dict:
        """What a checkpoint holds besides the weights: best.pt's (`values`, its validation),
        or checkpoint.pt's (None)."""
        return {}


@dataclass
class Run:
    """One run as the loop sees it."""

    out: Path
    options: RunOptions  # steps and intervals
    recipe: dict  # seed, lr, warmup
    config: dict  # what the checkpoints hold as "config"
    state: dict | None  # the checkpoint the run goes on from; None: a new run
    process: Process


def train_loop(trainer: Trainer, run: Run) -> nn.Module:
    """Train until run.options.steps (or its wall-time budget); -> the trained model (not the
    DDP wrapper)."""
    started = time.monotonic()
    seed_everything(run.recipe["seed"])
    model = trainer.build()
    ddp = wrap_model(model, run.process)
    optimizer = trainer.optimizer(model)
    step, best = _restored(trainer, run, model, optimizer)
    items, batch_size, collate = trainer.data()
    per_epoch = steps_per_epoch(items, batch_size, run.process)
    epoch, done = divmod(step, max(per_epoch, 1))  # batches() refuses a split under one batch
    stream = batches(items, batch_size, run.process, run.recipe["seed"], collate, start_epoch=epoch)
    for _ in range(done):
        next(stream)
    log = resumed_metrics_log(run.out, step, run.process)
    steps = run.options.steps
    if run.process.is_main:
        print(
            f"{trainer.banner(model, per_epoch)}; {run.process.world_size} process(es) on "
            f"{run.process.device}; {'resuming at' if step else 'starting at'} step {step} "
            f"of {steps}",
            flush=True,
        )
    window = _Window()
    while step < steps:
        batch = next(stream)
        lr = begin_step(optimizer, run.recipe, step, steps, run.process.rank)
        loss, values = trainer.step(ddp, batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), GRAD_CLIP)
        optimizer.step()
        trainer.stepped(model)
        step += 1
        window.add(values)
        out_of_time = False
        if _due(step, run.options.log_every, steps):
            _log_training(trainer, model, run, log, step, lr, window)
            window = _Window()
            out_of_time = _past_budget(started, run)
        if _due(step, run.options.val_every, steps) or out_of_time:
            best = _validate(trainer, model, run, log, step, best)
        if run.process.is_main and (_due(step, run.options.checkpoint_every, steps) or out_of_time):
            _checkpoint(trainer, run, model, optimizer, step, best)
        if out_of_time:
            if run.process.is_main:
                print(
                    f"stopped at step {step} of {steps}: past --max-minutes "
                    f"{run.options.max_minutes:g} (--resume goes on)",
                    flush=True,
                )
            break
    return model


def _restored(trainer: Trainer, run: Run, model: nn.Module, optimizer) -> tuple[int, float]:
    """The step and best validation figure to go on from: the resumed run's (its model and
    optimizer loaded), or a fresh start's."""
    step, best = 0, trainer.worst
    if run.state is not None:
        model.load_state_dict(run.state["model"])
        if run.state["optimizer"] is not None:
            optimizer.load_state_dict(run.state["optimizer"])
        step, best = run.state["step"], run.state[trainer.best_name]
    trainer.restored(model, run.state)
    return step, best


def _checkpoint(trainer: Trainer, run: Run, model: nn.Module, optimizer, step: int, best) -> None:
    save_checkpoint(
        run.out / "checkpoint.pt",
        model,
        optimizer,
        step,
        run.config,
        **{trainer.best_name: best},
        **trainer.checkpoint_extras(None),
    )


def _past_budget(started: float, run: Run) -> bool:
    """Whether the run is past its wall-time budget (every rank decides alike: rank 0's
    clock, through the mean of the ranks' flags)."""
    if run.options.max_minutes is None:
        return False
    over = float(time.monotonic() - started > 60 * run.options.max_minutes)
    return all_reduce_mean(dict(over=over if run.process.is_main else 0.0), run.process)["over"] > 0


def _due(step: int, every: int, steps: int) -> bool:
    return step % every == 0 or step == steps


class _Window:
    """The sums of the values of the steps since the last log line, kept on the device until
    the line is written (reading a value back each step would stall the GPU)."""

    def __init__(self):
        self.names: list[str] = []
        self.sums: Tensor | None = None
        self.count = 0
        self.start = time.perf_counter()

    def add(self, values: dict[str, Tensor]) -> None:
        stacked = torch.stack(list(values.values()))
        self.names = list(values)
        self.sums = stacked if self.sums is None else self.sums + stacked
        self.count += 1

    def means(self) -> dict[str, float]:
        return dict(zip(self.names, (self.sums / self.count).tolist(), strict=False))

    def rate(self) -> float:
        """Steps a second."""
        return self.count / (time.perf_counter() - self.start)


def _log_training(
    trainer: Trainer,
    model: nn.Module,
    run: Run,
    log: MetricsLog,
    step: int,
    lr: float,
    window: _Window,
) -> None:
    steps, rate = run.options.steps, window.rate()
    values = all_reduce_mean(window.means(), run.process)
    log.write(
        "train", step, lr=lr, **values, **trainer.train_extras(model), steps_per_s=round(rate, 3)
    )
    if run.process.is_main:
        print(
            f"step {step}/{steps}  {trainer.train_line(values)}  lr {lr:.2e}  {rate:.2f} "
            f"steps/s  eta {format_duration((steps - step) / rate)}",
            flush=True,
        )


def _validate(
    trainer: Trainer, model: nn.Module, run: Run, log: MetricsLog, step: int, best: float
) -> float:
    """Validate, log and keep the model in best.pt if it is the best so far; -> the best score."""
    values = trainer.validate(model)
    if values is None:
        return best
    score = values[trainer.metric]
    improved = score > best if trainer.higher_is_better else score < best
    best = max(best, score) if trainer.higher_is_better else min(best, score)
    log.write("val", step, **values)
    if run.process.is_main:
        print(f"val {step}  {trainer.val_line(values)}{'  (best)' if improved else ''}", flush=True)
        if improved:
            save_checkpoint(
                run.out / "best.pt",
                trainer.kept(model),
                None,
                step,
                run.config,
                **{trainer.best_name: best},
                **trainer.checkpoint_extras(values),
            )
    return best
