"""The add-on's side of the scene: our armature (created once, reused), motion written as
Actions with one key per motion frame, actions read back, and a user's armature read at rest.
numpy arrives with the runtime, so this module is imported only once the runtime is found."""

from __future__ import annotations

import bpy
import numpy as np

from . import motion_keys
from .motion_keys import BONE_NAMES, OurRig
from .names import RIG_KEY

ARMATURE = "MOGO"  # our armature object's name
SLOTTED = bpy.app.version >= (4, 4, 0)  # actions animate through slots (channel bags)


def our_armature(context, ours: OurRig):
    """Our armature object, reused when one built for this rest skeleton exists, else built:
    bones named for the segment they move (Mixamo/Unity style), rest = the bundle's T-pose,
    feet on the floor, facing -Y as Blender's front view expects."""
    existing = find_ours(ours)
    if existing is not None:
        if existing.name not in context.scene.objects:
            context.scene.collection.objects.link(existing)
        return existing
    data = bpy.data.armatures.new(ARMATURE)
    armature = bpy.data.objects.new(ARMATURE, data)  # "MOGO.001" beside another one
    context.scene.collection.objects.link(armature)
    armature[RIG_KEY] = _signature(ours)
    data.display_type = "STICK"
    _build_bones(context, armature, ours)
    return armature


def find_ours(ours: OurRig):
    """The armature built for this rest skeleton (another bundle's has other bones), if any."""
    signature = _signature(ours)
    return next(
        (
            thing
            for thing in bpy.data.objects
            if thing.type == "ARMATURE" and thing.get(RIG_KEY) == signature
        ),
        None,
    )


def _signature(ours: OurRig) -> str:
    return ",".join(f"{v:.4f}" for v in ours.heads.ravel())


def _build_bones(context, armature, ours: OurRig) -> None:
    previous = context.view_layer.objects.active
    mode = previous.mode if previous is not None else "OBJECT"
    if mode != "OBJECT":
        bpy.ops.object.mode_set(mode="OBJECT")
    context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    bones = armature.data.edit_bones
    for joint, name in enumerate(BONE_NAMES):
        bone = bones.new(name)
        bone.head, bone.tail = ours.heads[joint], ours.tails[joint]
        bone.roll = 0.0
    for joint, parent in enumerate(ours.skeleton.parents):
        if parent >= 0:
            bones[BONE_NAMES[joint]].parent = bones[BONE_NAMES[parent]]
    bpy.ops.object.mode_set(mode="OBJECT")
    context.view_layer.objects.active = previous or armature


def rest_frames(armature, names) -> np.ndarray:
    """(K, 3, 3) each bone's rest frame in armature space."""
    return np.array([np.array(armature.data.bones[n].matrix_local.to_3x3()) for n in names])


def parents_of(armature, names) -> list[int | None]:
    index = {name: k for k, name in enumerate(names)}
    return [
        index.get(armature.data.bones[n].parent.name) if armature.data.bones[n].parent else None
        for n in names
    ]


def new_action(armature, text: str, suffix: str = ""):
    """A new Action on the armature, named `text` + `suffix` within Blender's length
    (motion_keys.action_name; a second take never replaces the first: Blender numbers the
    name, and every take keeps a fake user so it stays in the file)."""
    action = bpy.data.actions.new(motion_keys.action_name(text, suffix))
    action.use_fake_user = True
    if armature.animation_data is None:
        armature.animation_data_create()
    armature.animation_data.action = action
    if SLOTTED:  # the action animates the armature through a slot bound to it
        armature.animation_data.action_slot = action.slots.new(id_type="OBJECT", name=armature.name)
    for bone in armature.pose.bones:
        bone.rotation_mode = "QUATERNION"
    return action


def channels(action, slot=None):
    """Where an action keeps its F-curves and their groups: the action itself before Blender
    4.4; from 4.4 (slotted actions; 5.0 has no Action.fcurves) the channel bag of `slot`
    (else its first, which new_action binds to the armature) in its keyframe strip, made
    where missing."""
    if not SLOTTED:
        return action
    if slot is None:
        slot = (
            action.slots[0]
            if len(action.slots)
            else action.slots.new(id_type="OBJECT", name=ARMATURE)
        )
    if not len(action.layers):
        action.layers.new("Layer").strips.new(type="KEYFRAME")
    return action.layers[0].strips[0].channelbag(slot, ensure=True)


def add_keys(
    action,
    bone: str,
    frames: np.ndarray,
    quaternions: np.ndarray,
    locations: np.ndarray | None = None,
) -> None:
    """Keys at `frames` for one pose bone: rotation (T, 4), location (T, 3) if given; appended
    to the bone's curves when they exist (a stream's chunks)."""
    values_of = [("rotation_quaternion", quaternions)]
    if locations is not None:
        values_of.append(("location", locations))
    bag = channels(action)
    for prop, values in values_of:
        path = f'pose.bones["{bone}"].{prop}'
        for axis in range(values.shape[1]):
            curve = bag.fcurves.find(path, index=axis)
            if curve is None:
                curve = bag.fcurves.new(path, index=axis)
                curve.group = bag.groups.get(bone) or bag.groups.new(bone)
            start = len(curve.keyframe_points)
            curve.keyframe_points.add(len(frames))
            co = np.stack([frames, values[:, axis]], axis=1).astype(np.float32)
            points = curve.keyframe_points
            for offset, (frame, value) in enumerate(co):
                points[start + offset].co = (frame, value)
                points[start + offset].interpolation = "LINEAR"
            curve.update()


def write_pose(
    action,
    armature,
    ours: OurRig,
    world: np.ndarray,
    pelvis: np.ndarray,
    frames: np.ndarray,
    previous: np.ndarray | None = None,
) -> np.ndarray:
    """Our motion (world rotations from rest, pelvis, Blender axes) as keys at `frames` on our
    armature; returns the last quaternions (continuity for the next chunk of a stream)."""
    rest = rest_frames(armature, BONE_NAMES)
    parents = [p if p >= 0 else None for p in ours.skeleton.parents]
    keys = motion_keys.pose_keys(world, rest, parents, previous)
    root = motion_keys.root_location(pelvis, ours.heads[0], rest[0], np.eye(3))
    for joint, name in enumerate(BONE_NAMES):
        add_keys(action, name, frames, keys[:, joint], root if joint == 0 else None)
    return keys[-1]


def read_pose(action, armature, ours: OurRig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An action on our armature back as (frames, world rotations, pelvis): what retarget
    bakes, whether it came from Generate, Live or was edited by hand."""
    rest = rest_frames(armature, BONE_NAMES)
    parents = [p if p >= 0 else None for p in ours.skeleton.parents]
    frames, quaternions, pelvis = None, [], None
    fcurves = channels(action, getattr(armature.animation_data, "action_slot", None)).fcurves
    for name in BONE_NAMES:
        path = f'pose.bones["{name}"].rotation_quaternion'
        curves = [fcurves.find(path, index=axis) for axis in range(4)]
        if any(curve is None for curve in curves):
            raise ValueError(f"the action {action.name!r} has no rotation keys for {name}")
        if frames is None:
            frames = np.array([point.co[0] for point in curves[0].keyframe_points])
        quaternions.append([[c.evaluate(f) for c in curves] for f in frames])
    location = [
        fcurves.find(f'pose.bones["{BONE_NAMES[0]}"].location', index=axis) for axis in range(3)
    ]
    offset = np.array([[c.evaluate(f) if c else 0.0 for c in location] for f in frames])
    pelvis = ours.heads[0] + offset @ rest[0].T
    quaternions = np.array(quaternions).transpose(1, 0, 2)
    quaternions /= np.linalg.norm(quaternions, axis=-1, keepdims=True)
    return frames, motion_keys.world_from_keys(quaternions, rest, parents), pelvis


def read_target(armature) -> motion_keys.Target:
    """A user's armature at rest, in the world (its object transform included)."""
    bones = sorted(armature.data.bones, key=lambda b: len(b.parent_recursive))
    names = [bone.name for bone in bones]
    matrix = np.array(armature.matrix_world)
    linear = matrix[:3, :3]
    u, _, vt = np.linalg.svd(linear)
    heads = np.array([np.array(b.head_local) for b in bones]) @ linear.T + matrix[:3, 3]
    tails = np.array([np.array(b.tail_local) for b in bones]) @ linear.T + matrix[:3, 3]
    return motion_keys.Target(
        names,
        parents_of(armature, names),
        rest_frames(armature, names),
        u @ vt,
        np.linalg.inv(linear),
        heads,
        tails,
    )


def match_scene(scene, fps: float, frames: int, match: bool) -> np.ndarray:
    """The scene frames of motion frames 0..frames-1: the scene set to the motion's rate and
    range (match), or keys spread over the scene's own rate from its start frame."""
    if match:
        scene.render.fps, scene.render.fps_base = round(fps), round(fps) / fps
        scene.frame_start, scene.frame_end = 1, frames
        return 1.0 + np.arange(frames)
    rate = scene.render.fps / scene.render.fps_base
    return scene.frame_start + np.arange(frames) * rate / fps
