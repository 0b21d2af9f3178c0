"""ONNX export of the MoSA-VQ encoder and decoder (mogo.export.models.vq) for the runtime:

    encoder  features (batch, frames, D) f32, normalised  ->  ids (batch, tokens, L) i64
    decoder  ids (batch, tokens, L) i64  ->  features (batch, tokens * down_factor, D) f32

Batch, frames and tokens are dynamic. tokens = ceil(frames / down_factor): a clip whose length
is not a multiple of down_factor is padded by repeating its last frame (the pose held) to whole
tokens, in the graph and in torch alike (`EncodeIds`; MoSAVQ.encode itself wants whole tokens),
and decodes to tokens * down_factor frames, which a caller cuts back to its length.

Exporter: torch.export (dynamo) at opset 20 through `export_module`, as for the transformer
(mogo.export.onnx.t2m_graphs), so that one exporter writes the whole bundle; the
legacy TorchScript exporter is deprecated. The nearest-code search exports as MatMul + ArgMin,
whose ties go to the first index as torch.argmin's do, and the code lookups as Gather, all plain
ops: onnxruntime gives the same ids as torch (tests/test_onnx_vq.py). The examples are 2 or more
long on every dynamic axis, since the exporter silently fixes an axis traced with size 0 or 1.

The decoder's entry also carries its receptive field in tokens (`export_vq_decoder`), which the
streaming decoder (mogo.stream_decoder) needs to know when a frame is final.

`vq_from_bundle` goes the other way: a bundle's two graphs back into a MoSAVQ, so that a
shipped model can be fine-tuned when its training checkpoints are gone (`mogo train vq --init
BUNDLE --tune decoder`). The weights keep their torch names in the graphs (with `_fp16` where
the bundle stores them in fp16, read back as the fp32 values the graphs compute with); the
codebooks and the per-level scale and bias are folded into constants, found by the structure
of the decoder's dequantisation. The model is checked against the graphs before it is
returned.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper
from torch import Tensor, nn
from torch.export import Dim

from mogo._session import cpu_session
from mogo.bundle import Bundle
from mogo.export.models.vq import MoSAVQ, VQConfig, decoder_receptive_field
from mogo.export.onnx.t2m_graphs import export_module
from mogo.manifest import DecoderGraph, Graph
from mogo.serve.onnx_graph import consumer_map, producer_map

IMPORT_MAX_DIFFERENCE = 1e-4  # decoded features, torch against the bundle's decoder graph
MIN_TOKEN_AGREEMENT = 0.99  # ids, torch against the bundle's encoder graph


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


def export_vq_encoder(model: MoSAVQ, path: str | os.PathLike) -> Graph:
    """Write the encoder graph to `path`. Returns its manifest entry."""
    c = model.config
    features = torch.zeros(2, 3 * c.down_factor + 1, c.feature_dim)  # not whole tokens
    names = dict(inputs=["features"], outputs=["ids"])
    export_module(
        EncodeIds(model), (features,), path, names, ({0: Dim("batch"), 1: Dim("frames")},)
    )
    return Graph(Path(path).name, ("features",), ("ids",))


def export_vq_decoder(model: MoSAVQ, path: str | os.PathLike) -> DecoderGraph:
    """Write the decoder graph to `path`. Returns its manifest entry, with the receptive field
    in tokens: the frames of token t depend on tokens t - left_context .. t + lookahead (what
    the streaming decoder is built with)."""
    ids = torch.zeros(2, 3, model.config.levels, dtype=torch.long)
    names = dict(inputs=["ids"], outputs=["features"])
    export_module(DecodeIds(model), (ids,), path, names, ({0: Dim("batch"), 1: Dim("tokens")},))
    left_context, lookahead = decoder_receptive_field(model.config)
    return DecoderGraph(Path(path).name, ("ids",), ("features",), left_context, lookahead)


def vq_from_bundle(root: str | os.PathLike) -> MoSAVQ:
    """The MoSA-VQ of a bundle (verified against its manifest) as a torch model in eval mode,
    with the bundle's normalisation statistics; no EMA codebook statistics (a bundle holds
    none), so it suits decoder fine-tuning, not training the codebooks on. Raises ValueError
    when the graphs cannot be read back into the model exactly."""
    bundle = Bundle.load(root)
    vq = bundle.manifest.vq
    model = MoSAVQ(VQConfig(**vq.config), bundle.mean, bundle.std)
    state = model.state_dict()
    graphs = {
        part: onnx.load(bundle.path(graph.file)).graph
        for part, graph in (("encoder", vq.encoder), ("decoder", vq.decoder))
    }
    weights = {}
    for graph in graphs.values():
        for tensor in graph.initializer:
            name = tensor.name.removesuffix("_fp16").removeprefix("model.")
            if name in state:
                weights[name] = torch.from_numpy(numpy_helper.to_array(tensor).astype(np.float32))
    missing = [
        name for name in state if name.startswith(("encoder.", "decoder.")) and name not in weights
    ]
    if missing:
        raise ValueError(
            f"{bundle.root}: its VQ graphs lack {', '.join(missing[:3])}"
            f"{' ...' if len(missing) > 3 else ''} (not a mogo export?)"
        )
    quantizer = _dequantisation(graphs["decoder"])
    codebook = quantizer["codebook"].reshape(state["quantizer.codebook"].shape)
    weights["quantizer.codebook"] = codebook
    weights["quantizer.scale"], weights["quantizer.bias"] = quantizer["scale"], quantizer["bias"]
    weights["quantizer.ema_sum"] = codebook.clone()
    weights["quantizer.ema_count"] = torch.ones(codebook.shape[:2])
    weights["quantizer.initialized"] = torch.ones(len(codebook), dtype=torch.bool)
    model.load_state_dict({**state, **weights})
    _check_against_graphs(model.eval(), bundle)
    return model


def _dequantisation(graph: onnx.GraphProto) -> dict[str, Tensor]:
    """The codebooks, W and b of the decoder's dequantisation, (codebook[ids] - b) / W, found
    by structure: the Gather whose output a Sub takes (its subtrahend is b), whose output a Div
    takes (its divisor is W). The exporter folds small constants under other names (the
    codebooks of a small model become one (L*K, C) table), so names cannot be relied on."""
    constants = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
    producers = producer_map(graph)
    consumers = consumer_map(graph)

    def value(name: str) -> np.ndarray:  # a constant, through the Casts and Reshapes on it
        if name in constants:
            return constants[name]
        node = producers.get(name)
        if node is not None and node.op_type == "Cast":
            return value(node.input[0]).astype(np.float32)
        if node is not None and node.op_type == "Reshape":
            return value(node.input[0]).reshape(value(node.input[1]))
        raise KeyError(name)

    for gather in (n for n in graph.node if n.op_type == "Gather"):
        sub = [n for n in consumers.get(gather.output[0], []) if n.op_type == "Sub"]
        div = [n for n in consumers.get(sub[0].output[0], []) if n.op_type == "Div"] if sub else []
        try:
            found = (
                dict(
                    codebook=value(gather.input[0]),
                    bias=value(sub[0].input[1]),
                    scale=value(div[0].input[1]),
                )
                if div
                else None
            )
        except KeyError:
            found = None
        if found is not None:
            return {
                name: torch.from_numpy(array.astype(np.float32)) for name, array in found.items()
            }
    raise ValueError("the VQ decoder graph has no dequantisation (codebook[ids] - b) / W")


def random_ids(config: VQConfig, batch: int, tokens: int, seed: int) -> Tensor:
    """Seeded random token ids (batch, tokens, L): what the checks of exported VQ graphs feed."""
    generator = torch.Generator().manual_seed(seed)
    return torch.randint(config.codebook_size, (batch, tokens, config.levels), generator=generator)


@torch.no_grad()
def token_agreement(model: MoSAVQ, bundle: Bundle) -> float:
    """The share of ids that the model's encoder and the bundle's encoder graph agree on, for
    features decoded (by the model) from random ids: whether the bundle's level graphs, trained
    on its tokens, fit the model's decoder."""
    features = model.eval().decode(random_ids(model.config, 2, 48, seed=0))
    graph = bundle.manifest.vq.encoder
    graph_ids = cpu_session(bundle.path(graph.file)).run(None, {graph.inputs[0]: features.numpy()})[
        0
    ]
    return float(np.mean(model.encode(features).numpy() == graph_ids))


@torch.no_grad()
def _check_against_graphs(model: MoSAVQ, bundle: Bundle) -> None:
    """Random ids decoded, and what they decode to encoded, in torch and in the bundle's
    graphs."""
    graph = bundle.manifest.vq.decoder
    ids = random_ids(model.config, 2, 48, seed=1)
    graph_features = cpu_session(bundle.path(graph.file)).run(None, {graph.inputs[0]: ids.numpy()})[
        0
    ]
    difference = float(np.abs(model.decode(ids).numpy() - graph_features).max())
    agreement = token_agreement(model, bundle)
    if difference > IMPORT_MAX_DIFFERENCE or agreement < MIN_TOKEN_AGREEMENT:
        raise ValueError(
            f"{bundle.root}: its VQ graphs do not read back into the model "
            f"(decoded features differ by {difference:.2g}, token agreement "
            f"{agreement:.1%})"
        )
