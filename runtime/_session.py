"""onnxruntime sessions the way the runtime wants them on a CPU."""
from __future__ import annotations

import os

import onnxruntime as ort


def cpu_session(path: str | os.PathLike, intra_op_threads: int = 1) -> ort.InferenceSession:
    """A CPU session whose thread pool does not spin between calls: spinning burns the core
    the token sampler needs and makes latency erratic when it is busy."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = intra_op_threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(os.fspath(path), options, providers=["CPUExecutionProvider"])
