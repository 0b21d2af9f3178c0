"""joints_to_features against the HumanML3D format itself, not against our own round trip.

Expected values come from hand-made clips and the documented 263-dim layout of the original
pipeline (process_file / inverse_kinematics_np of HumanML3D's motion_representation): contacts
are a foot joint's squared per-frame displacement < 0.002, left (ankle, foot) before right;
the facing is up x across, smoothed by gaussian_filter1d(sigma=20, mode='nearest'); joint
velocities of row t are in the facing frame of frame t, the root's XZ velocity in that of t+1.
Rotation matrices here are plain numpy, independent of runtime/motion/quaternion.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from mogo.motion.features import joints_to_features, local_rotations_from_joints
from mogo.motion.skeleton import SMPL_22

J = SMPL_22.num_joints
POS, ROT, VEL, CONTACT = slice(4, 67), slice(67, 193), slice(193, 259), slice(259, 263)
L_ANKLE, R_ANKLE, L_FOOT, R_FOOT = 7, 8, 10, 11


def _rest_pose() -> np.ndarray:
    """(J, 3) rest pose facing +Z, feet on the floor (lowest joint at y=0), root XZ at 0."""
    pose = np.zeros((J, 3))
    for joint, parent in enumerate(SMPL_22.parents):
        if parent >= 0:
            pose[joint] = pose[parent] + SMPL_22.rest_offsets[joint]
    pose[:, 1] -= pose[:, 1].min()
    return pose


def _yaw(angle: float) -> np.ndarray:
    """3x3 rotation by `angle` about +Y, counter-clockwise from above: +Z -> (sin, 0, cos)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _placed_in_world(canonical: np.ndarray) -> np.ndarray:
    """The same clip somewhere else: turned 90 degrees, moved, on a raised floor."""
    return canonical @ _yaw(np.pi / 2).T + np.array([3.0, 0.5, -2.0])


def test_the_rest_pose_faces_plus_z():
    # The hand-made clips below rely on it: up x (right - left) of hips and shoulders is +Z.
    pose = _rest_pose()
    r_hip, l_hip, r_sh, l_sh = SMPL_22.face_joints
    across = pose[r_hip] - pose[l_hip] + pose[r_sh] - pose[l_sh]
    forward = np.cross([0.0, 1.0, 0.0], across)
    np.testing.assert_allclose(forward / np.linalg.norm(forward), [0.0, 0.0, 1.0])


def _walk_then_sidestep() -> tuple[np.ndarray, np.ndarray]:
    """Canonical clip (11 frames): the body moves 0.1 m/frame forward (+Z) for 5 frames, then
    0.1 m/frame to its left (+X) for 5; the left foot stays planted, the right moves along.
    Returns the canonical joints and the root displacement of each step (10, 3)."""
    steps = np.array([[0.0, 0.0, 0.1]] * 5 + [[0.1, 0.0, 0.0]] * 5)
    offsets = np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    joints = _rest_pose()[None] + offsets[:, None]
    joints[:, [L_ANKLE, L_FOOT]] = _rest_pose()[[L_ANKLE, L_FOOT]]
    return joints, steps


def test_a_hand_made_clip_gives_the_documented_blocks():
    canonical, steps = _walk_then_sidestep()
    features, _ = joints_to_features(_placed_in_world(canonical))
    assert features.shape == (10, 263)
    pose = _rest_pose()

    np.testing.assert_allclose(features[:, 0], 0.0, atol=1e-7)  # no turning
    # Root XZ velocity in the facing frame: forward is +Z (column 2), the left is +X (column 1).
    np.testing.assert_allclose(features[:, 1:3], steps[:, [0, 2]], atol=1e-6)
    np.testing.assert_allclose(features[:, 3], pose[0, 1], atol=1e-6)  # pelvis above the floor

    relative = canonical[:-1] - canonical[:-1, :1] * np.array([1.0, 0.0, 1.0])
    np.testing.assert_allclose(features[:, POS].reshape(10, J - 1, 3), relative[:, 1:], atol=1e-6)

    velocity = np.repeat(steps[:, None], J, axis=1)
    velocity[:, [L_ANKLE, L_FOOT]] = 0.0
    np.testing.assert_allclose(features[:, VEL].reshape(10, J, 3), velocity, atol=1e-6)

    # Left ankle, left foot, right ankle, right foot: only the planted left foot is in contact.
    np.testing.assert_array_equal(features[:, CONTACT], np.tile([1.0, 1.0, 0.0, 0.0], (10, 1)))


def test_rotations_block_is_the_identity_when_every_bone_lies_along_its_raw_offset():
    # Each local rotation is then zero, and its continuous 6D form is the first two columns of
    # the identity matrix (quaternion_to_cont6d_np in the original).
    pose = np.zeros((J, 3))
    for joint, parent in enumerate(SMPL_22.parents):
        if parent >= 0:
            length = np.linalg.norm(SMPL_22.rest_offsets[joint])
            pose[joint] = pose[parent] + length * SMPL_22.raw_offsets[joint]
    features, _ = joints_to_features(_placed_in_world(np.repeat(pose[None], 3, axis=0)))
    rotations = features[:, ROT].reshape(2, J - 1, 6)
    np.testing.assert_allclose(
        rotations, np.broadcast_to([1.0, 0, 0, 0, 1.0, 0], rotations.shape), atol=1e-6
    )


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3x3 matrix of the shortest rotation taking unit vector a onto unit vector b (Rodrigues)."""
    axis, cos = np.cross(a, b), float(a @ b)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + cos)


@pytest.mark.parametrize("leaf", ["left_wrist", "head", "right_foot"])
def test_a_turned_bone_at_the_end_of_a_chain_gives_its_rotation(leaf):
    # Every other bone along its raw offset, so the leaf's local rotation is the one taking its
    # raw offset onto the turned bone; its 6D form is that matrix's first two columns.
    joint = SMPL_22.index(leaf)
    pose = np.zeros((J, 3))
    bone = (
        _yaw(0.7)
        @ np.array([[1.0, 0, 0], [0, 0.6, -0.8], [0, 0.8, 0.6]])
        @ SMPL_22.raw_offsets[joint]
    )
    for j, parent in enumerate(SMPL_22.parents):
        if parent >= 0:
            direction = bone if j == joint else SMPL_22.raw_offsets[j]
            pose[j] = pose[parent] + np.linalg.norm(SMPL_22.rest_offsets[j]) * direction
    features, _ = joints_to_features(_placed_in_world(np.repeat(pose[None], 3, axis=0)))
    rotation = _rotation_between(SMPL_22.raw_offsets[joint], bone)
    rotations = features[:, ROT].reshape(2, J - 1, 6)
    np.testing.assert_allclose(
        rotations[:, joint - 1],
        np.broadcast_to(np.concatenate([rotation[:, 0], rotation[:, 1]]), (2, 6)),
        atol=1e-6,
    )


def test_given_local_rotations_fill_the_6d_block_and_must_have_their_shape():
    clip = np.repeat(_rest_pose()[None], 3, axis=0)
    half = np.sin(np.pi / 4) * np.array([1.0, 0.0, 0.0])  # 90 degrees about +X, every joint
    rotations = np.broadcast_to(np.array([np.cos(np.pi / 4), *half]), (3, J, 4))
    features, _ = joints_to_features(clip, local_rotations=rotations)
    np.testing.assert_allclose(
        features[:, ROT].reshape(2, J - 1, 6),
        np.broadcast_to([1.0, 0, 0, 0, 0, 1.0], (2, J - 1, 6)),
        atol=1e-6,
    )  # columns of Rx(90): x, z
    for wrong in (rotations[..., :3], np.ones((3, 22, 5)), np.ones((3, 23, 4))):
        with pytest.raises(
            ValueError,
            match=r"^local_rotations must be \(3, 22, 4\), got "
            rf"\({', '.join(map(str, wrong.shape))}\)$",
        ):
            joints_to_features(clip, local_rotations=wrong)


def test_a_facing_sigma_of_zero_or_less_smooths_nothing():
    angles = 0.3 * np.sin(0.5 * np.arange(30))
    joints = _placed_in_world(_turning_clip(angles, 0.03))
    unsmoothed, _ = joints_to_features(joints, facing_sigma=0)
    np.testing.assert_allclose(unsmoothed[:, 0], -0.5 * np.diff(angles), atol=1e-6)
    np.testing.assert_array_equal(joints_to_features(joints, facing_sigma=-2.0)[0], unsmoothed)


def test_local_rotations_start_with_the_root_rotation_given():
    positions = _turning_clip(0.2 * np.arange(4), 0.05)
    root = np.stack(
        [np.cos(0.1 * np.arange(4)), np.zeros(4), np.sin(0.1 * np.arange(4)), np.zeros(4)], axis=-1
    )
    rotations = local_rotations_from_joints(positions, SMPL_22, root)
    assert rotations.shape == (4, J, 4)
    np.testing.assert_array_equal(rotations[:, 0], root)


def test_a_frame_with_no_left_right_direction_is_refused_by_name():
    clip = np.repeat(_rest_pose()[None], 5, axis=0)
    clip[3, [1, 16]] = clip[3, [2, 17]]  # left hip and shoulder onto the right ones
    with pytest.raises(
        ValueError,
        match="^cannot compute the facing direction at frame 3: "
        "the hips and shoulders give no left-right direction$",
    ):
        joints_to_features(clip)


def test_two_frames_are_the_shortest_clip():
    features, canonical = joints_to_features(np.repeat(_rest_pose()[None], 2, axis=0))
    assert features.shape == (1, 263) and canonical.shape == (2, J, 3)


def _contact_clip(ankle_step: float, foot_step: float) -> np.ndarray:
    """A still body whose left ankle and left foot slide along X by the given m/frame."""
    joints = np.repeat(_rest_pose()[None], 4, axis=0)
    frames = np.arange(4)[:, None]
    joints[:, L_ANKLE, 0] += ankle_step * frames[:, 0]
    joints[:, L_FOOT, 2] += foot_step * frames[:, 0]
    joints[:, R_FOOT, 0] += 0.5 * frames[:, 0]  # far above the threshold
    return joints


@pytest.mark.parametrize(
    "squared, expected", [(0.00199, 1.0), (0.00201, 0.0), (0.00099, 1.0), (0.0039, 0.0)]
)
def test_contact_threshold_is_0_002_squared_metres_per_frame(squared, expected):
    # Strictly below 0.002 m^2 of displacement per frame (not per second) is a contact.
    step = np.sqrt(squared)
    features, _ = joints_to_features(_placed_in_world(_contact_clip(step, 0.0)))
    np.testing.assert_array_equal(features[:, 259], expected)  # left ankle
    np.testing.assert_array_equal(features[:, 260], 1.0)  # left foot still
    np.testing.assert_array_equal(features[:, 261], 1.0)  # right ankle still
    np.testing.assert_array_equal(features[:, 262], 0.0)  # right foot moving


def test_each_contact_column_belongs_to_its_own_joint():
    joints = _contact_clip(0.0, 0.3)  # only the left foot (toe) moves, and the right foot
    features, _ = joints_to_features(joints)
    np.testing.assert_array_equal(features[:, CONTACT], np.tile([1.0, 0.0, 1.0, 0.0], (3, 1)))


def _turning_clip(angles: np.ndarray, speed: float, rolls: np.ndarray | None = None) -> np.ndarray:
    """The rest pose turned to the given yaw each frame, its root walking forward at `speed`
    m/frame along its facing; starts canonical (root XZ at 0, facing +Z). `rolls`: angles
    (rad) the body leans sideways (about its forward axis) each frame."""
    headings = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=-1)
    root = np.concatenate([np.zeros((1, 3)), np.cumsum(speed * headings[:-1], axis=0)])
    rolls = np.zeros_like(angles) if rolls is None else rolls
    pose = _rest_pose()
    return np.stack(
        [pose @ _roll(b).T @ _yaw(a).T + r for a, b, r in zip(angles, rolls, root, strict=False)]
    )


def _roll(angle: float) -> np.ndarray:
    """3x3 rotation by `angle` about +Z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_joint_velocities_are_in_the_facing_frame_of_the_current_frame():
    # Without smoothing, a body turning 0.2 rad per frame while walking: world-frame velocities,
    # those in the facing frame of t and those in the frame of t+1 all differ.
    angles = 0.2 * np.arange(8)
    joints = _turning_clip(angles, 0.05)
    features, _ = joints_to_features(_placed_in_world(joints), facing_sigma=0)

    np.testing.assert_allclose(features[:, 0], -0.1, atol=1e-6)  # -(half the turn) per frame
    step = joints[1:] - joints[:-1]
    expected = np.einsum("tij,tkj->tki", np.stack([_yaw(-a) for a in angles[:-1]]), step)
    np.testing.assert_allclose(features[:, VEL].reshape(7, J, 3), expected, atol=1e-5)
    # The root's XZ velocity uses the facing of t+1 (r_rot[1:] in the original).
    root = np.einsum("tij,tj->ti", np.stack([_yaw(-a) for a in angles[1:]]), step[:, 0])
    np.testing.assert_allclose(features[:, 1:3], root[:, [0, 2]], atol=1e-6)
    np.testing.assert_allclose(
        features[:, POS].reshape(7, J - 1, 3),
        np.broadcast_to(_rest_pose()[1:], (7, J - 1, 3)),
        atol=1e-5,
    )


def _scipy_facing(joints: np.ndarray, sigma: float = 20.0) -> np.ndarray:
    """The original's facing angle per frame: up x normalised across, then scipy's filter."""
    from scipy.ndimage import gaussian_filter1d  # dev-only, independent of our filter

    r_hip, l_hip, r_sh, l_sh = SMPL_22.face_joints
    across = joints[:, r_hip] - joints[:, l_hip] + joints[:, r_sh] - joints[:, l_sh]
    across /= np.linalg.norm(across, axis=-1, keepdims=True)
    forward = np.cross(np.array([[0.0, 1.0, 0.0]]), across, axis=-1)
    forward = gaussian_filter1d(forward, sigma, axis=0, mode="nearest")
    return np.unwrap(np.arctan2(forward[:, 0], forward[:, 2]))


# 40 and 200 frames: shorter and longer than the 80-frame half-kernel of the default sigma
# (None: HumanML3D's 20); sigma 0.75 (a facing_sigma of one's own) cuts its kernel at an odd
# radius, 3 frames; a body that leans sideways weighs less in the smoothing, as in the original
@pytest.mark.parametrize(
    "frames, sigma, lean", [(40, None, 0.0), (200, None, 0.0), (60, 0.75, 0.0), (120, None, 0.6)]
)
def test_facing_is_smoothed_like_scipy_gaussian_filter1d(frames, sigma, lean):
    pytest.importorskip("scipy")
    rng = np.random.default_rng(3)
    angles = (
        0.04 * np.arange(frames)
        + 0.3 * np.sin(0.1 * np.arange(frames))
        + rng.normal(0.0, 0.15, frames)
    )
    joints = _turning_clip(angles, 0.03, lean * np.sin(0.3 * np.arange(frames)) ** 2)
    options = {} if sigma is None else dict(facing_sigma=sigma)
    sigma = 20.0 if sigma is None else sigma
    features, _ = joints_to_features(_placed_in_world(joints), **options)
    expected = -0.5 * np.diff(_scipy_facing(joints, sigma))
    # Both filters are float64 with the same 161-tap kernel (truncate=4.0); what remains is the
    # float32 output (values ~0.02 rad, rounding ~2e-9). A kernel cut at 2 sigma, or sigma 10,
    # moves these angles by ~1e-4 or more.
    np.testing.assert_allclose(features[:, 0], expected, rtol=0, atol=2e-7)
    # The smoothed facing also sets the frame of the joint velocities.
    facing = _scipy_facing(joints, sigma)
    step = joints[1:, 0] - joints[:-1, 0]
    local = np.einsum("tij,tj->ti", np.stack([_yaw(-a) for a in facing[:-1]]), step)
    np.testing.assert_allclose(features[:, 193:196], local, atol=1e-6)


def test_a_displacement_of_exactly_the_threshold_is_not_a_contact():
    # The original compares with a strict '<'. 0.0625 m is exact in binary and so is its
    # square; the clip is already canonical, so no rotation blurs the displacement.
    joints = _contact_clip(0.0, 0.0)
    joints[:, L_ANKLE, 0] = 0.25 + 0.0625 * np.arange(4)
    features, _ = joints_to_features(joints, contact_threshold=0.0625**2)
    np.testing.assert_array_equal(features[:, 259], 0.0)
    features, _ = joints_to_features(joints, contact_threshold=np.nextafter(0.0625**2, 1.0))
    np.testing.assert_array_equal(features[:, 259], 1.0)
