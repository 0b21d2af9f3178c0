"""Blender's side of `python -m mogo.bench.quality.blender_addon`: the add-on as a user has it,
headless. Install and enable it from its zip, check the message without a runtime, press its
Install (the runtime wheel it ships, into an empty folder; the runtime's dependencies come from
this environment's site-packages, added after it), Generate twice (a 24 fps scene), build a
Mixamo-named armature of other proportions with arms in an A-pose, map it with the preset and
Retarget; record every bone's world head per frame on both armatures, name two Actions of a
long prompt, and optionally render one frame to PNG.

    blender -b --factory-startup --python bench/blender/addon_scene.py -- REQUEST.json
REQUEST.json: {"zip", "site_packages", "empty" (a folder without the runtime), "installed" (an
empty folder Install fills), "prompt",
"seconds", "seed", "scale": {"leg", "arm", "torso"}, "a_pose" (degrees), "result", optionally
"png", "frame", "size", "samples"}. Run with BLENDER_USER_SCRIPTS set to a scratch folder: the
add-on is installed there, not into the user's Blender.
"""

import json
import math
import os
import site
import sys
import time

import addon_utils
import bpy
from bpy_extras import anim_utils
from mathutils import Matrix, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from stage import render  # noqa: E402 - the sibling script, found once the folder is on the path

LEGS = ("UpLeg", "Leg", "Foot", "ToeBase")
ARMS = ("Arm", "ForeArm", "Hand")
TARGET_OFFSET = Vector((1.2, 0.0, 0.0))  # the target stands beside ours


def main() -> None:
    request = json.loads(open(sys.argv[sys.argv.index("--") + 1]).read())
    result = _installed(request)
    scene = bpy.context.scene
    scene.render.fps = 24  # Blender's default: the add-on sets the motion's own
    settings = scene.mogo
    settings.prompt, settings.seconds, settings.seed = (
        request["prompt"],
        request["seconds"],
        request["seed"],
    )
    started = time.perf_counter()
    bpy.ops.mogo.generate()
    result["generate_seconds"] = time.perf_counter() - started
    ours = bpy.data.objects["MOGO"]
    first = ours.animation_data.action
    result.update(
        fps=scene.render.fps / scene.render.fps_base,
        frame_start=scene.frame_start,
        frame_end=scene.frame_end,
        keys=len(_hips_keys(first)),
        ours=_heads(scene, ours),
    )  # as Generate left it playing
    properties = settings.bl_rna.properties
    result["sampling"] = {
        name: [properties[name].default, properties[name].hard_min, properties[name].hard_max]
        for name in ("temperature", "top_k", "top_p", "guidance")
    }  # the panel's: Sampling's defaults and limits
    settings.custom_sampling, settings.top_k = True, 5
    bpy.ops.mogo.generate()  # a second take, with the panel's own sampling: a new action
    result["actions"] = [first.name, ours.animation_data.action.name]
    result["second_take_plays"] = _plays(scene, ours)
    ours.animation_data.action = first
    target = _target(ours, request["scale"], math.radians(request["a_pose"]))
    settings.target = target
    result["empty_prompt"] = _empty_prompt_error(settings)
    bpy.ops.mogo.map_preset(preset="MIXAMO")
    result["mapped"] = sum(bool(item.bone) for item in settings.mapping)
    bpy.ops.mogo.retarget()
    result["retarget_action"] = target.animation_data.action.name
    result["target"] = _heads(scene, target)
    result["target_rest"] = {
        b.name: list(target.matrix_world @ b.head_local) for b in target.data.bones
    }
    if request.get("png"):
        _render(scene, [ours, target], request)
    result["live"] = _live(scene, request.get("live_frames", 20))
    result["long_names"] = _long_names(target)
    with open(request["result"], "w") as file:
        json.dump(result, file)


def _installed(request: dict) -> dict:
    """The add-on installed from the zip as a user does it; Generate without the runtime,
    then Install with its defaults (the wheel the zip ships): what each said."""
    bpy.ops.wm.read_factory_settings(use_empty=True)  # no default cube, camera or light
    bpy.ops.preferences.addon_install(filepath=request["zip"], overwrite=True)
    addon_utils.enable("mogo_blender", default_set=True, handle_error=_raise)
    preferences = bpy.context.preferences.addons["mogo_blender"].preferences
    result = {"python": list(sys.version_info[:2]), "blender": bpy.app.version_string}
    preferences.site_packages = request["empty"]
    result["without_runtime"] = _error_of(bpy.ops.mogo.generate)
    preferences.site_packages, preferences.source = request["installed"], ""  # the default
    result["install"] = _error_of(bpy.ops.mogo.install_runtime)  # mogo-edge only: no deps
    site.addsitedir(request["site_packages"])  # numpy, onnxruntime, ...: after the folder
    from mogo_blender import environment

    result["runtime_file"] = environment.runtime().__file__
    return result


def _live(scene, frames: int) -> dict:
    """Live mode as the timeline would drive it: the playhead follows the keys (headless
    Blender runs no timers, so the add-on's timer function is called here), the prompt
    switched after `frames` and stopped `frames` after the switch took effect."""
    from mogo_blender import ui  # the installed add-on's own module

    scene.mogo.prompt, scene.mogo.live_prompt = "a person walks forward.", "a person jogs."
    bpy.ops.mogo.live(mode="START")
    session, started, switched = ui.SESSION["live"], time.monotonic(), False
    prompts = session.stream.prompts  # (frame, prompt): the worker appends the switch
    while time.monotonic() - started < 120:
        time.sleep(0.05)
        scene.frame_current = int(session.start + session.written * session.step)
        session.tick()
        if not switched and session.written >= frames:
            bpy.ops.mogo.live(mode="SWITCH")
            switched = True
        if len(prompts) == 2 and session.written >= prompts[1][0] + frames:
            break
    bpy.ops.mogo.live(mode="STOP")
    ours = bpy.data.objects["MOGO"]
    return dict(
        action=ours.animation_data.action.name,
        written=session.written,
        prompts=session.stream.prompts,
        keys=_hips_keys(ours.animation_data.action),
        plays=_plays(scene, ours),
        error=str(session.error or ""),
        running="live" in ui.SESSION,
    )


def _long_names(target) -> list[str]:
    """Two retarget-style Actions of a prompt too long for Blender's names, as Blender named
    them (the second numbered by Blender itself)."""
    from mogo_blender import scene as addon_scene

    prompt = "a person walks forward, then waves with the right hand, then turns around and claps"
    return [addon_scene.new_action(target, prompt, f" on {target.name}").name for _ in (1, 2)]


def _hips_keys(action) -> list[float]:
    """The frames of the Hips' rotation keys: in Action.fcurves before Blender 4.4, from 4.4
    in the channel bag of the action's slot (5.0 has no Action.fcurves)."""
    curves = (
        action.fcurves
        if bpy.app.version < (4, 4, 0)
        else anim_utils.action_get_channelbag_for_slot(action, action.slots[0]).fcurves
    )
    points = curves.find('pose.bones["Hips"].rotation_quaternion', index=0).keyframe_points
    return [point.co[0] for point in points]


def _plays(scene, armature) -> bool:
    """Whether the armature moves with its current action, first to last frame (on Blender
    4.4+ an action whose slot is not bound to the armature leaves it still)."""
    bone, heads = armature.pose.bones["Hips"], []
    for frame in armature.animation_data.action.frame_range:
        scene.frame_set(int(frame))
        heads.append(armature.matrix_world @ bone.head)
    return (heads[1] - heads[0]).length > 0.05


def _raise(error):
    raise error


def _error_of(operator) -> str:
    try:
        operator()
    except RuntimeError as error:  # an operator's ERROR report, as Python sees it
        return str(error)
    return ""


def _empty_prompt_error(settings) -> str:
    prompt, settings.prompt = settings.prompt, "  "
    error = _error_of(bpy.ops.mogo.generate)
    settings.prompt = prompt
    return error


def _target(ours, scale: dict, a_pose: float):
    """A Mixamo-named copy of our rest skeleton ('mixamorig:' prefix, a HeadTop_End leaf the
    mapping leaves out), legs, arms and torso scaled apart, arms lowered by `a_pose`, with the
    object transform of a Mixamo FBX import (bones in centimetres, Y up: scale 0.01, turned
    90 degrees about X), beside ours."""
    heads, tails = {}, {}
    for bone in ours.data.bones:  # parents first
        name, parent = bone.name, bone.parent
        heads[name] = (
            bone.head_local
            if parent is None
            else heads[parent.name]
            + _shape(parent.name, scale, a_pose) @ (bone.head_local - parent.head_local)
        )
        tails[name] = heads[name] + _shape(name, scale, a_pose) @ (
            bone.tail_local - bone.head_local
        )
    lift = Vector((0, 0, ours.data.bones["LeftFoot"].head_local.z - heads["LeftFoot"].z))
    heads["HeadTop_End"], tails["HeadTop_End"] = tails["Head"], tails["Head"] + Vector((0, 0, 0.05))
    data = bpy.data.armatures.new("Mannequin")
    target = bpy.data.objects.new("Mannequin", data)
    bpy.context.scene.collection.objects.link(target)
    target.matrix_world = (
        Matrix.Translation(TARGET_OFFSET)
        @ Matrix.Rotation(math.radians(90), 4, "X")
        @ Matrix.Scale(0.01, 4)
    )
    local = target.matrix_world.inverted()
    bpy.context.view_layer.objects.active = target
    bpy.ops.object.mode_set(mode="EDIT")
    for name in heads:  # feet on the floor, as ours
        edit = data.edit_bones.new("mixamorig:" + name)
        edit.head = local @ (heads[name] + lift + TARGET_OFFSET)
        edit.tail = local @ (tails[name] + lift + TARGET_OFFSET)
    for bone in ours.data.bones:
        if bone.parent is not None:
            data.edit_bones["mixamorig:" + bone.name].parent = data.edit_bones[
                "mixamorig:" + bone.parent.name
            ]
    data.edit_bones["mixamorig:HeadTop_End"].parent = data.edit_bones["mixamorig:Head"]
    bpy.ops.object.mode_set(mode="OBJECT")
    return target


def _shape(name: str, scale: dict, a_pose: float) -> Matrix:
    """A segment's scale (by body part) and turn (arms lowered into the A-pose)."""
    factor = scale["leg" if name.endswith(LEGS) else "arm" if name.endswith(ARMS) else "torso"]
    if not name.endswith(ARMS):
        return Matrix.Identity(3) * factor
    return Matrix.Rotation(a_pose if name.startswith("Left") else -a_pose, 3, "Y") * factor


def _heads(scene, armature) -> dict:
    """Bone name -> [[x, y, z] world, per frame of the action]."""
    first, last = armature.animation_data.action.frame_range
    heads = {bone.name: [] for bone in armature.pose.bones}
    for frame in range(int(first), int(last) + 1):
        scene.frame_set(frame)
        for bone in armature.pose.bones:
            heads[bone.name].append(list(armature.matrix_world @ bone.head))
    return heads


def _render(scene, armatures, request: dict) -> None:
    """Both armatures as rods parented to their bones, a floor, a camera and a sun; Cycles
    on the CPU (Workbench and EEVEE need a display)."""
    for armature, colour in zip(armatures, ((0.8, 0.45, 0.15), (0.3, 0.45, 0.75)), strict=False):
        _rods(armature, colour)
    scene.frame_set(scene.frame_start + request.get("frame", 0))
    bpy.ops.mesh.primitive_plane_add(size=12.0)
    _paint(bpy.context.object, "floor", (0.35, 0.37, 0.4))
    middle = sum((a.matrix_world @ a.pose.bones[0].head for a in armatures), Vector()) / 2
    target = Vector((middle.x, middle.y, 0.9))
    render(scene, target, Vector((3.4, -5.2, 0.5)), request, [640, 400])


def _rods(armature, colour) -> None:
    """A tapered rod along every bone (a ball for the head), each parented to its bone."""
    armature.data.pose_position = "REST"
    bpy.context.view_layer.update()
    for bone in armature.pose.bones:
        head, tail = armature.matrix_world @ bone.head, armature.matrix_world @ bone.tail
        length = (tail - head).length
        if bone.name.endswith("Head"):
            bpy.ops.mesh.primitive_uv_sphere_add(radius=0.1, location=head + (tail - head) * 0.6)
        elif length >= 0.03 and not bone.name.endswith("HeadTop_End"):
            bpy.ops.mesh.primitive_cone_add(
                radius1=0.045, radius2=0.03, depth=length, location=(head + tail) / 2
            )
            bpy.context.object.rotation_euler = (tail - head).to_track_quat("Z", "Y").to_euler()
        else:
            continue
        rod = bpy.context.object
        _paint(rod, armature.name, colour)
        bpy.context.view_layer.update()
        world = rod.matrix_world.copy()
        rod.parent, rod.parent_type, rod.parent_bone = armature, "BONE", bone.name
        bpy.context.view_layer.update()
        rod.matrix_world = world
    armature.data.pose_position = "POSE"


def _paint(thing, name: str, colour) -> None:
    material = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    material.diffuse_color = (*colour, 1.0)
    material.use_nodes = True
    material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (*colour, 1)
    thing.data.materials.append(material)


if __name__ == "__main__":  # Blender runs --python scripts as __main__
    main()
