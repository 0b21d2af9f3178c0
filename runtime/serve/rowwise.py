"""Level graphs whose rows never influence each other, so streams can share one call.

An int8 bundle's level graphs quantise each MatMul input with DynamicQuantizeLinear: one scale
and zero point for the whole tensor, every batch row included. Batched as exported, a stream's
numbers would depend on whatever other streams share the call. `rowwise_graph` rewrites each
such input to be quantised batch row by batch row (DynamicQuantizeLinear's formula over every
axis but the batch) and keeps the int8 weights:

    q = saturate(round(x / s_r) + z_r)           s_r, z_r from batch row r's min and max (and 0)
    y = (MatMulInteger(q, W, 0, w_z) - z_r * colsum(W - w_z)) * s_r * w_s

The integer part is exact, so a row's result is the same in any batch. For a batch of one row
this is the exported graph's arithmetic (the same logits, to a float rounding where onnxruntime
fuses differently). Graphs without DynamicQuantizeLinear come back unchanged.

Where this CPU's onnxruntime multiplies uint8 by int8 exactly (`signed_products_exact`), the
weights are stored as int8, W - 128 with w_z - 128: the same W - w_z, so the same integers,
and 5-7x faster products at 100 rows than uint8 by uint8 (AVX-512 VNNI or AMX do them in one
instruction). Where a CPU has only AVX2, onnxruntime's uint8 by int8 kernel adds pairs of
products in 16 bits and can saturate, so the weights stay uint8 there.

Needs the `onnx` package (the serve extra), which the base runtime does not.
"""

from __future__ import annotations

import functools
import os

import numpy as np
import onnx
from onnx import helper, numpy_helper

from mogo._session import cpu_session
from mogo.serve.onnx_graph import consumer_map


def rowwise_graph(path: str | os.PathLike, signed: bool | None = None) -> bytes:
    """The level graph at `path`, dynamic quantisation made per row, serialised for
    onnxruntime. signed: store the weights as int8 (None: where `signed_products_exact`)."""
    model = onnx.load(os.fspath(path))
    graph = model.graph
    ranks = _ranks(model)
    weights = {init.name: numpy_helper.to_array(init) for init in graph.initializer}
    consumers = consumer_map(graph)
    after: dict[int, list[onnx.NodeProto]] = {}  # nodes to insert after a node (by id)
    nodes = []
    for node in graph.node:
        if node.op_type != "DynamicQuantizeLinear":
            nodes.append(node)
            nodes += after.pop(id(node), [])
            continue
        quantized, scale, zero_point = node.output
        prefix = (node.name or quantized) + "/"
        nodes += _rowwise_quantize(node.input[0], ranks[node.input[0]], prefix)
        for user in consumers.get(quantized, []):  # MatMulInteger(q, W, z, w_z)
            after[id(user)] = _zero_point_correction(user, prefix, weights)
        for user in consumers.get(scale, []):  # Mul(s, w_s): each row's own scale instead
            user.input[:] = [prefix + "scale" if name == scale else name for name in user.input]
    graph.ClearField("node")
    graph.node.extend(nodes)
    if signed if signed is not None else signed_products_exact():
        _sign_weights(graph)
    return model.SerializeToString()


@functools.cache
def signed_products_exact() -> bool:
    """Whether onnxruntime's MatMulInteger of uint8 by constant int8 weights is exact on this
    CPU: a probe with products that saturate a 16-bit pair sum (255 * -128 twice), at one row
    and at eight (the kernels may differ)."""
    rng = np.random.default_rng(0)
    a = np.concatenate([np.full((1, 256), 255), rng.integers(0, 256, (7, 256))]).astype(np.uint8)
    b = np.concatenate(
        [np.full((256, 1), -128), np.full((256, 1), 127), rng.integers(-128, 128, (256, 6))],
        axis=1,
    ).astype(np.int8)
    zero = np.array(-3, np.int8)
    graph = helper.make_graph(
        [helper.make_node("MatMulInteger", ["a", "b", "", "zero"], ["y"])],
        "signed_products_probe",
        [helper.make_tensor_value_info("a", onnx.TensorProto.UINT8, ("rows", 256))],
        [helper.make_tensor_value_info("y", onnx.TensorProto.INT32, ("rows", b.shape[1]))],
        [numpy_helper.from_array(b, "b"), numpy_helper.from_array(zero, "zero")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=8)
    session = cpu_session(model.SerializeToString())
    want = a.astype(np.int32) @ (b.astype(np.int32) - zero)
    return all(
        np.array_equal(session.run(None, {"a": a[:rows]})[0], want[:rows]) for rows in (1, 8)
    )


def _sign_weights(graph: onnx.GraphProto) -> None:
    """Every MatMulInteger's uint8 weights and zero point as int8, both less 128 (the same
    W - w_z). All or none: where a weight is read otherwise, the graph is left as it is."""
    initializers = {init.name: init for init in graph.initializer}
    readers = consumer_map(graph)
    matmuls = [node for node in graph.node if node.op_type == "MatMulInteger"]
    names = {name for node in matmuls for name in node.input[1::2]}  # W and w_z
    if any(
        name not in initializers
        or initializers[name].data_type != onnx.TensorProto.UINT8
        or any(user.op_type != "MatMulInteger" or name in user.input[::2] for user in readers[name])
        for name in names
    ):
        return
    for name in sorted(names):
        array = numpy_helper.to_array(initializers[name]).astype(np.int16) - 128
        initializers[name].CopyFrom(numpy_helper.from_array(array.astype(np.int8), name))


def _ranks(model: onnx.ModelProto) -> dict[str, int]:
    """The rank of every tensor shape inference can tell."""
    inferred = onnx.shape_inference.infer_shapes(model).graph
    return {
        value.name: len(value.type.tensor_type.shape.dim)
        for value in [*inferred.input, *inferred.value_info]
        if value.type.tensor_type.HasField("shape")
    }


def _rowwise_quantize(x: str, rank: int, p: str) -> list[onnx.NodeProto]:
    """DynamicQuantizeLinear's formula over every axis but the batch: p+q (uint8), p+scale
    (float) and p+zero (int32), one per batch row, shaped to broadcast (B, 1, ...)."""

    def constant(name, value, dtype):
        return helper.make_node(
            "Constant",
            [],
            [p + name],
            value=numpy_helper.from_array(np.array(value, dtype), p + name),
        )

    node = helper.make_node
    return [
        constant("c0", 0.0, np.float32),
        constant("c255", 255.0, np.float32),
        constant("tiny", 1e-30, np.float32),
        constant("axes", list(range(1, rank)), np.int64),
        node("ReduceMax", [x, p + "axes"], [p + "max0"], keepdims=0),  # (B,)
        node("ReduceMin", [x, p + "axes"], [p + "min0"], keepdims=0),
        node("Max", [p + "max0", p + "c0"], [p + "max"]),
        node("Min", [p + "min0", p + "c0"], [p + "min"]),
        node("Sub", [p + "max", p + "min"], [p + "range"]),
        node("Div", [p + "range", p + "c255"], [p + "scale0"]),
        node("Max", [p + "scale0", p + "tiny"], [p + "scale_rows"]),  # all-zero rows: any
        node("Neg", [p + "min"], [p + "neg_min"]),
        # saturate(round(-min / scale)), and x quantised with its row's scale and zero point:
        # each one pass, as onnxruntime's DynamicQuantizeLinear does it with the tensor's
        node("QuantizeLinear", [p + "neg_min", p + "scale_rows"], [p + "zero_rows"], axis=0),
        node("QuantizeLinear", [x, p + "scale_rows", p + "zero_rows"], [p + "q"], axis=0),
        node("Unsqueeze", [p + "scale_rows", p + "axes"], [p + "scale"]),
        node("Cast", [p + "zero_rows"], [p + "zero_rows_int"], to=onnx.TensorProto.INT32),
        node("Unsqueeze", [p + "zero_rows_int", p + "axes"], [p + "zero"]),
    ]


def _zero_point_correction(
    matmul: onnx.NodeProto, p: str, weights: dict[str, np.ndarray]
) -> list[onnx.NodeProto]:
    """Turn MatMulInteger(q, W, z, w_z) into MatMulInteger(q, W, 0, w_z) - z_r * colsum, under
    its own output name: onnxruntime takes only one zero point for the whole of input A."""
    _, w_name, _, w_zero_name = matmul.input
    w = weights[w_name].astype(np.int32) - weights[w_zero_name].astype(np.int32)
    colsum = w.sum(axis=-2, keepdims=True).astype(np.int32)  # (..., 1, N): per head too
    out, raw, name = matmul.output[0], matmul.output[0] + "/raw", p + matmul.output[0]
    matmul.input[:] = [p + "q", w_name, "", w_zero_name]
    matmul.output[:] = [raw]
    return [
        helper.make_node(
            "Constant",
            [],
            [name + "/colsum"],
            value=numpy_helper.from_array(colsum, name + "/colsum"),
        ),
        helper.make_node("Mul", [p + "zero", name + "/colsum"], [name + "/shift"]),
        helper.make_node("Sub", [raw, name + "/shift"], [out]),
    ]
