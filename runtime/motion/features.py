"""HumanML3D motion features <-> joint positions (and the 251-dim KIT-ML twin).

Feature row t of a clip with T frames (T-1 rows), J joints:
  [0]                 root yaw velocity: half-angle of the facing change from frame t to t+1
  [1:3]               root XZ velocity from t to t+1, in the facing frame of t+1
  [3]                 root height at t
  [4 : 4+3(J-1)]      joints 1..J-1 relative to the root (XZ root-centred), facing +Z, at t
  [.. : +6(J-1)]      continuous 6D local rotations of joints 1..J-1 at t
  [.. : +3J]          joint velocities from t to t+1, in the facing frame of t
  [-4:]               foot contacts from t to t+1 (left ankle, left toe, right ankle, right toe)

`features_to_joints` is the compatibility contract with the HumanML3D tooling; the forward
direction follows the same pipeline (canonicalise, facing, IK) so that recovering the features
reproduces the canonical joints.
"""

from __future__ import annotations

import numpy as np

from .quaternion import cross, qbetween, qinv, qmul, qrot, qto_cont6d, qyaw
from .skeleton import SMPL_22, Skeleton, skeleton_for_feature_dim

FOOT_CONTACT_THRESHOLD = 0.002  # squared per-frame displacement (m^2), as in HumanML3D
FACING_SMOOTHING_FRAMES = 20.0  # Gaussian sigma on the facing direction, as in HumanML3D


def feature_layout(skeleton: Skeleton) -> list[tuple[str, int, int]]:
    """The blocks of a feature row as (name, start, stop), in the order of the docstring above:
    what a bundle's manifest states for programs that read the features without this code."""
    j = skeleton.num_joints
    widths = [
        ("root_yaw_velocity", 1),
        ("root_xz_velocity", 2),
        ("root_height", 1),
        ("joint_positions", 3 * (j - 1)),
        ("joint_rotations_6d", 6 * (j - 1)),
        ("joint_velocities", 3 * j),
        ("foot_contacts", 4),
    ]
    stops = np.cumsum([width for _, width in widths])
    return [
        (name, int(stop - width), int(stop))
        for (name, width), stop in zip(widths, stops, strict=False)
    ]


def features_to_joints(features: np.ndarray, skeleton: Skeleton | None = None) -> np.ndarray:
    """Recover joint positions (..., T, J, 3) from features (..., T, D)."""
    features = np.asarray(features)
    skeleton = _checked_skeleton(features, skeleton)
    f = features.astype(np.float64)
    zeros = np.zeros(f.shape[:-2])
    joints = _joints(f, skeleton, zeros, np.zeros(f.shape[:-2] + (2,)))
    return joints.astype(features.dtype if features.dtype.kind == "f" else np.float32)


class JointStream:
    """`features_to_joints` for features that arrive in pieces: pushing a clip's rows in any
    chunks gives the joints of one call on the whole clip. The root's yaw and XZ position are
    carried from chunk to chunk, so a stream can run forever."""

    def __init__(self, skeleton: Skeleton = SMPL_22):
        self.skeleton = skeleton
        self.half_angle = 0.0  # root yaw (half-angle) at the next frame
        self.xz = np.zeros(2)  # root XZ at the next frame

    def push(self, features: np.ndarray) -> np.ndarray:
        """features (n, D) -> joints (n, J, 3) float32."""
        return joints_together([self], np.asarray(features)[None])[0]


def joints_together(streams: list[JointStream], features: np.ndarray) -> np.ndarray:
    """`push` of as many rows to each of several streams of one skeleton at once (the server's
    streams of a round): features (B, n, D) -> joints (B, n, J, 3) float32, the numbers of B
    pushes (the maths is elementwise per stream) in one pass of numpy calls, not B."""
    skeleton = streams[0].skeleton
    if any(stream.skeleton is not skeleton for stream in streams):
        raise ValueError("joints_together needs streams of one skeleton")
    f = np.asarray(features, dtype=np.float64)
    _checked_skeleton(f, skeleton)
    if f.shape[1] == 0:
        return np.zeros((*f.shape[:2], skeleton.num_joints, 3), np.float32)
    half_angles = np.array([stream.half_angle for stream in streams], np.float64)
    joints = _joints(f, skeleton, half_angles, np.array([stream.xz for stream in streams]))
    # each root's yaw and XZ after its rows (each stream's own sum: the order of its terms)
    half_angles += [rows[:, 0].sum() for rows in f]
    last = f[:, -1]
    velocity = np.stack([last[:, 1], np.zeros(len(f)), last[:, 2]], -1)
    step = qrot(qinv(qyaw(2 * half_angles)), velocity)
    xz = joints[:, -1, 0, ::2] + step[:, ::2]
    for stream, half_angle, position in zip(streams, half_angles, xz, strict=True):
        stream.half_angle, stream.xz = half_angle, position
    return joints.astype(np.float32)


def _checked_skeleton(features: np.ndarray, skeleton: Skeleton | None) -> Skeleton:
    if features.ndim < 2:
        raise ValueError(f"features must be (..., T, D), got shape {features.shape}")
    skeleton = skeleton or skeleton_for_feature_dim(features.shape[-1])
    if features.shape[-1] != skeleton.feature_dim:
        raise ValueError(
            f"features have {features.shape[-1]} dims, the {skeleton.name} "
            f"skeleton needs {skeleton.feature_dim}"
        )
    return skeleton


def _joints(
    f: np.ndarray, skeleton: Skeleton, start_half_angle: np.ndarray, start_xz: np.ndarray
) -> np.ndarray:
    """Joints (..., T, J, 3) float64 of features f (..., T, D), the root starting at the given
    yaw half-angle (...,) and XZ position (..., 2)."""
    root_quat, root_pos = _recover_root(f, start_half_angle, start_xz)
    num_rel = skeleton.num_joints - 1
    relative = f[..., 4 : 4 + 3 * num_rel].reshape(f.shape[:-1] + (num_rel, 3))
    relative = qrot(qinv(root_quat)[..., None, :], relative)
    relative[..., 0] += root_pos[..., None, 0]
    relative[..., 2] += root_pos[..., None, 2]
    return np.concatenate([root_pos[..., None, :], relative], axis=-2)


def _recover_root(
    f: np.ndarray, start_half_angle: np.ndarray, start_xz: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Root rotation quaternions (..., T, 4) and positions (..., T, 3) from features."""
    half_angle = np.zeros_like(f[..., 0])
    half_angle[..., 1:] = np.cumsum(f[..., :-1, 0], axis=-1)
    half_angle += np.asarray(start_half_angle)[..., None]
    zeros = np.zeros_like(half_angle)
    root_quat = np.stack([np.cos(half_angle), zeros, np.sin(half_angle), zeros], axis=-1)
    velocity = np.zeros(f.shape[:-1] + (3,))
    velocity[..., 1:, 0] = f[..., :-1, 1]
    velocity[..., 1:, 2] = f[..., :-1, 2]
    root_pos = np.cumsum(qrot(qinv(root_quat), velocity), axis=-2)
    root_pos[..., 0] += np.asarray(start_xz)[..., None, 0]
    root_pos[..., 2] += np.asarray(start_xz)[..., None, 1]
    root_pos[..., 1] = f[..., 3]
    return root_quat, root_pos


def canonicalize(
    joints: np.ndarray, skeleton: Skeleton = SMPL_22, facing_sigma: float = FACING_SMOOTHING_FRAMES
) -> np.ndarray:
    """Put a clip on the floor (lowest joint at y=0), its first root XZ at the origin, and its
    first (smoothed) facing direction along +Z."""
    positions = np.array(joints, dtype=np.float64)
    positions[..., 1] -= positions[..., 1].min()
    positions -= positions[0, 0] * np.array([1.0, 0.0, 1.0])
    forward = facing_directions(positions, skeleton, facing_sigma)
    to_z = qbetween(forward[0], np.array([0.0, 0.0, 1.0]))
    return qrot(to_z, positions)


def facing_directions(
    positions: np.ndarray, skeleton: Skeleton, facing_sigma: float = FACING_SMOOTHING_FRAMES
) -> np.ndarray:
    """Unit horizontal facing direction of each frame (T, 3): up x (right - left) of hips and
    shoulders, Gaussian-smoothed over time. As in HumanML3D, right - left is made unit length
    with its height in it, so a frame where the body rolls weighs less in the smoothing."""
    r_hip, l_hip, r_shoulder, l_shoulder = skeleton.face_joints
    across = (
        positions[:, r_hip]
        - positions[:, l_hip]
        + positions[:, r_shoulder]
        - positions[:, l_shoulder]
    )
    across /= _safe_norm(across, "the hips and shoulders give no left-right direction")
    forward = cross(np.array([0.0, 1.0, 0.0]), across)
    if facing_sigma > 0:
        forward = _gaussian_smooth(forward, facing_sigma)
    return forward / _safe_norm(
        forward, "the facing direction reverses within the smoothing window"
    )


def joints_to_features(
    joints: np.ndarray,
    skeleton: Skeleton = SMPL_22,
    local_rotations: np.ndarray | None = None,
    facing_sigma: float = FACING_SMOOTHING_FRAMES,
    contact_threshold: float = FOOT_CONTACT_THRESHOLD,
) -> tuple[np.ndarray, np.ndarray]:
    """Features (T-1, D) float32 and canonical joints (T, J, 3) float32 of a clip.

    `local_rotations` (T, J, 4) are used for the 6D block when known, in the convention of
    `local_rotations_from_joints`; otherwise they are solved from the positions.
    """
    joints = skeleton.checked_joints(joints, min_frames=2)
    positions = canonicalize(joints, skeleton, facing_sigma)

    forward = facing_directions(positions, skeleton, facing_sigma)
    facing = np.unwrap(np.arctan2(forward[:, 0], forward[:, 2]))
    facing -= facing[0]
    # Rotation taking the world into the character's facing frame (facing -> +Z).
    root_quat = qyaw(-facing)

    root_velocity = qrot(root_quat[1:], positions[1:, 0] - positions[:-1, 0])
    yaw_velocity = -0.5 * np.diff(facing)

    relative = positions.copy()
    relative[:, :, [0, 2]] -= positions[:, :1, [0, 2]]
    relative = qrot(root_quat[:, None], relative)

    if local_rotations is None:
        local_rotations = local_rotations_from_joints(positions, skeleton, root_quat)
    elif local_rotations.shape != joints.shape[:2] + (4,):
        raise ValueError(
            f"local_rotations must be {joints.shape[:2] + (4,)}, got {local_rotations.shape}"
        )
    rotations_6d = qto_cont6d(local_rotations[:, 1:])

    joint_velocity = qrot(root_quat[:-1, None], positions[1:] - positions[:-1])
    contacts = foot_contacts(positions, skeleton, contact_threshold)

    frames = positions.shape[0] - 1
    features = np.concatenate(
        [
            yaw_velocity[:, None],
            root_velocity[:, [0, 2]],
            positions[:-1, 0, 1:2],
            relative[:-1, 1:].reshape(frames, -1),
            rotations_6d[:-1].reshape(frames, -1),
            joint_velocity.reshape(frames, -1),
            contacts,
        ],
        axis=-1,
    )
    return features.astype(np.float32), positions.astype(np.float32)


def local_rotations_from_joints(
    positions: np.ndarray, skeleton: Skeleton, root_quat: np.ndarray
) -> np.ndarray:
    """Per-joint local rotations (T, J, 4) by the HumanML3D inverse kinematics.

    Joint j's rotation turns its raw offset direction onto the observed parent->j bone,
    relative to the accumulated rotation along its chain (each chain starts from the root's
    facing rotation). Twist about a bone is not observable from positions and is zero. Signs
    are left as they come: the 6D block they feed is the same for q and -q.
    """
    frames = positions.shape[0]
    rotations = np.zeros((frames, skeleton.num_joints, 4))
    rotations[:, 0] = root_quat
    for chain in skeleton.chains:
        accumulated = root_quat
        for parent, child in zip(chain[:-1], chain[1:], strict=False):
            bone = positions[:, child] - positions[:, parent]
            rest = np.broadcast_to(skeleton.raw_offsets[child], bone.shape)
            local = qmul(qinv(accumulated), qbetween(rest, bone))
            rotations[:, child] = local
            accumulated = qmul(accumulated, local)
    return rotations


def foot_contacts(
    positions: np.ndarray, skeleton: Skeleton, threshold: float = FOOT_CONTACT_THRESHOLD
) -> np.ndarray:
    """(T-1, 4) float32 flags: 1 where a foot joint moved less than the threshold."""
    feet = list(skeleton.left_foot) + list(skeleton.right_foot)
    step = positions[1:, feet] - positions[:-1, feet]
    return (np.sum(step**2, axis=-1) < threshold).astype(np.float32)


def _gaussian_smooth(x: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian filter along axis 0 with edge-value padding (scipy's mode='nearest')."""
    radius = int(4.0 * sigma + 0.5)
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (offsets / sigma) ** 2)
    kernel /= kernel.sum()
    padded = np.concatenate([np.repeat(x[:1], radius, 0), x, np.repeat(x[-1:], radius, 0)], 0)
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * radius + 1, axis=0)
    return windows @ kernel


def _safe_norm(v: np.ndarray, why: str) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(norm < 1e-8):
        frame = int(np.argmin(norm[:, 0]))
        raise ValueError(f"cannot compute the facing direction at frame {frame}: {why}")
    return norm
