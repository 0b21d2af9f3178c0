"""The picture the Blender checks render (check_import.py, addon_scene.py): a camera looking
at a target from an offset, a sun, a grey world, Cycles on the CPU. Run inside Blender: its
sibling scripts import it."""

import math

import bpy
from mathutils import Vector


def render(scene, target: Vector, offset: Vector, request: dict, size: list) -> None:
    """Renders `scene` to request["png"] (request["size"] or `size` pixels, request["samples"]
    samples)."""
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    camera.location = target + offset
    camera.rotation_euler = (target - camera.location).to_track_quat("-Z", "Y").to_euler()
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 2.5
    sun.rotation_euler = (math.radians(40), 0.0, math.radians(30))
    for thing in (camera, sun):
        scene.collection.objects.link(thing)
    scene.camera = camera
    scene.world = bpy.data.worlds.new("world")
    scene.world.color = (0.25, 0.27, 0.3)
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples = "CPU", request.get("samples", 16)
    scene.cycles.use_denoising = False  # Debian's build has no OpenImageDenoise
    scene.render.resolution_x, scene.render.resolution_y = request.get("size", size)
    scene.render.resolution_percentage = 100
    scene.render.filepath = request["png"]
    bpy.ops.render.render(write_still=True)
