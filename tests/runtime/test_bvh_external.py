"""Our BVH files read by a third-party reader (bvhio, a dev dependency): its forward
kinematics gives what our rig says, the rest pose is a clean T-pose, angles are continuous.
Nothing here uses mogo.motion.bvh's reader."""

from itertools import pairwise

import numpy as np
import pytest

from mogo import MotionGenerator
from mogo.motion import rig
from mogo.motion.bvh import NAMINGS, UNITS, save_bvh
from mogo.motion.quaternion import qfrom_axis_angle, qmul, qrot, qyaw
from mogo.motion.skeleton import SMPL_22

bvhio = pytest.importorskip("bvhio")


def _clip(seed: int, swing_degrees: float, frames: int = 60, turns: float = 2.0) -> np.ndarray:
    """Rigid SMPL_22 motion: smooth random local swings, a root turning `turns` circles."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, frames)[:, None]
    axes = rng.normal(size=(22, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    angles = np.radians(swing_degrees) * np.sin(
        2 * np.pi * rng.uniform(1, 3, 22) * t + rng.uniform(0, 2 * np.pi, 22)
    )
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
        joints[:, j] = joints[:, p] + qrot(
            world[:, p], np.broadcast_to(SMPL_22.rest_offsets[j], joints[:, j].shape)
        )
        world[:, j] = qmul(world[:, p], local[:, j])
    return joints


def _write(tmp_path, joints: np.ndarray, **options):
    """The file written, read by bvhio: (its joint hierarchy, the motion lines (T, C))."""
    path = tmp_path / "clip.bvh"
    save_bvh(path, joints, SMPL_22, fps=20.0, **options)
    motion = path.read_text().split("Frame Time:")[1].splitlines()[1:]
    return bvhio.readAsHierarchy(str(path)), np.array([line.split() for line in motion], float)


def _positions(parsed, naming: str = "mixamo", scale: float = 1.0) -> np.ndarray:
    """bvhio's world positions of every frame, in SMPL_22 joint order and metres."""
    root, values = parsed
    layout = [joint for joint, _, _ in root.layout()]
    order = [NAMINGS[naming].index(joint.Name) for joint in layout]
    out = np.zeros((len(values), 22, 3))
    for frame in range(len(values)):
        root.loadPose(frame, recursive=True)
        out[frame, order] = [list(joint.PositionWorld) for joint in layout]
    return out / scale


def _rest(parsed) -> dict[str, np.ndarray]:
    """Rest-pose world positions by bvhio (offsets alone), by joint name."""
    root = parsed[0]
    root.loadRestPose(recursive=True)
    return {joint.Name: np.array(list(joint.PositionWorld)) for joint, _, _ in root.layout()}


def test_rest_pose_is_a_clean_t_pose_on_the_floor(tmp_path):
    rest = _rest(_write(tmp_path, _clip(seed=0, swing_degrees=40.0)))
    assert list(rest)[0] == "Hips" and len(rest) == 22
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        chain = [rest[f"{side}{part}"] for part in ("Arm", "ForeArm", "Hand")]
        for a, b in pairwise(chain):  # arms straight out along +-X
            np.testing.assert_allclose(b - a, [sign * np.linalg.norm(b - a), 0, 0], atol=1e-6)
        leg = [rest[f"{side}{part}"] for part in ("UpLeg", "Leg", "Foot")]
        for a, b in pairwise(leg):  # legs straight down
            np.testing.assert_allclose(b - a, [0, -np.linalg.norm(b - a), 0], atol=1e-6)
        foot, toe = rest[f"{side}Foot"], rest[f"{side}ToeBase"]
        assert foot[1] == pytest.approx(0.0, abs=1e-6) and toe[1] == pytest.approx(0.0, abs=1e-6)
        assert toe[2] - foot[2] > 0.1  # flat, pointing forward (+Z, the facing)
        twin = rest[f"{side}Hand"] * (sign, 1, 1)
        np.testing.assert_allclose(twin, rest["LeftHand"], atol=1e-6)  # symmetric
    spine = [rest[name] for name in ("Spine", "Spine1", "Spine2")] + [rest["Neck"], rest["Head"]]
    for a, b in ((spine[0], spine[1]), (spine[1], spine[2]), (spine[3], spine[4])):
        np.testing.assert_allclose((b - a)[[0, 2]], 0.0, atol=1e-6)  # bones straight up
        assert (b - a)[1] > 0.05


def test_end_sites_continue_the_last_bone_of_each_chain(tmp_path):
    """The tips of the head, hands and toes (End Site offsets, read off the text) point on
    along their joint's own offset: the head up, the hands out, the toes forward."""
    path = tmp_path / "clip.bvh"
    save_bvh(path, _clip(seed=0, swing_degrees=10.0, frames=4), SMPL_22, fps=20.0)
    lines = [line.split() for line in path.read_text().split("MOTION")[0].splitlines()]
    tips = {}
    for i, words in enumerate(lines):
        if words[0] in ("ROOT", "JOINT"):
            name, offset = words[1], np.array(lines[i + 2][1:], float)
        elif words == ["End", "Site"]:
            tips[name] = offset, np.array(lines[i + 2][1:], float)
    assert sorted(tips) == ["Head", "LeftHand", "LeftToeBase", "RightHand", "RightToeBase"]
    for name, (offset, tip) in tips.items():
        np.testing.assert_allclose(np.cross(offset, tip), 0.0, atol=1e-5, err_msg=name)
        assert offset @ tip > 0.0001, name


@pytest.mark.parametrize("naming,scale", [("mixamo", 1.0), ("smpl", 100.0)])
def test_bvhio_reads_what_our_rig_says(tmp_path, naming, scale):
    """bvhio's forward kinematics equals our rig's; for motion of the corpus's proportions
    that is the joints themselves, in either naming and unit."""
    joints = _clip(seed=1, swing_degrees=90.0)
    np.testing.assert_allclose(
        _positions(_write(tmp_path, joints, naming=naming, scale=scale), naming, scale),
        joints,
        atol=1e-5,
    )
    stretched = joints + 0.003 * np.random.default_rng(2).normal(size=joints.shape)
    ours = rig.posed_joints(stretched, SMPL_22)
    theirs = _positions(_write(tmp_path, stretched))
    np.testing.assert_allclose(theirs, ours, atol=1e-5)
    assert np.linalg.norm(theirs - stretched, axis=-1).mean() < 0.01
    exact = _positions(
        _write(tmp_path, stretched, scale=100.0, bone_translations=True), scale=100.0
    )
    np.testing.assert_allclose(exact, stretched, atol=1e-5)


def test_a_file_in_centimetres_is_the_file_in_metres_times_100(tmp_path):
    """--bvh-units cm: every OFFSET line (end sites included) and the root's position channels
    are 100 times those of the file in metres, read off the text; the angles are the same."""
    joints = _clip(seed=3, swing_degrees=40.0, frames=10)
    offsets, motion = {}, {}
    for unit in ("m", "cm"):
        path = tmp_path / f"{unit}.bvh"
        save_bvh(path, joints, SMPL_22, fps=20.0, scale=UNITS[unit])
        head, frames = path.read_text().split("Frame Time:")
        offsets[unit] = np.array(
            [line.split()[1:] for line in head.splitlines() if line.strip().startswith("OFFSET")],
            float,
        )
        motion[unit] = np.array([line.split() for line in frames.splitlines()[1:]], float)
    assert len(offsets["m"]) == 22 + 5  # the joints and the end sites (head, hands, feet)
    np.testing.assert_allclose(offsets["cm"], 100 * offsets["m"], atol=1e-4)
    np.testing.assert_allclose(motion["cm"][:, :3], 100 * motion["m"][:, :3], atol=1e-4)
    np.testing.assert_array_equal(motion["cm"][:, 3:], motion["m"][:, 3:])


def test_a_spinning_clip_has_unwrapped_angles(tmp_path):
    """Two full turns of the root and of the head: no channel jumps by 360 between frames."""
    joints = _clip(seed=3, swing_degrees=20.0, frames=80, turns=2.0)
    _, values = _write(tmp_path, joints)
    steps = np.abs(np.diff(values[:, 3:], axis=0))  # every rotation channel
    assert steps.max() < 180.0
    spin = np.ptp(values[:, 3:6], axis=0).max()
    assert spin > 600.0  # the root's yaw runs on through 720 degrees instead of wrapping


def test_a_generated_spin_reads_back_and_turns_on_past_a_circle(tmp_path):
    """The shipped model's spin (its root turns about 370 degrees in 4 s): forward kinematics
    of the file is within a centimetre on average (the README's figure), exact with
    bone_translations, and the root's Y channel runs on without a jump."""
    motion = MotionGenerator.load().generate(
        "a person spins around in a circle.", seconds=4.0, seed=0
    )
    motion.save_bvh(tmp_path / "spin.bvh")
    parsed = (
        bvhio.readAsHierarchy(str(tmp_path / "spin.bvh")),
        np.array(
            [
                line.split()
                for line in (tmp_path / "spin.bvh")
                .read_text()
                .split("Frame Time:")[1]
                .splitlines()[1:]
            ],
            float,
        ),
    )
    error = np.linalg.norm(_positions(parsed) - motion.joints, axis=-1)
    assert error.mean() < 0.01
    values = parsed[1]
    assert np.ptp(values[:, 5]) > 300.0 and np.abs(np.diff(values[:, 3:], axis=0)).max() < 180
    motion.save_bvh(tmp_path / "exact.bvh", scale=100.0, bone_translations=True)
    exact = _positions((bvhio.readAsHierarchy(str(tmp_path / "exact.bvh")), parsed[1]), scale=100.0)
    np.testing.assert_allclose(exact, motion.joints, atol=1e-5)


@pytest.mark.parametrize("twist", [0.0, 10.0])
def test_a_somersault_has_continuous_angles(tmp_path, twist):
    """The root pitching through a full circle crosses X = +-90 degrees, where the principal
    ZXY angles flip Z and Y by 180 in one frame; the file keeps the equivalent continuous ones
    (X running on past 90), which tools interpolate without a spurious half turn. With a
    twist about the spine swaying by +-`twist` degrees, Z and Y wrap past +-180 together on
    the way, which must not be taken for a jump."""
    frames = 73
    t = np.linspace(0.0, 1.0, frames)
    local = np.tile(np.array([1.0, 0, 0, 0]), (frames, 22, 1))
    local[:, 0] = qmul(
        qfrom_axis_angle(np.array([1.0, 0, 0]), np.radians(360 * t)),
        qyaw(np.radians(twist * np.sin(6 * np.pi * t))),
    )
    joints = _pose(local, np.tile([0.0, 1.0, 0.0], (frames, 1)))
    parsed = _write(tmp_path, joints)
    steps = np.abs(np.diff(parsed[1][:, 3:6], axis=0))  # the root: 5 degrees a frame, or so
    assert steps.max() < 15.0
    np.testing.assert_allclose(_positions(parsed), joints, atol=1e-5)


@pytest.mark.parametrize(
    "phases", [[("z", 178), ("x", 100), ("z", 0)], [("z", 90), ("x", 150), ("z", 178)]]
)
def test_a_tumble_keeps_continuous_angles(tmp_path, phases):
    """The root rolls (about Z), pitches past X = 90, rolls again: each frame's triple is the
    one nearest the frame before (not frame 0, nor an older one), so no channel jumps."""
    z, x = [0.0], [0.0]
    for axis, target in phases:  # 11 frames per phase, one angle moving
        z += list(np.linspace(z[-1], target if axis == "z" else z[-1], 12)[1:])
        x += list(np.linspace(x[-1], target if axis == "x" else x[-1], 12)[1:])
    local = np.tile(np.array([1.0, 0, 0, 0]), (len(z), 22, 1))
    local[:, 0] = qmul(
        qfrom_axis_angle(np.array([0, 0, 1.0]), np.radians(z)),
        qfrom_axis_angle(np.array([1.0, 0, 0]), np.radians(x)),
    )
    joints = _pose(local, np.tile([0.0, 1.0, 0.0], (len(z), 1)))
    parsed = _write(tmp_path, joints)
    assert np.abs(np.diff(parsed[1][:, 3:6], axis=0)).max() < 30.0  # 16 degrees a frame at most
    np.testing.assert_allclose(_positions(parsed), joints, atol=1e-5)


def test_the_first_frame_has_the_principal_angles(tmp_path):
    """Continuity starts from frame 0 as extracted (X within +-90 degrees), even when the
    clip ends past X = 90, where the other triple of frame 0 would be nearer its last frame."""
    frames = 5
    local = np.tile(np.array([1.0, 0, 0, 0]), (frames, 22, 1))
    local[:, 0] = qfrom_axis_angle(np.array([1.0, 0, 0]), np.radians(np.linspace(86, 106, frames)))
    parsed = _write(tmp_path, _pose(local, np.tile([0.0, 1.0, 0.0], (frames, 1))))
    np.testing.assert_allclose(
        parsed[1][:, 3:6], [[0, 86 + 5 * t, 0] for t in range(frames)], atol=1e-4
    )  # Z X Y of the root, X running on past 90 at once


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
        np.array([1.0, 0, 0]), np.full(frames, np.radians(-degrees))
    )
    joints = _pose(local, np.tile([0.0, 0.3, 0.0], (frames, 1)))
    parsed = _write(tmp_path, joints)
    root = parsed[1][:, 3:6]  # Zrotation Xrotation Yrotation of the pelvis
    np.testing.assert_allclose(root[:, 1], degrees, atol=1e-4)
    np.testing.assert_allclose(_positions(parsed), joints, atol=1e-5)
