"""How fast the ONNX VQ decoder runs on one CPU thread:
`python -m mogo.bench.speed.vq_decoder_speed`.

Exports `VQConfig.cpu_default()` with random weights (the cost does not depend on them), centred,
causal and with the shipped low-latency decoder's lookahead of 2, and prints a markdown table:
the time to decode a 196-token clip in one call, the cost of a streaming push of one token (a
window of left_context + 1 + lookahead tokens is decoded each time; for lookahead 2 also its
step graph, mogo.export.onnx.vq_step_graph, a token a call), and the .onnx file sizes. Medians
of `--repeats` after a warm-up.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from mogo._session import cpu_session
from mogo.export.models.vq import MoSAVQ, VQConfig
from mogo.export.onnx.vq_graphs import export_vq_decoder, export_vq_encoder
from mogo.export.onnx.vq_step_graph import export_vq_step_decoder
from mogo.motion.skeleton import MAX_FRAMES
from mogo.stream_decoder import StepDecoder, StreamingDecoder

CLIP_TOKENS = MAX_FRAMES  # the longest HumanML3D clip at one token a frame (down_factor 1)


def median_ms(call, repeats: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def measure(config: VQConfig, folder: Path, repeats: int) -> dict:
    torch.manual_seed(0)
    model = MoSAVQ(config).eval()
    export_vq_encoder(model, folder / "vq_encoder.onnx")
    graph = export_vq_decoder(model, folder / "vq_decoder.onnx")
    decoder = StreamingDecoder(
        folder / "vq_decoder.onnx",
        graph.left_context,
        graph.lookahead,
        config.codebook_size,
        intra_op_threads=1,
    )
    rng = np.random.default_rng(0)
    clip = rng.integers(config.codebook_size, size=(CLIP_TOKENS, config.levels))
    stream = iter(rng.integers(config.codebook_size, size=(10**6, 1, config.levels)))
    step = None
    if config.decoder_lookahead is not None:
        step_graph = export_vq_step_decoder(model, folder / "step.onnx")
        session = cpu_session(folder / "step.onnx", 1)
        step = StepDecoder(session, step_graph, graph.left_context, config.codebook_size)
    for ids in (next(stream) for _ in range(graph.left_context + graph.lookahead + 1)):
        decoder.push(ids)  # past the stream's start: every push decodes a full window
        if step is not None:
            step.push(ids)
    return dict(
        context=f"{graph.left_context} + {graph.lookahead}",
        clip_ms=median_ms(lambda: decoder.decode_offline(clip), repeats),
        push_ms=median_ms(lambda: decoder.push(next(stream)), 10 * repeats),
        step_ms=None if step is None else median_ms(lambda: step.push(next(stream)), 10 * repeats),
        encoder_mb=(folder / "vq_encoder.onnx").stat().st_size / 2**20,
        decoder_mb=(folder / "vq_decoder.onnx").stat().st_size / 2**20,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--down-factor", type=int, default=1)
    args = parser.parse_args()

    print(
        f"| decoder | context (tokens) | {CLIP_TOKENS}-token clip (ms) | one-token push (ms) | "
        "one-token step graph (ms) | encoder .onnx (MiB) | decoder .onnx (MiB) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    kinds = {"centred": {}, "causal": dict(causal=True), "lookahead 2": dict(decoder_lookahead=2)}
    for name, switches in kinds.items():
        config = replace(VQConfig.cpu_default(), down_factor=args.down_factor, **switches)
        with tempfile.TemporaryDirectory() as tmp:
            r = measure(config, Path(tmp), args.repeats)
        step = "-" if r["step_ms"] is None else f"{r['step_ms']:.2f}"
        print(
            f"| {name} | {r['context']} | {r['clip_ms']:.1f} | {r['push_ms']:.2f} | {step} | "
            f"{r['encoder_mb']:.1f} | {r['decoder_mb']:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
