"""The rig's rotations: the same pose gives the same local rotations whichever way the body
faces, twist follows the body (no flips), and the leaves (head, hands, toes) are derived."""

import numpy as np

from mogo import MotionGenerator
from mogo.motion import rig
from mogo.motion.quaternion import qrot, qyaw
from mogo.motion.skeleton import SMPL_22


def _local(joints: np.ndarray) -> np.ndarray:
    offsets = rig.rest_offsets(SMPL_22)
    return rig.local_rotations(rig.world_rotations(joints, SMPL_22, offsets), SMPL_22)


def _walk() -> np.ndarray:
    return (
        MotionGenerator.load()
        .generate("a person walks forward and waves.", seconds=3.0, seed=0)
        .joints.astype(np.float64)
    )


def test_local_rotations_do_not_depend_on_the_facing():
    """Turned to face away (and every other way), the body's joints keep their rotations."""
    joints = _walk()
    reference = _local(joints)
    for degrees in (90.0, 180.0, 270.0):
        turned = qrot(qyaw(np.full(joints.shape[:2], np.radians(degrees))), joints)
        np.testing.assert_allclose(_local(turned)[:, 1:], reference[:, 1:], atol=1e-6)


def test_rotations_change_smoothly_and_the_leaves_move():
    local = _local(_walk())
    cosines = (np.einsum("tjab,tjab->tj", local[1:], local[:-1]) - 1) / 2  # cos of each step
    assert np.degrees(np.arccos(np.clip(cosines, -1, 1))).max() < 45.0  # no twist flips
    angles = np.degrees(np.arccos(np.clip((np.trace(local, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))
    for name in ("head", "left_wrist", "right_wrist", "left_foot", "right_foot"):
        assert np.ptp(angles[:, SMPL_22.index(name)]) > 1.0, name


def test_forward_kinematics_keeps_the_rig_rigid():
    joints = _walk()
    offsets = rig.rest_offsets(SMPL_22)
    posed = rig.posed_joints(joints, SMPL_22)
    bones = np.linalg.norm(posed[:, 1:] - posed[:, SMPL_22.parents[1:]], axis=-1)
    np.testing.assert_allclose(
        bones, np.broadcast_to(np.linalg.norm(offsets[1:], axis=-1), bones.shape), atol=1e-9
    )
    error = np.linalg.norm(posed - joints, axis=-1)
    assert error.mean() < 0.02 and error.max() < 0.15  # docs/bvh.md states the figures
