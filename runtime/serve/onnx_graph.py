"""What the ONNX graph rewrites share (mogo.serve's rowwise and newslot, mogo.export's VQ
graphs): the nodes that read each value. Plain protobuf walking: no onnx import needed here."""

from __future__ import annotations


def consumer_map(graph) -> dict[str, list]:
    """Value name -> the nodes (onnx.NodeProto) of `graph` that take it as an input, in order."""
    consumers: dict[str, list] = {}
    for node in graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    return consumers
