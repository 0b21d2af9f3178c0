"""The bundle's VQ on real clips, to look at:
`python -m mogo.bench.quality.vq_reconstruction --data DIR --out DIR [--bundle B] [--clips N]`.

Torch-free, the graphs the runtime runs: each clip's features -> the bundle's ONNX VQ encoder
-> token ids -> its decoder -> joints. Prints each clip's MPJPE (global joints, root trajectory
included, in mm) and writes OUT/ID.gif, the original (left) beside the reconstruction (right),
and OUT/contact_sheet.png: a row per clip, a frame every 1.5 s, original above reconstruction.
Clips are the first N test-split clips of at least 4 seconds (mirrors skipped).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from mogo.clip import Motion
from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.generator import MotionGenerator
from mogo.motion.features import features_to_joints
from mogo.motion.render import render_frames

MIN_FRAMES = 80
SHEET_SECONDS = 1.5  # between the frames of a contact-sheet row
THUMBNAIL = 128


def reconstruct(generator: MotionGenerator, features: np.ndarray) -> np.ndarray:
    """Features (T, D) -> joints (T', J, 3) of their VQ round trip (T' = T cut to whole
    tokens)."""
    joints = features_to_joints(features, generator.skeleton)
    motion = Motion(features, joints, generator.fps, np.zeros((0, 0), np.int64), generator.skeleton)
    tokens = generator.encode_motion(motion)
    return generator.decode(tokens, [(0, "")]).joints


def side_by_side(left: list[Image.Image], right: list[Image.Image]) -> list[Image.Image]:
    frames = []
    for a, b in zip(left, right, strict=False):
        frame = Image.new("RGB", (a.width + b.width, a.height))
        frame.paste(a.convert("RGB"), (0, 0))
        frame.paste(b.convert("RGB"), (a.width, 0))
        frames.append(frame)
    return frames


def write_pair(
    original: np.ndarray,
    rebuilt: np.ndarray,
    left_title: str,
    right_title: str,
    fps: float,
    gif: Path,
    every: float = SHEET_SECONDS,
) -> list[tuple[Image.Image, Image.Image]]:
    """`gif`: the original (left) beside its reconstruction (right); returns the contact
    sheet's row for them: a pair of frames every `every` seconds."""
    left = render_frames(original, left_title, fps)
    right = render_frames(rebuilt, right_title, fps)
    frames = side_by_side(left, right)
    frames[0].save(gif, save_all=True, append_images=frames[1:], duration=1000.0 / fps, loop=0)
    step = max(1, int(round(every * fps)))
    return [(left[t], right[t]) for t in range(0, len(frames), step)]


def contact_sheet(
    rows: list[list[tuple[Image.Image, Image.Image]]], path: Path, size: int = THUMBNAIL
) -> None:
    """A PNG: per clip, its row of originals above its row of reconstructions, frames of
    `size` pixels."""
    columns = max(len(row) for row in rows)
    sheet = Image.new("RGB", (columns * size, 2 * size * len(rows)), "white")
    for r, row in enumerate(rows):
        for c, (a, b) in enumerate(row):
            for k, image in enumerate((a, b)):
                sheet.paste(
                    image.convert("RGB").resize((size, size)), (c * size, (2 * r + k) * size)
                )
    sheet.quantize(64).save(path, optimize=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="HumanML3D-layout folder")
    parser.add_argument("--out", type=Path, required=True, help="folder for the GIFs and sheet")
    parser.add_argument("--bundle", help="bundle folder (default: the shipped one)")
    parser.add_argument("--clips", type=int, default=4)
    args = parser.parse_args()
    generator = MotionGenerator.load(args.bundle)
    folder = HumanML3DFolder(args.data, splits=("test",))
    args.out.mkdir(parents=True, exist_ok=True)
    rows, errors = [], []
    for clip_id in folder.ids("test"):
        if len(rows) == args.clips:
            break
        features = folder.features(clip_id)
        if len(features) < MIN_FRAMES or clip_id.startswith("M"):  # M: a mirror of another
            continue
        original = features_to_joints(features, generator.skeleton)
        rebuilt = reconstruct(generator, features)
        original = original[: len(rebuilt)]
        error = 1000 * np.linalg.norm(rebuilt - original, axis=-1).mean()
        errors.append(error)
        caption = folder.first_caption(clip_id)
        rows.append(
            write_pair(
                original,
                rebuilt,
                f"{clip_id} original: {caption}",
                f"VQ reconstruction, MPJPE {error:.1f} mm",
                generator.fps,
                args.out / f"{clip_id}.gif",
            )
        )
        print(f"{clip_id}: {len(rebuilt)} frames, MPJPE {error:.1f} mm  ({caption})", flush=True)
    if not rows:
        raise SystemExit(f"no test clip of at least {MIN_FRAMES} frames in {args.data}")
    contact_sheet(rows, args.out / "contact_sheet.png")
    print(f"mean MPJPE {np.mean(errors):.1f} mm over {len(errors)} clips; wrote {args.out}")


if __name__ == "__main__":
    main()
