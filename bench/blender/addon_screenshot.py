"""A screenshot of the add-on in Blender's own window (docs/blender.md): a walk generated and
retargeted as addon_scene.py does it, the sidebar's MOGO tab open. Needs a display (Xvfb):

    xvfb-run -a -s "-screen 0 1280x800x24" blender --factory-startup --enable-event-simulate \
        --python bench/blender/addon_screenshot.py -- REQUEST.json
REQUEST.json: addon_scene.py's keys (zip, site_packages, prompt, seconds, seed, scale, a_pose,
frame) and "png". Blender 3.4's Python API cannot pick a sidebar tab, so a click on the tab is
simulated (--enable-event-simulate), at the tab's place in a 1280x800 window.
"""

import json
import os
import sys

import addon_utils
import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from addon_scene import _target  # noqa: E402 - Blender's modules first

TAB = (-10, 555)  # the MOGO tab: from the sidebar's right edge, from the window's bottom


def main() -> None:
    request = json.loads(open(sys.argv[sys.argv.index("--") + 1]).read())
    for thing in list(bpy.data.objects):  # the default cube, camera and light
        bpy.data.objects.remove(thing)
    bpy.ops.preferences.addon_install(filepath=request["zip"], overwrite=True)
    addon_utils.enable("mogo_blender", default_set=True)
    preferences = bpy.context.preferences.addons["mogo_blender"].preferences
    preferences.site_packages = request["site_packages"]
    settings = bpy.context.scene.mogo
    settings.prompt, settings.seconds, settings.seed = (
        request["prompt"],
        request["seconds"],
        request["seed"],
    )
    bpy.ops.mogo.generate()  # with a window: on a worker thread, progress in the status bar
    bpy.app.timers.register(lambda: _retarget(request), first_interval=0.5)


def _retarget(request: dict):
    """Once Generate has written its action: the target, its mapping, Retarget."""
    ours = bpy.data.objects.get("MOGO")
    if ours is None or ours.animation_data is None:
        return 0.5  # still generating
    settings = bpy.context.scene.mogo
    settings.target = _target(ours, request["scale"], request["a_pose"] * 3.14159265 / 180)
    bpy.ops.mogo.map_preset(preset="MIXAMO")
    bpy.ops.mogo.retarget()
    bpy.context.scene.frame_set(bpy.context.scene.frame_start + request.get("frame", 0))
    bpy.app.timers.register(lambda: _shoot(request["png"]), first_interval=1.0)


def _shoot(png: str):
    window = bpy.context.window_manager.windows[0]
    area = next(a for a in window.screen.areas if a.type == "VIEW_3D")
    area.spaces.active.show_region_ui = True
    area.spaces.active.overlay.show_floor = True
    sidebar = next(r for r in area.regions if r.type == "UI")
    window.event_simulate("ESC", "PRESS")  # the splash screen
    for value in ("PRESS", "RELEASE"):
        window.event_simulate("LEFTMOUSE", value, x=sidebar.x + sidebar.width + TAB[0], y=TAB[1])
    view = next(r for r in area.regions if r.type == "WINDOW")
    with bpy.context.temp_override(window=window, area=area, region=view):
        bpy.ops.view3d.view_axis(type="FRONT")
        bpy.ops.view3d.view_orbit(angle=0.5, type="ORBITLEFT")
        bpy.ops.view3d.view_persportho()
        bpy.ops.view3d.view_all()
    bpy.app.timers.register(lambda: _save(window, area, png), first_interval=1.0)


def _save(window, area, png: str):
    with bpy.context.temp_override(window=window, area=area):
        bpy.ops.screen.screenshot(filepath=png)
    bpy.ops.wm.quit_blender()


main()
