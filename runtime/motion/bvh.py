"""BVH export of joint-position clips (mogo.motion.mocap reads BVH files).

A BVH stores a rest skeleton (offsets) and per-frame local joint rotations, which is what
Blender, Unity and Unreal retarget from. The file's skeleton is mogo.motion.rig's: one rigid
character for every clip of a bundle, a clean T-pose at zero rotation, feet on the floor, with
rotations solved from the clip's joints (twist included; head, hands and toes derived). Each
joint is named for the bone it moves: Mixamo/Unity names by default (Hips, LeftUpLeg, LeftArm,
...: a name-matching retargeter lines the chains up bone for bone), or the SMPL joint names.
Generated bones stretch by centimetres while a rigid bone cannot, so forward kinematics of the
file is off the clip's joints by that much (docs/bvh.md); `bone_translations=True` also writes
every joint's per-frame offset as position channels, which gives the joints back exactly, for
tools that read position channels on every joint (Blender does; retargeting keeps only the
rotations). Euler angles stay continuous from frame to frame (whole turns, and the equivalent
triple past X = 90 degrees), so a spin or a somersault interpolates cleanly.
"""

from __future__ import annotations

import math
import os
import reprlib
from numbers import Real
from pathlib import Path

import numpy as np

from mogo.motion import rig, rigs
from mogo.motion.skeleton import SMPL_22, Skeleton

EULER_ORDER = "ZXY"  # channel order in the file: R = Rz @ Rx @ Ry
_GIMBAL = 1e-6
UNITS = {"m": 1.0, "cm": 100.0}  # the file's length unit -> its scale from metres
MAX_SCALE = 1e4  # beyond, a person's offsets lose their precision in the file's digits
# Joint names in the file: each SMPL_22 joint named for the bone it moves (Mixamo/Unity), or
# its SMPL name. The first is the default.
NAMINGS = {
    "mixamo": tuple(rigs.RIGS["Mixamo"][name] for name in SMPL_22.joint_names),
    "smpl": SMPL_22.joint_names,
}


def save_bvh(
    path: str | os.PathLike,
    joints: np.ndarray,
    skeleton: Skeleton,
    fps: float,
    scale: float = 1.0,
    bone_translations: bool = False,
    naming: str = "mixamo",
) -> None:
    """Write joints (T, J, 3) in metres (Y up) as a BVH of the rig; `scale` multiplies every
    length (1 = metres, which Blender imports at its default scale; 100 = centimetres; see
    UNITS); `bone_translations`: position channels on every joint too (see the module doc);
    `naming`: a key of NAMINGS."""
    joints = rig.checked_joints(joints, skeleton, fps)
    check_options(scale, bone_translations, naming)
    names = joint_names(naming)
    offsets = rig.rest_offsets(skeleton)
    world = rig.world_rotations(joints, skeleton, offsets)
    angles = np.degrees(_continuous(_matrix_to_zxy(rig.local_rotations(world, skeleton))))
    parents = skeleton.parents
    bones = np.zeros_like(joints)  # (T, J, 3) each bone in its parent's frame, per frame
    for child in range(1, skeleton.num_joints):
        parent = parents[child]
        bones[:, child] = np.einsum(
            "tji,tj->ti", world[:, parent], joints[:, child] - joints[:, parent]
        )
    bones[:, 0] = joints[:, 0]  # the root's position channels: where it is

    lines = ["HIERARCHY"]
    _write_joint(
        lines,
        skeleton,
        names,
        0,
        offsets * scale,
        rig.end_sites(skeleton, offsets * scale),
        depth=0,
        translations=bone_translations,
    )
    lines += ["MOTION", f"Frames: {len(joints)}", f"Frame Time: {1.0 / fps:.8f}"]
    columns = [
        np.concatenate([bones[:, j] * scale, angles[:, j]], axis=1)
        if j == 0 or bone_translations
        else angles[:, j]
        for j in rig.depth_first(skeleton)
    ]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in np.concatenate(columns, axis=1)]
    Path(path).write_text("\n".join(lines) + "\n")


def check_options(scale: object, bone_translations: object, naming: object) -> None:
    """save_bvh's options, each a TypeError or ValueError naming it (Motion.save_take checks
    them before any file is written)."""
    if isinstance(scale, bool) or not isinstance(scale, Real):
        raise TypeError(f"scale must be a number, got {type(scale).__name__}")
    if not (math.isfinite(scale) and 0 < scale <= MAX_SCALE):
        raise ValueError(f"scale must be a positive number up to {MAX_SCALE:g}, got {scale!r}")
    if not isinstance(bone_translations, (bool, np.bool_)):
        raise TypeError(
            f"bone_translations must be True or False, got {type(bone_translations).__name__}"
        )
    joint_names(naming)


def joint_names(naming: object) -> tuple[str, ...]:
    """The joint names of a naming (a key of NAMINGS), or a ValueError naming the choices."""
    if not isinstance(naming, str) or naming not in NAMINGS:
        raise ValueError(f"naming must be one of {', '.join(NAMINGS)}, got {reprlib.repr(naming)}")
    return NAMINGS[naming]


def _write_joint(
    lines: list[str],
    skeleton: Skeleton,
    names: tuple[str, ...],
    joint: int,
    offsets: np.ndarray,
    tips: dict[int, np.ndarray],
    depth: int,
    translations: bool,
) -> None:
    pad = "  " * depth
    kind = "ROOT" if depth == 0 else "JOINT"
    lines += [
        f"{pad}{kind} {names[joint]}",
        f"{pad}{{",
        f"{pad}  OFFSET {offsets[joint, 0]:.6f} {offsets[joint, 1]:.6f} {offsets[joint, 2]:.6f}",
    ]
    rotation_channels = " ".join(f"{axis}rotation" for axis in EULER_ORDER)
    if depth == 0 or translations:
        lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition {rotation_channels}")
    else:
        lines.append(f"{pad}  CHANNELS 3 {rotation_channels}")
    kids = [c for c in range(skeleton.num_joints) if skeleton.parents[c] == joint]
    for child in kids:
        _write_joint(lines, skeleton, names, child, offsets, tips, depth + 1, translations)
    if not kids:
        tip = tips[joint]
        lines += [
            f"{pad}  End Site",
            f"{pad}  {{",
            f"{pad}    OFFSET {tip[0]:.6f} {tip[1]:.6f} {tip[2]:.6f}",
            f"{pad}  }}",
        ]
    lines.append(f"{pad}}}")


def _continuous(angles: np.ndarray) -> np.ndarray:
    """Euler angles (T, J, 3) made continuous over frames, so tools can interpolate them: of
    the two triples that give each rotation, (z, x, y) and (z + pi, pi - x, y + pi), the one
    nearest the previous frame, then unwrapped (whole turns added) frame to frame."""
    z, x, y = np.moveaxis(angles, -1, 0)
    alternate = np.stack([z + np.pi, np.pi - x, y + np.pi], axis=-1)
    chosen = angles.copy()
    for t in range(1, len(angles)):
        steps = [
            np.abs((c[t] - chosen[t - 1] + np.pi) % (2 * np.pi) - np.pi).sum(-1)
            for c in (angles, alternate)
        ]
        chosen[t] = np.where((steps[1] < steps[0])[:, None], alternate[t], angles[t])
    return np.unwrap(chosen, axis=0)


def _matrix_to_zxy(m: np.ndarray) -> np.ndarray:
    """Euler angles (..., 3) radians, ordered (z, x, y), with m = Rz @ Rx @ Ry."""
    x = np.arcsin(np.clip(m[..., 2, 1], -1.0, 1.0))
    locked = np.abs(np.cos(x)) < _GIMBAL
    z = np.where(
        locked, np.arctan2(m[..., 1, 0], m[..., 0, 0]), np.arctan2(-m[..., 0, 1], m[..., 1, 1])
    )
    y = np.where(locked, 0.0, np.arctan2(-m[..., 2, 0], m[..., 2, 2]))
    return np.stack([z, x, y], axis=-1)
