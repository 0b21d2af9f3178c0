"""The error of bundles' VQ on a whole split, through their graphs (torch-free):
`python -m mogo.bench.quality.vq_report --data DIR [--bundle B ...] [--split test] [--threads N]
[--low-latency]` (`--low-latency`: a second row per bundle, its low-latency decoder's).

What the VQ issue's target is measured on: every clip of the split encoded and decoded whole
by the bundle's ONNX encoder and decoder (as `mogo bench eval`'s reconstruction row), joints
recovered as the runtime recovers them, MPJPE in mm with the root trajectory included, a mean
over clips. Two parts split it: the error with the clip's true root features (feature 0..3:
the poses alone) and with all features true but the root's (the trajectory alone, integrated
from per-frame velocities); they do not add up. Then the median, the 90th percentile and the
worst clip, since a few clips that turn and then travel dominate the mean. Prints a markdown
table, a row per bundle.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mogo.bench.quality.evaluate import reconstruct
from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.generator import MotionGenerator
from mogo.motion.features import features_to_joints
from mogo.motion.skeleton import Skeleton

ROOT_FEATURES = slice(0, 4)  # yaw velocity, XZ velocity, height


def clip_errors(
    real: np.ndarray, rebuilt: np.ndarray, skeleton: Skeleton | None = None
) -> tuple[float, float, float]:
    """MPJPE (mm) of a clip's reconstruction (T, D): whole, with the true root features (the
    poses alone), and with every feature true but the root's (the trajectory alone); joints
    of `skeleton` (a bundle's), else of the skeleton with D-dim features."""
    joints = features_to_joints(real, skeleton)
    poses, trajectory = rebuilt.copy(), real.copy()
    poses[:, ROOT_FEATURES] = real[:, ROOT_FEATURES]
    trajectory[:, ROOT_FEATURES] = rebuilt[:, ROOT_FEATURES]
    return tuple(
        1000 * float(np.linalg.norm(features_to_joints(f, skeleton) - joints, axis=-1).mean())
        for f in (rebuilt, poses, trajectory)
    )


def report(
    generator: MotionGenerator,
    folder: HumanML3DFolder,
    split: str = "test",
    limit: int | None = None,
    threads: int = 1,
    low_latency: bool = False,
) -> dict:
    ids = folder.ids(split)[:limit]
    real = [folder.features(clip_id) for clip_id in ids]
    errors = np.array(
        [
            clip_errors(r, b, generator.skeleton)
            for r, b in zip(real, reconstruct(generator, real, threads, low_latency), strict=False)
        ]
    )
    worst = int(np.argmax(errors[:, 0]))
    return dict(
        clips=len(ids),
        mpjpe_mm=float(errors[:, 0].mean()),
        poses_mm=float(errors[:, 1].mean()),
        trajectory_mm=float(errors[:, 2].mean()),
        median_mm=float(np.median(errors[:, 0])),
        p90_mm=float(np.percentile(errors[:, 0], 90)),
        worst=(ids[worst], float(errors[worst, 0])),
    )


def format_table(rows: dict[str, dict]) -> str:
    lines = [
        "| bundle | clips | MPJPE (mm) | poses alone | trajectory alone | median | 90th "
        "percentile | worst clip |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for name, r in rows.items():
        lines.append(
            f"| {name} | {r['clips']} | {r['mpjpe_mm']:.2f} | {r['poses_mm']:.2f} | "
            f"{r['trajectory_mm']:.2f} | {r['median_mm']:.2f} | {r['p90_mm']:.2f} | "
            f"{r['worst'][0]}: {r['worst'][1]:.0f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="HumanML3D-layout folder")
    parser.add_argument(
        "--bundle", nargs="+", default=[None], help="bundle folders (default: the shipped one)"
    )
    parser.add_argument("--split", default="test")
    parser.add_argument("--limit", type=int, help="the first N clips of the split (default all)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--low-latency",
        action="store_true",
        help="also each bundle's low-latency decoder (a row of its own)",
    )
    args = parser.parse_args()
    folder = HumanML3DFolder(args.data, splits=(args.split,))
    rows = {}
    for bundle in args.bundle:
        generator = MotionGenerator.load(bundle)
        name = bundle or "default"
        rows[name] = report(generator, folder, args.split, args.limit, args.threads)
        if args.low_latency:
            rows[f"{name}, low-latency decoder"] = report(
                generator, folder, args.split, args.limit, args.threads, True
            )
    print(f"{args.split} split of {args.data}, each clip encoded and decoded whole\n")
    print(format_table(rows))


if __name__ == "__main__":
    main()
