"""What the machine can do at best, measured in the same run as the latencies they bound:
memory read bandwidth (a large matrix-vector product) and float32 matrix FLOP/s, both in torch
at the thread count used. A step can be no faster than its bytes over the bandwidth
nor its FLOPs over the peak; the larger of the two is its floor."""

from __future__ import annotations

import os
import platform
import time

import torch

from mogo.bench.speed.quick import cpu, features_line

BANDWIDTH_BYTES = 512 * 2**20  # far larger than any CPU cache
MATMUL_SIZE = 1024


def read_bandwidth(threads: int, repeats: int = 5) -> float:
    """Bytes per second a float32 matrix-vector product on `threads` torch threads reads from
    memory: the access pattern of a decode step, on a matrix far larger than any CPU cache.
    Best of `repeats`: the floor is what is possible."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        matrix = torch.ones(BANDWIDTH_BYTES // 4 // 4096, 4096)
        vector = torch.ones(4096)
        best = 0.0
        for _ in range(repeats + 1):
            start = time.perf_counter()
            torch.mv(matrix, vector)
            best = max(best, BANDWIDTH_BYTES / (time.perf_counter() - start))
        return best
    finally:
        torch.set_num_threads(previous)


def matmul_flops(threads: int, repeats: int = 5) -> float:
    """float32 FLOP/s of a square matrix product on `threads` torch threads."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        a = torch.randn(MATMUL_SIZE, MATMUL_SIZE)
        times = []
        for _ in range(repeats + 1):
            start = time.perf_counter()
            a @ a
            times.append(time.perf_counter() - start)
        return 2 * MATMUL_SIZE**3 / min(times[1:])
    finally:
        torch.set_num_threads(previous)


def describe() -> str:
    """One line: processor, cores, instruction sets, Python and library versions."""
    import onnxruntime

    model, flags = cpu()
    return (
        f"{model}, {os.cpu_count()} cores ({features_line(flags)}), Python "
        f"{platform.python_version()}, onnxruntime {onnxruntime.__version__}, torch "
        f"{torch.__version__}"
    )
