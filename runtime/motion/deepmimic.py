"""DeepMimic motion files (the humanoid3d clips pybullet ships) -> our 22 joints, numpy only.

A file is JSON, {"Frames": [[...], ...]} with 44 numbers a frame: duration, root xyz, root
quaternion, then per joint its rotation in its parent's frame: chest, neck, right hip, right
knee, right ankle, right shoulder, right elbow, left hip, left knee, left ankle, left shoulder,
left elbow; quaternions w x y z, knees and elbows one angle about their Z axis. Y up, metres,
the body facing +X (its left is -Z). Forward kinematics on the DeepMimic humanoid's bones gives
hips, knees, ankles, chest, neck, shoulders, elbows and wrists (a fixed point at the
end of the forearm). What that humanoid lacks is a fixed point of the body part it belongs to:
- pelvis 7 cm above the root (root frame): DeepMimic's root is the centre of its hip joints,
  SMPL's pelvis joint sits 7 cm above the hips, and the shipped model has only seen SMPL's
  geometry (docs/real_motion.md: what the root itself as the pelvis costs);
- spine1 halfway from the pelvis to the chest joint (root frame); spine2 the chest joint;
  spine3 a quarter of the way from the chest joint to the neck (chest frame), as the CMU map
  of mogo.motion.rigs places it: close to SMPL's spacing;
- head 10 cm above the neck joint and 2 cm forward (neck frame);
- collars 21.5 cm above the chest joint, 7.5 cm to the side, 1 cm back (chest frame): between
  the neck's base and the shoulder, a little below the shoulder as in SMPL;
- toes (left_foot, right_foot) at the ball of the foot, 12 cm forward of the ankle and 3.5 cm
  down (ankle frame), near the front of DeepMimic's foot box.
No wrist, head or toe rotation exists in the file: those points move rigidly with their part.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mogo.motion.quaternion import qnormalize, qto_matrix
from mogo.motion.skeleton import SMPL_22
from mogo.motion.untrusted import checked_finite, parse_json

VALUES_PER_FRAME = 44
# the humanoid's joints: parent and offset in the parent's frame (metres), parents first
_BONES = {
    "root": (None, (0.0, 0.0, 0.0)),
    "chest": ("root", (0.0, 0.236151, 0.0)),
    "neck": ("chest", (0.0, 0.223894, 0.0)),
    "right_hip": ("root", (0.0, 0.0, 0.084887)),
    "right_knee": ("right_hip", (0.0, -0.421546, 0.0)),
    "right_ankle": ("right_knee", (0.0, -0.409870, 0.0)),
    "right_shoulder": ("chest", (-0.02405, 0.24350, 0.18311)),
    "right_elbow": ("right_shoulder", (0.0, -0.274788, 0.0)),
    "left_hip": ("root", (0.0, 0.0, -0.084887)),
    "left_knee": ("left_hip", (0.0, -0.421546, 0.0)),
    "left_ankle": ("left_knee", (0.0, -0.409870, 0.0)),
    "left_shoulder": ("chest", (-0.02405, 0.24350, -0.18311)),
    "left_elbow": ("left_shoulder", (0.0, -0.274788, 0.0)),
}
# the file's rotations after the root's, in order: (joint, 4 for a quaternion, 1 for an angle)
_LAYOUT = (
    ("chest", 4),
    ("neck", 4),
    ("right_hip", 4),
    ("right_knee", 1),
    ("right_ankle", 4),
    ("right_shoulder", 4),
    ("right_elbow", 1),
    ("left_hip", 4),
    ("left_knee", 1),
    ("left_ankle", 4),
    ("left_shoulder", 4),
    ("left_elbow", 1),
)
# each of our joints: the humanoid's part it moves with and its place in that part's frame
_POINTS = {
    "pelvis": ("root", (0, 0.07, 0)),
    "spine1": ("root", (0, (0.07 + 0.236151) / 2, 0)),
    "spine2": ("chest", (0, 0, 0)),
    "spine3": ("chest", (0, 0.25 * 0.223894, 0)),
    "neck": ("neck", (0, 0, 0)),
    "head": ("neck", (0.02, 0.10, 0)),
    "left_collar": ("chest", (-0.01, 0.215, -0.075)),
    "right_collar": ("chest", (-0.01, 0.215, 0.075)),
    "left_wrist": ("left_elbow", (0, -0.258947, 0)),
    "right_wrist": ("right_elbow", (0, -0.258947, 0)),
    "left_foot": ("left_ankle", (0.12, -0.035, 0)),
    "right_foot": ("right_ankle", (0.12, -0.035, 0)),
}


def is_deepmimic(text: str) -> bool:
    """Whether a file's text looks like a DeepMimic motion (a JSON object with "Frames")."""
    return text.lstrip().startswith("{") and '"Frames"' in text[:4096]


def read_deepmimic(text: str, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Joints (T, 22, 3) in metres, Y up, and the times (T,) of the frames of a DeepMimic
    file's text (not always evenly spaced: frames last as long as their first number says);
    ValueError, one line naming the file, for what is not such a file."""
    document = parse_json(text, str(path))
    rows = document.get("Frames") if isinstance(document, dict) else None
    if (
        not isinstance(rows, list)
        or len(rows) < 2
        or not all(
            isinstance(row, list)
            and len(row) == VALUES_PER_FRAME
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)
            for row in rows
        )
    ):
        raise ValueError(
            f'{path}: not a DeepMimic motion file: "Frames" must be a list of at '
            f"least 2 rows of {VALUES_PER_FRAME} numbers (humanoid3d)"
        )
    frames = np.array([[_finite_or_inf(v) for v in row] for row in rows], dtype=np.float64)
    checked_finite(frames, str(path))
    durations = frames[:-1, 0]  # the last frame's duration is often 0: nothing follows it
    if np.any(durations <= 0):
        raise ValueError(f"{path}: frame durations must be positive, got {durations.min():g} s")
    rotations, positions = _forward_kinematics(frames)
    joints = np.zeros((len(frames), SMPL_22.num_joints, 3))
    for k, name in enumerate(SMPL_22.joint_names):
        part, offset = _POINTS.get(name, (name, (0, 0, 0)))
        joints[:, k] = positions[part] + rotations[part] @ np.array(offset, dtype=np.float64)
    return joints, np.concatenate([[0.0], np.cumsum(durations)])


def _finite_or_inf(value: int | float) -> float:
    """A JSON number as a float; an integer too large for one as infinity (refused)."""
    try:
        return float(value)
    except OverflowError:
        return math.inf


def _forward_kinematics(frames: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """World rotations (T, 3, 3) and positions (T, 3) of every part of the humanoid."""
    local = {"root": qto_matrix(qnormalize(frames[:, 4:8]))}
    column = 8
    for joint, width in _LAYOUT:
        values = frames[:, column : column + width]
        column += width
        if width == 1:  # a hinge about Z
            half = 0.5 * values[:, 0]
            values = np.stack([np.cos(half), 0 * half, 0 * half, np.sin(half)], axis=-1)
        local[joint] = qto_matrix(qnormalize(values))
    rotations, positions = {}, {}
    for joint, (parent, offset) in _BONES.items():
        if parent is None:
            rotations[joint], positions[joint] = local[joint], frames[:, 1:4]
        else:
            rotations[joint] = rotations[parent] @ local[joint]
            positions[joint] = positions[parent] + rotations[parent] @ np.array(offset)
    return rotations, positions
