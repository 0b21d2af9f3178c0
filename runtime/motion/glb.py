"""GLB (binary glTF 2.0) export: a skinned mannequin animated by joint rotations.

Where a BVH carries a skeleton only, a GLB carries something to look at: three.js, Blender and
most engines play it as it is. The skeleton is mogo.motion.rig's (the bundle's one T-pose
character, the rotations it solves), its nodes named as the BVH's (Mixamo names by default);
the mesh is procedural, a ball at every joint and a tapered rod along every bone, each part
bound wholly to the joint that moves it. The animation: a rotation per joint per frame
(linear, quaternions kept on one hemisphere frame to frame) and the root's translation.
glTF is Y up, metres, facing +Z: our joints' own frame, so nothing is converted.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np

from mogo.motion import rig
from mogo.motion.quaternion import qfrom_matrix
from mogo.motion.skeleton import Skeleton

SEGMENTS = 10  # around each rod and ball
# Radii in metres by the joint's name without its side: a rod along the bone the joint moves
# (to its centre child: the upper spine's rod ends at the neck), a ball at the joint.
ROD = {
    "pelvis": 0.0,
    "hip": 0.065,
    "knee": 0.05,
    "ankle": 0.04,
    "foot": 0.03,
    "spine1": 0.075,
    "spine2": 0.08,
    "spine3": 0.085,
    "neck": 0.045,
    "head": 0.0,
    "collar": 0.045,
    "shoulder": 0.05,
    "elbow": 0.04,
    "wrist": 0.03,
}
BALL = {"pelvis": 0.12, "head": 0.1, "wrist": 0.04, "foot": 0.045}
_BALL_DEFAULT = 0.05
_FLOAT, _UINT16, _UINT32 = 5126, 5123, 5125  # glTF component types
_ARRAY, _ELEMENTS = 34962, 34963  # bufferView targets


def save_glb(
    path: str | os.PathLike,
    joints: np.ndarray,
    skeleton: Skeleton,
    fps: float,
    names: tuple[str, ...],
) -> None:
    """Write joints (T, J, 3) in metres (Y up) as an animated, skinned GLB; `names`: the node
    name of each joint (mogo.motion.bvh.joint_names)."""
    joints = rig.checked_joints(joints, skeleton, fps)
    offsets = rig.rest_offsets(skeleton)
    local = rig.local_rotations(rig.world_rotations(joints, skeleton, offsets), skeleton)
    rest = rig.forward(
        offsets, skeleton, offsets[None, 0], np.tile(np.eye(3), (1, len(offsets), 1, 1))
    )[0]
    quaternions = qfrom_matrix(local)
    flips = np.sign(np.sum(quaternions[1:] * quaternions[:-1], axis=-1))  # (T-1, J)
    quaternions[1:] *= np.cumprod(np.where(flips == 0, 1.0, flips), axis=0)[..., None]
    gltf = _Builder()
    times = np.arange(len(joints), dtype=np.float32) / np.float32(fps)
    document = dict(
        asset=dict(version="2.0", generator="mogo"),
        scene=0,
        scenes=[dict(nodes=[0, skeleton.num_joints])],
        nodes=_nodes(skeleton, offsets, names),
        **_mannequin_parts(gltf, skeleton, offsets, rest),
        animations=[_animation(gltf, times, quaternions, joints[:, 0])],
        accessors=gltf.accessors,
        bufferViews=gltf.views,
        buffers=[dict(byteLength=len(gltf.blob))],
    )
    Path(path).write_bytes(_glb(document, bytes(gltf.blob)))


def _mannequin_parts(gltf: _Builder, skeleton: Skeleton, offsets, rest) -> dict:
    """The document's mesh, its material and its skin: the mannequin, skinned to the rig."""
    mesh = _mannequin(skeleton, offsets, rest)
    return dict(
        meshes=[
            dict(
                name="mannequin",
                primitives=[
                    dict(
                        attributes=dict(
                            POSITION=gltf.add(mesh[0], "VEC3", _ARRAY, bounds=True),
                            NORMAL=gltf.add(mesh[1], "VEC3", _ARRAY),
                            JOINTS_0=gltf.add(mesh[2], "VEC4", _ARRAY),
                            WEIGHTS_0=gltf.add(mesh[3], "VEC4", _ARRAY),
                        ),
                        indices=gltf.add(mesh[4], "SCALAR", _ELEMENTS),
                        material=0,
                    )
                ],
            )
        ],
        materials=[
            dict(
                name="mannequin",
                pbrMetallicRoughness=dict(
                    baseColorFactor=[0.3, 0.45, 0.75, 1.0], metallicFactor=0.0, roughnessFactor=0.7
                ),
                doubleSided=True,
            )
        ],
        skins=[
            dict(
                joints=list(range(skeleton.num_joints)),
                skeleton=0,
                inverseBindMatrices=gltf.add(_inverse_binds(rest), "MAT4"),
            )
        ],
    )


class _Builder:
    """The binary buffer, its views and accessors, appended to in order."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add(
        self, array: np.ndarray, kind: str, target: int | None = None, bounds: bool = False
    ) -> int:
        """One array as a bufferView and an accessor; returns the accessor's index."""
        component = {
            np.dtype(np.float32): _FLOAT,
            np.dtype(np.uint16): _UINT16,
            np.dtype(np.uint32): _UINT32,
        }[array.dtype]
        view = dict(buffer=0, byteOffset=len(self.blob), byteLength=array.nbytes)
        if target is not None:
            view["target"] = target
        self.blob += array.tobytes()
        self.blob += bytes(-len(self.blob) % 4)
        self.views.append(view)
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[kind]
        accessor = dict(
            bufferView=len(self.views) - 1,
            componentType=component,
            count=int(array.size // width),
            type=kind,
        )
        if bounds:
            flat = array.reshape(-1, width)
            accessor.update(min=flat.min(0).tolist(), max=flat.max(0).tolist())
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def _nodes(skeleton: Skeleton, offsets: np.ndarray, names: tuple[str, ...]) -> list[dict]:
    nodes = []
    for joint in range(skeleton.num_joints):
        node = dict(name=names[joint], translation=offsets[joint].tolist())
        kids = [int(c) for c in np.flatnonzero(skeleton.parents == joint)]
        if kids:
            node["children"] = kids
        nodes.append(node)
    return nodes + [dict(name="mannequin", mesh=0, skin=0)]


def _animation(
    gltf: _Builder, times: np.ndarray, quaternions: np.ndarray, root: np.ndarray
) -> dict:
    """Rotations of every joint node (glTF's x, y, z, w) and the root's translation."""
    clock = gltf.add(times, "SCALAR", bounds=True)
    samplers, channels = [], []
    outputs = [
        (joint, "rotation", quaternions[:, joint][:, [1, 2, 3, 0]], "VEC4")
        for joint in range(quaternions.shape[1])
    ] + [(0, "translation", root, "VEC3")]
    for node, path, values, kind in outputs:
        samplers.append(
            dict(
                input=clock,
                interpolation="LINEAR",
                output=gltf.add(np.ascontiguousarray(values, dtype=np.float32), kind),
            )
        )
        channels.append(dict(sampler=len(samplers) - 1, target=dict(node=node, path=path)))
    return dict(name="motion", samplers=samplers, channels=channels)


def _inverse_binds(rest: np.ndarray) -> np.ndarray:
    """Column-major 4x4 inverses of each joint's rest transform (a translation: rest rotations
    are zero)."""
    matrices = np.tile(np.eye(4, dtype=np.float32), (len(rest), 1, 1))
    matrices[:, :3, 3] = -rest
    return np.ascontiguousarray(np.swapaxes(matrices, 1, 2))


def _mannequin(skeleton: Skeleton, offsets: np.ndarray, rest: np.ndarray) -> tuple:
    """Positions, normals, joints, weights and triangle indices of the rest-pose mesh."""
    parts = []
    tips = rig.end_sites(skeleton, offsets)
    for joint, name in enumerate(skeleton.joint_names):
        part = name.split("_")[-1]
        parts.append((_ball(rest[joint], BALL.get(part, _BALL_DEFAULT)), joint))
        kids = np.flatnonzero(skeleton.parents == joint)
        centre = [c for c in kids if not skeleton.joint_names[c].startswith(("left_", "right_"))]
        ends = [rest[c] for c in (kids if len(kids) == 1 else centre)]
        if joint in tips:
            ends.append(rest[joint] + tips[joint])
        if ROD[part] and len(ends) == 1:
            parts.append((_rod(rest[joint], ends[0], ROD[part]), joint))
    positions, normals, bound, triangles, count = [], [], [], [], 0
    for (points, directions, faces), joint in parts:
        positions.append(points)
        normals.append(directions)
        bound.append(np.full(len(points), joint))
        triangles.append(faces + count)
        count += len(points)
    bound = np.concatenate(bound)
    joints = np.zeros((count, 4), np.uint16)
    joints[:, 0] = bound
    weights = np.zeros((count, 4), np.float32)
    weights[:, 0] = 1.0
    return (
        np.concatenate(positions).astype(np.float32),
        np.concatenate(normals).astype(np.float32),
        joints,
        weights,
        np.concatenate(triangles).astype(np.uint32).ravel(),
    )


def _ball(centre: np.ndarray, radius: float) -> tuple:
    rings = SEGMENTS // 2 + 1
    polar = np.linspace(0.0, np.pi, rings)[:, None]
    around = np.linspace(0.0, 2 * np.pi, SEGMENTS, endpoint=False)[None]
    directions = np.stack(
        [
            np.sin(polar) * np.cos(around),
            np.cos(polar) + 0 * around,
            np.sin(polar) * np.sin(around),
        ],
        -1,
    ).reshape(-1, 3)
    return centre + radius * directions, directions, _grid(rings, SEGMENTS)


def _rod(start: np.ndarray, end: np.ndarray, radius: float) -> tuple:
    axis = (end - start) / np.linalg.norm(end - start)
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    around = np.linspace(0.0, 2 * np.pi, SEGMENTS, endpoint=False)[:, None]
    directions = np.cos(around) * u + np.sin(around) * v  # (S, 3)
    taper = np.array([1.0, 0.75])[:, None, None]  # thinner toward the child
    points = np.stack([start, end])[:, None] + radius * taper * directions[None]
    return points.reshape(-1, 3), np.tile(directions, (2, 1)), _grid(2, SEGMENTS)


def _grid(rows: int, columns: int) -> np.ndarray:
    """Triangles (N, 3) joining a rows x columns grid of vertices, wrapping around columns,
    wound counter-clockwise seen from outside."""
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(columns), indexing="ij")
    a, b = r * columns + c, r * columns + (c + 1) % columns
    quads = np.stack([a, b, a + columns, b, b + columns, a + columns], -1).reshape(-1, 3)
    return quads


def _glb(document: dict, binary: bytes) -> bytes:
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary += bytes(-len(binary) % 4)
    length = 12 + 8 + len(text) + 8 + len(binary)
    return (
        struct.pack("<4sII", b"glTF", 2, length)
        + struct.pack("<I4s", len(text), b"JSON")
        + text
        + struct.pack("<I4s", len(binary), b"BIN\0")
        + binary
    )
