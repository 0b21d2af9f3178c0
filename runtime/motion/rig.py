"""One rigid character for every clip of a bundle, and the joint rotations that pose it.

Exporters (BVH) write a rest skeleton and per-frame local rotations; DCC tools and retargeters
(Blender, Unity, Mixamo) expect one skeleton per character, a clean T-pose at zero rotation, and
rotations with a sensible twist. This module gives both, from joint positions alone:

- the rest skeleton: the bundle's canonical bone lengths (the manifest's rest offsets), left
  and right averaged; at zero rotation the spine, neck and head bones point straight up, arms
  straight out along +-X, legs straight down, feet flat along +Z (the facing), on the floor;
- world rotations per frame: the pelvis and the upper spine get full frames fitted to their
  child joints (Kabsch: hips + spine, neck + collars), so nothing flips when the character
  faces away; every other bone points at its observed child, twisted by a body reference
  (the spine and neck by the lateral axes of pelvis and chest, collars by the chest's facing,
  an upper arm by the plane its elbow bends in, a thigh by its knee's bend and then its
  foot), falling back smoothly to the parent's twist where the reference vanishes (a straight
  limb); elbows, knees and ankles take their parent's twist (hinges);
- bones aim from where the rig put their joint, so length differences do not add up along
  the chains;
- the leaves, which positions do not determine, are derived: the head continues half the
  neck's bend, a relaxed hand droops under gravity, toes lie flat while the ball of the foot
  touches the floor.
Rigid bones cannot follow generated bones that stretch by centimetres, so the rig's joints are
off the clip's by the length differences (docs/bvh.md states the figures).
"""

from __future__ import annotations

import numpy as np

from mogo.motion.quaternion import cross, qbetween, qnormalize, qto_matrix
from mogo.motion.skeleton import SMPL_22, Skeleton

X, Y, Z = np.eye(3)
# Rest direction of each bone (parent -> joint) by the joint's name without its side; None: the
# canonical vector (left and right averaged) from a joint with several children (pelvis, upper
# spine), fixed in that joint's frame: the corpus's hips, spine base, collars and neck base, so
# motion of the corpus's proportions comes back exactly; a DCC bone spans none of them.
_REST_DIRECTION = {
    "hip": None,
    "knee": -Y,
    "ankle": -Y,
    "foot": Z,
    "spine1": None,
    "spine2": Y,
    "spine3": Y,
    "neck": None,
    "head": Y,
    "collar": None,
    "shoulder": X,
    "elbow": X,
    "wrist": X,
}
_SPINE_SHARE = {"spine1": 1 / 3, "spine2": 2 / 3, "neck": 1.0}  # chest's lateral axis vs pelvis'
BEND_FULL = np.sin(np.radians(20.0))  # a reference this far off the bone decides the twist alone
HAND_DROOP = 0.3  # a relaxed hand points along forearm + this much straight down
TOE_CONTACT = 0.05  # metres: toes lie flat with the ball this close to the floor, free at twice
# Leaf bones' length as a share of the bone before them: the End Site of the BVH.
END_SITE = {"head": 1.0, "wrist": 0.3, "foot": 0.4}


def check(skeleton: Skeleton) -> None:
    """The rig is the SMPL 22-joint one: its rules name joints."""
    if skeleton.joint_names != SMPL_22.joint_names or skeleton.rest_offsets is None:
        raise ValueError(
            f"the rig needs the {SMPL_22.name} skeleton with rest offsets, got {skeleton.name}"
        )


def checked_joints(joints: np.ndarray, skeleton: Skeleton, fps: float) -> np.ndarray:
    """Joints (T, J, 3) as float64, or a ValueError saying what is wrong (exporters' checks:
    Skeleton.checked_joints, and a positive fps)."""
    joints = skeleton.checked_joints(np.asarray(joints, dtype=np.float64))
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    return joints


def rest_offsets(skeleton: Skeleton) -> np.ndarray:
    """(J, 3) bone vectors in metres of the clean T-pose; row 0 is the pelvis above the floor."""
    check(skeleton)
    source = np.asarray(skeleton.rest_offsets, dtype=np.float64)
    symmetric = (source + source[skeleton.mirror_permutation()] * (-1.0, 1.0, 1.0)) / 2
    lengths = np.linalg.norm(symmetric, axis=1)
    offsets = np.zeros_like(symmetric)
    for joint, name in enumerate(skeleton.joint_names[1:], start=1):
        side = -1.0 if name.startswith("right_") else 1.0
        direction = _REST_DIRECTION[name.split("_")[-1]]
        if direction is None:
            offsets[joint] = symmetric[joint]
        else:
            offsets[joint] = lengths[joint] * direction * (side if direction[0] else 1.0)
    legs = [skeleton.index(n) for n in ("left_hip", "left_knee", "left_ankle")]
    offsets[0, 1] = -offsets[legs, 1].sum()  # ankles and feet on the floor
    return offsets + 0.0  # no negative zeros in files


def end_sites(skeleton: Skeleton, offsets: np.ndarray) -> dict[int, np.ndarray]:
    """Leaf joint -> its End Site offset (the tip of the head, hand or toes)."""
    tips = {}
    for joint, name in enumerate(skeleton.joint_names):
        share = END_SITE.get(name.split("_")[-1])
        if share is not None:
            tips[joint] = share * offsets[joint]
    return tips


def world_rotations(joints: np.ndarray, skeleton: Skeleton, offsets: np.ndarray) -> np.ndarray:
    """Rotations (T, J, 3, 3) of every joint's frame in the world (see the module doc). Each
    bone aims from where the rig has put its joint at the clip's next joint, so bone-length
    differences do not add up along the chains. (Two-bone IK reaching the clip's hands and
    feet was tried: it halves their error but bends or straightens knees and elbows by up to
    15 cm, a larger error over all joints.)"""
    joints = np.asarray(joints, dtype=np.float64)
    index, parents = skeleton.index, skeleton.parents
    children = _children(skeleton)
    rotations = np.zeros(joints.shape[:2] + (3, 3))
    for name in ("pelvis", "spine3"):
        joint = index(name)
        kids = children[joint]
        rotations[:, joint] = _kabsch(offsets[kids], joints[:, kids] - joints[:, joint, None])
    lateral = {part: rotations[:, index(part)][..., 0] for part in ("pelvis", "spine3")}
    chest = rotations[:, index("spine3")]
    floor = joints[:, [index("left_foot"), index("right_foot")], 1].min()
    posed = joints.copy()  # the rig's joints, filled in parent before child
    for joint in depth_first(skeleton):
        name = skeleton.joint_names[joint]
        part = name.split("_")[-1]
        parent = np.eye(3) if joint == 0 else rotations[:, parents[joint]]
        if not children[joint]:
            rotations[:, joint] = _leaf(part, joints, joint, parent, offsets[joint], chest, floor)
        elif part not in ("pelvis", "spine3"):
            child = children[joint][0]
            if np.any(np.linalg.norm(joints[:, child] - joints[:, joint], axis=-1) < 1e-9):
                raise ValueError(f"joint {name} coincides with its child")
            rest_ref, candidates = _references(part, joints, child, lateral, chest, skeleton)
            aim = joints[:, child] - posed[:, joint]
            rotations[:, joint] = _aim(offsets[child], rest_ref, aim, candidates, parent)
        for child in children[joint]:
            posed[:, child] = posed[:, joint] + rotations[:, joint] @ offsets[child]
    return rotations


def local_rotations(world: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """Each joint's rotation in its parent's frame (the root's in the world)."""
    local = world.copy()
    for joint, parent in enumerate(skeleton.parents):
        if parent >= 0:
            local[:, joint] = np.swapaxes(world[:, parent], -1, -2) @ world[:, joint]
    return local


def forward(
    offsets: np.ndarray, skeleton: Skeleton, root: np.ndarray, local: np.ndarray
) -> np.ndarray:
    """Joint positions (T, J, 3) of the rig posed by local rotations, the pelvis at `root`."""
    world = np.zeros_like(local)
    joints = np.zeros(local.shape[:2] + (3,))
    for joint in depth_first(skeleton):
        parent = skeleton.parents[joint]
        if parent < 0:
            world[:, joint], joints[:, joint] = local[:, joint], root
        else:
            world[:, joint] = world[:, parent] @ local[:, joint]
            joints[:, joint] = joints[:, parent] + world[:, parent] @ offsets[joint]
    return joints


def posed_joints(joints: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """The rig's joints (T, J, 3) posed like `joints`: what an exported file gives back."""
    offsets = rest_offsets(skeleton)
    local = local_rotations(world_rotations(joints, skeleton, offsets), skeleton)
    return forward(offsets, skeleton, np.asarray(joints, dtype=np.float64)[:, 0], local)


def depth_first(skeleton: Skeleton) -> list[int]:
    """Joints in hierarchy order (each after its parent), as a BVH lists them."""
    children = _children(skeleton)
    order, stack = [], [0]
    while stack:
        joint = stack.pop()
        order.append(joint)
        stack.extend(reversed(children[joint]))
    return order


def _children(skeleton: Skeleton) -> list[list[int]]:
    parents = skeleton.parents
    return [
        [c for c in range(skeleton.num_joints) if parents[c] == j]
        for j in range(skeleton.num_joints)
    ]


def _references(
    part: str, joints: np.ndarray, child: int, lateral: dict, chest: np.ndarray, skeleton: Skeleton
) -> tuple[np.ndarray, list[np.ndarray]]:
    """A bone's rest twist reference and the observed ones that set its twist, best first."""
    if part in _SPINE_SHARE:
        share = _SPINE_SHARE[part]
        return X, [(1 - share) * lateral["pelvis"] + share * lateral["spine3"]]
    if part == "collar":
        return Z, [chest[..., 2]]
    grandchild = [c for c in range(skeleton.num_joints) if skeleton.parents[c] == child]
    if part in ("shoulder", "hip"):
        limb = _unit(joints[:, child] - joints[:, skeleton.parents[child]])
        below = _unit(joints[:, grandchild[0]] - joints[:, child])
        if part == "shoulder":  # the elbow bends forward from the T-pose
            return Z, [below - limb * _dot(below, limb)]
        toe = [c for c in range(skeleton.num_joints) if skeleton.parents[c] == grandchild[0]]
        foot = _unit(joints[:, toe[0]] - joints[:, grandchild[0]])
        return Z, [limb * _dot(below, limb) - below, foot]  # the knee's front, then the foot
    return Z, []  # hinges and the ankle: the parent's twist


def _aim(
    rest_bone: np.ndarray,
    rest_ref: np.ndarray,
    bone: np.ndarray,
    candidates: list[np.ndarray],
    parent: np.ndarray,
) -> np.ndarray:
    """The rotation taking the rest bone onto the observed bone, twisted so the rest reference
    goes to the observed references' blend (each weighted by how far it is off the bone, the
    parent's twist taking what is left)."""
    direction = _unit(bone)
    swing = qto_matrix(qbetween(parent @ _unit(rest_bone), direction)) @ parent
    if not candidates:
        return swing
    reference = np.zeros_like(direction)
    left = np.ones(direction.shape[:-1] + (1,))
    for candidate in candidates:
        across = candidate - direction * _dot(candidate, direction)
        length = np.linalg.norm(across, axis=-1, keepdims=True)
        weight = np.clip(length / BEND_FULL, 0.0, 1.0)
        reference += left * weight * across / np.maximum(length, 1e-12)
        left = left * (1.0 - weight)
    reference += left * (swing @ rest_ref)
    fallback = np.linalg.norm(cross(direction, reference), axis=-1) < 1e-6
    reference[fallback] = (swing @ rest_ref)[fallback]
    return _frame(direction, reference) @ _frame(_unit(rest_bone), rest_ref).T


def _leaf(
    part: str,
    joints: np.ndarray,
    joint: int,
    parent: np.ndarray,
    offset: np.ndarray,
    chest: np.ndarray,
    floor: float,
) -> np.ndarray:
    """A leaf's world rotation: its parent's, turned as the module doc says."""
    bone = parent @ _unit(offset)  # the parent's bone as the rig has it
    if part == "head":  # on from the neck by half the neck's bend from the chest's up
        half = qnormalize(qbetween(chest[..., 1], bone) + np.array([1.0, 0.0, 0.0, 0.0]))
        return qto_matrix(half) @ parent  # (shortest arcs have w >= 0: the half is the sum's)
    if part == "wrist":
        target = _unit(bone - HAND_DROOP * Y)
    else:  # toes: flat on the floor in contact, following the foot higher up
        height = joints[:, joint, 1] - floor
        contact = np.clip(2.0 - height / TOE_CONTACT, 0.0, 1.0)[:, None]
        flat = bone * (1.0, 0.0, 1.0)
        contact *= np.clip(np.linalg.norm(flat, axis=-1, keepdims=True) / BEND_FULL, 0.0, 1.0)
        target = _unit(bone + contact * (_unit(flat) - bone))
    return qto_matrix(qbetween(bone, target)) @ parent


def _frame(primary: np.ndarray, secondary: np.ndarray) -> np.ndarray:
    """Orthonormal frames (..., 3, 3): columns primary, primary x secondary, and their cross."""
    second = _unit(cross(primary, secondary))
    return np.stack([primary, second, cross(primary, second)], axis=-1)


def _kabsch(rest: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Rotations (T, 3, 3) best taking rest vectors (C, 3) onto observed ones (T, C, 3)."""
    covariance = np.einsum("tci,cj->tij", observed, rest)
    u, _, vt = np.linalg.svd(covariance)
    sign = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= sign[:, None]
    return u @ vt


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 1e-12)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1, keepdims=True)
