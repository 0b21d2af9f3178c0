"""The VQ decoder for full windows only: every convolution unpadded, so a window decodes to
its interior frames alone.

A streaming decoder (mogo.stream_decoder) decodes, for every 8 new frames, a window of the
left context, the 8 new tokens and the lookahead (31 + 8 + 31 = 70 tokens on the shipped
bundle), and keeps the 8 frames in the middle: the others are only there to feed them. Each
convolution of the exported graph zero-pads its input to keep the length, so all 70
positions go through every layer. `interior_graph` drops the padding: a convolution padded
by l and r then returns its input's length less l on the left and r on the right, the
residual branches are cut to the length of what they are added to, and the graph returns
the frames of the tokens between the left context and the lookahead. Each of those frames is
the same dot products over the same inputs as before (to a float rounding at most: the
matrix products are narrower); a window of the shipped decoder takes about 40% of the
multiplications. A low-latency decoder (a long left context, a short lookahead: padded more
on the left) decodes a window for every token: cut, it computes that token's frames alone.
Only a window whose new tokens lie a receptive field from both its ends may go through it
(mogo.stream_decoder's push_many chooses). It needs convolutions padded to keep the length
(any split between the sides) and the `onnx` package (the serve extra); a graph it cannot
cut is refused, and `interior_session` checks the cut one against the exported one on
random windows at load (None: the server decodes whole windows). The bundle on disk is not
changed.
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
) -> tuple[ort.InferenceSession, tuple[int, int]] | None:
    """(a one-thread session of the decoder graph at `path` unpadded, the tokens it drops on
    the left and on the right), checked against `whole` (its session as exported) on random
    windows; None where the graph cannot be cut or the check fails: the caller decodes whole
    windows."""
    try:
        data, cut = interior_graph(Path(path).read_bytes())
    except ValueError:
        return None
    session = graph_session(data, graph, 1)
    levels = whole.get_inputs()[0].shape[-1]
    left, right = cut
    ids = np.random.default_rng(0).integers(0, codebook_size, (2, left + right + 9, levels))
    expected = whole.run(None, {graph.inputs[0]: ids})[0][:, left : ids.shape[1] - right]
    got = session.run(None, {graph.inputs[0]: ids})[0]
    if got.shape != expected.shape or not np.allclose(got, expected, rtol=1e-4, atol=1e-4):
        return None
    return session, cut


def interior_graph(data: bytes) -> tuple[bytes, tuple[int, int]]:
    """(the serialised decoder graph `data` with unpadded convolutions, the tokens it drops
    on the left and on the right); ValueError for a graph it cannot cut: padding that does not
    keep the length, strides, branches joined by anything but Add, any other op on the time
    path (an upsampling among them: tokens and frames would differ)."""
    model = onnx.load_from_string(data)
    graph = model.graph
    crop = {value.name: (0, 0) for value in graph.input}  # positions lost on each side so far
    nodes = []
    for node in graph.node:
        cropped = [crop[name] for name in node.input if name in crop]
        if not cropped:  # constants
            nodes.append(node)
            continue
        if node.op_type == "Conv":
            left, right = _unpadded(node)
            crop[node.output[0]] = (cropped[0][0] + left, cropped[0][1] + right)
        elif node.op_type not in POSITIONWISE:
            raise ValueError(f"{node.name}: {node.op_type} on the time path")
        elif len(set(cropped)) > 1:
            if node.op_type != "Add":
                raise ValueError(
                    f"{node.name}: branches of different lengths joined by {node.op_type}, not Add"
                )
            target = (max(c[0] for c in cropped), max(c[1] for c in cropped))
            nodes += _cut_to(node, crop, target, graph)
            crop[node.output[0]] = target
        else:
            crop[node.output[0]] = cropped[0]
        nodes.append(node)
    graph.ClearField("node")
    graph.node.extend(nodes)
    graph.ClearField("value_info")  # the lengths it states are the padded graph's
    for output in graph.output:
        output.type.tensor_type.shape.dim[1].dim_param = "interior_frames"
    return model.SerializeToString(), crop[graph.output[0].name]


def _unpadded(conv: onnx.NodeProto) -> tuple[int, int]:
    """Drop a length-keeping convolution's padding in place; the positions it drops on the
    left and on the right."""
    attributes = {a.name: helper.get_attribute_value(a) for a in conv.attribute}
    pads, kernel = attributes.get("pads", [0, 0]), attributes.get("kernel_shape", [None])
    dilation = attributes.get("dilations", [1])[0]
    if attributes.get("auto_pad", b"NOTSET") != b"NOTSET" or attributes.get("strides", [1]) != [1]:
        raise ValueError(f"{conv.name}: auto_pad or strides")
    if len(pads) != 2 or kernel[0] is None or sum(pads) != dilation * (kernel[0] - 1):
        raise ValueError(f"{conv.name}: padding {pads} does not keep the length")
    for attribute in conv.attribute:
        if attribute.name == "pads":
            attribute.ints[:] = [0, 0]
    return pads[0], pads[1]


def _cut_to(
    add: onnx.NodeProto,
    crop: dict[str, tuple[int, int]],
    target: tuple[int, int],
    graph: onnx.GraphProto,
) -> list[onnx.NodeProto]:
    """Slices (last axis: time, in the convolutions' (batch, channels, time)) that cut the
    longer inputs of `add` to the length of the shortest; `add` then reads them."""
    slices = []
    for k, name in enumerate(add.input):
        left, right = target[0] - crop[name][0], target[1] - crop[name][1]
        if left or right:
            bounds = [f"{name}.interior_{which}" for which in ("starts", "ends", "axes")]
            end = -right if right else np.iinfo(np.int64).max  # an end of 0 would be empty
            for bound, value in zip(bounds, (left, end, -1), strict=False):
                graph.initializer.append(numpy_helper.from_array(np.array([value]), bound))
            sliced = f"{name}.interior"
            slices.append(
                helper.make_node(
                    "Slice", [name, *bounds], [sliced], name=f"{add.name}.interior_{k}"
                )
            )
            add.input[k] = sliced
    return slices
