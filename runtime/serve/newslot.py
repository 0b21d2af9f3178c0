"""Level graphs that return only the new cache slot, so the server keeps each cache in place.

As exported, a level graph concatenates every layer's past keys and values with the new step's
and returns the whole result as its present: each step copies the whole cache (about 3.5 MB a
stream) into a new output, and reads it again to attend over it. `newslot_graph` rewrites the
attention to take past and new apart and returns the new slot alone, under the same output
names:

    scores = Concat(q @ past_k^T, q @ new_k^T)            (was q @ Concat(past_k, new_k)^T)
    out = probs[..., :P] @ past_v + probs[..., P:] @ new_v  (was probs @ Concat(past_v, new_v))

The same numbers to a float rounding (the sum over slots is split in two); for a prefill (no
past) the present is every new slot, as before. The caller (mogo.serve.stepper) writes the new
slot into its cache arrays. Needs the `onnx` package (the serve extra).
"""
from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from mogo.serve.onnx_graph import consumer_map


def newslot_graph(data: bytes) -> bytes:
    """The serialised level graph `data` with past and new attended apart and only the new
    slot as each present; refused (ValueError) if its attention is not the exported pattern."""
    model = onnx.load_from_string(data)
    graph = model.graph
    consumers = consumer_map(graph)
    pasts = {value.name for value in graph.input if value.name.startswith("past_key_values")}
    nodes, replaced = [], set()
    for node in graph.node:
        if node.op_type != "Concat" or node.input[0] not in pasts:
            nodes.append(node)
            continue
        users = consumers.get(node.output[0], [])
        if len(users) != 1:
            raise ValueError(f"{node.output[0]}: expected one consumer, got {len(users)}")
        if node.input[0].endswith(".key"):
            new_nodes, gone = _scores(node, users[0], consumers)
        else:
            new_nodes, gone = _weighted_values(node, users[0])
        nodes += new_nodes
        replaced |= gone
    nodes = [node for node in nodes if id(node) not in replaced]
    graph.ClearField("node")
    graph.node.extend(_in_order(nodes, graph))
    return model.SerializeToString()


def _scores(concat: onnx.NodeProto, transpose: onnx.NodeProto,
            consumers: dict[str, list[onnx.NodeProto]]) -> tuple[list, set]:
    """Concat(past_k, new_k) -> Transpose -> MatMul(q, .): the two score blocks, joined."""
    users = consumers.get(transpose.output[0], [])
    if transpose.op_type != "Transpose" or len(users) != 1 or users[0].op_type != "MatMul":
        raise ValueError(f"{concat.output[0]}: not the keys of an attention")
    matmul = users[0]
    past, new = concat.input
    p, perm = concat.output[0] + "/", list(transpose.attribute[0].ints)
    node = helper.make_node
    return [node("Transpose", [past], [p + "past_t"], perm=perm),
            node("Transpose", [new], [p + "new_t"], perm=perm),
            node("MatMul", [matmul.input[0], p + "past_t"], [p + "past_scores"]),
            node("MatMul", [matmul.input[0], p + "new_t"], [p + "new_scores"]),
            node("Concat", [p + "past_scores", p + "new_scores"], [matmul.output[0]], axis=-1),
            node("Identity", [new], [concat.output[0]])], {id(transpose), id(matmul)}


def _weighted_values(concat: onnx.NodeProto, matmul: onnx.NodeProto) -> tuple[list, set]:
    """MatMul(probs, Concat(past_v, new_v)): the two blocks of probs times their values."""
    if matmul.op_type != "MatMul" or matmul.input[1] != concat.output[0]:
        raise ValueError(f"{concat.output[0]}: not the values of an attention")
    past, new = concat.input
    probs, p = matmul.input[0], concat.output[0] + "/"

    def constant(name, value):
        return helper.make_node("Constant", [], [p + name], value=numpy_helper.from_array(
            np.array([value], np.int64), p + name))

    node = helper.make_node
    return [constant("zero", 0), constant("end", np.iinfo(np.int64).max), constant("axis", -1),
            node("Shape", [past], [p + "slots"], start=2, end=3),
            node("Slice", [probs, p + "zero", p + "slots", p + "axis"], [p + "past_probs"]),
            node("Slice", [probs, p + "slots", p + "end", p + "axis"], [p + "new_probs"]),
            node("MatMul", [p + "past_probs", past], [p + "past_out"]),
            node("MatMul", [p + "new_probs", new], [p + "new_out"]),
            node("Add", [p + "past_out", p + "new_out"], [matmul.output[0]]),
            node("Identity", [new], [concat.output[0]])], {id(matmul)}


def _in_order(nodes: list[onnx.NodeProto], graph: onnx.GraphProto) -> list[onnx.NodeProto]:
    """The nodes in an order where each comes after its inputs' producers (the new ones use
    tensors made after the concatenation they replace)."""
    ready = {value.name for value in [*graph.input, *graph.initializer]} | {""}
    ordered, pending = [], nodes
    while pending:
        waiting = []
        for node in pending:
            if all(name in ready for name in node.input):
                ordered.append(node)
                ready.update(node.output)
            else:
                waiting.append(node)
        if len(waiting) == len(pending):
            raise ValueError("the rewritten level graph has a cycle")
        pending = waiting
    return ordered
