"""The Blender add-on in a real Blender, headless: what it writes against what the runtime says.

    python -m mogo.bench.quality.blender_addon [--png docs/blender_retarget.png]
                                               [--screenshot docs/blender_panel.png]
                                               [--bpy-python /tmp/bpy4-venv/bin/python]

Builds the add-on zip (`mogo blender-addon`), and has Blender (bench/blender/addon_scene.py)
install it, Generate a walk and Retarget it onto a Mixamo-named armature of other proportions
(legs x1.2, arms x0.85 in a 40 degree A-pose, torso x1.1). Prints a markdown table: our
armature's joints against the runtime's rig (mogo.motion.rig) and against the generated
joints, and the target's feet, hands and hips against ours scaled by its proportions.
--screenshot: Blender's window with the panel (bench/blender/addon_screenshot.py, on xvfb-run).
--bpy-python: a Python with the `bpy` module from PyPI (Blender 4.x) runs the same scene script
instead of a blender executable (bench/blender/bpy_module.py).
Blender's Python must be the version of this one: the add-on's Install puts the runtime wheel
it ships into an empty folder, with pip told to take nothing from an index (no network), and
the runtime's dependencies come from this environment's site-packages.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mogo import MotionGenerator
from mogo.blender.addon_zip import addon_bytes
from mogo.motion import rig
from mogo.motion.bvh import NAMINGS

SCRIPT = Path(__file__).resolve().parents[1] / "blender" / "addon_scene.py"
SCREENSHOT_SCRIPT = SCRIPT.with_name("addon_screenshot.py")
BPY_MODULE = SCRIPT.with_name("bpy_module.py")
SCALE = dict(leg=1.2, arm=0.85, torso=1.1)
A_POSE = 40.0  # degrees the target's arms hang below the T-pose
# Our joint (Mixamo bone name) -> the chain root its position is measured from, and its scale.
FOLLOWERS = {
    "LeftFoot": ("LeftUpLeg", "leg"),
    "RightFoot": ("RightUpLeg", "leg"),
    "LeftToeBase": ("LeftUpLeg", "leg"),
    "LeftHand": ("LeftArm", "arm"),
    "RightHand": ("RightArm", "arm"),
}


class PythonMismatch(RuntimeError):
    """Blender's Python is not this one's version: its site-packages cannot be shared."""


@dataclass
class Figures:
    scene: dict  # what Blender answered (fps, frames, actions, messages, heads)
    frames: int  # of the generated motion
    rig_max: float  # metres: our armature's joints against the runtime's rig, worst
    joints_mean: float  # metres: against the generated joints (the rigid-skeleton error)
    joints_max: float
    follow: dict  # label -> worst distance (m) of the target's joint from ours scaled


def background(blender: str) -> list[str]:
    """The command that runs a scene script (and its arguments) in a headless Blender."""
    return [blender, "-b", "--factory-startup", "--python"]


def as_module(python: str) -> list[str]:
    """The same under a Python that has the `bpy` module (Blender 4.x wheels from PyPI)."""
    return [python, str(BPY_MODULE)]


def run(
    launcher: list[str],
    prompt: str = "a person walks forward.",
    seconds: float = 3.0,
    seed: int = 0,
    png: Path | None = None,
    frame: int = 30,
    size: tuple[int, int] = (640, 400),
    samples: int = 16,
    timeout: float = 300.0,
) -> Figures:
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        request = _request(folder, prompt, seconds, seed, frame)
        request.update(size=list(size), samples=samples)
        if png is not None:
            request["png"] = str(folder / "frame.png")
        done = _blender(launcher, SCRIPT, folder, request, timeout)
        result_path = folder / "result.json"
        if not result_path.is_file():
            _explain(done, request)
        scene = json.loads(result_path.read_text())
        if png is not None:
            _small_png(Path(request["png"]), png)
    motion = MotionGenerator.load().generate(prompt, seconds=seconds, seed=seed)
    return _figures(scene, motion)


def screenshot(blender: str, png: Path, timeout: float = 300.0) -> None:
    """Blender's window with the add-on's panel after Generate and Retarget, on a virtual
    display (xvfb-run)."""
    xvfb = shutil.which("xvfb-run")
    if xvfb is None:
        raise RuntimeError("the screenshot needs a virtual display: apt-get install xvfb")
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        request = dict(
            _request(folder, "a person walks forward.", 3.0, 0, 30), png=str(folder / "screen.png")
        )
        done = _blender(
            [
                xvfb,
                "-a",
                "-s",
                "-screen 0 1280x800x24",
                blender,
                "--enable-event-simulate",
                "--factory-startup",
                "--python",
            ],
            SCREENSHOT_SCRIPT,
            folder,
            request,
            timeout,
        )
        if not Path(request["png"]).is_file():
            _explain(done, request)
        _small_png(Path(request["png"]), png)


def _request(folder: Path, prompt: str, seconds: float, seed: int, frame: int) -> dict:
    """The add-on zip and an empty folder in `folder`, and the request both scripts read."""
    (folder / "mogo_blender.zip").write_bytes(addon_bytes())
    (folder / "empty").mkdir()
    (folder / "installed").mkdir()
    return dict(
        zip=str(folder / "mogo_blender.zip"),
        empty=str(folder / "empty"),
        installed=str(folder / "installed"),
        site_packages=sysconfig.get_paths()["purelib"],
        prompt=prompt,
        seconds=seconds,
        seed=seed,
        scale=SCALE,
        a_pose=A_POSE,
        frame=frame,
        result=str(folder / "result.json"),
    )


def _blender(
    launcher: list[str], script: Path, folder: Path, request: dict, timeout: float
) -> subprocess.CompletedProcess:
    (folder / "request.json").write_text(json.dumps(request))
    return subprocess.run(
        launcher + [str(script), "--", str(folder / "request.json")],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=_clean_environment(folder / "scripts"),
    )


def _clean_environment(scripts: Path) -> dict:
    """Blender as a user starts it: outside any virtual environment (a Debian Blender finds a
    venv's python3 on PATH and takes its site-packages: this one's, or another activated
    before it), add-ons installed into `scripts`, pip never reaching an index."""
    environment = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    environment["PATH"] = os.pathsep.join(
        p
        for p in environment.get("PATH", "").split(os.pathsep)
        if not Path(p).resolve().is_relative_to(Path(sys.prefix).resolve())
        and not (Path(p).parent / "pyvenv.cfg").exists()
    )
    environment["BLENDER_USER_SCRIPTS"] = str(scripts)
    # Install: the shipped wheel alone, no index (the dependencies are this environment's)
    environment.update(PIP_NO_INDEX="1", PIP_NO_DEPS="1")
    return environment


def _explain(done: subprocess.CompletedProcess, request: dict) -> None:
    """Why Blender wrote no result. Its runtime-missing line for the empty folder is expected
    (a check); for this environment's site-packages it means another Python version."""
    output = done.stdout + done.stderr
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    if (
        "UserError: MOGO runtime not found" in output  # the dependencies appended after Install
        or f"missing in {request['site_packages']})" in output
        or "numpy.core" in output
    ):
        raise PythonMismatch(f"Blender's Python cannot use this Python {version}'s packages")
    raise RuntimeError(f"Blender failed:\n{output[-3000:]}")


def _small_png(rendered: Path, out: Path) -> None:
    from PIL import Image

    out.parent.mkdir(parents=True, exist_ok=True)
    Image.open(rendered).convert("RGB").quantize(64).save(out, optimize=True)


def _ours(heads: dict, name: str) -> np.ndarray:
    """A bone's heads (T, 3) from Blender's axes (Z up, facing -Y) to ours (Y up, facing +Z)."""
    x, y, z = np.moveaxis(np.array(heads[name]), -1, 0)
    return np.stack([x, z, -y], axis=-1)


def _figures(scene: dict, motion) -> Figures:
    joints = motion.joints.astype(np.float64)
    armature = np.stack([_ours(scene["ours"], name) for name in NAMINGS["mixamo"]], axis=1)
    posed = rig.posed_joints(joints, motion.skeleton)
    rigid = np.linalg.norm(armature - joints, axis=-1)
    target = {name.split(":")[-1]: _ours(scene["target"], name) for name in scene["target"]}
    rest = {
        name.split(":")[-1]: _ours({"x": [head]}, "x")[0]
        for name, head in scene["target_rest"].items()
    }
    ours = dict(zip(NAMINGS["mixamo"], np.moveaxis(armature, 1, 0), strict=False))
    follow = {}
    for name, (root, part) in FOLLOWERS.items():
        expected = SCALE[part] * (ours[name] - ours[root])
        follow[f"{name} from {root}"] = _worst(target[name] - target[root], expected)
    follow["Hips (root motion)"] = _worst(
        target["Hips"] - rest["Hips"], SCALE["leg"] * (ours["Hips"] - _rest_hips(motion))
    )
    return Figures(
        scene,
        len(joints),
        float(np.abs(armature - posed).max()),
        float(rigid.mean()),
        float(rigid.max()),
        follow,
    )


def _rest_hips(motion) -> np.ndarray:
    return rig.rest_offsets(motion.skeleton)[0]


def _worst(found: np.ndarray, expected: np.ndarray) -> float:
    return float(np.linalg.norm(found - expected, axis=-1).max())


def table(figures: Figures) -> str:
    scene = figures.scene
    lines = [
        "| check | figure |",
        "|---|---:|",
        f"| Blender | {scene['blender']} |",
        f"| frames / keys / scene fps | {figures.frames} / {scene['keys']} / {scene['fps']:g} |",
        f"| our armature vs the runtime's rig, max (cm) | {figures.rig_max * 100:.4f} |",
        f"| our armature vs the generated joints, mean / max (cm) | "
        f"{figures.joints_mean * 100:.2f} / {figures.joints_max * 100:.2f} |",
    ]
    lines += [
        f"| target {label} vs ours x its scale, max (cm) | {error * 100:.3f} |"
        for label, error in figures.follow.items()
    ]
    lines.append(
        f"| Generate in Blender, {figures.frames} frames (s) | {scene['generate_seconds']:.2f} |"
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--png", type=Path, help="render a frame of the retargeted walk here")
    parser.add_argument(
        "--screenshot",
        type=Path,
        help="Blender's window with the panel, on a virtual display, here",
    )
    parser.add_argument("--blender", default=shutil.which("blender"))
    parser.add_argument("--bpy-python", help="a Python with the bpy module, instead of Blender")
    args = parser.parse_args()
    if not (args.blender or args.bpy_python):
        parser.exit(2, "blender_addon: error: no blender on PATH (--blender, --bpy-python)\n")
    if args.screenshot and not args.blender:
        parser.exit(2, "blender_addon: error: --screenshot needs a blender executable\n")
    figures = run(
        as_module(args.bpy_python) if args.bpy_python else background(args.blender), png=args.png
    )
    print(table(figures))
    if args.png:
        print(f"wrote {args.png}")
    if args.screenshot:
        screenshot(args.blender, args.screenshot)
        print(f"wrote {args.screenshot}")


if __name__ == "__main__":
    main()
