"""How far the rigid BVH is from the generated joints, and what Blender reads from it.

    python -m mogo.bench.quality.bvh_check [--png docs/bvh_blender.png]

Generates clips with the shipped bundle, writes each as the default BVH (the bundle's rigid
T-pose rig, Mixamo names, metres), and prints a markdown table: forward kinematics of the file
(our reader) against the generated joints, then, where Blender is installed, Blender's own
importer run headless (bench/blender/check_import.py) against the rig and against the joints.
--png renders one frame and the rest pose side by side with Blender (Cycles, CPU).

Blender: `apt-get install blender` (Debian, 3.4). Its glTF importer (the .glb check) also needs
numpy older than 1.24 in the system's Python, which Debian's blender does not pull in:
`/usr/bin/python3 -m pip install --break-system-packages 'numpy<1.24'`.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from mogo import MotionGenerator
from mogo.motion.bvh import NAMINGS, save_bvh
from mogo.motion.mocap import read_bvh

BLENDER_SCRIPT = Path(__file__).resolve().parents[1] / "blender" / "check_import.py"
PROMPTS = (
    "a person walks forward.",
    "a person jumps up and down.",
    "a person spins around in a circle.",
    "a person waves with the right hand.",
    "a person kicks with the left leg.",
    "a person squats down and stands up.",
)


@dataclass
class Check:
    prompt: str
    frames: int
    rig: np.ndarray  # (T, J) metres: the file's forward kinematics against the joints
    blender: dict | None = None  # check_import.py's answer


def rig_positions(bvh: Path, naming: str, scale: float) -> np.ndarray:
    """(T, J, 3) metres: our reader's forward kinematics of the file, in skeleton order."""
    clip = read_bvh(bvh)
    positions = np.empty_like(clip.positions)
    positions[:, [NAMINGS[naming].index(name) for name in clip.names]] = clip.positions
    return positions / scale


def rig_error(joints: np.ndarray, bvh: Path, naming: str, scale: float) -> np.ndarray:
    """(T, J) distance between our reader's forward kinematics of the file and the joints."""
    return np.linalg.norm(rig_positions(bvh, naming, scale) - joints, axis=-1)


def blender_check(
    file: Path,
    names: tuple[str, ...],
    fps: float,
    references: dict[str, np.ndarray],
    scale: float = 1.0,
    blender: str = "blender",
    png: Path | None = None,
    frame: int = 0,
    size: tuple[int, int] = (480, 480),
    samples: int = 16,
    timeout: float = 300.0,
) -> dict:
    """Blender's import of a .bvh or .glb against reference joints (label -> (T, J, 3) metres,
    in the order of `names`, the file's joint names)."""
    with tempfile.TemporaryDirectory() as folder:
        request = dict(
            file=str(file),
            scale=scale,
            fps=fps,
            result=f"{folder}/result.json",
            references={
                label: {name: positions[:, i].tolist() for i, name in enumerate(names)}
                for label, positions in references.items()
            },
            frame=frame,
            size=list(size),
            samples=samples,
        )
        if png is not None:
            request.update(png=f"{folder}/frame.png", rest_png=f"{folder}/rest.png")
        Path(folder, "request.json").write_text(json.dumps(request))
        done = subprocess.run(
            [
                blender,
                "-b",
                "--factory-startup",
                "--python",
                str(BLENDER_SCRIPT),
                "--",
                f"{folder}/request.json",
            ],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        if not Path(request["result"]).is_file():
            raise RuntimeError(f"Blender failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}")
        result = json.loads(Path(request["result"]).read_text())
        if png is not None:
            _side_by_side([request["rest_png"], request["png"]], png)
    return result


def _side_by_side(paths: list[str], out: Path) -> None:
    images = [Image.open(path).convert("RGB") for path in paths]
    sheet = Image.new("RGB", (sum(i.width for i in images), images[0].height))
    for index, image in enumerate(images):
        sheet.paste(image, (index * images[0].width, 0))
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet.quantize(64).save(out, optimize=True)  # a small file for the docs


def run(
    prompts: tuple[str, ...], seconds: float, seed: int, png: Path | None, blender: str | None
) -> list[Check]:
    generator = MotionGenerator.load()
    checks = []
    with tempfile.TemporaryDirectory() as folder:
        for index, prompt in enumerate(prompts):
            motion = generator.generate(prompt, seconds=seconds, seed=seed)
            joints = motion.joints.astype(np.float64)
            path = Path(folder, f"clip{index}.bvh")
            save_bvh(path, joints, motion.skeleton, motion.fps)
            check = Check(prompt, len(joints), rig_error(joints, path, "mixamo", 1.0))
            if blender:
                check.blender = blender_check(
                    path,
                    NAMINGS["mixamo"],
                    motion.fps,
                    dict(joints=joints, rig=rig_positions(path, "mixamo", 1.0)),
                    blender=blender,
                    png=png if index == 0 else None,
                    frame=len(joints) // 2,
                )
            checks.append(check)
    return checks


def table(checks: list[Check]) -> str:
    """Markdown: per clip and over all, mean / max in cm."""

    def pair(values) -> str:
        return f"{np.mean(values) * 100:.2f} / {np.max(values) * 100:.2f}"

    with_blender = all(c.blender for c in checks)
    head = "| clip | frames | rig file vs joints (cm) |"
    rule = "|---|---:|---:|"
    if with_blender:
        head += " Blender vs rig file (cm) | Blender vs joints (cm) |"
        rule += "---:|---:|"
    lines = [head, rule]

    def blender_cells(found: list[dict]) -> str:
        cells = ""
        for label in ("rig", "joints"):
            errors = [b["errors"][label] for b in found]
            mean = sum(e["mean"] for e in errors) / len(errors)
            cells += f" {mean * 100:.2f} / {max(e['max'] for e in errors) * 100:.2f} |"
        return cells

    for check in checks:
        line = f"| {check.prompt} | {check.frames} | {pair(check.rig)} |"
        lines.append(line + (blender_cells([check.blender]) if with_blender else ""))
    every = np.concatenate([c.rig.ravel() for c in checks])
    line = f"| **all** | {sum(c.frames for c in checks)} | {pair(every)} |"
    lines.append(line + (blender_cells([c.blender for c in checks]) if with_blender else ""))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--png", type=Path, help="render the first clip and the rest pose here")
    parser.add_argument(
        "--blender",
        default=shutil.which("blender"),
        help="Blender executable (default: blender on PATH; none: skip)",
    )
    args = parser.parse_args()
    checks = run(PROMPTS, args.seconds, args.seed, args.png, args.blender)
    print(table(checks))
    if args.blender:
        print(f"\nBlender scene fps after import: {checks[0].blender['fps']:g}")
    if args.png:
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
