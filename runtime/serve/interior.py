"""The VQ decoder for full windows only: every convolution unpadded, so a window decodes to
its interior frames alone.

A streaming decoder (mogo.stream_decoder) decodes, for every 8 new frames, a window of the
left context, the 8 new tokens and the lookahead (31 + 8 + 31 = 70 tokens on the shipped
bundle), and keeps the 8 frames in the middle: the others are only there to feed them. Each
convolution of the exported graph zero-pads its input to keep the length, so all 70
positions go through every layer. `interior_graph` drops the padding: a convolution with
dilation d then returns its input's length less 2d, the residual branches are cut to the
length of what they are added to, and the graph returns the frames of the tokens between the
left context and the lookahead. Each of those frames is the same dot products over the same
inputs as before (to a float rounding at most: the matrix products are narrower); a window
of the shipped decoder takes about 40% of the multiplications. Only a window whose new
tokens lie a receptive field from both its ends may go through it (mogo.stream_decoder's
push_many chooses). It needs a receptive field as wide on both sides (a non-causal decoder:
padding p on each side of each convolution), and the `onnx` package (the serve extra); a
graph it cannot cut is refused, and `interior_session` checks the cut one against the
exported one on random windows at load (None: the server decodes whole windows). The bundle
on disk is not changed.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import helper, numpy_helper

from mogo._session import graph_session
from mogo.manifest import Graph

# ops that keep every time position where it is (what lies between the convolutions)
POSITIONWISE = {
    "Add",
    "Sub",
    "Mul",
    "Div",
    "Relu",
    "LeakyRelu",
    "Gelu",
    "Sigmoid",
    "Tanh",
    "Cast",
    "Identity",
    "Gather",
    "ReduceSum",
    "Transpose",
}


def interior_session(
    path: str | os.PathLike, graph: Graph, whole: ort.InferenceSession, codebook_size: int
) -> tuple[ort.InferenceSession, int] | None:
    """(a one-thread session of the decoder graph at `path` unpadded, the tokens it drops on
    each side), checked against `whole` (its session as exported) on random windows; None
    where the graph cannot be cut or the check fails: the caller decodes whole windows."""
    try:
        data, cut = interior_graph(Path(path).read_bytes())
    except ValueError:
        return None
    session = graph_session(data, graph, 1)
    levels = whole.get_inputs()[0].shape[-1]
    ids = np.random.default_rng(0).integers(0, codebook_size, (2, 2 * cut + 9, levels))
    expected = whole.run(None, {graph.inputs[0]: ids})[0][:, cut:-cut]
    got = session.run(None, {graph.inputs[0]: ids})[0]
    if got.shape != expected.shape or not np.allclose(got, expected, rtol=1e-4, atol=1e-4):
        return None
    return session, cut


def interior_graph(data: bytes) -> tuple[bytes, int]:
    """(the serialised decoder graph `data` with unpadded convolutions, the tokens it drops
    on each side); ValueError for a graph it cannot cut: padding that is not the same on both
    sides or does not keep the length, strides, branches joined by anything but Add, any
    other op on the time path (an upsampling among them: tokens and frames would differ)."""
    model = onnx.load_from_string(data)
    graph = model.graph
    crop = {value.name: 0 for value in graph.input}  # positions lost on each side so far
    nodes = []
    for node in graph.node:
        cropped = [crop[name] for name in node.input if name in crop]
        if not cropped:  # constants
            nodes.append(node)
            continue
        if node.op_type == "Conv":
            crop[node.output[0]] = cropped[0] + _unpadded(node)
        elif node.op_type not in POSITIONWISE:
            raise ValueError(f"{node.name}: {node.op_type} on the time path")
        elif len(set(cropped)) > 1:
            if node.op_type != "Add":
                raise ValueError(
                    f"{node.name}: branches of different lengths joined by {node.op_type}, not Add"
                )
            nodes += _cut_to(node, crop, max(cropped), graph)
            crop[node.output[0]] = max(cropped)
        else:
            crop[node.output[0]] = cropped[0]
        nodes.append(node)
    graph.ClearField("node")
    graph.node.extend(nodes)
    graph.ClearField("value_info")  # the lengths it states are the padded graph's
    for output in graph.output:
        output.type.tensor_type.shape.dim[1].dim_param = "interior_frames"
    return model.SerializeToString(), crop[graph.output[0].name]


def _unpadded(conv: onnx.NodeProto) -> int:
    """Drop a length-keeping convolution's padding in place; the positions it drops on each
    side."""
    attributes = {a.name: helper.get_attribute_value(a) for a in conv.attribute}
    pads, kernel = attributes.get("pads", [0, 0]), attributes.get("kernel_shape", [None])
    dilation = attributes.get("dilations", [1])[0]
    if attributes.get("auto_pad", b"NOTSET") != b"NOTSET" or attributes.get("strides", [1]) != [1]:
        raise ValueError(f"{conv.name}: auto_pad or strides")
    if (
        len(pads) != 2
        or pads[0] != pads[1]
        or kernel[0] is None
        or 2 * pads[0] != dilation * (kernel[0] - 1)
    ):
        raise ValueError(
            f"{conv.name}: padding {pads} is not the same on both sides or does not keep the length"
        )
    for attribute in conv.attribute:
        if attribute.name == "pads":
            attribute.ints[:] = [0, 0]
    return pads[0]


def _cut_to(
    add: onnx.NodeProto, crop: dict[str, int], target: int, graph: onnx.GraphProto
) -> list[onnx.NodeProto]:
    """Slices (last axis: time, in the convolutions' (batch, channels, time)) that cut the
    longer inputs of `add` to the length of the shortest; `add` then reads them."""
    slices = []
    for k, name in enumerate(add.input):
        cut = target - crop[name]
        if cut:
            bounds = [f"{name}.interior_{which}" for which in ("starts", "ends", "axes")]
            for bound, value in zip(bounds, (cut, -cut, -1), strict=False):
                graph.initializer.append(numpy_helper.from_array(np.array([value]), bound))
            sliced = f"{name}.interior"
            slices.append(
                helper.make_node(
                    "Slice", [name, *bounds], [sliced], name=f"{add.name}.interior_{k}"
                )
            )
            add.input[k] = sliced
    return slices
