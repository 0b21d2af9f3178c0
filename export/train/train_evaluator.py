"""`mogo train evaluator`: the text-motion evaluator (mogo.export.models.evaluator), trained
contrastively on the caption spans of a dataset, then exported for torch-free evaluation.

RUN/ holds
    tokenizer.json   trained on the training captions
    checkpoint.pt    latest: weights, optimizer, step, config, normalisation
    best.pt          highest validation R-precision (top 1, batches of 32): weights, config
    metrics.jsonl    train and val records
    evaluator/       the ONNX export of best.pt (`mogo.bench.quality.evaluator` loads it)

`EvaluatorTrainer` plugs into the training loop (mogo.export.train.loop, which makes resuming
exact).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch
from tokenizers import Tokenizer
from torch import Tensor, nn
from torch.utils.data import Dataset

from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.export.data.metrics import R_PRECISION_BATCH, matching_score, r_precision
from mogo.export.models.evaluator import Evaluator, EvaluatorConfig
from mogo.export.models.runs import load_checkpoint
from mogo.export.models.text_encoder import encode_captions, train_tokenizer
from mogo.export.onnx.evaluator_graphs import export_evaluator
from mogo.export.train.datasets import TextMotionDataset, collate_text_motion
from mogo.export.train.loop import Run, Trainer, train_loop
from mogo.export.train.options import EvaluatorTrainOptions
from mogo.export.train.training import (
    Process,
    end_process,
    finish_together,
    make_optimizer,
    merge_recipe,
    previous_run,
    start_process,
)
from mogo.motion.skeleton import MAX_FRAMES, MIN_FRAMES

TOKENIZER = "tokenizer.json"
VOCAB = dict(tiny=100, cpu_default=4000)
PRESETS = dict(tiny=EvaluatorConfig.tiny, cpu_default=EvaluatorConfig)


def train_evaluator(options: EvaluatorTrainOptions) -> None:
    """Train (or resume) an evaluator run, then export its best.pt to RUN/evaluator."""
    options.check_intervals()
    out = Path(options.out)
    state = previous_run(out, options.resume)
    recipe = merge_recipe(
        EvaluatorTrainOptions.recipe_defaults(),
        options.given(),
        None if state is None else state["config"],
    )
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
            train_tokenizer(
                captions, VOCAB[recipe["preset"]], PRESETS[recipe["preset"]](0).max_length
            ).save(str(out / TOKENIZER))
        if process.distributed:
            torch.distributed.barrier()
        tokenizer = Tokenizer.from_file(str(out / TOKENIZER))
        model_config = (
            EvaluatorConfig(**state["config"]["model"])
            if state is not None
            else replace(
                PRESETS[recipe["preset"]](tokenizer.get_vocab_size(), folder.feature_dim),
                max_frames=MAX_FRAMES,
            )
        )
        config = dict(
            model=asdict(model_config),
            recipe=recipe,
            tokenizer=TOKENIZER,
            data=str(folder.root.resolve()),
            world_size=process.world_size,
            mean=folder.mean.tolist(),
            std=folder.std.tolist(),
        )
        model = train_loop(
            EvaluatorTrainer(config, tokenizer, train_set, val_set, options.val_spans, process),
            Run(out, options, recipe, config, state, process),
        )
        if process.is_main:
            _export_best(model, tokenizer, folder, out, config)
        finish_together(process)
    finally:
        end_process(process)


def _export_best(model, tokenizer: Tokenizer, folder: HumanML3DFolder, out: Path, config) -> None:
    """The run's best.pt as the evaluator `mogo bench eval` reads, in RUN/evaluator."""
    best = load_checkpoint(out / "best.pt")
    model.load_state_dict(best["model"])
    export_evaluator(
        model.eval(),
        tokenizer,
        folder.mean,
        folder.std,
        out / "evaluator",
        training=dict(
            step=best["step"], data=config["data"], recipe=config["recipe"], val=best["val"]
        ),
    )
    print(f"wrote {out / 'evaluator'} (best.pt of step {best['step']})", flush=True)


class EvaluatorTrainer(Trainer):
    """The evaluator in the training loop: caption spans and their motion, the contrastive loss
    and in-batch retrieval accuracy, R-precision on the val spans."""

    best_name, metric, higher_is_better, worst = "best_r1", "r1", True, -1.0

    def __init__(
        self,
        config: dict,
        tokenizer: Tokenizer,
        train_set: TextMotionDataset,
        val_set: TextMotionDataset,
        val_spans: int,
        process: Process,
    ):
        self.config, self.recipe, self.tokenizer = config, config["recipe"], tokenizer
        self.train_set, self.val_set, self.val_spans = train_set, val_set, val_spans
        self.process = process

    def build(self) -> Evaluator:
        return Evaluator(EvaluatorConfig(**self.config["model"]))

    def optimizer(self, model: nn.Module) -> torch.optim.Optimizer:
        return make_optimizer(model, self.recipe["lr"])

    def data(self) -> tuple[Dataset, int, Callable | None]:
        return self.train_set, self.recipe["batch_size"], collate_text_motion

    def banner(self, model: nn.Module, per_epoch: int) -> str:
        return (
            f"evaluator: {sum(p.numel() for p in model.parameters()) / 1e6:.2f}M "
            f"parameters; {len(self.train_set)} train / {len(self.val_set)} val spans, "
            f"{per_epoch} steps an epoch"
        )

    def step(self, model: nn.Module, batch: dict) -> tuple[Tensor, dict[str, Tensor]]:
        device = self.process.device
        ids, mask = encode_captions(self.tokenizer, batch["captions"])
        loss, accuracy = model(
            ids.to(device), mask.to(device), batch["motion"].to(device), batch["lengths"].to(device)
        )
        return loss, dict(loss=loss.detach(), batch_acc=accuracy)

    def train_line(self, values: dict[str, float]) -> str:
        return f"loss {values['loss']:.4f}  in-batch top-1 {values['batch_acc']:.3f}"

    def train_extras(self, model: nn.Module) -> dict:
        return dict(temperature=1 / model.log_scale.exp())

    def validate(self, model: nn.Module) -> dict[str, float]:
        return validate(model, self.val_set, self.tokenizer, self.val_spans, self.process.device)

    def val_line(self, values: dict[str, float]) -> str:
        return (
            f"R-precision top-1/2/3 {values['r1']:.3f} / {values['r2']:.3f} / "
            f"{values['r3']:.3f}  matching {values['matching']:.3f}"
        )

    def checkpoint_extras(self, values: dict[str, float] | None) -> dict:
        return {} if values is None else dict(val=values)


@torch.no_grad()
def embed_spans(
    model: Evaluator,
    dataset: TextMotionDataset,
    tokenizer: Tokenizer,
    indices: list[int],
    device: torch.device,
    batch_size: int = 64,
) -> tuple[np.ndarray, np.ndarray]:
    """(text, motion) embeddings of the dataset items `indices` (their epoch-0 windows)."""
    texts, motions = [], []
    for first in range(0, len(indices), batch_size):
        batch = collate_text_motion([dataset[i] for i in indices[first : first + batch_size]])
        ids, mask = encode_captions(tokenizer, batch["captions"])
        texts.append(model.embed_text(ids.to(device), mask.to(device)).cpu().numpy())
        motions.append(
            model.embed_motion(batch["motion"].to(device), batch["lengths"].to(device))
            .cpu()
            .numpy()
        )
    return np.concatenate(texts), np.concatenate(motions)


def validate(
    model: Evaluator,
    dataset: TextMotionDataset,
    tokenizer: Tokenizer,
    spans: int,
    device: torch.device,
) -> dict[str, float]:
    """R-precision top-1/2/3 (batches of 32, the protocol's, or all the spans when fewer; 20
    shuffles) and the matching distance on a fixed sample of `spans` validation spans (0: all),
    in eval mode."""
    model.eval()
    rng = np.random.default_rng(0)
    indices = sorted(rng.permutation(len(dataset))[: spans or len(dataset)].tolist())
    text, motion = embed_spans(model, dataset, tokenizer, indices, device)
    model.train()
    batch = min(R_PRECISION_BATCH, len(indices))
    precision = np.mean([r_precision(text, motion, rng, batch) for _ in range(20)], axis=0)
    return dict(
        r1=float(precision[0]),
        r2=float(precision[1]),
        r3=float(precision[2]),
        matching=matching_score(text, motion),
    )
