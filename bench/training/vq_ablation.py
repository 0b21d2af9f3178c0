"""The MoSA-VQ ablation table: depth, scale-bias, decorrelation, causal decoder.

    python -m mogo.bench.training.vq_ablation --data DIR --runs DIR --steps 3000 --batch-size 256

Trains every variant below with the same recipe (`mogo train vq`, one process per variant,
`--parallel` at a time; a variant whose run already reached `--steps` is not trained again),
then decodes every test-split clip whole with each variant's best.pt and prints a markdown
table, also written to RUNS/ablation.md and RUNS/ablation.json. MPJPE is on global joint
positions recovered from the features (root trajectory included), in mm.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import torch

from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.export.models.runs import load_checkpoint, load_vq
from mogo.export.models.vq import reconstruction_metrics
from mogo.export.train.train_vq import clip_batches, whole_clips

VARIANTS = {  # name: extra `mogo train vq` arguments
    "6 levels (default)": [],
    "3 levels": ["--levels", "3"],
    "1 level": ["--levels", "1"],
    "6 levels, no scale-bias": ["--no-scale-bias"],
    "6 levels, no decorrelation": ["--decorrelation", "0"],
    "6 levels, causal decoder": ["--causal"],
}


def run_folder(runs: Path, name: str) -> Path:
    return runs / name.replace(" ", "_").replace(",", "").replace("(", "").replace(")", "")


def train_variants(args: argparse.Namespace) -> None:
    """Train the variants not yet trained to --steps, `--parallel` processes at a time."""
    pending = []
    for name, extra in VARIANTS.items():
        run = run_folder(args.runs, name)
        checkpoint = run / "checkpoint.pt"
        if checkpoint.is_file() and load_checkpoint(checkpoint)["step"] >= args.steps:
            continue
        command = [
            sys.executable,
            "-m",
            "mogo",
            "train",
            "vq",
            "--data",
            str(args.data),
            "--out",
            str(run),
            "--steps",
            str(args.steps),
            "--batch-size",
            str(args.batch_size),
            "--warmup",
            str(args.warmup),
            "--device",
            args.device,
            "--config",
            args.config,
            "--val-every",
            str(args.steps),
            "--log-every",
            str(max(1, args.steps // 10)),
            *extra,
        ]
        if checkpoint.is_file():
            command.append("--resume")
        pending.append((name, run, command))
    running: list[tuple[str, subprocess.Popen]] = []
    start = time.perf_counter()
    while pending or running:
        while pending and len(running) < args.parallel:
            name, run, command = pending.pop(0)
            run.mkdir(parents=True, exist_ok=True)
            log = (run / "train.log").open("a")
            print(f"training {name}: {' '.join(command[3:])}", flush=True)
            running.append((name, subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)))
        time.sleep(2)
        for name, process in list(running):
            if process.poll() is not None:
                running.remove((name, process))
                status = "done" if process.returncode == 0 else f"FAILED ({process.returncode})"
                print(f"{name}: {status} after {time.perf_counter() - start:.0f}s", flush=True)
                if process.returncode:
                    raise SystemExit(f"{name} failed; see {run_folder(args.runs, name)}/train.log")


def evaluate(args: argparse.Namespace) -> list[dict]:
    folder = HumanML3DFolder(args.data)
    device = torch.device("cuda" if args.device != "cpu" and torch.cuda.is_available() else "cpu")
    rows = []
    for name in VARIANTS:
        run = run_folder(args.runs, name)
        model = load_vq(run).to(device)
        clips = whole_clips(folder, "test", model.config.down_factor, args.test_clips)
        metrics = reconstruction_metrics(model, clip_batches(clips, device))
        state = load_checkpoint(run / "best.pt")
        c = model.config
        rows.append(
            dict(
                variant=name,
                levels=c.levels,
                scale_bias=c.scale_bias,
                decorrelation=c.decorrelation,
                causal=c.causal,
                step=state["step"],
                test_clips=len(clips),
                **metrics,
            )
        )
        print(f"evaluated {name}: MPJPE {metrics['mpjpe_mm']:.1f} mm", flush=True)
    return rows


def markdown(rows: list[dict], args: argparse.Namespace) -> str:
    lines = [
        f"MoSA-VQ ablation: {args.steps} steps of {args.batch_size} crops each, test split "
        f"of {args.data} ({rows[0]['test_clips']} clips decoded whole).",
        "",
        "| variant | MPJPE (mm) | feature L1 | MPJPE with the first 1 / 3 / 6 levels (mm) "
        "| share of error removed per level | mean perplexity | codebook usage |",
        "|---|---:|---:|---|---|---:|---:|",
    ]
    for r in rows:
        by = r["mpjpe_mm_by_levels"]
        firsts = " / ".join(f"{by[k - 1]:.1f}" if k <= len(by) else "-" for k in (1, 3, 6))
        gains = " ".join(f"{g:.2f}" for g in r["level_gain"])
        perplexity = sum(r["perplexity"]) / len(r["perplexity"])
        usage = sum(r["codebook_usage"]) / len(r["codebook_usage"])
        lines.append(
            f"| {r['variant']} | {r['mpjpe_mm']:.1f} | {r['feature_l1']:.4f} | "
            f"{firsts} | {gains} | {perplexity:.0f} | {usage:.0%} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="dataset folder")
    parser.add_argument("--runs", type=Path, required=True, help="folder for the variants' runs")
    parser.add_argument("--config", default="cpu_default", help="VQ size preset")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--parallel", type=int, default=1, help="variants trained at once")
    parser.add_argument("--device", default="auto", help="auto, cpu or cuda")
    parser.add_argument("--test-clips", type=int, default=None, help="(default: all)")
    parser.add_argument("--evaluate-only", action="store_true")
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "2")
    if not args.evaluate_only:
        train_variants(args)
    rows = evaluate(args)
    table = markdown(rows, args)
    (args.runs / "ablation.md").write_text(table)
    (args.runs / "ablation.json").write_text(json.dumps(rows, indent=1) + "\n")
    print(table)


if __name__ == "__main__":
    main()
