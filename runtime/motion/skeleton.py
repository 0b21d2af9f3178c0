"""Skeletons of the HumanML3D (22-joint SMPL) and KIT-ML (21-joint MMM) motion formats.

The raw offsets are the unit bone directions that the feature pipeline's inverse kinematics
aligns bones with (they define what a "zero" local rotation means in the 6D features); the
rest offsets are bone vectors in metres, used by the procedural animator and by exporters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mogo.motion.untrusted import checked_finite


@dataclass(frozen=True)
class Skeleton:
    name: str
    joint_names: tuple[str, ...]
    chains: tuple[tuple[int, ...], ...]  # kinematic chains, each starting at an existing joint
    raw_offsets: np.ndarray  # (J, 3) unit bone directions from the parent, root row zero
    rest_offsets: np.ndarray | None  # (J, 3) bone vectors in metres, Y up, facing +Z
    face_joints: tuple[int, int, int, int]  # right hip, left hip, right shoulder, left shoulder
    left_foot: tuple[int, int]  # ankle, toe: contact joints
    right_foot: tuple[int, int]
    fps: float

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def feature_dim(self) -> int:
        """4 root + (J-1)*3 positions + (J-1)*6 rotations + J*3 velocities + 4 contacts."""
        j = self.num_joints
        return 4 + (j - 1) * 9 + j * 3 + 4

    @property
    def parents(self) -> np.ndarray:
        parents = np.full(self.num_joints, -1, dtype=np.int64)
        for chain in self.chains:
            for parent, child in zip(chain[:-1], chain[1:], strict=False):
                parents[child] = parent
        return parents

    def index(self, name: str) -> int:
        return self.joint_names.index(name)

    def checked_joints(self, joints: np.ndarray, min_frames: int = 1) -> np.ndarray:
        """Joints (T, J, 3) of this skeleton as an array, or a ValueError saying what is wrong:
        the shape, too few frames, NaN or infinite values (the one check, in one wording, of
        everything that reads or writes joints)."""
        joints = np.asarray(joints)
        if joints.ndim != 3 or joints.shape[1:] != (self.num_joints, 3):
            raise ValueError(
                f"joints must be (T, {self.num_joints}, 3) for the {self.name} "
                f"skeleton, got shape {joints.shape}"
            )
        if len(joints) < min_frames:
            raise ValueError(
                f"a clip needs at least {min_frames} frame"
                f"{'s' if min_frames > 1 else ''}, got {len(joints)}"
            )
        return checked_finite(joints, "joints")

    def mirror_permutation(self) -> np.ndarray:
        """Joint index of each joint's left/right twin (itself for centre joints)."""
        names = list(self.joint_names)
        swapped = [_swap_side(n) for n in names]
        return np.array([names.index(s) for s in swapped], dtype=np.int64)


def _swap_side(name: str) -> str:
    for a, b in (("left_", "right_"), ("right_", "left_")):
        if name.startswith(a):
            return b + name[len(a) :]
    return name


def _directions(rows: list[tuple[int, int, int]]) -> np.ndarray:
    return np.array(rows, dtype=np.float64)


SMPL_22 = Skeleton(
    name="humanml3d",
    joint_names=(
        "pelvis",
        "left_hip",
        "right_hip",
        "spine1",
        "left_knee",
        "right_knee",
        "spine2",
        "left_ankle",
        "right_ankle",
        "spine3",
        "left_foot",
        "right_foot",
        "neck",
        "left_collar",
        "right_collar",
        "head",
        "left_shoulder",
        "right_shoulder",
        "left_elbow",
        "right_elbow",
        "left_wrist",
        "right_wrist",
    ),
    chains=(
        (0, 2, 5, 8, 11),
        (0, 1, 4, 7, 10),
        (0, 3, 6, 9, 12, 15),
        (9, 14, 17, 19, 21),
        (9, 13, 16, 18, 20),
    ),
    raw_offsets=_directions(
        [
            (0, 0, 0),
            (1, 0, 0),
            (-1, 0, 0),
            (0, 1, 0),
            (0, -1, 0),
            (0, -1, 0),
            (0, 1, 0),
            (0, -1, 0),
            (0, -1, 0),
            (0, 1, 0),
            (0, 0, 1),
            (0, 0, 1),
            (0, 1, 0),
            (1, 0, 0),
            (-1, 0, 0),
            (0, 0, 1),
            (0, -1, 0),
            (0, -1, 0),
            (0, -1, 0),
            (0, -1, 0),
            (0, -1, 0),
            (0, -1, 0),
        ]
    ),
    # An adult of about 1.72 m standing with arms hanging (pelvis 0.96 m above the floor).
    # +X is the character's left.
    rest_offsets=np.array(
        [
            (0.0, 0.0, 0.0),  # pelvis
            (0.09, -0.07, 0.0),  # left_hip
            (-0.09, -0.07, 0.0),  # right_hip
            (0.0, 0.11, -0.01),  # spine1
            (0.0, -0.40, 0.0),  # left_knee (thigh)
            (0.0, -0.40, 0.0),  # right_knee
            (0.0, 0.13, 0.0),  # spine2
            (0.0, -0.41, -0.01),  # left_ankle (shin)
            (0.0, -0.41, -0.01),  # right_ankle
            (0.0, 0.05, 0.02),  # spine3
            (0.0, -0.06, 0.13),  # left_foot (ball of the foot)
            (0.0, -0.06, 0.13),  # right_foot
            (0.0, 0.21, -0.01),  # neck
            (0.07, 0.12, -0.01),  # left_collar
            (-0.07, 0.12, -0.01),  # right_collar
            (0.0, 0.10, 0.04),  # head
            (0.11, 0.03, 0.0),  # left_shoulder
            (-0.11, 0.03, 0.0),  # right_shoulder
            (0.0, -0.27, 0.0),  # left_elbow (upper arm)
            (0.0, -0.27, 0.0),  # right_elbow
            (0.0, -0.25, 0.0),  # left_wrist (forearm)
            (0.0, -0.25, 0.0),  # right_wrist
        ],
        dtype=np.float64,
    ),
    face_joints=(2, 1, 17, 16),
    left_foot=(7, 10),
    right_foot=(8, 11),
    fps=20.0,
)

KIT_21 = Skeleton(
    name="kit",
    joint_names=(
        "root",
        "torso",
        "chest",
        "neck",
        "head",
        "right_shoulder",
        "right_elbow",
        "right_wrist",
        "left_shoulder",
        "left_elbow",
        "left_wrist",
        "right_hip",
        "right_knee",
        "right_ankle",
        "right_heel",
        "right_toe",
        "left_hip",
        "left_knee",
        "left_ankle",
        "left_heel",
        "left_toe",
    ),
    chains=(
        (0, 11, 12, 13, 14, 15),
        (0, 16, 17, 18, 19, 20),
        (0, 1, 2, 3, 4),
        (3, 5, 6, 7),
        (3, 8, 9, 10),
    ),
    raw_offsets=_directions(
        [
            (0, 0, 0),
            (0, 1, 0),
            (0, 1, 0),
            (0, 1, 0),
            (0, 1, 0),
            (1, 0, 0),
            (0, -1, 0),
            (0, -1, 0),
            (-1, 0, 0),
            (0, -1, 0),
            (0, -1, 0),
            (1, 0, 0),
            (0, -1, 0),
            (0, -1, 0),
            (0, 0, 1),
            (0, 0, 1),
            (-1, 0, 0),
            (0, -1, 0),
            (0, -1, 0),
            (0, 0, 1),
            (0, 0, 1),
        ]
    ),
    rest_offsets=None,  # KIT-ML bone lengths vary per subject; the format needs directions only
    face_joints=(11, 16, 5, 8),
    left_foot=(19, 20),
    right_foot=(14, 15),
    fps=12.5,
)

SKELETONS = {SMPL_22.name: SMPL_22, KIT_21.name: KIT_21}

# HumanML3D's clip lengths: caption spans of MIN_FRAMES..MAX_FRAMES feature rows are what the
# standard loaders train and evaluate on. At SMPL_22's 20 fps the longest is 9.8 s, the most a
# bundle generates in one clip unless its manifest says otherwise.
MIN_FRAMES, MAX_FRAMES = 40, 196
MAX_SECONDS = MAX_FRAMES / SMPL_22.fps


def skeleton_for_feature_dim(dim: int) -> Skeleton:
    for skeleton in SKELETONS.values():
        if skeleton.feature_dim == dim:
            return skeleton
    known = ", ".join(f"{s.feature_dim} ({s.name})" for s in SKELETONS.values())
    raise ValueError(f"no skeleton has {dim}-dim features; known: {known}")
