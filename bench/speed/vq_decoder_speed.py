"""How fast the ONNX VQ decoder runs on one CPU thread:
`python -m mogo.bench.speed.vq_decoder_speed`.

Exports `VQConfig.cpu_default()` with random weights (the cost does not depend on them), centred
and causal, and prints a markdown table: the time to decode a 196-token clip in one call, the
cost of a streaming push of one token (a window of left_context + 1 + lookahead tokens is
decoded each time), and the .onnx file sizes. Medians of `--repeats` after a warm-up.
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

from mogo.export.models.vq import MoSAVQ, VQConfig
from mogo.export.onnx.vq_graphs import export_vq_decoder, export_vq_encoder
from mogo.motion.skeleton import MAX_FRAMES
from mogo.stream_decoder import StreamingDecoder

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
    for ids in (next(stream) for _ in range(graph.left_context + graph.lookahead + 1)):
        decoder.push(ids)  # past the stream's start: every push decodes a full window
    return dict(
        context=f"{graph.left_context} + {graph.lookahead}",
        clip_ms=median_ms(lambda: decoder.decode_offline(clip), repeats),
        push_ms=median_ms(lambda: decoder.push(next(stream)), 10 * repeats),
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
        "encoder .onnx (MiB) | decoder .onnx (MiB) |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for causal in (False, True):
        config = replace(VQConfig.cpu_default(), causal=causal, down_factor=args.down_factor)
        with tempfile.TemporaryDirectory() as tmp:
            r = measure(config, Path(tmp), args.repeats)
        print(
            f"| {'causal' if causal else 'centred'} | {r['context']} | {r['clip_ms']:.1f} | "
            f"{r['push_ms']:.2f} | {r['encoder_mb']:.1f} | {r['decoder_mb']:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
