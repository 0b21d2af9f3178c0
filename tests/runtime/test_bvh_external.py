"""Our BVH files checked against what the format means, not against our own reader.

The only PyPI parser found (`bvh` 0.3) is unmaintained and has no stated licence, so this
file holds its own small reader: tokens -> hierarchy, then forward kinematics done the BVH
way (each joint's rotation is the product of its rotation channels in the order they are
listed, applied to the OFFSET or the position channels), frame by frame, with Rodrigues
matrices. Nothing here imports mogo.motion.bvh's reader or its rotation helpers.
"""
import numpy as np
import pytest

from mogo import MotionGenerator
from mogo.motion.bvh import save_bvh
from mogo.motion.quaternion import qfrom_axis_angle, qmul, qrot, qyaw
from mogo.motion.skeleton import SMPL_22

AXES = {"X": np.array([1.0, 0, 0]), "Y": np.array([0, 1.0, 0]), "Z": np.array([0, 0, 1.0])}


def _parse(text: str) -> tuple[list[dict], np.ndarray, float]:
    """Joints (name, parent, offset, channels) in file order, motion (T, C), frame time."""
    head, motion = text.split("MOTION")
    joints, stack, pending = [], [], None
    for line in head.splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] in ("ROOT", "JOINT"):
            pending = {"name": words[1], "parent": stack[-1] if stack else None}
        elif words[0] == "End":
            pending = "end"
        elif words[0] == "{":
            if isinstance(pending, dict):
                joints.append(pending)
                stack.append(len(joints) - 1)
            else:
                stack.append("end")
            pending = None
        elif words[0] == "}":
            stack.pop()
        elif words[0] == "OFFSET" and stack[-1] != "end":
            joints[stack[-1]]["offset"] = np.array(words[1:4], dtype=float)
        elif words[0] == "CHANNELS":
            joints[stack[-1]]["channels"] = words[2:2 + int(words[1])]
    lines = motion.strip().splitlines()
    frames, frame_time = int(lines[0].split(":")[1]), float(lines[1].split(":")[1])
    values = np.array([line.split() for line in lines[2:]], dtype=float)
    assert values.shape == (frames, sum(len(j["channels"]) for j in joints))
    return joints, values, frame_time


def _rotation(axis: str, degrees: float) -> np.ndarray:
    """Rodrigues: rotation by `degrees` about a coordinate axis (right-handed)."""
    k = AXES[axis]
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    angle = np.radians(degrees)
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def _forward_kinematics(joints: list[dict], row: np.ndarray) -> dict[str, np.ndarray]:
    """World position of every joint for one motion line."""
    world, column = {}, 0
    for index, joint in enumerate(joints):
        rotation, translation = np.eye(3), joint["offset"].copy()
        for channel in joint["channels"]:
            if channel.endswith("position"):
                translation["XYZ".index(channel[0])] = row[column]
            else:
                rotation = rotation @ _rotation(channel[0], row[column])
            column += 1
        parent = joint["parent"]
        if parent is None:
            world[index] = (translation, rotation)
        else:
            position, frame = world[parent]
            world[index] = (position + frame @ translation, frame @ rotation)
    return {joints[i]["name"]: world[i][0] for i in world}


def _clip(seed: int, swing_degrees: float, frames: int = 60, turns: float = 2.0) -> np.ndarray:
    """Rigid SMPL_22 motion: smooth random local swings, a root turning `turns` circles."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, frames)[:, None]
    axes = rng.normal(size=(22, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    angles = np.radians(swing_degrees) * np.sin(2 * np.pi * rng.uniform(1, 3, 22) * t
                                                + rng.uniform(0, 2 * np.pi, 22))
    local = qfrom_axis_angle(axes[None], angles)
    local[:, 0] = qmul(qyaw(2 * np.pi * turns * t[:, 0]), local[:, 0])
    return _pose(local, np.stack([np.sin(3 * t[:, 0]), 0.9 + 0 * t[:, 0], t[:, 0]], -1))


def _pose(local: np.ndarray, root: np.ndarray) -> np.ndarray:
    """Joints (T, 22, 3) from local quaternions (T, 22, 4) on the skeleton's rest offsets."""
    world = np.zeros_like(local)
    joints = np.zeros(local.shape[:2] + (3,))
    world[:, 0], joints[:, 0] = local[:, 0], root
    for j in range(1, 22):
        p = SMPL_22.parents[j]
        joints[:, j] = joints[:, p] + qrot(world[:, p], np.broadcast_to(
            SMPL_22.rest_offsets[j], joints[:, j].shape))
        world[:, j] = qmul(world[:, p], local[:, j])
    return joints


def _write(tmp_path, joints: np.ndarray, **options) -> tuple[list[dict], np.ndarray, float]:
    path = tmp_path / "clip.bvh"
    save_bvh(path, joints, SMPL_22, fps=20.0, **options)
    return _parse(path.read_text())


def _positions(parsed, scale: float = 1.0) -> np.ndarray:
    """FK of every frame, back in SMPL_22 joint order and metres."""
    joints, values, _ = parsed
    out = np.zeros((len(values), 22, 3))
    for t, row in enumerate(values):
        for name, position in _forward_kinematics(joints, row).items():
            out[t, SMPL_22.index(name)] = position / scale
    return out


def _rest(parsed) -> dict[str, np.ndarray]:
    """Rest-pose world positions: forward kinematics of the offsets alone."""
    joints = parsed[0]
    zero = [dict(j, channels=[]) for j in joints]
    return _forward_kinematics(zero, np.zeros(0))


def test_rest_pose_is_an_upright_t_pose_of_the_skeleton(tmp_path):
    parsed = _write(tmp_path, _clip(seed=0, swing_degrees=40.0))
    joints = parsed[0]
    assert [j["name"] for j in joints][0] == "pelvis" and len(joints) == 22
    offsets = {j["name"]: j["offset"] for j in joints}
    for name, offset in offsets.items():  # bone lengths: the skeleton's, within a millimetre
        expected = np.linalg.norm(SMPL_22.rest_offsets[SMPL_22.index(name)])
        assert abs(np.linalg.norm(offset) - expected) < 1e-3, name
    rest = _rest(parsed)
    assert rest["head"][1] > rest["neck"][1] > rest["spine3"][1] > rest["pelvis"][1]
    for side, sign in (("left", 1.0), ("right", -1.0)):  # skeleton.py: left_hip is +x
        for part in ("hip", "collar", "shoulder", "elbow", "wrist"):
            assert sign * (rest[f"{side}_{part}"][0] - rest["pelvis"][0]) > 0.05, (side, part)
        for part in ("elbow", "wrist"):  # arms straight out sideways, not inward or down
            direction = offsets[f"{side}_{part}"] / np.linalg.norm(offsets[f"{side}_{part}"])
            assert direction @ (sign * AXES["X"]) > 0.99, (side, part)
        assert rest[f"{side}_wrist"][0] * sign > rest[f"{side}_elbow"][0] * sign
        assert rest[f"{side}_ankle"][1] < rest[f"{side}_knee"][1] < rest["pelvis"][1]
        assert offsets[f"{side}_foot"][2] > 0.1  # toes forward (+z, the facing)


def test_forward_kinematics_of_the_file_gives_the_joints(tmp_path):
    joints = _clip(seed=1, swing_degrees=90.0)
    np.testing.assert_allclose(_positions(_write(tmp_path, joints)), joints, atol=1e-5)
    stretched = joints + 0.003 * np.random.default_rng(2).normal(size=joints.shape)
    rigid = np.linalg.norm(_positions(_write(tmp_path, stretched)) - stretched, axis=-1)
    assert rigid.mean() < 0.01  # README: within about a centimetre on average
    exact = _positions(_write(tmp_path, stretched, scale=100.0, bone_translations=True), 100.0)
    np.testing.assert_allclose(exact, stretched, atol=1e-5)


def test_a_spinning_clip_has_unwrapped_angles(tmp_path):
    """Two full turns of the root and of the head: no channel jumps by 360 between frames."""
    joints = _clip(seed=3, swing_degrees=20.0, frames=80, turns=2.0)
    _, values, _ = _write(tmp_path, joints)
    steps = np.abs(np.diff(values[:, 3:], axis=0))  # every rotation channel
    assert steps.max() < 180.0
    spin = np.ptp(values[:, 3:6], axis=0).max()
    assert spin > 600.0  # the root's yaw runs on through 720 degrees instead of wrapping


def test_a_generated_spin_reads_back_and_turns_on_past_a_circle(tmp_path):
    """The shipped model's spin (its root turns about 370 degrees in 4 s): forward kinematics
    of the file is within a centimetre on average (the README's figure), exact with
    bone_translations, and the root's Y channel runs on without a jump."""
    motion = MotionGenerator.load().generate("a person spins around in a circle.",
                                             seconds=4.0, seed=0)
    motion.save_bvh(tmp_path / "spin.bvh")
    parsed = _parse((tmp_path / "spin.bvh").read_text())
    error = np.linalg.norm(_positions(parsed) - motion.joints, axis=-1)
    assert error.mean() < 0.01
    values = parsed[1]
    assert np.ptp(values[:, 5]) > 300.0 and np.abs(np.diff(values[:, 3:], axis=0)).max() < 180
    motion.save_bvh(tmp_path / "exact.bvh", scale=100.0, bone_translations=True)
    exact = _positions(_parse((tmp_path / "exact.bvh").read_text()), scale=100.0)
    np.testing.assert_allclose(exact, motion.joints, atol=1e-5)


def test_a_somersault_has_continuous_angles(tmp_path):
    """The root pitching through a full circle crosses X = +-90 degrees, where the principal
    ZXY angles flip Z and Y by 180 in one frame; the file keeps the equivalent continuous ones
    (X running on past 90), which tools interpolate without a spurious half turn."""
    frames = 73
    local = np.tile(np.array([1.0, 0, 0, 0]), (frames, 22, 1))
    local[:, 0] = qfrom_axis_angle(np.array([1.0, 0, 0]), np.radians(np.linspace(0, 360, frames)))
    joints = _pose(local, np.tile([0.0, 1.0, 0.0], (frames, 1)))
    parsed = _write(tmp_path, joints)
    assert np.abs(np.diff(parsed[1][:, 3:], axis=0)).max() < 10.0  # 5 degrees a frame
    np.testing.assert_allclose(_positions(parsed), joints, atol=1e-5)


@pytest.mark.parametrize("degrees", [90.0, -90.0])
def test_gimbal_locked_poses_come_back(tmp_path, degrees):
    """A body lying on its front or back (the root's X channel at +-90 degrees, where Z and Y
    turn about the same axis) and a leg kicked straight forward: FK still gives the joints."""
    frames = 6
    local = np.tile(np.array([1.0, 0, 0, 0]), (frames, 22, 1))
    yaw = np.radians(np.linspace(0, 150, frames))
    pitch = qfrom_axis_angle(np.array([1.0, 0, 0]), np.full(frames, np.radians(degrees)))
    local[:, 0] = qmul(pitch, qyaw(yaw))  # Rx(+-90) @ Ry(yaw): locked ZXY
    local[:, SMPL_22.index("left_hip")] = qfrom_axis_angle(
        np.array([1.0, 0, 0]), np.full(frames, np.radians(-degrees)))
    joints = _pose(local, np.tile([0.0, 0.3, 0.0], (frames, 1)))
    parsed = _write(tmp_path, joints)
    root = parsed[1][:, 3:6]  # Zrotation Xrotation Yrotation of the pelvis
    np.testing.assert_allclose(root[:, 1], degrees, atol=1e-4)
    np.testing.assert_allclose(_positions(parsed), joints, atol=1e-5)
