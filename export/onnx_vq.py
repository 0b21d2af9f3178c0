"""ONNX export of the MoSA-VQ encoder and decoder (mogo.export.vq) for the runtime:

    encoder  features (batch, frames, D) f32, normalised  ->  ids (batch, tokens, L) i64
    decoder  ids (batch, tokens, L) i64  ->  features (batch, tokens * down_factor, D) f32

Batch, frames and tokens are dynamic. tokens = ceil(frames / down_factor): a clip whose length
is not a multiple of down_factor is padded by repeating its last frame (the pose held) to whole
tokens, in the graph and in torch alike (`EncodeIds`; MoSAVQ.encode itself wants whole tokens),
and decodes to tokens * down_factor frames, which a caller cuts back to its length.

Exporter: torch.export (dynamo) at opset 20 through `export_module`, as for the transformer
(mogo.export.onnx_t2m, design/onnx-notes.md), so that one exporter writes the whole bundle; the
legacy TorchScript exporter is deprecated. The nearest-code search exports as MatMul + ArgMin,
whose ties go to the first index as torch.argmin's do, and the code lookups as Gather, all plain
ops: onnxruntime gives the same ids as torch (tests/test_onnx_vq.py). The examples are 2 or more
long on every dynamic axis, since the exporter silently fixes an axis traced with size 0 or 1.

The decoder's entry also carries its receptive field in tokens (`decoder_context`), which the
streaming decoder (mogo.runtime.stream_decoder) needs to know when a frame is final.
"""
from __future__ import annotations

import os

import torch
from torch import Tensor, nn
from torch.export import Dim

from mogo.export.onnx_t2m import export_module
from mogo.export.vq import MoSAVQ, decoder_receptive_field


class EncodeIds(nn.Module):
    """`MoSAVQ.encode` for any number of frames: padded to whole tokens with the last frame."""

    def __init__(self, model: MoSAVQ):
        super().__init__()
        self.model = model

    def forward(self, features: Tensor) -> Tensor:
        down = self.model.config.down_factor
        if down > 1:
            frames = features.shape[1]
            padded = (frames + down - 1) // down * down
            features = features[:, torch.arange(padded).clamp(max=frames - 1)]
        return self.model.encode(features)


class DecodeIds(nn.Module):
    """`MoSAVQ.decode` as a module, for export."""

    def __init__(self, model: MoSAVQ):
        super().__init__()
        self.model = model

    def forward(self, ids: Tensor) -> Tensor:
        return self.model.decode(ids)


def decoder_context(model: MoSAVQ) -> dict:
    """The decoder's receptive field in tokens: the frames of token t depend on tokens
    t - left_context .. t + lookahead (what the streaming decoder is built with)."""
    left_context, lookahead = decoder_receptive_field(model.config)
    return dict(left_context=left_context, lookahead=lookahead)


def export_vq_encoder(model: MoSAVQ, path: str | os.PathLike) -> dict:
    """Write the encoder graph to `path`. Returns its input and output names and the sizes."""
    c = model.config
    features = torch.zeros(2, 3 * c.down_factor + 1, c.feature_dim)  # not whole tokens
    names = dict(inputs=["features"], outputs=["ids"])
    export_module(EncodeIds(model), (features,), path, names,
                  ({0: Dim("batch"), 1: Dim("frames")},))
    return dict(names, **_sizes(model))


def export_vq_decoder(model: MoSAVQ, path: str | os.PathLike) -> dict:
    """Write the decoder graph to `path`. Returns its input and output names, the sizes and
    the receptive field (`decoder_context`)."""
    ids = torch.zeros(2, 3, model.config.levels, dtype=torch.long)
    names = dict(inputs=["ids"], outputs=["features"])
    export_module(DecodeIds(model), (ids,), path, names, ({0: Dim("batch"), 1: Dim("tokens")},))
    return dict(names, **_sizes(model), **decoder_context(model))


def _sizes(model: MoSAVQ) -> dict:
    c = model.config
    return dict(levels=c.levels, codebook_size=c.codebook_size, down_factor=c.down_factor,
                feature_dim=c.feature_dim)
