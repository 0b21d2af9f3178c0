"""Level graphs for the engine's KV pool (mogo.kv_pool): any positions per row, new slots out.

The exported level graph takes one `positions` / `past_positions` vector for its whole batch and
returns each layer's cache with the new slots appended (a Concat of the whole past, every call:
43% of a level call's time at 100 rows of 80 slots, in an onnxruntime profile). Rewritten here
(on top of mogo.serve.rowwise, so rows never mix):

- `positions` is (batch, seq) and `past_positions` (batch, slots): each row has its own, the
  new slots' included. A slot at a position after the query's is masked, as the exported graph
  masks the future, so a row's unused slots hold mogo.kv_pool.MASKED and any finite numbers:
  rows whose caches differ in length and step share one call.
- a last input `slots` (batch, seq) says where each row's new slots go: right after its own,
  so the attention sums what the exported graph sums, in the same order, plus zeros;
- `present.L.key` / `.value` are the new slots only (batch, heads, seq, head_dim), which the
  caller writes into its pool.

The copy of the past stays (a ScatterElements where the Concat was): an attention that read the
past in place and added the new slot's terms apart rounded differently (products of other
widths) and changed a served stream's tokens within 80 steps.

The rewrite knows the exporter's pattern (mogo.export.onnx.t2m_graphs) and refuses another.
"""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import onnx
from onnx import helper, numpy_helper

from mogo.manifest import BundleError, Graph
from mogo.serve.onnx_graph import consumer_map
from mogo.serve.rowwise import rowwise_graph


def pooled_levels(levels: list[Graph]) -> list[Graph]:
    """The manifest's level graphs as pooled: the input `slots` follows the others."""
    return [replace(graph, inputs=(*graph.inputs, "slots")) for graph in levels]


def pooled_graph(path: str | os.PathLike) -> bytes:
    """The level graph at `path`, made row-wise, with per-row positions and new slots out."""
    model = onnx.load_from_string(rowwise_graph(path))
    graph = model.graph
    before: dict[str, list] = {}  # nodes to insert before a node (by its first output)
    try:
        reshaped = _row_positions(graph, before)
        _new_slots_out(graph, before)
    except (KeyError, IndexError, ValueError) as error:
        raise BundleError(f"{path}: not a level graph the server can pool ({error})") from None
    # the nodes keep their order: onnxruntime's fusions depend on it (a re-sorted graph fused
    # one LayerNormalization less and rounded differently)
    nodes = [new for node in graph.node for new in [*before.pop(node.output[0], []), node]]
    graph.ClearField("node")
    graph.node.extend(nodes)
    # shapes inferred for the graph as exported go where they changed (onnxruntime's fusions
    # need the others)
    kept = [value for value in graph.value_info if value.name not in reshaped]
    graph.ClearField("value_info")
    graph.value_info.extend(kept)
    read = {name for node in graph.node for name in node.input}
    used = [init for init in graph.initializer if init.name in read]  # axes the rewrite
    graph.ClearField("initializer")  # replaced: onnxruntime warns of unused ones on stderr
    graph.initializer.extend(used)
    return model.SerializeToString()


def _constant(graph, name: str, value) -> str:
    graph.initializer.append(numpy_helper.from_array(np.array(value, np.int64), name))
    return name


def _only(nodes: list, op: str, what: str):
    found = [node for node in nodes if node.op_type == op]
    if len(found) != 1:
        raise ValueError(f"expected one {op} reading {what}, found {len(found)}")
    return found[0]


def _row_positions(graph, before: dict[str, list]) -> set[str]:
    """positions (seq,) -> (batch, seq), past_positions (past,) -> (batch, past) and the key
    positions as they are (the new slots' included): every node between them and the
    attention scores gets a batch axis in front. Returns the values whose shapes changed."""
    inputs = {value.name: value for value in graph.input}
    for name, dims in (("positions", ["batch", "seq"]), ("past_positions", ["batch", "past"])):
        shape = inputs[name].type.tensor_type.shape
        shape.ClearField("dim")
        for dim in dims:
            shape.dim.add().dim_param = dim
    users = consumer_map(graph)
    axis1, axis2 = _constant(graph, "pooled/axis1", [1]), _constant(graph, "pooled/axis2", [2])
    cat = _only(users["past_positions"], "Concat", "past_positions")  # key positions: the
    cat.op_type = "Identity"  # past's, the new slots' included (the caller writes them)
    del cat.attribute[:]
    del cat.input[1:]
    query = _only(users["positions"], "Unsqueeze", "positions")  # (S, 1) -> (B, S, 1)
    query.input[1] = axis2
    keys = _only(users[cat.output[0]], "Unsqueeze", "the key positions")  # -> (B, 1, P + S)
    keys.input[1] = axis1
    offset = _only(users[keys.output[0]], "Sub", "the key positions")
    future = _only(users[offset.output[0]], "Less", "the offsets")  # (B, S, P+S) -> (B, 1, ..)
    mask = future.output[0] + "/rows"
    for user in users[future.output[0]]:
        user.input[:] = [mask if name == future.output[0] else name for name in user.input]
    clamp = _only(users[offset.output[0]], "Clip", "the offsets")
    before[clamp.output[0]] = [helper.make_node("Unsqueeze", [future.output[0], axis1], [mask])]
    _only(users[clamp.output[0]], "Unsqueeze", "the distances").input[1] = axis1
    # prefix rows: (S,) -> (1, S) -> (1, S, 1) becomes (B, S) -> (B, S, 1) -> as is
    prefix = _only(users["positions"], "Equal", "positions")
    first = _only(users[prefix.output[0]], "Unsqueeze", "the prefix flags")
    first.input[1] = axis2
    second = _only(users[first.output[0]], "Unsqueeze", "the prefix flags")
    second.op_type = "Identity"
    del second.input[1:]
    changed = [cat, query, keys, offset, future, clamp, prefix, first, second]
    return {node.output[0] for node in changed} | {
        _only(users[clamp.output[0]], "Unsqueeze", "the distances").output[0]
    }


def _new_slots_out(graph, before: dict[str, list]) -> None:
    """Each layer's Concat(past, new) becomes a ScatterElements of the new slots into the past
    at `slots` (batch, seq), so a row's slots keep the order its own cache would give them
    (its slots, the new ones, then masked ones: the attention's sums then run over the same
    numbers in the same order, plus zeros); the present output is the new slots only."""
    users = consumer_map(graph)
    outputs = {value.name for value in graph.output}
    graph.input.append(
        helper.make_tensor_value_info("slots", onnx.TensorProto.INT64, ["batch", "seq"])
    )
    _constant(graph, "pooled/axes13", [1, 3])
    slots = helper.make_node("Unsqueeze", ["slots", "pooled/axes13"], ["pooled/slots4"])
    concats = [
        node
        for node in graph.node
        if node.op_type == "Concat" and node.output[0] in outputs and node.output[0] != "logits"
    ]
    if not concats:
        raise ValueError("no present made by a Concat")
    for k, cat in enumerate(concats):
        past, new = cat.input
        present = cat.output[0]
        whole = present + "/pooled"
        for user in users[present]:
            user.input[:] = [whole if name == present else name for name in user.input]
        cat.op_type = "ScatterElements"
        del cat.attribute[:]
        cat.attribute.append(helper.make_attribute("axis", 2))
        cat.input[:] = [past, whole + "/index", new]
        cat.output[:] = [whole]
        before[whole] = [slots] * (k == 0) + (
            [
                helper.make_node("Shape", [new], [whole + "/shape"]),
                helper.make_node("Expand", ["pooled/slots4", whole + "/shape"], [whole + "/index"]),
                helper.make_node("Identity", [new], [present]),
            ]
        )
    for value in graph.output:
        if value.name != "logits":
            value.type.tensor_type.shape.dim[2].dim_param = "seq"
