"""The VQ decoder one token at a time, for low-latency streams: a graph that keeps each
convolution's past inputs as state, so a step costs one column of every layer, not a window.

    ids (B, 1, L) i64, position (B,) i64, state (B, S) f32
        ->  features (B, 1, D) f32: the frame of token position - lookahead; state (B, S) f32

A window decode of the low-latency decoder (mogo.stream_decoder) re-runs every layer over 63
tokens for each new frame. Here each convolution reads its last (kernel - 1) * dilation input
columns from the state and the new column from the layer below, and writes the columns it
will need next back. A layer with right context r answers r columns late, so the frame that
comes out belongs to token position - lookahead, and each residual block's skip path waits as
long as its convolution (its own columns in the state). The offline decode pads every layer's
input with zeros before the first frame: columns of negative position are zeroed before they
enter a layer's state, which gives the same frames. The state is one flat float vector per
stream, so a server steps many streams in one call by stacking them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor, nn
from torch.export import Dim

from mogo.export.models.vq import Conv, MoSAVQ, ResBlock
from mogo.export.onnx.t2m_graphs import export_module
from mogo.manifest import StepDecoderGraph


@dataclass(frozen=True)
class _Slot:
    """Where one buffer lives in the flat state: (channels, columns) at `start`."""

    start: int
    channels: int
    columns: int

    @property
    def size(self) -> int:
        return self.channels * self.columns


class DecodeStep(nn.Module):
    """`MoSAVQ.decode` one token at a time, its convolutions' context carried in a state."""

    def __init__(self, model: MoSAVQ):
        super().__init__()
        if model.config.down_factor != 1:
            raise ValueError("a step decoder needs one token per frame (down_factor 1)")
        self.model = model
        self.layers = list(model.decoder.net)
        self.slots: dict[int, _Slot] = {}  # id(module) -> its buffer (a skip: id of the block)
        size = 0
        for module in model.decoder.net.modules():
            if isinstance(module, Conv):
                slot = _Slot(size, module.conv.in_channels, module.left + module.right)
            elif isinstance(module, ResBlock):
                conv = next(m for m in module.net if isinstance(m, Conv))
                slot = _Slot(size, conv.conv.in_channels, conv.right)
            else:
                continue
            self.slots[id(module)] = slot
            size += slot.size
        self.state_size = size
        self.lookahead = sum(m.right for m in model.decoder.net.modules() if isinstance(m, Conv))

    def forward(self, ids: Tensor, position: Tensor, state: Tensor) -> tuple[Tensor, Tensor]:
        x = self.model.quantizer.dequantize(ids).transpose(1, 2)  # (B, C, 1)
        out: dict[int, Tensor] = {}
        x, _ = self._run(self.layers, x, (position[:, None, None], 0), state, out)
        return x.transpose(1, 2), torch.cat([out[k] for k in self.slots if k in out], dim=1)

    def _run(self, layers, x: Tensor, at: tuple[Tensor, int], state: Tensor, out: dict):
        """x (B, C, 1), the column of token position - delay at this depth, `at` = (position
        (B, 1, 1), delay): each convolution's right context adds to the delay; each buffer's
        next contents go to `out`."""
        for layer in layers:
            if isinstance(layer, Conv):
                x, at = self._conv(layer, x, at, state, out)
            elif isinstance(layer, ResBlock):
                skip = self._delayed(x, id(layer), state, out)
                inner, at = self._run(layer.net, x, at, state, out)
                x = skip + inner
            elif isinstance(layer, nn.Sequential):
                x, at = self._run(layer, x, at, state, out)
            elif isinstance(layer, (nn.ReLU, nn.Dropout)):
                x = layer(x)
            else:
                raise TypeError(f"no step rule for {type(layer).__name__}")
        return x, at

    def _conv(self, conv: Conv, x: Tensor, at: tuple[Tensor, int], state: Tensor, out: dict):
        position, delay = at
        if delay and self.slots[id(conv)].columns:  # columns before the first frame: the
            x = x * (position >= delay).to(x.dtype)  # zero padding of the offline decode
        return conv.conv(self._window(x, id(conv), state, out)), (position, delay + conv.right)

    def _delayed(self, x: Tensor, key: int, state: Tensor, out: dict[int, Tensor]) -> Tensor:
        """x as it was some steps ago (a skip path waiting as long as its convolution)."""
        return self._window(x, key, state, out)[:, :, :1]

    def _window(self, x: Tensor, key: int, state: Tensor, out: dict[int, Tensor]) -> Tensor:
        """The buffer of `key` with the new column x (B, C, 1) after it: (B, C, columns + 1);
        its last `columns` columns are the buffer's next contents."""
        slot = self.slots[key]
        if not slot.columns:
            return x
        past = state[:, slot.start : slot.start + slot.size].reshape(
            -1, slot.channels, slot.columns
        )
        window = torch.cat([past, x], dim=2)
        out[key] = window[:, :, 1:].reshape(-1, slot.size)
        return window


def export_vq_step_decoder(model: MoSAVQ, path: str | os.PathLike) -> StepDecoderGraph:
    """Write the step decoder graph of `model`'s decoder to `path`; its manifest entry."""
    step = DecodeStep(model)
    batch = 2
    examples = (
        torch.zeros(batch, 1, model.config.levels, dtype=torch.long),
        torch.arange(batch, dtype=torch.long),
        torch.zeros(batch, step.state_size),
    )
    names = dict(inputs=["ids", "position", "state"], outputs=["features", "next_state"])
    b = Dim("batch")
    export_module(step, examples, path, names, ({0: b}, {0: b}, {0: b}))
    return StepDecoderGraph(
        Path(path).name,
        tuple(names["inputs"]),
        tuple(names["outputs"]),
        step.lookahead,
        step.state_size,
    )
