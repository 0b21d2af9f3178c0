"""Stick-figure GIFs of joint positions, with numpy and Pillow only (part of the CPU runtime).

A pinhole camera looks at the figure from its front-left (the start pose faces +Z), at a
fixed world orientation, and pans with the root's smoothed floor position, so the world-fixed
floor grid scrolls under a walking figure. Frames are drawn straight into a fixed palette, so
writing the GIF needs no colour quantisation (a 196-frame clip renders in a fraction of a
second).
"""

from __future__ import annotations

import itertools
import math
import textwrap
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
from PIL import GifImagePlugin, Image, ImageChops, ImageDraw, ImageFont

from .skeleton import KIT_21, SMPL_22, Skeleton

# Palette indices; frames are "P" images so GIF encoding is a straight copy.
BACKGROUND, GRID, SHADOW, SPINE, LEFT, RIGHT, TEXT = range(7)
PALETTE = [
    (250, 250, 247),  # background
    (212, 212, 206),  # floor grid
    (196, 196, 190),  # shadow on the floor
    (70, 70, 70),  # spine, neck, head
    (38, 110, 200),  # left limbs (blue)
    (214, 68, 48),  # right limbs (red)
    (25, 25, 25),  # text, joints
]


@dataclass(frozen=True)
class Camera:
    """View settings; the defaults frame a standing adult below a three-line caption."""

    size: int = 320  # square image, pixels
    azimuth_deg: float = 35.0  # about +Y, from +Z toward +X (the figure's front-left)
    elevation_deg: float = 14.0
    distance: float = 5.0  # metres from the look-at point
    look_height: float = 0.9  # metres: about the pelvis of a standing adult
    focal: float = 600.0  # pixels
    centre_y: float = 188.0  # pixel row of the look-at point, below the caption band
    follow_seconds: float = 0.5  # time constant of the pan that follows the root
    grid_step: float = 0.5  # metres between floor lines
    grid_radius: float = 2.5  # half-width of the floor square around the look-at point


def render_frames(
    joints: np.ndarray,
    caption: str = "",
    fps: float | None = None,
    skeleton: Skeleton | None = None,
    camera: Camera = Camera(),
) -> list[Image.Image]:
    """One palette image per frame of `joints` (T, J, 3), metres, Y up, floor at y = 0.

    The skeleton is inferred from J (22: HumanML3D, 21: KIT-ML) when not given; `fps`
    (default: the skeleton's) labels the frame counter and times the camera's pan.
    """
    return list(iter_frames(joints, caption, fps, skeleton, camera))


def iter_frames(
    joints: np.ndarray,
    caption: str = "",
    fps: float | None = None,
    skeleton: Skeleton | None = None,
    camera: Camera = Camera(),
) -> Iterator[Image.Image]:
    """render_frames one image at a time, so a clip of any length needs the memory of one
    image; the joints are checked now, before the first image is asked for."""
    joints = np.asarray(joints, dtype=np.float64)
    skeleton = _check_joints(joints, skeleton)
    fps = skeleton.fps if fps is None else fps
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    frames = joints.shape[0]
    font = ImageFont.load_default(size=13)
    look_at = np.zeros((frames, 3))
    look_at[:, [0, 2]] = _follow(joints[:, 0, [0, 2]], camera.follow_seconds * fps)
    look_at[:, 1] = camera.look_height
    base = Image.new("P", (camera.size, camera.size), BACKGROUND)
    base.putpalette([c for rgb in PALETTE for c in rgb])
    for i, line in enumerate(_wrap(caption, font, camera.size - 16, max_lines=3)):
        ImageDraw.Draw(base).text((8, 6 + 16 * i), line, fill=TEXT, font=font)  # drawn once
    return _images(joints, look_at, skeleton, camera, base, fps, font)


def _images(
    joints: np.ndarray,
    look_at: np.ndarray,
    skeleton: Skeleton,
    camera: Camera,
    base: Image.Image,
    fps: float,
    font: ImageFont.FreeTypeFont,
) -> Iterator[Image.Image]:
    frames = len(joints)
    for start in range(0, frames, _CHUNK):
        scene = _Scene.project(
            joints[start : start + _CHUNK], look_at[start : start + _CHUNK], skeleton, camera
        )
        for t in range(start, start + len(scene.pixels)):
            yield _draw(
                base.copy(), scene, t - start, f"frame {t + 1}/{frames}   {t / fps:.2f} s", font
            )


_CHUNK = 256  # frames projected at a time: vectorised, yet memory does not grow with the clip


@dataclass(frozen=True)
class _Scene:
    """What some frames are drawn from, projected to pixels."""

    bones: list[tuple[int, int]]  # (parent, child)
    bone_colours: list[int]
    pixels: np.ndarray  # (T, J, 2)
    shadow_pixels: np.ndarray  # (T, J, 2)
    bone_depth: np.ndarray  # (T, B)
    grid_pixels: np.ndarray  # (T, lines, ends, xy)

    @classmethod
    def project(
        cls, joints: np.ndarray, look_at: np.ndarray, skeleton: Skeleton, camera: Camera
    ) -> _Scene:
        project = _projector(camera, look_at)  # (T, ..., 3) world -> (T, ..., 2) pixels, depth
        bones = [(int(p), j) for j, p in enumerate(skeleton.parents) if p >= 0]
        parents, children = np.array(bones).T
        pixels, depth = project(joints)  # (T, J, 2), (T, J)
        shadow = joints.copy()
        shadow[..., 1] = 0.0
        grid_pixels, _ = project(_grid_lines(look_at, camera).reshape(len(joints), -1, 3))
        return cls(
            bones,
            _bone_colours(skeleton, bones),
            pixels,
            project(shadow)[0],
            depth[:, parents] + depth[:, children],
            grid_pixels.reshape(len(joints), -1, 2, 2),
        )


def _draw(
    image: Image.Image, scene: _Scene, t: int, label: str, font: ImageFont.FreeTypeFont
) -> Image.Image:
    """Frame t drawn over the background image (caption included)."""
    draw = ImageDraw.Draw(image)
    for a, b in scene.grid_pixels[t]:
        draw.line([tuple(a), tuple(b)], fill=GRID, width=1)
    shadow, pixels = scene.shadow_pixels[t], scene.pixels[t]
    for p, c in scene.bones:
        draw.line([tuple(shadow[p]), tuple(shadow[c])], fill=SHADOW, width=3)
    for k in np.argsort(-scene.bone_depth[t]):  # far bones first, near ones drawn over them
        p, c = scene.bones[k]
        draw.line([tuple(pixels[p]), tuple(pixels[c])], fill=scene.bone_colours[k], width=4)
    for x, y in pixels:
        draw.ellipse([x - 2.5, y - 2.5, x + 2.5, y + 2.5], fill=TEXT)
    draw.text((8, image.size[1] - 20), label, fill=TEXT, font=font)
    return image


def save_gif(
    joints: np.ndarray,
    path: str | Path,
    caption: str = "",
    fps: float | None = None,
    skeleton: Skeleton | None = None,
    camera: Camera = Camera(),
) -> Path:
    """Write a looping stick-figure GIF of `joints` (T, J, 3) with one GIF frame per frame,
    frame by frame: the memory of a few images, whatever the clip's length."""
    joints = np.asarray(joints, dtype=np.float64)
    fps = _check_joints(joints, skeleton).fps if fps is None else fps
    images = iter_frames(joints, caption, fps, skeleton, camera)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as file:
        write_gif(file, images, 1000.0 / fps)
    return path


def write_gif(file: BinaryIO, images: Iterator[Image.Image], duration_ms: float) -> None:
    """A looping GIF of palette images that share one palette, written as they come (Pillow's
    own save_all holds every frame until the end). As Pillow writes them, each frame after
    the first is only the rectangle that changed; the frame counter changes every frame, so
    no frame is ever empty."""
    first = next(images)
    header, _ = GifImagePlugin.getheader(first, info=dict(loop=0, duration=duration_ms))
    file.writelines(header)
    previous = None
    for image in itertools.chain([first], images):
        box = (
            (0, 0, *image.size)
            if previous is None
            else ImageChops.subtract_modulo(image, previous).getbbox() or (0, 0, 1, 1)
        )
        file.writelines(
            GifImagePlugin.getdata(image.crop(box), offset=box[:2], duration=duration_ms)
        )
        previous = image
    file.write(b";")


def _check_joints(joints: np.ndarray, skeleton: Skeleton | None) -> Skeleton:
    if joints.ndim != 3 or joints.shape[-1] != 3 or joints.shape[0] < 1:
        raise ValueError(f"joints must be (T, J, 3) with T >= 1, got shape {joints.shape}")
    skeleton = skeleton or _skeleton_for_joints(joints.shape[1])
    skeleton.checked_joints(joints)
    return skeleton


def _skeleton_for_joints(num_joints: int) -> Skeleton:
    for skeleton in (SMPL_22, KIT_21):
        if skeleton.num_joints == num_joints:
            return skeleton
    raise ValueError(
        f"cannot infer a skeleton for {num_joints} joints; known: "
        f"{SMPL_22.num_joints} ({SMPL_22.name}), {KIT_21.num_joints} ({KIT_21.name})"
    )


def _follow(xz: np.ndarray, frames_lag: float) -> np.ndarray:
    """Zero-lag smoothing (an exponential filter run forward, then backward) of (T, 2)."""
    alpha = 1.0 - math.exp(-1.0 / max(frames_lag, 1e-6))
    out = xz.copy()
    for t in range(1, len(out)):
        out[t] = out[t - 1] + alpha * (out[t] - out[t - 1])
    for t in range(len(out) - 2, -1, -1):
        out[t] = out[t + 1] + alpha * (out[t] - out[t + 1])
    return out


def _projector(camera: Camera, look_at: np.ndarray):
    """Perspective projection for a camera at a fixed direction from a moving look-at point."""
    az, el = math.radians(camera.azimuth_deg), math.radians(camera.elevation_deg)
    back = np.array([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])
    forward = -back
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    eye = look_at + camera.distance * back  # (T, 3)
    centre = np.array([camera.size / 2, camera.centre_y])

    def project(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """points (T, N, 3) -> pixels (T, N, 2), depth (T, N)."""
        rel = points - eye[:, None]
        depth = np.maximum(rel @ forward, 1e-3)
        xy = np.stack([rel @ right, -(rel @ up)], axis=-1) / depth[..., None]
        return centre + camera.focal * xy, depth

    return project


def _grid_lines(look_at: np.ndarray, camera: Camera) -> np.ndarray:
    """World-fixed floor lines every grid_step metres, spanning a square of about
    grid_radius around each frame's look-at point: (T, lines, 2 ends, 3)."""
    step = camera.grid_step
    half = math.ceil(camera.grid_radius / step)
    offsets = step * np.arange(-half, half + 1)  # (N,)
    snapped = np.floor(look_at[:, [0, 2]] / step) * step  # (T, 2): nearest line at or below
    across = np.stack([-half * step, half * step])  # the two ends of each line
    frames, n = len(look_at), len(offsets)
    lines = np.zeros((frames, 2, n, 2, 3))
    lines[:, 0, :, :, 0] = (snapped[:, 0, None] + offsets)[:, :, None]  # lines along Z
    lines[:, 0, :, :, 2] = snapped[:, 1, None, None] + across
    lines[:, 1, :, :, 2] = (snapped[:, 1, None] + offsets)[:, :, None]  # lines along X
    lines[:, 1, :, :, 0] = snapped[:, 0, None, None] + across
    return lines.reshape(frames, 2 * n, 2, 3)


def _bone_colours(skeleton: Skeleton, bones: list[tuple[int, int]]) -> list[int]:
    """Left limbs blue, right limbs red, the rest neutral, by the name of each bone's child."""
    colours = []
    for _, child in bones:
        name = skeleton.joint_names[child]
        colours.append(
            LEFT if name.startswith("left_") else RIGHT if name.startswith("right_") else SPINE
        )
    return colours


def _wrap(text: str, font: ImageFont.FreeTypeFont, width_px: int, max_lines: int) -> list[str]:
    """Wrap to lines that fit `width_px`, ending with an ellipsis if it needs more lines.
    Only the text that can show is measured (no glyph is narrower than a pixel), and the
    search for the line length starts at the font's average, so any caption wraps at once."""
    text = " ".join(text.split())
    if not text:
        return []
    shown = text[: (max_lines + 1) * max(int(width_px), 1)]
    average = max(font.getlength(shown), 1.0) / len(shown)
    chars = min(len(shown), max(8, int(width_px / average)))
    while chars > 8 and max(map(font.getlength, textwrap.wrap(shown, chars))) > width_px:
        chars -= 1
    lines = textwrap.wrap(shown, chars)
    if len(lines) > max_lines or len(shown) < len(text):
        lines = lines[:max_lines]
        lines[-1] = textwrap.shorten(lines[-1] + " ...", chars, placeholder=" ...")
    return lines
