"""onnxruntime sessions the way the runtime wants them on a CPU."""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

import onnxruntime as ort
from onnxruntime.capi import onnxruntime_pybind11_state as _state

from mogo.manifest import BundleError, Graph, io_types

# onnxruntime's own exceptions share no base class but Exception; these are all of them
_ORT_ERRORS = tuple(
    value
    for value in vars(_state).values()
    if isinstance(value, type) and issubclass(value, Exception)
)


def cpu_session(path: str | os.PathLike | bytes, intra_op_threads: int = 1) -> ort.InferenceSession:
    """A CPU session whose thread pool does not spin between calls: spinning burns the core
    the token sampler needs and makes latency erratic when it is busy. A file onnxruntime
    cannot load is a BundleError naming it (a sha256 that matches only says the bytes are the
    ones the manifest was written for, not that they are a graph). `path` may also be a
    serialised graph (bytes), one rewritten in memory.

    The graph is loaded from its bytes, with external data looked for in an empty folder: a
    graph whose weights are in another file (one no checksum vouches for) is refused, so every
    byte a session loads is one the manifest lists."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = intra_op_threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        data = path if isinstance(path, bytes) else Path(path).read_bytes()
    except OSError as error:
        raise BundleError(f"{path}: cannot read it ({error.strerror or error})") from None
    with tempfile.TemporaryDirectory(prefix="mogo-no-external-data-") as nothing:
        options.add_session_config_entry(
            "session.model_external_initializers_file_folder_path", nothing
        )
        try:
            return ort.InferenceSession(data, options, providers=["CPUExecutionProvider"])
        except _ORT_ERRORS as error:
            if "External data" in str(error):
                raise BundleError(
                    f"{path}: keeps weights in another file (ONNX external "
                    "data); a bundle's graphs hold all their weights"
                ) from None
            raise BundleError(f"{path}: not a valid ONNX graph: {_cause(error)}") from None


def graph_session(
    path: str | os.PathLike | bytes,
    graph: Graph,
    intra_op_threads: int = 1,
    types: tuple[list, list] | None = None,
) -> ort.InferenceSession:
    """`cpu_session`, refused unless the graph's input and output names are the manifest's in
    its order (the runtime feeds and reads the graphs by these names) and, given `types`
    (mogo.manifest.io_types), their element types and fixed last sizes are those too."""
    session = cpu_session(path, intra_op_threads)
    for kind, actual, expected in (
        ("inputs", [i.name for i in session.get_inputs()], list(graph.inputs)),
        ("outputs", [o.name for o in session.get_outputs()], list(graph.outputs)),
    ):
        if actual != expected:
            raise BundleError(
                f"{path}: the graph's {kind} are not the manifest's "
                f"({_difference(actual, expected)})"
            )
    if types is not None:
        check_types(path, session, types)
    return session


def check_types(
    path: str | os.PathLike | bytes, session: ort.InferenceSession, types: tuple[list, list]
) -> None:
    """A BundleError naming the first input or output whose element type, or fixed last size,
    is not what the runtime gives or reads (`types`: mogo.manifest.io_types)."""
    for kind, args, expected in (
        ("input", session.get_inputs(), types[0]),
        ("output", session.get_outputs(), types[1]),
    ):
        for arg, (element, size) in zip(args, expected, strict=False):
            last = arg.shape[-1] if arg.shape else None
            if arg.type != element or (size is not None and isinstance(last, int) and last != size):
                raise BundleError(
                    f"{path}: {kind} {arg.name} is {arg.type} of shape "
                    f"{arg.shape}; the manifest's model needs {element} with a "
                    f"last axis of {'any size' if size is None else size}"
                )


def check_width(path: str | os.PathLike, name: str, array, size: int | None) -> None:
    """What a graph returned has the last size the manifest says (a graph may leave it open)."""
    if size is not None and array.shape[-1:] != (size,):
        raise BundleError(
            f"{path}: output {name} has shape {array.shape}; the manifest's model "
            f"needs a last axis of {size}"
        )


def _cause(error: Exception) -> str:
    """The first line of onnxruntime's message, without its code and the path (named already)."""
    text = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
    text = re.sub(r"^\[ONNXRuntimeError\] : \d+ : \w+ : ", "", text)
    return re.sub(r"^Load model from .* failed:\s*", "", text)


def _difference(actual: list[str], expected: list[str]) -> str:
    for index, (name, wanted) in enumerate(zip(actual, expected, strict=False)):  # may differ
        if name != wanted:
            return f"number {index} is {name!r}, the manifest says {wanted!r}"
    return f"{len(actual)} in the graph, {len(expected)} in the manifest"


class NamedGraph:
    """A bundle graph's session with its manifest names: inputs in, first output out."""

    def __init__(self, bundle, graph: Graph, threads: int):
        self.path = bundle.path(graph.file)
        self.types = io_types(bundle.manifest, graph)
        self.session = graph_session(self.path, graph, threads, self.types)
        self.inputs, self.outputs = list(graph.inputs), list(graph.outputs)
        self.output = self.outputs[0]

    def run(self, *arrays):
        return self.run_all(*arrays)[0]

    def run_all(self, *arrays) -> list:
        """Every output, each checked against the last size the manifest gives it."""
        outputs = self.session.run(self.outputs, dict(zip(self.inputs, arrays, strict=False)))
        for name, array, (_, size) in zip(self.outputs, outputs, self.types[1], strict=False):
            check_width(self.path, name, array, size)
        return outputs
