"""BVH export of joint-position clips (mogo.motion.mocap reads BVH files).

A BVH stores a rest skeleton (offsets) and per-frame local joint rotations, which is what
Blender, Unity and Unreal retarget from. Rotations are solved per frame from positions:
- a joint with several children (pelvis, upper spine) gets the rotation that best maps its
  rest child offsets onto the observed ones (Kabsch): a full 3D frame from the hips or the
  shoulders, so nothing flips when the character faces backwards;
- a joint with one child gets its parent's rotation followed by the shortest swing that turns
  the rest bone onto the observed bone, so twist follows the parent smoothly.
The rest pose is a T-pose (arms out to the sides), which keeps every common pose far from
the 180-degree swing where a shortest arc is undefined. Rest offsets are the bone vectors
averaged over the clip in their parent's frame, so forward kinematics of the file gives the
positions back up to the clip's own bone-length jitter. Generated motion has such jitter
(bones that stretch by a few cm): `bone_translations=True` also writes every joint's
per-frame offset as position channels, which gives the positions back exactly, for tools
that read position channels on every joint (Blender does; retargeting to a rig keeps only
the rotations). Euler angles stay continuous from frame to frame (whole turns, and the
equivalent triple past X = 90 degrees), so a spin or a somersault interpolates cleanly.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from mogo.motion.quaternion import qbetween, qto_matrix
from mogo.motion.skeleton import Skeleton

EULER_ORDER = "ZXY"  # channel order in the file: R = Rz @ Rx @ Ry
_GIMBAL = 1e-6
_END_SITE_FRACTION = 0.25  # a leaf's end site: this fraction of its bone, continued


def save_bvh(path: str | os.PathLike, joints: np.ndarray, skeleton: Skeleton, fps: float,
             scale: float = 1.0, bone_translations: bool = False) -> None:
    """Write joints (T, J, 3) in metres (Y up) as a BVH; `scale` multiplies every length
    (1 = metres, which Blender imports at its default scale; 100 = centimetres);
    `bone_translations`: position channels on every joint too (see the module doc)."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.num_joints, 3) or len(joints) < 1:
        raise ValueError(f"joints must be (T, {skeleton.num_joints}, 3) for the "
                         f"{skeleton.name} skeleton, got shape {joints.shape}")
    if not np.all(np.isfinite(joints)):
        raise ValueError("joints contain NaN or infinite values")
    if fps <= 0 or scale <= 0:
        raise ValueError(f"fps and scale must be positive, got {fps} and {scale}")
    rotations = global_rotations(joints, skeleton)  # (T, J, 3, 3)
    parents = skeleton.parents
    bones = np.zeros_like(joints)  # (T, J, 3) each bone in its parent's frame, per frame
    for child in range(1, skeleton.num_joints):
        parent = parents[child]
        bones[:, child] = np.einsum("tji,tj->ti", rotations[:, parent],
                                    joints[:, child] - joints[:, parent])
    offsets = bones.mean(0)
    local = rotations.copy()
    for joint in range(1, skeleton.num_joints):
        local[:, joint] = np.swapaxes(rotations[:, parents[joint]], -1, -2) @ rotations[:, joint]
    angles = np.degrees(_continuous(_matrix_to_zxy(local)))  # (T, J, 3)

    lines = ["HIERARCHY"]
    _write_joint(lines, skeleton, 0, offsets * scale, depth=0, translations=bone_translations)
    lines += ["MOTION", f"Frames: {len(joints)}", f"Frame Time: {1.0 / fps:.8f}"]
    order = _depth_first(skeleton)
    bones[:, 0] = joints[:, 0]  # the root's position channels: where it is
    columns = [np.concatenate([bones[:, j] * scale, angles[:, j]], axis=1)
               if j == 0 or bone_translations else angles[:, j] for j in order]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in np.concatenate(columns, axis=1)]
    Path(path).write_text("\n".join(lines) + "\n")


def global_rotations(joints: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """World rotation matrices (T, J, 3, 3) of every joint's frame (see the module doc)."""
    frames, num_joints = joints.shape[:2]
    rest = rest_directions(skeleton)
    children = _children(skeleton)
    rotations = np.zeros((frames, num_joints, 3, 3))
    for joint in _depth_first(skeleton):
        parent = skeleton.parents[joint]
        parent_rotation = np.eye(3) if parent < 0 else rotations[:, parent]
        kids = children[joint]
        if len(kids) > 1:
            observed = joints[:, kids] - joints[:, joint, None]  # (T, C, 3)
            rotations[:, joint] = _kabsch(rest[kids], observed)
        elif len(kids) == 1:
            bone = joints[:, kids[0]] - joints[:, joint]
            if np.any(np.linalg.norm(bone, axis=-1) < 1e-9):
                raise ValueError(f"joint {skeleton.joint_names[joint]} coincides with its child")
            current = parent_rotation @ rest[kids[0]]
            rotations[:, joint] = qto_matrix(qbetween(current, bone)) @ parent_rotation
        else:
            rotations[:, joint] = parent_rotation
    return rotations


def rest_directions(skeleton: Skeleton) -> np.ndarray:
    """(J, 3) unit direction of each bone (parent -> joint) in the T-pose: the skeleton's
    own rest or raw offsets, with the bones past the shoulders turned out sideways."""
    offsets = skeleton.rest_offsets if skeleton.rest_offsets is not None else skeleton.raw_offsets
    directions = np.array(offsets, dtype=np.float64)
    for joint, name in enumerate(skeleton.joint_names):
        if name.endswith(("_elbow", "_wrist")):
            shoulder = skeleton.index(name.rsplit("_", 1)[0] + "_shoulder")
            side = np.sign(directions[shoulder, 0]) or (1.0 if name.startswith("left") else -1.0)
            directions[joint] = (side, 0.0, 0.0)
    norms = np.linalg.norm(directions, axis=-1, keepdims=True)
    return np.divide(directions, norms, out=np.zeros_like(directions), where=norms > 0)


def _write_joint(lines: list[str], skeleton: Skeleton, joint: int, offsets: np.ndarray,
                 depth: int, translations: bool) -> None:
    pad = "  " * depth
    kind = "ROOT" if depth == 0 else "JOINT"
    lines += [f"{pad}{kind} {skeleton.joint_names[joint]}", f"{pad}{{",
              f"{pad}  OFFSET {offsets[joint, 0]:.6f} {offsets[joint, 1]:.6f} "
              f"{offsets[joint, 2]:.6f}"]
    rotation_channels = " ".join(f"{axis}rotation" for axis in EULER_ORDER)
    if depth == 0 or translations:
        lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition {rotation_channels}")
    else:
        lines.append(f"{pad}  CHANNELS 3 {rotation_channels}")
    kids = _children(skeleton)[joint]
    for child in kids:
        _write_joint(lines, skeleton, child, offsets, depth + 1, translations)
    if not kids:
        tip = _END_SITE_FRACTION * offsets[joint]
        lines += [f"{pad}  End Site", f"{pad}  {{",
                  f"{pad}    OFFSET {tip[0]:.6f} {tip[1]:.6f} {tip[2]:.6f}", f"{pad}  }}"]
    lines.append(f"{pad}}}")


def _children(skeleton: Skeleton) -> list[list[int]]:
    parents = skeleton.parents
    return [[c for c in range(skeleton.num_joints) if parents[c] == j]
            for j in range(skeleton.num_joints)]


def _depth_first(skeleton: Skeleton) -> list[int]:
    """Joints in the order the hierarchy (and so each motion line) lists them."""
    children = _children(skeleton)
    order, stack = [], [0]
    while stack:
        joint = stack.pop()
        order.append(joint)
        stack.extend(reversed(children[joint]))
    return order


def _kabsch(rest: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Rotations (T, 3, 3) best taking rest vectors (C, 3) onto observed ones (T, C, 3)."""
    covariance = np.einsum("tci,cj->tij", observed, rest)  # (T, 3, 3)
    u, _, vt = np.linalg.svd(covariance)
    sign = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= sign[:, None]
    return u @ vt


def _continuous(angles: np.ndarray) -> np.ndarray:
    """Euler angles (T, J, 3) made continuous over frames, so tools can interpolate them: of
    the two triples that give each rotation, (z, x, y) and (z + pi, pi - x, y + pi), the one
    nearest the previous frame, then unwrapped (whole turns added) frame to frame."""
    alternate = angles + np.array([np.pi, 0.0, np.pi])
    alternate[..., 1] = np.pi - angles[..., 1]
    chosen = angles.copy()
    for t in range(1, len(angles)):
        steps = [np.abs((c[t] - chosen[t - 1] + np.pi) % (2 * np.pi) - np.pi).sum(-1)
                 for c in (angles, alternate)]
        chosen[t] = np.where((steps[1] < steps[0])[:, None], alternate[t], angles[t])
    return np.unwrap(chosen, axis=0)


def _matrix_to_zxy(m: np.ndarray) -> np.ndarray:
    """Euler angles (..., 3) radians, ordered (z, x, y), with m = Rz @ Rx @ Ry."""
    x = np.arcsin(np.clip(m[..., 2, 1], -1.0, 1.0))
    locked = np.abs(np.cos(x)) < _GIMBAL
    z = np.where(locked, np.arctan2(m[..., 1, 0], m[..., 0, 0]),
                 np.arctan2(-m[..., 0, 1], m[..., 1, 1]))
    y = np.where(locked, 0.0, np.arctan2(-m[..., 2, 0], m[..., 2, 2]))
    return np.stack([z, x, y], axis=-1)
