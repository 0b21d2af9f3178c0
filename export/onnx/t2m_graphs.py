"""ONNX export of the RQHC-Transformer (one graph per level) and of the text encoder.

A level graph is `T2M.level_forward` with its cache spelled out as one input and one output per
layer and tensor, the names onnxruntime-genai and HF Optimum use:

    inputs   prompt (batch, text_dim) f32, uncond (batch,) bool, token_ids (batch, seq, L) i64,
             positions (seq,) i64, past_positions (past,) i64,
             past_key_values.{i}.key, past_key_values.{i}.value   (batch, heads, past, head_dim)
    outputs  logits (batch, K[+1]),  present.{i}.key, present.{i}.value  (batch, heads, past+seq, ..)

in that order: the runtime feeds the names it is given by role, the first five inputs as listed,
then the cache pairs layer by layer; present.{i}.key is fed back as past_key_values.{i}.key.
Batch, seq and past are dynamic, so one graph serves prefill, decode, guidance (batch 2) and an
empty cache (past 0). The exporter is torch.export (dynamo) at opset 20; it fixes an axis whose
example size is 0 or 1, so the examples (zeros: a trace keeps shapes, not values) are 2 or
more long on every axis.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import Tensor, nn
from torch.export import Dim

from mogo.export.models.t2m import T2M
from mogo.export.models.text_encoder import TextEncoder
from mogo.manifest import Graph
from mogo.token_generator import LEVEL_INPUTS

OPSET = 20


def cache_names(num_layers: int) -> tuple[list[str], list[str]]:
    """The past (input) and present (output) cache names, key then value, layer by layer."""
    past = [f"past_key_values.{i}.{t}" for i in range(num_layers) for t in ("key", "value")]
    return past, [name.replace("past_key_values", "present") for name in past]


class LevelStep(nn.Module):
    """`level_forward` of one level with the cache as flat varargs (key, value, key, ...)."""

    def __init__(self, model: T2M, level: int):
        super().__init__()
        self.model, self.level = model, level

    def forward(
        self,
        prompt: Tensor,
        uncond: Tensor,
        token_ids: Tensor,
        positions: Tensor,
        past_positions: Tensor,
        *past: Tensor,
    ) -> tuple[Tensor, ...]:
        logits, presents = self.model.level_forward(
            self.level,
            prompt,
            uncond,
            token_ids,
            positions,
            past_positions,
            list(zip(past[0::2], past[1::2], strict=False)),
        )
        return logits, *[t for pair in presents for t in pair]


class EncodeText(nn.Module):
    """The `TextEncoder` seam as a module, for export."""

    def __init__(self, encoder: TextEncoder):
        super().__init__()
        self.encoder = encoder

    def forward(self, token_ids: Tensor, attention_mask: Tensor) -> Tensor:
        return self.encoder.encode(token_ids, attention_mask)


def export_level(model: T2M, level: int, path: str | os.PathLike) -> Graph:
    """Write the graph of `level` to `path` (one self-contained file). Returns its manifest
    entry: input and output names in protocol order (the cache sizes are in the input shapes)."""
    config = model.config
    layers, heads, head_dim = config.layers[level], config.heads[level], config.head_dim
    batch, seq, past = 2, 3, 4  # >= 2 and distinct, so that no axis is fixed or merged
    examples = (
        torch.zeros(batch, config.text_dim),
        torch.tensor([False, True]),
        torch.zeros(batch, seq, config.num_levels, dtype=torch.long),
        torch.arange(past, past + seq),
        torch.arange(past),
        *[torch.zeros(batch, heads, past, head_dim) for _ in range(2 * layers)],
    )
    b, s, p = Dim("batch"), Dim("seq"), Dim("past")
    dynamic_shapes = (
        {0: b},
        {0: b},
        {0: b, 1: s},
        {0: s},
        {0: p},
        tuple({0: b, 2: p} for _ in range(2 * layers)),
    )
    past_names, present_names = cache_names(layers)
    names = dict(inputs=LEVEL_INPUTS + past_names, outputs=["logits"] + present_names)
    export_module(LevelStep(model, level), examples, path, names, dynamic_shapes)
    return _graph(path, names)


def export_text_encoder(encoder: TextEncoder, path: str | os.PathLike, max_length: int) -> Graph:
    """Write the text encoder, token_ids and attention_mask (batch, seq <= max_length) int64 ->
    prompt_embedding (batch, output_dim), to `path`. Returns its manifest entry."""
    if max_length < 2:
        raise ValueError(f"max_length must be >= 2 to export a dynamic length, got {max_length}")
    token_ids = torch.zeros(2, max_length, dtype=torch.long)
    attention_mask = torch.ones(2, max_length, dtype=torch.long)
    b, s = Dim("batch"), Dim("seq", max=max_length)
    names = dict(inputs=["token_ids", "attention_mask"], outputs=["prompt_embedding"])
    export_module(
        EncodeText(encoder), (token_ids, attention_mask), path, names, ({0: b, 1: s}, {0: b, 1: s})
    )
    return _graph(path, names)


def _graph(path: str | os.PathLike, names: dict) -> Graph:
    return Graph(Path(path).name, tuple(names["inputs"]), tuple(names["outputs"]))


def export_module(
    module: nn.Module, examples: tuple, path: str | os.PathLike, names: dict, dynamic_shapes: tuple
) -> None:
    """Export `module` to one self-contained file at OPSET with the given input and output
    names, in eval mode (no dropout, no prompt dropout), leaving the caller's modules in the
    mode they were in."""
    modes = [(m, m.training) for m in module.modules()]
    try:
        torch.onnx.export(
            module.eval(),
            examples,
            os.fspath(path),
            dynamo=True,
            opset_version=OPSET,
            input_names=names["inputs"],
            output_names=names["outputs"],
            dynamic_shapes=dynamic_shapes,
            external_data=False,
            verbose=False,
        )
    finally:
        for m, training in modes:
            m.training = training
