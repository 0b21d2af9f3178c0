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
- `present.L.key` / `.value` are the new slots only (batch, heads, seq, head_dim);
- the graph is cut into stages after each layer's presents, and each layer's attention reads
  its past input as it is: mogo.kv_pool.StagedSession writes the new slots into the pasts
  between stages. So a call reads its rows of the pool in place, where a graph writing them
  itself would copy every slot it reads (a ScatterElements where the Concat was). The
  attention still sees one cache with the new slot in it, so it rounds as the exported graph
  does; one that added the new slot's terms apart rounded differently (products of other
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


def pooled_stages(path: str | os.PathLike, signed: bool | None = None) -> list[bytes]:
    """The level graph at `path`, made row-wise (`signed`: mogo.serve.rowwise.rowwise_graph),
    with per-row positions and new slots out, cut into stages (mogo.kv_pool.StagedSession runs
    them), serialised for onnxruntime."""
    model = onnx.load_from_string(rowwise_graph(path, signed))
    graph = model.graph
    before: dict[str, list] = {}  # nodes to insert before a node (by its first output)
    try:
        reshaped = _row_positions(graph, before)
        pairs = _new_slots_out(graph)
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
    try:
        return _stages(model, pairs)
    except (KeyError, ValueError) as error:  # KeyError: a value shape inference cannot type
        raise BundleError(f"{path}: not a level graph the server can pool ({error})") from None


def _stages(model, pairs: list[tuple[str, str]]) -> list[bytes]:
    """`model` cut after each layer's presents (`pairs`: (past input, present output) of each
    key and value, in node order), each stage a graph of its own: it takes what it reads of
    the graph's inputs and of earlier stages' values, and gives what later stages read and the
    graph outputs it makes. Constants go with every stage that reads them, so each stage folds
    them as the whole graph did. ValueError where a stage would read a past before the stage
    that makes its new slots ends."""
    graph = model.graph
    cuts = {present for _, present in pairs[1::2]}
    ends = [k + 1 for k, node in enumerate(graph.node) if node.output[0] in cuts]
    spans = list(zip([0, *ends], [*ends, len(graph.node)], strict=True))
    constants = {node.output[0]: node for node in graph.node if node.op_type == "Constant"}
    stages = [[n for n in graph.node[a:b] if n.op_type != "Constant"] for a, b in spans]
    reads = [{name for node in nodes for name in node.input if name} for nodes in stages]
    for k, nodes in enumerate(stages):
        nodes[:0] = [constants[name] for name in sorted(reads[k] & constants.keys())]
    makes = [{name for node in nodes for name in node.output} for nodes in stages]
    made_in = {name: k for k, names in enumerate(makes) for name in names}
    for past, present in pairs:
        readers = [
            k
            for k, nodes in enumerate(stages)
            if any(past in node.input and node.op_type != "Shape" for node in nodes)
        ]
        if min(readers, default=len(stages)) <= made_in[present]:
            raise ValueError(f"{past} is read before its new slots are made")
    inferred = onnx.shape_inference.infer_shapes(model).graph
    values = {v.name: v for v in [*inferred.value_info, *graph.input, *graph.output]}
    known = {v.name: v for v in graph.value_info}
    initializers = {init.name: init for init in graph.initializer}
    later = [set().union(*reads[k + 1 :]) for k in range(len(stages))]
    outputs = {value.name for value in graph.output}
    serialised = []
    for k, nodes in enumerate(stages):
        taken = sorted(reads[k] - makes[k] - initializers.keys(), key=_order(graph.input))
        given = sorted(makes[k] & (later[k] | outputs), key=_order(graph.output))
        stage = helper.make_graph(
            nodes,
            f"{graph.name}/stage{k}",
            [values[name] for name in taken],
            [values[name] for name in given],
            [initializers[name] for name in sorted(reads[k] & initializers.keys())],
            value_info=[known[name] for name in sorted(makes[k] & known.keys())],
        )
        serialised.append(
            helper.make_model(
                stage, opset_imports=model.opset_import, ir_version=model.ir_version
            ).SerializeToString()
        )
    return serialised


def _order(values):
    """Sort key: the names of `values` (a graph's inputs or outputs) first, in their order,
    then other names alphabetically."""
    order = {value.name: k for k, value in enumerate(values)}
    return lambda name: (order.get(name, len(order)), name)


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


def _new_slots_out(graph) -> list[tuple[str, str]]:
    """Each layer's Concat(past, new) goes: its readers read the past input, into which the
    caller has written the new slots (at `slots`, right after the row's own) before the stage
    that reads it runs; the present output is the new slots only (an Identity where the Concat
    was). Returns (past input, present output) of each Concat, in node order."""
    users = consumer_map(graph)
    outputs = {value.name for value in graph.output}
    graph.input.append(
        helper.make_tensor_value_info("slots", onnx.TensorProto.INT64, ["batch", "seq"])
    )
    concats = [
        node
        for node in graph.node
        if node.op_type == "Concat" and node.output[0] in outputs and node.output[0] != "logits"
    ]
    if not concats or len(concats) % 2:  # a key and a value a layer
        raise ValueError("no key and value presents made by a Concat")
    pairs = []
    for cat in concats:
        past, new = cat.input
        present = cat.output[0]
        pairs.append((past, present))
        for user in users[present]:
            user.input[:] = [past if name == present else name for name in user.input]
        cat.op_type = "Identity"
        del cat.attribute[:]
        cat.input[:] = [new]
    for value in graph.output:
        if value.name != "logits":
            value.type.tensor_type.shape.dim[2].dim_param = "seq"
    return pairs
