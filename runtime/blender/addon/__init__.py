"""MOGO for Blender: text -> motion on an armature in the scene, retargeted onto your own rig,
or streamed live while the timeline plays. The runtime (the `mogo` package and its numpy,
onnxruntime, tokenizers, pillow) comes from the folder set in the add-on's preferences; the
add-on only calls its public API and its rig. Built into a zip by `mogo blender-addon`."""

bl_info = {
    "name": "MOGO motion",
    "author": "MOGO",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "3D View > Sidebar > MOGO",
    "description": "Text to 3D human motion: generate, stream live, retarget onto your armature",
    "category": "Animation",
}

import bpy  # noqa: E402 - after bl_info, which Blender reads without importing

from . import environment, ui  # noqa: E402

CLASSES = environment.CLASSES + ui.CLASSES


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.mogo = bpy.props.PointerProperty(type=ui.MOGO_PG_settings)


def unregister():
    session = ui.SESSION.pop("live", None)
    if session is not None:
        session.stop()
    del bpy.types.Scene.mogo
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
