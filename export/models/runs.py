"""Trained runs read back into models: the checkpoint format (mogo.export.train.training writes
it), a `mogo train vq` run's VQ and a `mogo train t2m` run's T2M, text encoder, tokenizer and
token caches. What `mogo export`, the benchmarks and a fine-tuning run read."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
import torch
from tokenizers import Tokenizer
from torch import nn

from mogo.bundle import file_sha256
from mogo.export.models.t2m import T2M, T2MConfig, TextToMotion
from mogo.export.models.text_encoder import TEXT_ENCODERS
from mogo.export.models.vq import MoSAVQ, VQConfig

CHECKPOINT_FORMAT = 1


def load_checkpoint(path: Path) -> dict:
    """A checkpoint written by `save_checkpoint`, loaded without running any pickled code."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several types for truncated or foreign files
        raise ValueError(f"{path}: not a readable mogo checkpoint ({error})") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not a mogo checkpoint of format {CHECKPOINT_FORMAT}")
    return state


# -- VQ runs -----------------------------------------------------------------------------------


def vq_checkpoint(run_dir: str | Path) -> Path:
    """The VQ run's best.pt (lowest validation error) if it has one, else its checkpoint.pt."""
    run = Path(run_dir)
    if not run.is_dir():
        raise FileNotFoundError(f"{run}: no such VQ run folder")
    for name in ("best.pt", "checkpoint.pt"):
        if (run / name).is_file():
            return run / name
    raise FileNotFoundError(f"{run}: no best.pt or checkpoint.pt (is it a `mogo train vq` run?)")


def read_vq_checkpoint(path: Path) -> dict:
    state = load_checkpoint(path)
    if set(state.get("config", ())) != {f.name for f in fields(VQConfig)}:
        raise ValueError(f"{path}: not a `mogo train vq` checkpoint")
    return state


def load_vq(run_dir: str | Path) -> MoSAVQ:
    """The trained MoSA-VQ of a run, in eval mode (its own normalisation statistics inside)."""
    state = read_vq_checkpoint(vq_checkpoint(run_dir))
    model = MoSAVQ(VQConfig(**state["config"]))
    model.load_state_dict(state["model"])
    return model.eval()


def tokens_sha256(state: dict, path: Path) -> str:
    """The sha256 of the checkpoint whose tokens the VQ checkpoint at `path` gives: its own, or
    for a decoder fine-tune, that of the VQ it kept the encoder and codebooks of (so a T2M
    trained on those tokens fits it)."""
    return state.get("recipe", {}).get("tokens_sha256") or file_sha256(path)


# -- T2M runs ----------------------------------------------------------------------------------


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
    model = build_text_to_motion(config["text_encoder"], T2MConfig(**config["t2m"]))
    model.load_state_dict(state["model"])
    model.eval()
    return model.t2m, model.text_encoder, Tokenizer.from_file(str(run / config["tokenizer"]))


def build_text_to_motion(text_encoder: dict, t2m_config: T2MConfig) -> TextToMotion:
    """A new TextToMotion from a checkpoint's text_encoder entry (kind, config) and T2M config."""
    if text_encoder["kind"] not in TEXT_ENCODERS:
        raise ValueError(
            f"unknown text encoder {text_encoder['kind']!r}; known: {', '.join(TEXT_ENCODERS)}"
        )
    return TextToMotion(
        TEXT_ENCODERS[text_encoder["kind"]].build(text_encoder["config"]), T2M(t2m_config)
    )


def read_tokens(path: Path) -> dict[str, np.ndarray]:
    """A T2M run's token cache (RUN/tokens/SPLIT.npz) as plain arrays."""
    with np.load(path, allow_pickle=False) as arrays:
        return {name: arrays[name] for name in arrays.files}
