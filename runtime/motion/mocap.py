"""Motion capture in: BVH and DeepMimic files -> our 22 joints in metres, Y up, numpy only.

BVH as found in the wild: any channel and Euler order, position channels on the root or on
every joint, any rig whose joint names a map of mogo.motion.rigs (or a mapping file) finds.
What a BVH does not state is detected from its rest pose (the hierarchy's offsets, a standing
pose in every rig) and said in MocapClip.description: the length unit, from the body's size
(ankle to head along the bones, about 1.5 m for an adult), and the up axis, the one the head is
farthest along from the ankles. DeepMimic files: mogo.motion.deepmimic.

Files may be hostile (docs/security.md): every size is bounded before anything is allocated
(MAX_SECONDS of motion, MAX_FRAMES frames, mogo.motion.untrusted's limit on a file's bytes),
and each problem is one ValueError line naming the file.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mogo.motion import rigs, untrusted
from mogo.motion.deepmimic import is_deepmimic, read_deepmimic
from mogo.motion.skeleton import SMPL_22, Skeleton

# a person's ankle-to-head length along the bones, metres (about 1.5 for 1.7 m tall)
BODY_LENGTH_RANGE = (0.5, 2.5)
ADULT_BODY_LENGTH = 1.5
UNITS = (
    ("metres", 1.0),
    ("centimetres", 100.0),
    ("millimetres", 1000.0),
    ("inches", 1 / 0.0254),
    ("feet", 1 / 0.3048),
    ("CMU units (1/0.45 inch)", 0.45 / 0.0254),
)  # the CMU database's BVH conversions
_AXES = ("X", "Y", "Z")
MAX_SECONDS = 3600.0  # of motion in a clip read in
MAX_FRAMES = 500_000  # in a clip file, and after resampling (about an hour at 120 fps)
MIN_FRAME_TIME = 1e-4  # seconds: 10,000 fps
MAX_COORDINATE = 1e4  # metres; beyond, float32 features lose the millimetre
_CHANNEL_NAMES = {f"{axis}{kind}" for axis in _AXES for kind in ("position", "rotation")}


@dataclass(frozen=True)
class BvhClip:
    """A BVH read back: joint names in file order, their parents (-1 for the root), rest
    offsets (J, 3), positions (T, J, 3) by forward kinematics, all in file units; fps."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    positions: np.ndarray
    fps: float


@dataclass(frozen=True)
class MocapClip:
    """A motion-capture file as our 22 joints (T, 22, 3) in metres, Y up, at its own frame
    rate; `description` says what was found (format, naming, unit, up axis, rate)."""

    joints: np.ndarray
    fps: float
    description: str


def read_mocap(path: str | os.PathLike, mapping: dict[str, rigs.Source] | None = None) -> MocapClip:
    """A BVH or DeepMimic file (told apart by their text) as our 22 joints; `mapping`: a rig
    map (mogo.motion.rigs.read_mapping) for BVH joint names no built-in map knows.
    ValueError, one line naming the file, for what cannot be read or mapped."""
    path = Path(path)
    text = untrusted.read_text(path, "motion-capture file")
    with np.errstate(all="ignore"):  # huge values: refused below as not finite, not warned
        if is_deepmimic(text):
            joints, times = read_deepmimic(text, path)
            steps = np.diff(times)
            fps = 1.0 / float(np.median(steps))
            rate = f"{fps:.4g} fps"
            check_length(path, int(times[-1] * fps) + 1, fps)
            if np.ptp(steps) > 0.01 * steps.min():  # keyframes unevenly spaced: evened out
                joints = _interpolate(joints, times, np.arange(0.0, times[-1] + 1e-9, 1.0 / fps))
                rate = f"uneven frame times ({steps.min():.4g} to {steps.max():.4g} s), {rate}"
            clip = MocapClip(joints, fps, f"DeepMimic humanoid, metres, Y up, {rate}")
        else:
            bvh = _parse_bvh(text, path)
            naming, sources = rigs.resolve(bvh.names, mapping, str(path))
            rest = _points(_rest_positions(bvh)[None], sources)[0]
            unit, factor = _unit(rest, path)
            up, turn = _up_axis(rest)
            clip = MocapClip(
                _points(bvh.positions, sources) @ turn.T / factor,
                bvh.fps,
                f"BVH, {naming} naming, {unit}, {up} up, {bvh.fps:.4g} fps",
            )
    check_coordinates(path, clip.joints)
    return clip


def check_coordinates(path: str | os.PathLike, joints: np.ndarray) -> None:
    """A ValueError naming the file unless joints (metres) are finite and within
    MAX_COORDINATE of the origin."""
    untrusted.checked_finite(
        joints, str(path), why=" (numbers too large, or a rotation of all zeros)"
    )
    if np.abs(joints).max() > MAX_COORDINATE:
        raise ValueError(
            f"{path}: coordinates up to {np.abs(joints).max():.3g}; joints are "
            f"metres, within {MAX_COORDINATE:g} m of the origin"
        )


def check_length(path: str | os.PathLike, frames: int, fps: float) -> None:
    """A ValueError naming the file where a clip of `frames` at `fps` is longer than
    MAX_SECONDS or MAX_FRAMES, or would be at 20 fps: checked before its arrays are made."""
    seconds = frames / fps
    if frames > MAX_FRAMES or seconds > MAX_SECONDS or seconds * SMPL_22.fps > MAX_FRAMES:
        raise ValueError(
            f"{path}: {frames} frames at {fps:.4g} fps ({seconds:.4g} s); clips "
            f"read in are at most {MAX_SECONDS:g} s and {MAX_FRAMES} frames"
        )


def read_bvh(path: str | os.PathLike) -> BvhClip:
    """Read a BVH (any channel order) and run forward kinematics: joint positions per frame."""
    path = Path(path)
    return _parse_bvh(untrusted.read_text(path, "BVH file"), path)


def body_length(joints: np.ndarray, skeleton: Skeleton = SMPL_22) -> float:
    """The median over frames of the bone path ankle -> root -> head of joints (T, J, 3)."""
    bones = np.linalg.norm(joints[:, 1:] - joints[:, skeleton.parents[1:]], axis=-1)
    lengths = np.concatenate([np.zeros((len(joints), 1)), bones], axis=1)  # by child joint
    path_length = np.zeros(len(joints))
    for end in (skeleton.right_foot[0], skeleton.joint_names.index("head")):
        while end > 0:
            path_length += lengths[:, end]
            end = skeleton.parents[end]
    return float(np.median(path_length))


def resample(joints: np.ndarray, source_fps: float, target_fps: float) -> np.ndarray:
    """Linear resampling of a clip (T, J, 3) from one frame rate to another."""
    if source_fps <= 0:
        raise ValueError(f"source fps must be positive, got {source_fps}")
    if source_fps == target_fps:
        return joints
    duration = (joints.shape[0] - 1) / source_fps
    return _interpolate(
        joints,
        np.arange(joints.shape[0]) / source_fps,
        np.arange(0.0, duration + 1e-9, 1.0 / target_fps),
    )


def _interpolate(joints: np.ndarray, source_times: np.ndarray, times: np.ndarray) -> np.ndarray:
    """A clip (T, ...) keyed at source_times, linearly interpolated at times."""
    flat = joints.reshape(joints.shape[0], -1)
    columns = [np.interp(times, source_times, flat[:, k]) for k in range(flat.shape[1])]
    return np.stack(columns, axis=-1).reshape((len(times),) + joints.shape[1:])


def _points(positions: np.ndarray, sources: list[tuple[int, int, float]]) -> np.ndarray:
    """Our 22 joints (T, 22, 3) from a rig's joints (T, J, 3): each a + f (b - a)."""
    a, b, f = (np.array(column) for column in zip(*sources, strict=False))
    return positions[:, a] + f[:, None] * (positions[:, b] - positions[:, a])


def _unit(rest: np.ndarray, path: Path) -> tuple[str, float]:
    """The unit (name, units per metre) that gives the rest body a person's size, the nearest
    to an adult's when several do; unknown units are scaled to an adult, and said so."""
    body = body_length(rest[None])
    low, high = BODY_LENGTH_RANGE
    fits = [
        (abs(math.log(body / factor / ADULT_BODY_LENGTH)), name, factor)
        for name, factor in UNITS
        if body > 0 and low <= body / factor <= high
    ]
    if fits:
        return min(fits)[1:]
    if body <= 0:
        raise ValueError(f"{path}: the rest skeleton has no size (all offsets zero)")
    factor = body / ADULT_BODY_LENGTH
    return f"unknown unit (a body of {body:.3g}, scaled to {ADULT_BODY_LENGTH:g} m)", factor


def _up_axis(rest: np.ndarray) -> tuple[str, np.ndarray]:
    """The axis the head is farthest along from the ankles in the rest pose (e.g. "Z"), and
    the rotation (3, 3) that turns it to +Y."""
    names = SMPL_22.joint_names
    rise = rest[names.index("head")] - 0.5 * (
        rest[names.index("left_ankle")] + rest[names.index("right_ankle")]
    )
    axis = int(np.argmax(np.abs(rise)))
    sign = 1.0 if rise[axis] >= 0 else -1.0
    up = np.zeros(3)
    up[axis] = sign
    target = np.array([0.0, 1.0, 0.0])
    if axis == 1:
        turn = np.eye(3) if sign > 0 else np.diag([1.0, -1.0, -1.0])  # a half turn about X
    else:  # a quarter turn about the axis perpendicular to both
        pivot = np.cross(up, target)
        turn = np.outer(target, up) - np.outer(up, target) + np.outer(pivot, pivot)
    return ("-" if sign < 0 else "") + _AXES[axis], turn


def _rest_positions(clip: BvhClip) -> np.ndarray:
    positions = np.zeros_like(clip.offsets)
    for joint, parent in enumerate(clip.parents):
        positions[joint] = clip.offsets[joint] + (positions[parent] if parent >= 0 else 0.0)
    return positions


def _parse_bvh(text: str, path: Path) -> BvhClip:
    tokens = text.split()
    if not tokens or tokens[0] != "HIERARCHY":
        raise ValueError(f"{path}: not a BVH file (no HIERARCHY) nor a DeepMimic motion")
    try:
        names, parents, offsets, channels, i = _hierarchy(tokens)
        if tokens[i : i + 2] != ["MOTION", "Frames:"] or tokens[i + 3 : i + 5] != [
            "Frame",
            "Time:",
        ]:
            raise _Unreadable("no MOTION section with Frames: and Frame Time:")
        frames, frame_time = _count(tokens[i + 2], "Frames:"), _number(tokens[i + 5])
        width = sum(len(c) for c in channels)
        if width == 0:
            raise _Unreadable("no joint has CHANNELS")
        if not frame_time >= MIN_FRAME_TIME:
            raise _Unreadable(
                f"Frame Time: must be at least {MIN_FRAME_TIME:g} s, got {tokens[i + 5][:20]}"
            )
        check_length(path, frames, 1.0 / frame_time)
        if frames < 1 or len(tokens) - (i + 6) != frames * width:
            raise ValueError(
                f"{path}: {len(tokens) - (i + 6)} motion values, expected "
                f"{frames} frames x {width} channels"
            )
        try:
            values = np.array(tokens[i + 6 :], dtype=np.float64)
        except ValueError:
            values = np.array([_number(value) for value in tokens[i + 6 :]])  # names the word
        if not np.all(np.isfinite(values)):
            raise _Unreadable("the motion values must be finite numbers")
    except IndexError:
        raise ValueError(f"{path}: not a readable BVH (the file ends too early)") from None
    except _Unreadable as error:
        raise ValueError(f"{path}: not a readable BVH ({error})") from None
    positions = _forward_kinematics(
        values.reshape(frames, width), parents, np.array(offsets), channels
    )
    return BvhClip(tuple(names), tuple(parents), np.array(offsets), positions, 1.0 / frame_time)


class _Unreadable(Exception):
    """What makes a BVH unreadable, said in a few words (the reader adds the file)."""


def _hierarchy(tokens: list[str]):
    """Names, parents, offsets, channels per joint, and the index of "MOTION"."""
    names, parents, offsets, channels = [], [], [], []
    stack: list[int] = []  # the joint of each open brace, _END_SITE for an End Site's
    i = 1
    while tokens[i] != "MOTION":
        word = tokens[i]
        inside = stack[-1] if stack else None
        if word in ("ROOT", "JOINT"):
            name, brace = _joint_name(tokens, i, inside)
            names.append(name)
            parents.append(-1 if inside is None else inside)
            offsets.append([0.0, 0.0, 0.0])
            channels.append([])
            stack.append(len(names) - 1)
            i = brace + 1
        elif word == "End":
            if inside in (None, _END_SITE) or tokens[i + 1 : i + 3] != ["Site", "{"]:
                raise _Unreadable("an End Site outside a joint or without its '{'")
            stack.append(_END_SITE)
            i += 3
        elif word == "}":
            if not stack:
                raise _Unreadable("a '}' closes no joint")
            stack.pop()
            i += 1
        elif word == "OFFSET":
            if inside is None:
                raise _Unreadable("an OFFSET outside any joint")
            offset = [_number(v) for v in tokens[i + 1 : i + 4]]
            if len(offset) != 3:
                raise IndexError
            if inside != _END_SITE:
                offsets[inside] = offset
            i += 4
        elif word == "CHANNELS":
            if inside in (None, _END_SITE):
                raise _Unreadable(
                    "CHANNELS in an End Site"
                    if inside == _END_SITE
                    else "CHANNELS outside any joint"
                )
            if channels[inside]:
                raise _Unreadable(f"two CHANNELS lines in joint {names[inside]}")
            channels[inside] = _joint_channels(tokens, i, names[inside])
            i += 2 + len(channels[inside])
        else:
            raise _Unreadable(f"unexpected word {word[:40]!r} in the hierarchy")
    if not names:
        raise _Unreadable("no joints")
    if stack:
        raise _Unreadable("a joint's '{' is never closed")
    return names, parents, offsets, channels, i


def _joint_name(tokens: list[str], i: int, inside: int | None) -> tuple[str, int]:
    """The name of the ROOT or JOINT at tokens[i] (it may hold spaces, "Bip01 L Thigh": all up
    to its "{"), and the index of that "{"."""
    word = tokens[i]
    if inside == _END_SITE or (word == "JOINT") != (inside is not None):
        raise _Unreadable(
            f"{word} {tokens[i + 1]} "
            + (
                "inside an End Site"
                if inside == _END_SITE
                else "outside any joint"
                if word == "JOINT"
                else "inside a joint"
            )
        )
    brace = i + 1
    while tokens[brace] not in ("{", "}", "MOTION"):
        brace += 1
    if tokens[brace] != "{" or brace == i + 1:
        raise _Unreadable(f"{word} without a name and a '{{'")
    return " ".join(tokens[i + 1 : brace]), brace


def _joint_channels(tokens: list[str], i: int, joint: str) -> list[str]:
    """The channels the CHANNELS line at tokens[i] gives `joint`: 1 to 6 known, different."""
    count = _count(tokens[i + 1], "CHANNELS")
    joint_channels = tokens[i + 2 : i + 2 + count]
    if not 1 <= count <= len(_CHANNEL_NAMES) or len(set(joint_channels)) != count:
        raise _Unreadable(
            f"CHANNELS {count} in joint {joint}: from 1 to {len(_CHANNEL_NAMES)} different channels"
        )
    if not set(joint_channels) <= _CHANNEL_NAMES:
        raise _Unreadable(f"unknown channel in {' '.join(joint_channels)}")
    return joint_channels


_END_SITE = -2


def _count(token: str, what: str) -> int:
    """A count of the file (`what`: its keyword): digits only, so never Python's own limit."""
    if not token.isascii() or not token.isdigit() or len(token) > 12:
        raise _Unreadable(f"{what} must be followed by a count, got {token[:20]!r}")
    return int(token)


def _number(token: str) -> float:
    """A finite number of the file."""
    try:
        value = float(token)
    except ValueError:
        raise _Unreadable(f"{token[:20]!r} is not a number") from None
    if not math.isfinite(value):
        raise _Unreadable(f"{token[:20]!r}: values must be finite numbers")
    return value


def _forward_kinematics(
    values: np.ndarray, parents: list[int], offsets: np.ndarray, channels: list[list[str]]
) -> np.ndarray:
    """Joint positions (T, J, 3): channels are applied in the order listed (R = R1 R2 R3); a
    joint's position channels replace its offset (the root's: where it is)."""
    frames = len(values)
    positions = np.zeros((frames, len(parents), 3))
    rotations = np.zeros((frames, len(parents), 3, 3))
    column = 0
    for joint, (parent, joint_channels) in enumerate(zip(parents, channels, strict=False)):
        translation = np.tile(offsets[joint], (frames, 1))
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
                "tij,tj->ti", rotations[:, parent], translation
            )
            rotations[:, joint] = rotations[:, parent] @ local
    return positions


def _axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices (T, 3, 3) about coordinate axis 0/1/2 by angles (T,) radians."""
    c, s = np.cos(angle), np.sin(angle)
    m = np.tile(np.eye(3), (len(angle), 1, 1))
    a, b = [(1, 2), (2, 0), (0, 1)][axis]
    m[:, a, a], m[:, a, b], m[:, b, a], m[:, b, b] = c, -s, s, c
    return m
