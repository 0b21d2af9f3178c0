"""The evaluator's ONNX export: the folder `mogo.bench.quality.evaluator` embeds with, without
torch. The graphs take token ids and mask, and normalised features and lengths; the folder also
holds the tokenizer and the mean/std the features are normalised with."""

from __future__ import annotations

import json
import os
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from tokenizers import Tokenizer
from torch import Tensor, nn

from mogo.export.models.evaluator import DOWN, Evaluator
from mogo.export.onnx.t2m_graphs import export_module

FORMAT = "mogo-evaluator"
FORMAT_VERSION = 1


class _Method(nn.Module):
    """One two-input method of the evaluator (embed_text, embed_motion) as a module, to export."""

    def __init__(self, model: Evaluator, name: str):
        super().__init__()
        self.model, self.name = model, name

    def forward(self, first: Tensor, second: Tensor) -> Tensor:
        return getattr(self.model, self.name)(first, second)


TEXT_GRAPH = dict(
    file="evaluator_text.onnx", inputs=["input_ids", "attention_mask"], outputs=["text_embedding"]
)
MOTION_GRAPH = dict(
    file="evaluator_motion.onnx", inputs=["features", "lengths"], outputs=["motion_embedding"]
)


def export_evaluator(
    model: Evaluator,
    tokenizer: Tokenizer,
    mean: np.ndarray,
    std: np.ndarray,
    out: str | Path,
    training: dict | None = None,
) -> dict:
    """Write an evaluator folder: both graphs, tokenizer.json, mean.npy / std.npy (what the
    motion graph's input is normalised with) and evaluator.json; -> the manifest."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    c = model.config
    batch, seq, frames = (
        torch.export.Dim("batch", min=1, max=1024),
        torch.export.Dim("seq", min=1, max=c.max_length),
        torch.export.Dim("frames", min=DOWN, max=c.max_frames),
    )
    ids = torch.ones(2, 5, dtype=torch.long)
    export_module(
        _Method(model, "embed_text"),
        (ids, torch.ones_like(ids)),
        out / TEXT_GRAPH["file"],
        TEXT_GRAPH,
        ({0: batch, 1: seq}, {0: batch, 1: seq}),
    )
    features, lengths = torch.zeros(2, 3 * DOWN, c.feature_dim), torch.tensor([3, 2]) * DOWN
    export_module(
        _Method(model, "embed_motion"),
        (features, lengths),
        out / MOTION_GRAPH["file"],
        MOTION_GRAPH,
        ({0: batch, 1: frames}, {0: batch}),
    )
    tokenizer.save(str(out / "tokenizer.json"))
    np.save(out / "mean.npy", np.asarray(mean, np.float32))
    np.save(out / "std.npy", np.asarray(std, np.float32))
    manifest = dict(
        format=FORMAT,
        format_version=FORMAT_VERSION,
        config=asdict(c),
        embed_dim=c.embed_dim,
        feature_dim=c.feature_dim,
        min_frames=DOWN,
        max_frames=c.max_frames,
        tokenizer="tokenizer.json",
        mean="mean.npy",
        std="std.npy",
        text=TEXT_GRAPH,
        motion=MOTION_GRAPH,
        distance="euclidean",
        training=training or {},
    )
    partial = out / "evaluator.json.partial"
    partial.write_text(json.dumps(manifest, indent=1))
    os.replace(partial, out / "evaluator.json")
    return manifest
