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

`VQTrainer` plugs into the training loop (mogo.export.train.loop, which makes resuming exact).
Under torchrun, DDP keeps the weights in step; the EMA codebooks are buffers, which DDP
broadcasts from rank 0 before every forward, so rank 0's codebook updates are the ones that
stand.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import asdict, replace
from pathlib import Path

import torch
from torch import Tensor, nn
from torch.utils.data import Dataset

from mogo.export.models.runs import read_vq_checkpoint, tokens_sha256, vq_checkpoint
from mogo.export.models.vq import MoSAVQ, VQConfig, decoder_receptive_field, reconstruction_metrics
from mogo.export.train.datasets import (
    HumanML3DFolder,
    MotionCropDataset,
    WholeClipBatches,
    whole_clip_features,
)
from mogo.export.train.loop import Run, Trainer, train_loop
from mogo.export.train.options import VQTrainOptions
from mogo.export.train.training import (
    Process,
    WeightAverage,
    end_process,
    equal_length_groups,
    finish_together,
    merge_recipe,
    previous_run,
    start_process,
)

PRESETS: dict[str, Callable[[], VQConfig]] = dict(
    tiny=VQConfig.tiny, cpu_default=VQConfig.cpu_default, paper=VQConfig.paper
)
# the recipe settings that change the model (None: the preset's value), for ablations
VQ_MODEL_SWITCHES = (
    "levels",
    "down_factor",
    "causal",
    "decoder_lookahead",
    "scale_bias",
    "decorrelation",
)
DECODER_SWITCHES = ("decoder_lookahead",)  # a decoder fine-tune may change these


def train_vq(options: VQTrainOptions) -> None:
    """Train (or resume) a VQ run; under torchrun every process calls this, rank 0 writes."""
    options.check_intervals()
    if options.val_clips <= 0:
        raise ValueError(f"--val-clips must be positive, got {options.val_clips}")
    out = Path(options.out)
    if options.init is not None and options.resume:
        raise ValueError(
            "--init starts a new run from trained weights; --resume continues a "
            "run: pass one of them"
        )
    state = previous_run(out, options.resume)
    given = {n: v for n, v in options.given().items() if n != "init"}
    init = None
    if options.init is not None:
        init, init_path = read_init(options.init)
        given = _recipe_of_init(given, init, init_path)
    recipe = merge_recipe(VQTrainOptions.recipe_defaults(), given, state)
    if recipe["preset"] not in PRESETS:
        raise ValueError(f"unknown config {recipe['preset']!r}; use {', '.join(PRESETS)}")
    if (
        recipe["batch_size"] <= 0
        or recipe["lr"] <= 0
        or recipe["warmup"] < 0
        or recipe["crop_frames"] < 1
    ):
        raise ValueError(
            f"need batch size > 0, lr > 0, warmup >= 0, crop frames >= 1, got "
            f"{recipe['batch_size']}, {recipe['lr']}, {recipe['warmup']}, "
            f"{recipe['crop_frames']}"
        )
    folder = HumanML3DFolder(options.data)
    config = (
        VQConfig(**state["config"])
        if state is not None
        else _config_of_init(init, recipe)
        if init is not None
        else vq_config(recipe, folder.feature_dim)
    )
    _check_fit(config, recipe, init, options, folder)
    process = start_process(options.device)
    try:
        if state is None and init is not None:
            state = _fine_tuning_state(init, folder)
        train_loop(
            VQTrainer(folder, config, recipe, options.val_clips, process),
            Run(out, options, recipe, asdict(config), state, process),
        )
        finish_together(process)
    finally:
        end_process(process)


def _check_fit(config: VQConfig, recipe: dict, init, options, folder: HumanML3DFolder) -> None:
    """A ValueError where the model, the data, --tune, --init and the crops do not fit."""
    if config.feature_dim != folder.feature_dim:
        raise ValueError(
            f"{options.init}: a VQ of {config.feature_dim} features; "
            f"{folder.root} has {folder.feature_dim}"
        )
    if recipe["tune"] not in ("all", "decoder"):
        raise ValueError(f"--tune must be all or decoder, got {recipe['tune']!r}")
    if recipe["tune"] == "decoder" and recipe["init"] is None:
        raise ValueError("--tune decoder fine-tunes a trained VQ: pass --init RUN")
    if init is not None and not init["ema"] and recipe["tune"] != "decoder":
        raise ValueError(
            f"--init {options.init}: a bundle keeps no codebook statistics to go "
            "on training from; pass --tune decoder"
        )
    if recipe["crop_frames"] % config.down_factor:
        raise ValueError(
            f"--crop-frames {recipe['crop_frames']} is not a multiple of the "
            f"down factor {config.down_factor}"
        )


def read_init(path: Path) -> tuple[dict, Path]:
    """What `--init` starts from, with its path: a VQ run's checkpoint, or a bundle's VQ read
    back from its graphs (`vq_from_bundle`). A bundle's tokens are named by the
    tokens_sha256 its VQ was trained with, else by its encoder graph's sha256; "ema" is False
    for a bundle, which holds no EMA codebook statistics."""
    from mogo.bundle import MANIFEST, read_manifest

    path = Path(path)
    if not (path / MANIFEST).is_file():
        checkpoint = vq_checkpoint(path)
        return {**read_vq_checkpoint(checkpoint), "ema": True}, checkpoint
    from mogo.export.onnx.vq_graphs import vq_from_bundle

    model = vq_from_bundle(path)
    manifest = read_manifest(path)
    trained = manifest.training.get("vq")
    recipe = (trained.recipe if trained else None) or {}  # the trainer's own record
    tokens = recipe.get("tokens_sha256") or manifest.files[manifest.vq.encoder.file].sha256
    return dict(
        config=asdict(model.config),
        model=model.state_dict(),
        ema=False,
        recipe=dict(preset=recipe.get("preset", "cpu_default"), tokens_sha256=tokens),
    ), path


def _recipe_of_init(given: dict, init: dict, path: Path) -> dict:
    """A fine-tuning run keeps the model of the run it starts from: its preset and switches
    (a given switch that differs is refused); the training settings are the new run's."""
    kept = [
        n
        for n in VQ_MODEL_SWITCHES
        if not (given["tune"] == "decoder" and n in DECODER_SWITCHES and given[n] is not None)
    ]
    fixed = {
        "preset": init["recipe"]["preset"],
        **{name: getattr(VQConfig(**init["config"]), name) for name in kept},
    }
    for name, value in fixed.items():
        if given[name] is not None and given[name] != value:
            flag = "--config" if name == "preset" else f"--{name.replace('_', '-')}"
            raise ValueError(
                f"{flag} {given[name]} differs from {value} of --init {path}; a "
                "fine-tuning run keeps the model it starts from"
            )
    recipe = {**given, **fixed, "init": str(path.resolve())}
    if given["tune"] == "decoder":
        recipe["tokens_sha256"] = tokens_sha256(init, path)
    return recipe


def _config_of_init(init: dict, recipe: dict) -> VQConfig:
    """The --init model's config, with the decoder switches a decoder fine-tune gives."""
    changed = {
        n: recipe[n]
        for n in DECODER_SWITCHES
        if recipe["tune"] == "decoder" and recipe[n] is not None
    }
    return replace(VQConfig(**init["config"]), **changed)


def _fine_tuning_state(init: dict, folder: HumanML3DFolder) -> dict:
    """What _train takes from the --init checkpoint: its weights, at step 0, with the
    normalisation statistics of the data the new run trains and validates on. A narrower
    decoder lookahead keeps the kernels as they are (their taps then read the inputs they
    shifted past some frames late): measured on 64 val clips, 39 mm at the start for a
    lookahead of 8, against 146 mm with each tap moved back onto the input it read."""
    statistics = {
        name: torch.as_tensor(value, dtype=torch.float32)
        for name, value in (("mean", folder.mean), ("std", folder.std))
    }
    return dict(
        model={**init["model"], **statistics}, optimizer=None, step=0, best_val_mpjpe_mm=math.inf
    )


def vq_config(recipe: dict, feature_dim: int) -> VQConfig:
    """The preset with the recipe's model switches and the data's feature size."""
    switches = {name: recipe[name] for name in VQ_MODEL_SWITCHES if recipe[name] is not None}
    return replace(PRESETS[recipe["preset"]](), feature_dim=feature_dim, **switches)


class VQTrainer(Trainer):
    """The MoSA-VQ in the training loop: batches of crops (or of whole clips), the VQ's losses,
    MPJPE of whole val clips decoded, and with a weight average, that average measured and
    kept."""

    best_name, metric = "best_val_mpjpe_mm", "mpjpe_mm"

    def __init__(
        self,
        folder: HumanML3DFolder,
        config: VQConfig,
        recipe: dict,
        val_clips: int,
        process: Process,
    ):
        self.folder, self.config, self.recipe, self.process = folder, config, recipe, process
        self.val_limit = val_clips
        self.decoder_only = recipe.get("tune") == "decoder"
        self.average: WeightAverage | None = None
        self.extra = dict(
            recipe=recipe, data=str(folder.root.resolve()), world_size=process.world_size
        )

    def build(self) -> MoSAVQ:
        model = MoSAVQ(self.config, self.folder.mean, self.folder.std)
        if self.decoder_only:
            model.encoder.requires_grad_(False)
            model.quantizer.requires_grad_(False)
        return model

    def optimizer(self, model: nn.Module) -> torch.optim.Optimizer:
        return torch.optim.AdamW(
            [p for p in model.parameters() if p.requires_grad],
            lr=self.recipe["lr"],
            betas=(0.9, 0.99),
            weight_decay=0.0,
        )

    def restored(self, model: nn.Module, state: dict | None) -> None:
        if self.recipe["weight_average"]:
            self.average = WeightAverage(model, self.recipe["weight_average"])
            if state is not None and state.get("averaged_parameters"):
                self.average.parameters = state["averaged_parameters"]

    def data(self) -> tuple[Dataset, int, Callable | None]:
        recipe, down = self.recipe, self.config.down_factor
        if recipe["whole_clips"]:  # items are batches already
            self.train_set = WholeClipBatches(
                self.folder, "train", recipe["batch_size"], recipe["seed"], down
            )
            batch_size, collate = 1, only_item
        else:
            self.train_set = MotionCropDataset(
                self.folder, "train", recipe["crop_frames"], recipe["seed"]
            )
            batch_size, collate = recipe["batch_size"], None
        self.val_clips = whole_clips(self.folder, "val", down, self.val_limit)
        return self.train_set, batch_size, collate

    def banner(self, model: nn.Module, per_epoch: int) -> str:
        config = self.config
        lookahead = (
            "causal"
            if config.causal
            else "centred"
            if config.decoder_lookahead is None
            else f"{decoder_receptive_field(config)[1]}-token lookahead"
        )
        if self.decoder_only:
            lookahead += " (fine-tuning the decoder alone)"
        return (
            f"vq: {sum(p.numel() for p in model.parameters()) / 1e6:.2f}M parameters, "
            f"{config.levels} levels of {config.codebook_size} codes, {lookahead} decoder; "
            f"{len(self.train_set.clips)} train clips, {len(self.val_clips)} val clips, "
            f"{per_epoch} steps an epoch"
        )

    def step(self, model: nn.Module, batch: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
        """Every loss term, then the mean perplexity and usage, and the codes re-drawn."""
        output = model(
            batch.to(self.process.device, non_blocking=True), decoder_only=self.decoder_only
        )
        stats = output.stats
        return output.losses["total"], dict(
            {name: value.detach() for name, value in output.losses.items()},
            perplexity=stats["perplexity"].mean(),
            usage=stats["usage"].mean(),
            dead_codes=stats["dead_codes"].sum(),
        )

    def stepped(self, model: nn.Module) -> None:
        if self.average is not None:
            self.average.update(model)

    def train_line(self, values: dict[str, float]) -> str:
        return (
            f"loss {values['total']:.4f}  recon {values['recon']:.4f}  joints "
            f"{values['joints']:.4f}  perplexity {values['perplexity']:.0f}"
        )

    def validate(self, model: nn.Module) -> dict[str, float] | None:
        """Rank 0 alone decodes the val clips."""
        if not self.process.is_main:
            return None
        return reconstruction_metrics(
            self.kept(model), clip_batches(self.val_clips, self.process.device)
        )

    def val_line(self, values: dict[str, float]) -> str:
        return (
            f"MPJPE {values['mpjpe_mm']:.1f} mm  feature L1 {values['feature_l1']:.4f}  "
            f"by levels {' '.join(f'{v:.0f}' for v in values['mpjpe_mm_by_levels'])} mm"
            f"{'  (averaged weights)' if self.average else ''}"
        )

    def kept(self, model: nn.Module) -> nn.Module:
        return model if self.average is None else self.average.averaged(model)

    def checkpoint_extras(self, values: dict[str, float] | None) -> dict:
        if values is not None:
            return dict(self.extra)
        return dict(
            averaged_parameters=None if self.average is None else self.average.parameters,
            **self.extra,
        )


def only_item(items: list[Tensor]) -> Tensor:
    """The DataLoader collate of batches of one item that is a batch itself."""
    return items[0]


def whole_clips(
    folder: HumanML3DFolder, split: str, down_factor: int, limit: int | None = None
) -> list[Tensor]:
    """The first `limit` clips of a split, normalised, each (1, T, D) cut to whole tokens."""
    return [
        torch.from_numpy(clip.copy())[None]
        for clip in whole_clip_features(folder, split, down_factor, limit)
    ]


def clip_batches(
    clips: list[Tensor], device: torch.device, batch_size: int = 128
) -> Iterator[Tensor]:
    """Clips (1, T, D) stacked into batches of equal T, so a whole split decodes in a few
    hundred calls."""
    for group in equal_length_groups([clip.shape[1] for clip in clips], batch_size):
        yield torch.cat([clips[i] for i in group]).to(device)
