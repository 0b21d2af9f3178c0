"""Blender's side of `python -m mogo.bench.quality.bvh_check`: import one of our BVH or GLB
files headless with Blender's own importer, read every bone's world head position per frame,
compare with reference joint positions, and optionally render one frame to PNG.

Run by Blender, not by mogo's Python (Blender's Python has neither mogo nor numpy):
    blender -b --factory-startup --python bench/blender/check_import.py -- REQUEST.json
REQUEST.json: {"file": a .bvh or .glb, "scale": file units per metre (BVH), "fps": the file's
frame rate, "references": {label: {joint
name: [[x, y, z] per frame] in metres, Y up}}, "result": path for the JSON answer,
optionally "png": path, "frame": 0-based frame to render, "size": [width, height], "samples",
"rest_png": path for the same view of the rest pose}.
The answer: {"fps": scene fps after import, "frames": count, "errors": {label: {"mean": m,
"max": m, "per_joint": {name: max m}}}}.

Debian/Ubuntu's Blender 3.4 runs on Python 3.11, which no longer accepts the 'rU' file mode its
BVH importer uses (every import fails with "invalid mode: 'rU'"); this script patches that in
its own process only.
"""

import builtins
import json
import math
import os
import sys

import bmesh
import bpy
from io_anim_bvh import import_bvh
from mathutils import Matrix, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from stage import render  # noqa: E402 - the sibling script, found once the folder is on the path


def _open_without_u(file, mode="r", *args, **kwargs):
    return builtins.open(file, mode.replace("U", ""), *args, **kwargs)


def main() -> None:
    request = json.loads(open(sys.argv[sys.argv.index("--") + 1]).read())
    import_bvh.open = _open_without_u  # the 'rU' fix, for this process only
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if request["file"].endswith(".glb"):  # glTF keys are seconds: frames at the scene's fps
        bpy.context.scene.render.fps = round(request["fps"])  # ours: 20 (12.5 for KIT has no GLB)
        bpy.ops.import_scene.gltf(filepath=request["file"])
    else:
        bpy.ops.import_anim.bvh(
            filepath=request["file"],
            global_scale=1.0 / request["scale"],
            update_scene_fps=True,
            update_scene_duration=True,
            axis_forward="-Z",
            axis_up="Y",
        )
    armature = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    scene = bpy.context.scene
    first, last = armature.animation_data.action.frame_range
    frames = int(round(last - first)) + 1
    heads = {bone.name: [] for bone in armature.pose.bones}
    request["first"] = int(first)
    for frame in range(frames):
        scene.frame_set(int(first) + frame)
        for bone in armature.pose.bones:
            x, y, z = armature.matrix_world @ bone.head  # Blender Z up -> the file's Y up
            heads[bone.name].append((x, z, -y))
    errors = {
        label: _errors(heads, reference) for label, reference in request["references"].items()
    }
    result = dict(fps=scene.render.fps / scene.render.fps_base, frames=frames, errors=errors)
    with open(request["result"], "w") as file:
        json.dump(result, file)
    if request.get("png"):
        _render(scene, armature, request)
        if request.get("rest_png"):  # the same scene in the rest pose, without the dots
            for thing in [o for o in scene.objects if o.name.startswith("dot")]:
                bpy.data.objects.remove(thing)
            armature.data.pose_position = "REST"
            scene.render.filepath = request["rest_png"]
            bpy.ops.render.render(write_still=True)


def _errors(heads: dict, reference: dict) -> dict:
    per_joint, total, count = {}, 0.0, 0
    for name, positions in reference.items():
        distances = [math.dist(a, b) for a, b in zip(heads[name], positions, strict=False)]
        per_joint[name] = max(distances)
        total, count = total + sum(distances), count + len(distances)
    return dict(mean=total / count, max=max(per_joint.values()), per_joint=per_joint)


def _render(scene, armature, request: dict) -> None:
    """A mannequin skinned to the imported bones (a rod per bone, a ball for the head; a GLB
    brings its own), red dots at the reference joints, a floor, a camera and a sun; Cycles on
    the CPU."""
    frame = request.get("frame", 0)
    if not any(o.type == "MESH" for o in scene.objects):
        _mannequin(armature)
    scene.frame_set(request["first"] + frame)
    dots = next(iter(request["references"].values()))
    for positions in dots.values():
        x, y, z = positions[frame]
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.022, location=(x, -z, y))
        bpy.context.object.name = "dot"
        bpy.context.object.data.materials.append(_material("dots", (0.8, 0.05, 0.05)))
    bpy.ops.mesh.primitive_plane_add(size=8.0)
    bpy.context.object.data.materials.append(_material("floor", (0.35, 0.37, 0.4)))
    pelvis = armature.matrix_world @ armature.pose.bones[0].head
    target = Vector((pelvis.x, pelvis.y, 0.85))
    render(scene, target, Vector((1.9, -2.9, 0.5)), request, [480, 480])


def _mannequin(armature) -> None:
    """One mesh: a tapered rod along every bone in the rest pose, each bound to its bone; a
    ball for the head and for bones too short for a rod (the hips: Blender ends a bone at the
    mean of its children's heads, as with Mixamo's own files)."""
    mesh = bpy.data.meshes.new("mannequin")
    body = bpy.data.objects.new("mannequin", mesh)
    bpy.context.scene.collection.objects.link(body)
    shapes = bmesh.new()
    layer = shapes.verts.layers.deform.verify()
    for index, bone in enumerate(armature.data.bones):
        body.vertex_groups.new(name=bone.name)  # the group the deform layer indexes
        head, tail = bone.head_local, bone.tail_local
        length = (tail - head).length
        if bone.name.lower() == "head" or length < 0.03:
            made = bmesh.ops.create_uvsphere(shapes, u_segments=12, v_segments=8, radius=0.1)
            where = Matrix.Translation(head + (tail - head) * (0.6 if length >= 0.03 else 0))
        else:
            made = bmesh.ops.create_cone(
                shapes, cap_ends=True, segments=10, radius1=0.045, radius2=0.03, depth=length
            )
            turn = (tail - head).to_track_quat("Z", "Y").to_matrix().to_4x4()
            where = Matrix.Translation((head + tail) / 2) @ turn
        bmesh.ops.transform(shapes, matrix=armature.matrix_world @ where, verts=made["verts"])
        for vertex in made["verts"]:
            vertex[layer][index] = 1.0
    shapes.to_mesh(mesh)
    body.modifiers.new("armature", "ARMATURE").object = armature
    mesh.materials.append(_material("body", (0.3, 0.45, 0.75)))


def _material(name: str, colour: tuple) -> bpy.types.Material:
    material = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    material.diffuse_color = (*colour, 1.0)
    material.use_nodes = True
    material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (*colour, 1)
    return material


main()
