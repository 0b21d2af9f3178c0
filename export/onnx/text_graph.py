"""The bundle's text graph for a pretrained sentence encoder: MiniLM's int8 ONNX graph (as
published, unchanged), then masked mean pooling and the trained adapter, joined into one file
with the runtime's names:

    token_ids, attention_mask (batch, seq) int64
      -> prompt_embedding (batch, text_dim): what the level graphs read
      -> sentence_embedding (batch, 384): unit length, what the repertoire is compared in

MiniLM's third input (token_type_ids, all zeros for one sentence) is made inside the graph.
"""

from __future__ import annotations

import os
from pathlib import Path

import onnx
import torch
from torch import Tensor, nn
from torch.export import Dim

from mogo.export.models.sentence_encoder import Adapter, mean_pool
from mogo.export.onnx.t2m_graphs import export_module
from mogo.manifest import Graph

INPUTS = ("token_ids", "attention_mask")
OUTPUTS = ("prompt_embedding", "sentence_embedding")
_MINILM = dict(
    ids="input_ids", mask="attention_mask", types="token_type_ids", hidden="last_hidden_state"
)
_PREFIX = "head/"


class Head(nn.Module):
    """MiniLM's last hidden states -> (prompt embedding, sentence embedding)."""

    def __init__(self, adapter: Adapter):
        super().__init__()
        self.adapter = adapter

    def forward(self, hidden: Tensor, attention_mask: Tensor) -> tuple[Tensor, Tensor]:
        sentence = mean_pool(hidden, attention_mask)
        return self.adapter(sentence), sentence


def export_sentence_text_graph(minilm: Path, adapter: Adapter, path: str | os.PathLike) -> Graph:
    """MiniLM's graph (`minilm`) + Head(adapter) -> one graph at `path`; its manifest entry."""
    head_path = Path(path).with_name("head.onnx")
    hidden = torch.randn(2, 7, adapter.linear.in_features)
    mask = torch.ones(2, 7, dtype=torch.long)
    b, s = Dim("batch"), Dim("seq")
    export_module(
        Head(adapter),
        (hidden, mask),
        head_path,
        dict(inputs=["hidden", "attention_mask"], outputs=list(OUTPUTS)),
        ({0: b, 1: s}, {0: b, 1: s}),
    )
    head = onnx.compose.add_prefix(onnx.load(head_path), _PREFIX)
    head_path.unlink()
    model = onnx.load(minilm)
    graph = model.graph
    rename = {
        _MINILM["ids"]: INPUTS[0],
        _PREFIX + "hidden": _MINILM["hidden"],
        _PREFIX + "attention_mask": _MINILM["mask"],
        **{_PREFIX + name: name for name in OUTPUTS},
    }
    for node in [*graph.node, *head.graph.node]:
        node.input[:] = [rename.get(name, name) for name in node.input]
        node.output[:] = [rename.get(name, name) for name in node.output]
    zeros = onnx.helper.make_node(
        "ConstantOfShape",
        ["token_type_shape"],
        [_MINILM["types"]],
        value=onnx.helper.make_tensor("zero", onnx.TensorProto.INT64, [1], [0]),
    )
    shape = onnx.helper.make_node("Shape", [INPUTS[0]], ["token_type_shape"])
    nodes = [shape, zeros, *graph.node, *head.graph.node]
    del graph.node[:]
    graph.node.extend(nodes)
    graph.initializer.extend(head.graph.initializer)
    inputs = {i.name: i for i in graph.input}
    inputs[_MINILM["ids"]].name = INPUTS[0]
    kept = [inputs[_MINILM["ids"]], inputs[_MINILM["mask"]]]
    del graph.input[:]
    graph.input.extend(kept)
    del graph.output[:]
    graph.output.extend(rename_value(o, rename) for o in head.graph.output)
    _merge_opsets(model, head)
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return Graph(Path(path).name, INPUTS, OUTPUTS)


def rename_value(value: onnx.ValueInfoProto, rename: dict) -> onnx.ValueInfoProto:
    value = onnx.ValueInfoProto.FromString(value.SerializeToString())
    value.name = rename.get(value.name, value.name)
    return value


def _merge_opsets(model: onnx.ModelProto, other: onnx.ModelProto) -> None:
    """The newer opset of each domain (the ops of both graphs keep their meaning in it)."""
    versions = {o.domain: o.version for o in model.opset_import}
    for o in other.opset_import:
        versions[o.domain] = max(versions.get(o.domain, 0), o.version)
    del model.opset_import[:]
    model.opset_import.extend(onnx.helper.make_opsetid(d, v) for d, v in versions.items())
    model.ir_version = max(model.ir_version, other.ir_version)
