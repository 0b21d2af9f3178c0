"""Reading motion capture: BVH files into joint positions, numpy only."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class BvhClip:
    """A BVH read back: joint names in file order, positions (T, J, 3) in file units, fps."""
    names: tuple[str, ...]
    positions: np.ndarray
    fps: float


def read_bvh(path: str | os.PathLike) -> BvhClip:
    """Read a BVH (any channel order) and run forward kinematics: joint positions per frame."""
    path = Path(path)
    tokens = path.read_text().split()
    if not tokens or tokens[0] != "HIERARCHY":
        raise ValueError(f"{path}: not a BVH file (no HIERARCHY)")
    names, parents, offsets, channels = [], [], [], []
    stack: list[int] = []
    i, end_site = 1, False
    while tokens[i] != "MOTION":
        word = tokens[i]
        if word in ("ROOT", "JOINT"):
            names.append(tokens[i + 1])
            parents.append(stack[-1] if stack else -1)
            i += 2
        elif word == "End":
            end_site, i = True, i + 2
        elif word == "{":
            stack.append(-2 if end_site else len(names) - 1)
            i += 1
        elif word == "}":
            end_site = False
            stack.pop()
            i += 1
        elif word == "OFFSET":
            if stack[-1] != -2:
                offsets.append([float(v) for v in tokens[i + 1:i + 4]])
            i += 4
        elif word == "CHANNELS":
            count = int(tokens[i + 1])
            channels.append(tokens[i + 2:i + 2 + count])
            i += 2 + count
        else:
            raise ValueError(f"{path}: unexpected word {word!r} in the hierarchy")
    frames = int(tokens[i + 2])
    frame_time = float(tokens[i + 5])
    values = np.array(tokens[i + 6:], dtype=np.float64)
    width = sum(len(c) for c in channels)
    if values.size != frames * width:
        raise ValueError(f"{path}: {values.size} motion values, expected {frames} x {width}")
    values = values.reshape(frames, width)

    positions = np.zeros((frames, len(names), 3))
    rotations = np.zeros((frames, len(names), 3, 3))
    column = 0
    for joint, (parent, joint_channels) in enumerate(zip(parents, channels)):
        translation = np.tile(np.array(offsets[joint]), (frames, 1))
        local = np.tile(np.eye(3), (frames, 1, 1))
        for channel in joint_channels:
            value = values[:, column]
            column += 1
            axis = "XYZ".index(channel[0])
            if channel.endswith("position"):
                translation[:, axis] = value
            else:
                local = local @ _axis_rotation(axis, np.radians(value))
        if parent < 0:
            positions[:, joint], rotations[:, joint] = translation, local
        else:
            positions[:, joint] = positions[:, parent] + np.einsum(
                "tij,tj->ti", rotations[:, parent], translation)
            rotations[:, joint] = rotations[:, parent] @ local
    return BvhClip(tuple(names), positions, 1.0 / frame_time)


def _axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices (T, 3, 3) about coordinate axis 0/1/2 by angles (T,) radians."""
    c, s = np.cos(angle), np.sin(angle)
    m = np.tile(np.eye(3), (len(angle), 1, 1))
    a, b = [(1, 2), (2, 0), (0, 1)][axis]
    m[:, a, a], m[:, a, b], m[:, b, a], m[:, b, b] = c, -s, s, c
    return m
