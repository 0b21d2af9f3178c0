"""onnxruntime sessions the way the runtime wants them on a CPU."""
from __future__ import annotations

import os
import re

import onnxruntime as ort
from onnxruntime.capi import onnxruntime_pybind11_state as _state

from mogo.manifest import BundleError, Graph

# onnxruntime's own exceptions share no base class but Exception; these are all of them
_ORT_ERRORS = tuple(value for value in vars(_state).values()
                    if isinstance(value, type) and issubclass(value, Exception))


def cpu_session(path: str | os.PathLike | bytes,
                intra_op_threads: int = 1) -> ort.InferenceSession:
    """A CPU session whose thread pool does not spin between calls: spinning burns the core
    the token sampler needs and makes latency erratic when it is busy. A file onnxruntime
    cannot load is a BundleError naming it (a sha256 that matches only says the bytes are the
    ones the manifest was written for, not that they are a graph). `path` may also be a
    serialised graph (bytes), one rewritten in memory."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = intra_op_threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        source = path if isinstance(path, bytes) else os.fspath(path)
        return ort.InferenceSession(source, options, providers=["CPUExecutionProvider"])
    except _ORT_ERRORS as error:
        raise BundleError(f"{path}: not a valid ONNX graph: {_cause(error)}") from None


def graph_session(path: str | os.PathLike | bytes, graph: Graph,
                  intra_op_threads: int = 1) -> ort.InferenceSession:
    """`cpu_session`, refused unless the graph's input and output names are the manifest's in
    its order: the runtime feeds and reads the graphs by these names."""
    session = cpu_session(path, intra_op_threads)
    for kind, actual, expected in (
            ("inputs", [i.name for i in session.get_inputs()], list(graph.inputs)),
            ("outputs", [o.name for o in session.get_outputs()], list(graph.outputs))):
        if actual != expected:
            raise BundleError(f"{path}: the graph's {kind} are not the manifest's "
                              f"({_difference(actual, expected)})")
    return session


def _cause(error: Exception) -> str:
    """The first line of onnxruntime's message, without its code and the path (named already)."""
    text = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
    text = re.sub(r"^\[ONNXRuntimeError\] : \d+ : \w+ : ", "", text)
    return re.sub(r"^Load model from .* failed:\s*", "", text)


def _difference(actual: list[str], expected: list[str]) -> str:
    for index, (name, wanted) in enumerate(zip(actual, expected)):
        if name != wanted:
            return f"number {index} is {name!r}, the manifest says {wanted!r}"
    return f"{len(actual)} in the graph, {len(expected)} in the manifest"


class NamedGraph:
    """A bundle graph's session with its manifest names: inputs in, first output out."""

    def __init__(self, bundle, graph: Graph, threads: int):
        self.session = graph_session(bundle.path(graph.file), graph, threads)
        self.inputs, self.outputs = list(graph.inputs), list(graph.outputs)
        self.output = self.outputs[0]

    def run(self, *arrays):
        return self.session.run([self.output], dict(zip(self.inputs, arrays)))[0]
