"""`mogo export portable --bundle IN --out OUT`: a bundle whose graphs run where Python does
not: Unity's inference engine (Sentis: ONNX opsets 7 to 15) and onnxruntime-web.

Every graph of IN is rewritten, nothing retrained: the int8 level graphs' quantised MatMuls
(DynamicQuantizeLinear, MatMulInteger) become float MatMuls of their dequantised weights and
their quantised embedding Gathers float Gathers; weights stored as int8 with a Cast become
float weights; the ops newer than opset 15 become their definitions in older ops
(LayerNormalization, Gelu; the axes of ReduceL2 as an attribute); the graphs are stamped
opset 15. The weights are stored fp16 (a Cast to fp32 each, computed in fp32) or fp32. The
manifest is IN's, less its int8 record; docs/portable.md measures what the rewrite costs.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import onnx
from onnx import helper, numpy_helper
from onnx.reference import ReferenceEvaluator

from mogo.bundle import Bundle, write_manifest
from mogo.export.onnx.bundle import new_folder, store_weights_fp16
from mogo.manifest import Fp16Storage, Manifest
from mogo.serve.onnx_graph import consumer_map, producer_map

OPSET = 15  # the newest Sentis imports (its docs: opsets 7 to 15)
IR_VERSION = 8  # the IR of opset 15


def export_portable(bundle_dir: Path, out: Path, fp16: bool = True) -> Manifest:
    """The portable bundle of `bundle_dir` in the new folder `out`; returns its manifest."""
    source = Bundle.load(bundle_dir)
    manifest = source.manifest
    out = new_folder(out)
    graphs = {graph.file for graph in manifest.graphs()}
    try:
        for name in manifest.files:
            if name in graphs:
                onnx.save(portable_graph(onnx.load(source.path(name))), out / name)
                if fp16:
                    store_weights_fp16(out / name)
            else:
                shutil.copy2(source.path(name), out / name)
        storage = Fp16Storage(files=tuple(sorted(graphs))) if fp16 else None
        return write_manifest(out, replace(manifest, int8=None, fp16_storage=storage))
    except BaseException:  # no half-written bundle left behind
        for path in out.iterdir():
            path.unlink()
        raise


def portable_graph(model: onnx.ModelProto) -> onnx.ModelProto:
    """`model` in float weights and opset-15 ops (see the module's docstring)."""
    graph = model.graph
    _fold_constants(graph)
    _float_matmuls(graph)
    _float_gathers(graph)
    nodes = []
    for node in graph.node:
        nodes.extend(_REWRITES.get(node.op_type, lambda n, g: [n])(node, graph))
    del graph.node[:]
    graph.node.extend(nodes)
    _drop_unused(graph)
    del graph.value_info[:]  # shapes of the tensors replaced; onnx infers them again
    del model.opset_import[:]
    model.opset_import.append(helper.make_opsetid("", OPSET))
    model.ir_version = IR_VERSION
    onnx.checker.check_model(model, full_check=True)
    return model


def _fold_constants(graph: onnx.GraphProto) -> None:
    """Casts and DequantizeLinear of weights (every input a weight) -> float weights."""
    weights = {w.name: w for w in graph.initializer}
    kept = []
    for node in graph.node:
        if node.op_type in ("Cast", "DequantizeLinear") and all(i in weights for i in node.input):
            single = helper.make_model(
                helper.make_graph(
                    [node],
                    "fold",
                    [],
                    [helper.make_tensor_value_info(node.output[0], 0, None)],
                    [weights[i] for i in node.input],
                ),
                opset_imports=[helper.make_opsetid("", 20)],
            )
            (value,) = ReferenceEvaluator(single).run(None, {})
            folded = numpy_helper.from_array(np.asarray(value), node.output[0])
            graph.initializer.append(folded)
            weights[folded.name] = folded
        else:
            kept.append(node)
    del graph.node[:]
    graph.node.extend(kept)


def _weight(graph: onnx.GraphProto, name: str) -> np.ndarray:
    return numpy_helper.to_array(next(w for w in graph.initializer if w.name == name))


def _dequantised(graph: onnx.GraphProto, data: str, scale: str, zero_point: str) -> np.ndarray:
    q = _weight(graph, data).astype(np.float32)
    return ((q - _weight(graph, zero_point).astype(np.float32)) * _weight(graph, scale)).astype(
        np.float32
    )


def _float_matmuls(graph: onnx.GraphProto) -> None:
    """DynamicQuantizeLinear(x) -> MatMulInteger(., Wq) -> Cast -> Mul(., scales), the dynamic
    int8 scheme of onnxruntime's quantize_dynamic, -> MatMul(x, W)."""
    producer, users = producer_map(graph), consumer_map(graph)
    replaced: dict[int, onnx.NodeProto | None] = {}
    for node in graph.node:
        if node.op_type != "MatMulInteger":
            continue
        quantise = producer[node.input[0]]
        (cast,) = users[node.output[0]]
        (rescale,) = users[cast.output[0]]
        weight = numpy_helper.from_array(
            _dequantised(
                graph, node.input[1], _weight_scale(graph, producer, rescale, cast), node.input[3]
            ),
            f"{node.input[1]}_float",
        )
        graph.initializer.append(weight)
        replaced[id(rescale)] = helper.make_node(
            "MatMul", [quantise.input[0], weight.name], list(rescale.output), name=node.name
        )
        replaced[id(node)] = replaced[id(cast)] = None
    _replace(graph, replaced)


def _weight_scale(graph, producer, rescale, cast) -> str:
    """The weight's scale: the Mul(activation scale, weight scale) that `rescale` applies."""
    scales = producer[next(i for i in rescale.input if i != cast.output[0])]
    weights = {w.name for w in graph.initializer}
    return next(i for i in scales.input if i in weights)


def _float_gathers(graph: onnx.GraphProto) -> None:
    """Gather(Wq, ids) -> DequantizeLinear(., scale, zero point) -> Gather(W, ids)."""
    producer = producer_map(graph)
    weights = {w.name for w in graph.initializer}
    replaced: dict[int, onnx.NodeProto | None] = {}
    for node in graph.node:
        gather = producer.get(node.input[0]) if node.op_type == "DequantizeLinear" else None
        if gather is None or gather.op_type != "Gather" or gather.input[0] not in weights:
            continue
        table = numpy_helper.from_array(
            _dequantised(graph, gather.input[0], *node.input[1:]), f"{gather.input[0]}_float"
        )
        graph.initializer.append(table)
        replaced[id(node)] = helper.make_node(
            "Gather",
            [table.name, gather.input[1]],
            list(node.output),
            name=node.name,
            axis=_attribute(gather, "axis", 0),
        )
        replaced[id(gather)] = None
    _replace(graph, replaced)


def _replace(graph: onnx.GraphProto, replaced: dict[int, onnx.NodeProto | None]) -> None:
    nodes = [replaced.get(id(n), n) for n in graph.node]
    del graph.node[:]
    graph.node.extend(n for n in nodes if n is not None)


def _layer_norm(node: onnx.NodeProto, graph: onnx.GraphProto) -> list[onnx.NodeProto]:
    """LayerNormalization (opset 17) over the last axis, as its definition."""
    if _attribute(node, "axis", -1) != -1:
        raise ValueError(f"{node.name}: LayerNormalization over axis {_attribute(node, 'axis')}")
    x, scale, *bias = node.input
    t = _names(
        node, "mean", "centred", "square", "variance", "var_eps", "std", "normed", "eps", "scaled"
    )
    graph.initializer.append(
        numpy_helper.from_array(np.array(_attribute(node, "epsilon", 1e-5), np.float32), t.eps)
    )
    out = node.output[0]
    return [
        helper.make_node("ReduceMean", [x], [t.mean], axes=[-1]),
        helper.make_node("Sub", [x, t.mean], [t.centred]),
        helper.make_node("Mul", [t.centred, t.centred], [t.square]),
        helper.make_node("ReduceMean", [t.square], [t.variance], axes=[-1]),
        helper.make_node("Add", [t.variance, t.eps], [t.var_eps]),
        helper.make_node("Sqrt", [t.var_eps], [t.std]),
        helper.make_node("Div", [t.centred, t.std], [t.normed]),
        helper.make_node("Mul", [t.normed, scale], [t.scaled if bias else out]),
        *([helper.make_node("Add", [t.scaled, bias[0]], [out])] if bias else []),
    ]


def _gelu(node: onnx.NodeProto, graph: onnx.GraphProto) -> list[onnx.NodeProto]:
    """Gelu (opset 20), exact (erf) form: x * (erf(x / sqrt 2) + 1) / 2."""
    if _attribute(node, "approximate", b"none") not in (b"none", "none"):
        raise ValueError(f"{node.name}: Gelu approximate={_attribute(node, 'approximate')}")
    t = _names(node, "scaled", "erf", "plus_one", "times_x", "sqrt2", "one", "half")
    for name, value in ((t.sqrt2, math.sqrt(2)), (t.one, 1.0), (t.half, 0.5)):
        graph.initializer.append(numpy_helper.from_array(np.array(value, np.float32), name))
    x = node.input[0]
    return [
        helper.make_node("Div", [x, t.sqrt2], [t.scaled]),
        helper.make_node("Erf", [t.scaled], [t.erf]),
        helper.make_node("Add", [t.erf, t.one], [t.plus_one]),
        helper.make_node("Mul", [x, t.plus_one], [t.times_x]),
        helper.make_node("Mul", [t.times_x, t.half], [node.output[0]]),
    ]


def _axes_attribute(node: onnx.NodeProto, graph: onnx.GraphProto) -> list[onnx.NodeProto]:
    """A Reduce op other than ReduceSum takes its axes as an input from opset 18, as an
    attribute before."""
    attributes = {a.name: helper.get_attribute_value(a) for a in node.attribute}
    if len(node.input) > 1 and node.input[1]:
        attributes["axes"] = [int(a) for a in _weight(graph, node.input[1])]
    attributes.pop("noop_with_empty_axes", None)  # 0 is the only behaviour before 18
    return [
        helper.make_node(
            node.op_type, [node.input[0]], list(node.output), name=node.name, **attributes
        )
    ]


_REWRITES = {
    "LayerNormalization": _layer_norm,
    "Gelu": _gelu,
    **{
        op: _axes_attribute
        for op in ("ReduceL2", "ReduceMean", "ReduceMax", "ReduceMin", "ReduceProd", "ReduceL1")
    },
}


def _names(node: onnx.NodeProto, *parts: str):
    base = node.name or node.output[0]
    return SimpleNamespace(**{part: f"{base}/{part}" for part in parts})


def _attribute(node: onnx.NodeProto, name: str, default=None):
    return next((helper.get_attribute_value(a) for a in node.attribute if a.name == name), default)


def _drop_unused(graph: onnx.GraphProto) -> None:
    """Nodes none of whose outputs is used, then weights no node reads."""
    needed = {o.name for o in graph.output}
    kept = []
    for node in reversed(graph.node):
        if any(out in needed for out in node.output):
            kept.append(node)
            needed.update(node.input)
    del graph.node[:]
    graph.node.extend(reversed(kept))
    weights = [w for w in graph.initializer if w.name in needed]
    del graph.initializer[:]
    graph.initializer.extend(weights)
