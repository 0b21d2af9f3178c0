"""What a training step costs, and how many fit in a GPU's minutes:
`python -m mogo.bench.training.train_cost [--batch 8] [--minutes 10]`.

FLOPs of one training step (forward and backward, torch's FlopCounterMode) of the VQ on
64-frame crops and of the transformer on 196-token spans, counted on the CPU at a small batch
and scaled to the recipe's (FLOPs are linear in the batch); the CPU's own rate timed on the same
steps. The GPU's rate is not assumed: it is what the H100 runs of the shipped model sustained
(docs/model.md: VQ 6000 steps of 256 crops in 9 min, transformer 6500 steps of 128 spans in
10.4 min), the same models and batches, so steps = minutes x that rate / FLOPs a step. Prints a
markdown table. Torch.
"""

from __future__ import annotations

import argparse
import time

import torch
from torch.utils.flop_counter import FlopCounterMode

from mogo.export.models.t2m import T2M, T2MConfig
from mogo.export.models.vq import MoSAVQ, VQConfig
from mogo.motion.skeleton import MAX_FRAMES

# (batch, steps, seconds) of the H100 runs in docs/model.md, and the crop / span they trained on
H100_RUNS = dict(vq=(256, 6000, 9 * 60, 64), t2m=(128, 6500, 10.4 * 60, MAX_FRAMES))


def _step(model: torch.nn.Module, kind: str, batch: int, frames: int) -> None:
    if kind == "vq":
        loss = model(torch.randn(batch, frames, model.config.feature_dim)).losses["total"]
    else:
        tokens = torch.randint(model.config.codebook_size, (batch, frames, model.config.num_levels))
        loss = model.loss(
            torch.randn(batch, model.config.text_dim), tokens, torch.full((batch,), frames)
        )[0]
    loss.backward()


def measure(kind: str, batch: int) -> tuple[float, float]:
    """(FLOPs of one training step at `batch`, CPU seconds of one such step)."""
    torch.manual_seed(0)
    model = MoSAVQ(VQConfig()) if kind == "vq" else T2M(T2MConfig())
    model.train()
    frames = H100_RUNS[kind][3]
    with FlopCounterMode(display=False) as counter:
        _step(model, kind, batch, frames)
    start = time.perf_counter()
    _step(model, kind, batch, frames)
    return float(counter.get_total_flops()), time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batch", type=int, default=8, help="batch counted on the CPU")
    parser.add_argument(
        "--minutes", type=float, default=10.0, help="GPU minutes for VQ and transformer together"
    )
    args = parser.parse_args()
    print(
        "| model | GFLOP a step (recipe batch) | CPU GFLOP/s | H100 sustained TFLOP/s "
        "| H100 steps/s | steps in half the minutes |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for kind, (batch, steps, seconds, _) in H100_RUNS.items():
        flops, cpu_seconds = measure(kind, args.batch)
        per_step = flops * batch / args.batch
        rate = per_step * steps / seconds
        fit = 60 * args.minutes / 2 * rate / per_step
        print(
            f"| {kind} (batch {batch}) | {per_step / 1e9:.0f} | "
            f"{flops / cpu_seconds / 1e9:.1f} | {rate / 1e12:.1f} | {steps / seconds:.1f} | "
            f"{fit:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
