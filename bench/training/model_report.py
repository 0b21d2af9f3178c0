"""Test-split figures of trained runs:
`python -m mogo.bench.training.model_report --data DIR --vq RUN --t2m RUN`.

Prints a markdown table: the VQ's reconstruction of whole test clips (MPJPE on recovered
joints, root trajectory included, and with the first k levels) and the transformer's
teacher-forced test loss and token accuracy per level (eval mode, the spans' captions).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.export.models.runs import load_t2m, load_vq
from mogo.export.models.t2m import TextToMotion
from mogo.export.models.vq import reconstruction_metrics
from mogo.export.train.train_t2m import TokenSpans, tokenize_split, validate
from mogo.export.train.train_vq import clip_batches, whole_clips
from mogo.export.train.training import Process
from mogo.motion.skeleton import MAX_FRAMES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--vq", type=Path, required=True, help="`mogo train vq` run")
    parser.add_argument("--t2m", type=Path, required=True, help="`mogo train t2m` run")
    parser.add_argument("--split", default="test")
    parser.add_argument("--clips", type=int, default=None, help="VQ clips (default: all)")
    args = parser.parse_args()
    process = Process(0, 1, torch.device("cuda" if torch.cuda.is_available() else "cpu"))
    folder = HumanML3DFolder(args.data)
    vq = load_vq(args.vq).to(process.device)
    clips = whole_clips(folder, args.split, vq.config.down_factor, args.clips)
    recon = reconstruction_metrics(vq, clip_batches(clips, process.device))
    t2m, text_encoder, tokenizer = load_t2m(args.t2m)
    model = TextToMotion(text_encoder, t2m).to(process.device)
    tokens = tokenize_split(folder, args.split, vq, {}, process.device)
    spans = TokenSpans(tokens, MAX_FRAMES // vq.config.down_factor)
    values = validate(model, spans, tokenizer, 64, process)
    by_levels = " / ".join(f"{v:.1f}" for v in recon["mpjpe_mm_by_levels"])
    accuracy = " / ".join(f"{values[f'acc_{l}']:.3f}" for l in range(t2m.config.num_levels))
    print(
        f"| {args.split} split | value |\n|---|---|\n"
        f"| VQ MPJPE, {len(clips)} whole clips (mm) | {recon['mpjpe_mm']:.1f} |\n"
        f"| VQ MPJPE with the first 1..L levels (mm) | {by_levels} |\n"
        f"| VQ feature L1 (normalised) | {recon['feature_l1']:.4f} |\n"
        f"| T2M teacher-forced loss (sum over levels), {len(spans)} spans | "
        f"{values['loss']:.3f} |\n"
        f"| T2M token accuracy per level | {accuracy} |"
    )


if __name__ == "__main__":
    main()
