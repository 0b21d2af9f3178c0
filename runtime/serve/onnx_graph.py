"""What the ONNX graph rewrites share (mogo.serve's rowwise, mogo.export's VQ and portable
graphs): the node that writes each value and the nodes that read it. Plain protobuf walking:
no onnx import needed here."""

from __future__ import annotations


def consumer_map(graph) -> dict[str, list]:
    """Value name -> the nodes (onnx.NodeProto) of `graph` that take it as an input, in order."""
    consumers: dict[str, list] = {}
    for node in graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    return consumers


def producer_map(graph) -> dict[str, object]:
    """Value name -> the node (onnx.NodeProto) of `graph` that outputs it."""
    return {name: node for node in graph.node for name in node.output}
