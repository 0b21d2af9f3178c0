"""The add-on's maths, numpy only (no bpy): our rig in Blender's axes, pose-bone keys from the
runtime's joint rotations (mogo.motion.rig solves them: nothing is solved a second time here),
and the retarget of those rotations onto another armature.

Blender's pose-bone rotation is in the bone's own rest frame B (armature space): a bone whose
world rotation relative to its rest is W, under a parent at W_p, takes B^T W_p^T W B. Ours is a
clean T-pose, so our world rotation from rest is the rig's rotation itself, turned into
Blender's axes (Z up, facing -Y) by C.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from mogo.motion import rig
from mogo.motion.bvh import NAMINGS
from mogo.motion.quaternion import qbetween, qfrom_matrix, qto_matrix

C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # ours (Y up) -> Blender
BONE_NAMES = NAMINGS["mixamo"]  # our armature's bones, each named for the segment it moves
LIMBS = ("shoulder", "elbow", "wrist", "hip", "knee", "ankle", "foot")  # see Target.rest_turn
# Retarget presets: for each of our joints, the names a target's bone may have (compared without
# case, punctuation and a "prefix:" such as Mixamo's "mixamorig:").
SMPL_NAMES = (
    "Pelvis",
    "L_Hip",
    "R_Hip",
    "Spine1",
    "L_Knee",
    "R_Knee",
    "Spine2",
    "L_Ankle",
    "R_Ankle",
    "Spine3",
    "L_Foot",
    "R_Foot",
    "Neck",
    "L_Collar",
    "R_Collar",
    "Head",
    "L_Shoulder",
    "R_Shoulder",
    "L_Elbow",
    "R_Elbow",
    "L_Wrist",
    "R_Wrist",
)
PRESETS = {
    "MIXAMO": [(name,) for name in BONE_NAMES],
    "SMPL": list(zip(SMPL_NAMES, NAMINGS["smpl"], strict=False)),
}
NAME_BYTES = 63  # Blender's longest ID name (UTF-8 bytes; 3.4 to 4.x)
NUMBERED = re.compile(r"\.\d{3,}$")  # ".001": Blender's number for a name already taken


def action_name(text: str, suffix: str = "") -> str:
    """An Action's name within Blender's NAME_BYTES, with room for the ".001" Blender adds to
    a name already taken: `text` cut after a whole word (mid-word only where a single word is
    too long), its own ".001" and `suffix` (" on Armature", " (live)") kept."""
    budget = NAME_BYTES - len(".001")
    number = match.group() if (match := NUMBERED.search(text)) else ""
    suffix = _cut(number + suffix, budget // 2, words=False)  # a long armature name: its half
    return (
        _cut(text[: len(text) - len(number)], budget - len(suffix.encode())) or "motion"
    ) + suffix


def _cut(text: str, limit: int, words: bool = True) -> str:
    """`text` within `limit` UTF-8 bytes: whole, or cut at its last space that fits (`words`;
    else, or where one word is too long, after the last whole character that fits)."""
    if len(text.encode()) <= limit:
        return text
    head = text.encode()[: limit + 1].decode("utf-8", "ignore")  # + 1: a space just after
    if words and " " in head.strip():
        return head.rsplit(" ", 1)[0].rstrip(" ,;:")
    return text.encode()[:limit].decode("utf-8", "ignore")


@dataclass(frozen=True)
class OurRig:
    """Our armature: the bundle's rigid T-pose rest skeleton in Blender's axes (metres)."""

    skeleton: object
    offsets: np.ndarray  # (J, 3) the rig's rest bone vectors, ours (Y up)
    heads: np.ndarray  # (J, 3) rest joint positions, Blender axes
    tails: np.ndarray  # (J, 3) where each bone points at rest

    @classmethod
    def of(cls, skeleton) -> OurRig:
        offsets = rig.rest_offsets(skeleton)
        heads = np.zeros_like(offsets)
        for joint in rig.depth_first(skeleton):
            parent = skeleton.parents[joint]
            heads[joint] = offsets[joint] if parent < 0 else heads[parent] + offsets[joint]
        ends = rig.end_sites(skeleton, offsets)
        tails = np.array(
            [
                heads[j] + (offsets[c] if c is not None else ends[j])
                for j, c in enumerate(chain_children(skeleton))
            ]
        )
        return cls(skeleton, offsets, heads @ C.T, tails @ C.T)

    def world(self, joints: np.ndarray) -> np.ndarray:
        """Each bone's world rotation from rest (T, J, 3, 3) in Blender's axes, for joints."""
        joints = rig.checked_joints(joints, self.skeleton, 1.0)
        return C @ rig.world_rotations(joints, self.skeleton, self.offsets) @ C.T


def chain_children(skeleton) -> list[int | None]:
    """The child each bone points at: the spine's at a fork (pelvis, chest), none at a leaf."""
    kids = [
        [c for c, p in enumerate(skeleton.parents) if p == j] for j in range(skeleton.num_joints)
    ]
    names = skeleton.joint_names
    return [
        next((c for c in k if "spine" in names[c] or "neck" in names[c]), k[0]) if k else None
        for k in kids
    ]


def pose_keys(
    world: np.ndarray, rest: np.ndarray, parents, previous: np.ndarray | None = None
) -> np.ndarray:
    """Pose-bone quaternions (T, J, 4) (w, x, y, z) for world rotations from rest (T, J, 3, 3)
    of bones with rest frames `rest` (J, 3, 3); None in `parents` for a root; `previous`: the
    last keys before these (sign continuity across chunks of a stream)."""
    parent_world = np.stack(
        [
            world[:, p] if p is not None else np.broadcast_to(np.eye(3), world[:, 0].shape)
            for p in parents
        ],
        axis=1,
    )
    rest_t = np.swapaxes(rest, -1, -2)
    basis = rest_t @ np.swapaxes(parent_world, -1, -2) @ world @ rest
    return continuous(qfrom_matrix(basis), previous)


def root_location(
    position: np.ndarray, rest_head: np.ndarray, rest: np.ndarray, to_armature: np.ndarray
) -> np.ndarray:
    """A root bone's location keys (T, 3): world positions `position` of its head, for a bone
    whose parents stay at rest, given its rest head (world), rest frame (armature space) and
    the armature object's inverse 3x3 matrix."""
    return (position - rest_head) @ to_armature.T @ rest


def continuous(quaternions: np.ndarray, previous: np.ndarray | None = None) -> np.ndarray:
    """q and -q are one rotation: each key the sign nearer the key before, so keys
    interpolate the short way."""
    q = np.array(quaternions)
    last = previous
    for t in range(len(q)):
        if last is not None:
            q[t] *= np.where(np.sum(q[t] * last, axis=-1, keepdims=True) < 0, -1.0, 1.0)
        last = q[t]
    return q


def world_from_keys(quaternions: np.ndarray, rest: np.ndarray, parents) -> np.ndarray:
    """The inverse of pose_keys: world rotations from rest (T, J, 3, 3) of an action's keys."""
    basis = qto_matrix(quaternions)
    world = np.zeros_like(basis)
    for joint, parent in enumerate(parents):  # parents before children
        local = rest[joint] @ basis[:, joint] @ rest[joint].T
        world[:, joint] = local if parent is None else world[:, parent] @ local
    return world


def normalised(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.rsplit(":", 1)[-1].lower())


def auto_map(preset: str, target_bones: list[str]) -> list[str]:
    """For each of our joints, the target bone the preset names ('' where none is there)."""
    found = {normalised(name): name for name in target_bones}
    return [
        next((found[normalised(c)] for c in candidates if normalised(c) in found), "")
        for candidates in PRESETS[preset]
    ]


@dataclass(frozen=True)
class Target:
    """A user's armature at rest, world space: bone names, parents (indices, parents first),
    rest frames in armature space (K, 3, 3), the object's rotation (3, 3, no scale), its
    inverse 3x3 matrix, and bone heads and tails (K, 3)."""

    names: list[str]
    parents: list[int | None]
    rest: np.ndarray
    rotation: np.ndarray
    to_armature: np.ndarray
    heads: np.ndarray
    tails: np.ndarray


def retarget(
    world: np.ndarray, pelvis: np.ndarray, ours: OurRig, target: Target, mapping: list[str]
) -> tuple[dict[str, np.ndarray], np.ndarray, float]:
    """Our motion (world rotations from rest (T, J, 3, 3) in Blender's axes, the pelvis (T, 3)
    in Blender's axes) on the target: quaternion keys (T, 4) per target bone that a joint maps
    to, the hips' location keys (T, 3), and the root-motion scale (leg length ratio).

    Each mapped bone turns in the world as our joint does; a limb bone first turns from its
    rest direction onto ours (an A-pose arm, a splayed leg), while torso, neck and head keep
    the target's own rest (every T-pose rig has them upright, and ours lean by the corpus's
    build). Bones mapped to nothing follow their parent."""
    index = {name: k for k, name in enumerate(target.names)}
    source = {index[name]: joint for joint, name in enumerate(mapping) if name in index}
    if 0 not in source.values():
        raise ValueError("map our Hips to a bone of the target (its root motion)")
    frames = world.shape[0]
    rest_world = target.rotation @ target.rest  # (K, 3, 3)
    delta = np.zeros((frames, len(target.names), 3, 3))
    keys = {}
    for k, parent in enumerate(target.parents):
        if k in source:
            delta[:, k] = world[:, source[k]] @ _rest_turn(k, source, ours, target, mapping)
        else:
            delta[:, k] = np.eye(3) if parent is None else delta[:, parent]
        if k in source:
            above = np.eye(3) if parent is None else delta[:, parent]
            basis = rest_world[k].T @ np.swapaxes(above, -1, -2) @ delta[:, k] @ rest_world[k]
            keys[target.names[k]] = continuous(qfrom_matrix(basis))
    scale = _leg_scale(ours, target, mapping, index)
    hips = next(k for k, joint in source.items() if joint == 0)
    position = target.heads[hips] + scale * (pelvis - ours.heads[0])
    return (
        keys,
        root_location(position, target.heads[hips], target.rest[hips], target.to_armature),
        scale,
    )


def _rest_turn(
    k: int, source: dict, ours: OurRig, target: Target, mapping: list[str]
) -> np.ndarray:
    """The turn taking a limb bone's rest direction onto ours (identity off the limbs)."""
    joint = source[k]
    if ours.skeleton.joint_names[joint].split("_")[-1] not in LIMBS:
        return np.eye(3)
    child = chain_children(ours.skeleton)[joint]
    our_direction = ours.tails[joint] - ours.heads[joint]
    their_child = (
        target.names.index(mapping[child])
        if child is not None and mapping[child] in target.names
        else None
    )
    their_end = target.heads[their_child] if their_child is not None else target.tails[k]
    return qto_matrix(qbetween(their_end - target.heads[k], our_direction))


def _leg_scale(ours: OurRig, target: Target, mapping: list[str], index: dict) -> float:
    """Target leg length (hip -> knee -> ankle) over ours; the hips' heights where the left leg
    is not mapped."""
    names = ours.skeleton.joint_names
    leg = [names.index(n) for n in ("left_hip", "left_knee", "left_ankle")]
    if all(mapping[j] in index for j in leg):
        theirs = target.heads[[index[mapping[j]] for j in leg]]
        ours_heads = ours.heads[leg]
        return float(
            np.linalg.norm(np.diff(theirs, axis=0), axis=1).sum()
            / np.linalg.norm(np.diff(ours_heads, axis=0), axis=1).sum()
        )
    return float(target.heads[index[mapping[0]], 2] / ours.heads[0, 2])
