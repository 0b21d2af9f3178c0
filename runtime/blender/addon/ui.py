"""The panel (3D view sidebar, tab MOGO), its settings and its operators: Generate, Retarget
(with the bone mapping and its presets) and Live. The runtime is imported when an operator
runs, so the add-on registers, and says what is missing, without it."""

import warnings

import bpy

from . import environment
from .jobs import Background, UserError, reported
from .names import RIG_KEY
from .sampling import OPTIONS

SESSION: dict = {}  # the loaded MotionGenerator and our rig, per Blender session


def generator(mogo):
    """The runtime's MotionGenerator for the shipped bundle (loaded once, on first use: a
    worker thread may call this) and our rig."""
    if "generator" not in SESSION:
        from .motion_keys import OurRig

        loaded = mogo.MotionGenerator.load(threads=2)
        SESSION.update(generator=loaded, ours=OurRig.of(loaded.skeleton))
    return SESSION["generator"], SESSION["ours"]


SAMPLING = tuple(name for name, *_ in OPTIONS)


def request(settings) -> dict:
    """The panel's generation settings, read on the UI thread for a worker."""
    return dict(
        text=settings.prompt,
        seed=None if settings.seed < 0 else settings.seed,
        seconds=settings.seconds or None,
        sampling={name: getattr(settings, name) for name in SAMPLING}
        if settings.custom_sampling
        else {},
    )  # {}: the bundle's defaults


class MOGO_PG_bone(bpy.types.PropertyGroup):
    joint: bpy.props.StringProperty(name="Ours")
    bone: bpy.props.StringProperty(name="Target bone")


class MOGO_PG_settings(bpy.types.PropertyGroup):
    prompt: bpy.props.StringProperty(name="Prompt", default="a person walks forward")
    seconds: bpy.props.FloatProperty(
        name="Seconds",
        default=4.0,
        min=0.0,
        max=60.0,
        description="Length; 0 lets the model end the motion",
    )
    seed: bpy.props.IntProperty(
        name="Seed", default=0, min=-1, description="Same seed, same motion; -1 draws a fresh one"
    )
    custom_sampling: bpy.props.BoolProperty(name="Custom sampling", default=False)
    match_scene: bpy.props.BoolProperty(
        name="Set scene rate and range",
        default=True,
        description="Set the scene to the motion's frame rate and range (one key per scene "
        "frame); off: keys spread over the scene's own rate",
    )
    target: bpy.props.PointerProperty(
        name="Target",
        type=bpy.types.Object,
        poll=lambda self, thing: thing.type == "ARMATURE" and RIG_KEY not in thing,
    )
    mapping: bpy.props.CollectionProperty(type=MOGO_PG_bone)
    mapping_index: bpy.props.IntProperty()
    live_prompt: bpy.props.StringProperty(name="Switch to", default="a person jogs forward")


def _sampling_property(name, kind, default, low, high, help):
    """One of Sampling's options as a panel setting: its default, limits and help are
    Sampling's own (sampling.py is written from mogo.sampling by `mogo blender-addon`)."""
    limits = {key: value for key, value in (("min", low), ("max", high)) if value is not None}
    made = bpy.props.IntProperty if kind == "int" else bpy.props.FloatProperty
    return made(
        name=name.replace("_", " ").capitalize(), default=default, description=help, **limits
    )


MOGO_PG_settings.__annotations__.update(
    {option[0]: _sampling_property(*option) for option in OPTIONS}
)


class MOGO_OT_generate(Background, bpy.types.Operator):
    """Generate motion from the prompt onto the MOGO armature, as a new Action"""

    bl_idname = "mogo.generate"
    bl_label = "Generate"
    label = "generating motion"

    def prepare(self, context):
        if not context.scene.mogo.prompt.strip():
            raise UserError("type a prompt, e.g. 'a person walks forward'")
        self.mogo, self.request = environment.runtime(context), request(context.scene.mogo)

    def work(self):
        loaded, ours = generator(self.mogo)
        options = dict(self.request, sampling=loaded.sampling(**self.request["sampling"]))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            motion = loaded.generate(**options)
        return motion, ours, ours.world(motion.joints), [str(w.message) for w in caught]

    def finish(self, context, result):
        from . import scene as our_scene
        from .motion_keys import C

        motion, ours, world, notes = result
        armature = our_scene.our_armature(context, ours)
        action = our_scene.new_action(armature, motion.caption)
        frames = our_scene.match_scene(
            context.scene, motion.fps, len(motion.joints), context.scene.mogo.match_scene
        )
        our_scene.write_pose(action, armature, ours, world, motion.joints[:, 0] @ C.T, frames)
        action["mogo_seed"], action["mogo_fps"] = motion.seed, motion.fps
        for note in notes:
            self.report({"WARNING"}, f"MOGO: {note}")
        self.report(
            {"INFO"},
            f"MOGO: {action.name}: {len(frames)} frames at {motion.fps:g} fps, seed {motion.seed}",
        )


class MOGO_OT_map_preset(bpy.types.Operator):
    """Fill the bone mapping from a naming preset and the target's bone names"""

    bl_idname = "mogo.map_preset"
    bl_label = "Map bones"
    preset: bpy.props.EnumProperty(items=[("MIXAMO", "Mixamo / Unity", ""), ("SMPL", "SMPL", "")])

    @reported
    def execute(self, context):
        environment.runtime(context)
        fill_mapping(context.scene.mogo, self.preset)
        mapped = sum(bool(item.bone) for item in context.scene.mogo.mapping)
        self.report({"INFO"}, f"MOGO: {mapped} of {len(context.scene.mogo.mapping)} bones mapped")
        return {"FINISHED"}


def fill_mapping(settings, preset: str) -> None:
    from .motion_keys import BONE_NAMES, auto_map

    if settings.target is None:
        raise UserError("pick a target armature first")
    found = auto_map(preset, [bone.name for bone in settings.target.data.bones])
    settings.mapping.clear()
    for joint, bone in zip(BONE_NAMES, found, strict=False):
        item = settings.mapping.add()
        item.joint, item.bone = joint, bone


class MOGO_OT_retarget(bpy.types.Operator):
    """Bake the MOGO armature's current Action onto the target armature (a new Action)"""

    bl_idname = "mogo.retarget"
    bl_label = "Retarget"

    @reported
    def execute(self, context):
        from . import scene as our_scene
        from .motion_keys import retarget

        settings = context.scene.mogo
        _, ours = generator(environment.runtime(context))
        source = our_scene.find_ours(ours)
        action = source and source.animation_data and source.animation_data.action
        if not action:
            raise UserError("generate a motion first: the MOGO armature has no action")
        if settings.target is None:
            raise UserError("pick a target armature")
        if not len(settings.mapping):
            fill_mapping(settings, "MIXAMO")
        mapping = [item.bone for item in settings.mapping]
        frames, world, pelvis = our_scene.read_pose(action, source, ours)
        keys, location, scale = retarget(
            world, pelvis, ours, our_scene.read_target(settings.target), mapping
        )
        baked = our_scene.new_action(settings.target, action.name, f" on {settings.target.name}")
        hips = mapping[0]
        for bone, quaternions in keys.items():
            our_scene.add_keys(baked, bone, frames, quaternions, location if bone == hips else None)
        self.report(
            {"INFO"},
            f"MOGO: {baked.name}: {len(keys)} bones, {len(frames)} frames, "
            f"root motion x{scale:.2f}",
        )
        return {"FINISHED"}


class MOGO_OT_live(bpy.types.Operator):
    """Start live mode: stream motion onto the MOGO armature while the timeline plays"""

    bl_idname = "mogo.live"
    bl_label = "Live"
    mode: bpy.props.EnumProperty(
        items=[("START", "Start", ""), ("SWITCH", "Switch", ""), ("STOP", "Stop", "")]
    )

    @reported
    def execute(self, context):
        session = SESSION.get("live")
        if self.mode == "START":
            if session is not None:
                raise UserError("live mode is already running: stop it first")
            SESSION["live"] = start_live(context)
            if not bpy.app.background and not context.screen.is_animation_playing:
                bpy.ops.screen.animation_play()
        elif session is None:
            raise UserError("live mode is not running")
        elif self.mode == "SWITCH":
            session.switch(context.scene.mogo.live_prompt)
        else:
            frames = SESSION.pop("live").stop()
            self.report({"INFO"}, f"MOGO: live take kept as {session.action.name}: {frames} frames")
        return {"FINISHED"}


def start_live(context):
    from . import scene as our_scene
    from .live import LiveSession

    settings = context.scene.mogo
    loaded, ours = generator(environment.runtime(context))
    options = request(settings)
    stream = loaded.stream(
        options["text"], seed=options["seed"], sampling=loaded.sampling(**options["sampling"])
    )
    armature = our_scene.our_armature(context, ours)
    action = our_scene.new_action(armature, settings.prompt, " (live)")
    frames = our_scene.match_scene(context.scene, loaded.fps, 2, settings.match_scene)
    context.scene.frame_current = int(frames[0])
    return LiveSession(
        loaded, ours, armature, action, stream, float(frames[0]), float(frames[1] - frames[0])
    )


class MOGO_UL_mapping(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_property):
        row = layout.row(align=True)
        row.label(text=item.joint)
        target = context.scene.mogo.target
        if target is not None:
            row.prop_search(item, "bone", target.data, "bones", text="")
        else:
            row.prop(item, "bone", text="")


class MOGO_PT_panel(bpy.types.Panel):
    bl_label = "MOGO motion"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "MOGO"

    def draw(self, context):
        settings, layout = context.scene.mogo, self.layout
        for name in ("prompt", "seconds", "seed", "match_scene", "custom_sampling"):
            layout.prop(settings, name)
        if settings.custom_sampling:
            for name in SAMPLING:
                layout.prop(settings, name)
        layout.operator(MOGO_OT_generate.bl_idname, icon="ARMATURE_DATA")
        box = layout.box()
        box.label(text="Live")
        row = box.row()
        running = "live" in SESSION
        row.operator(
            MOGO_OT_live.bl_idname,
            text="Stop" if running else "Start",
            icon="PAUSE" if running else "PLAY",
        ).mode = "STOP" if running else "START"
        box.prop(settings, "live_prompt", text="")
        box.operator(MOGO_OT_live.bl_idname, text="Switch prompt").mode = "SWITCH"
        box = layout.box()
        box.label(text="Retarget")
        box.prop(settings, "target")
        row = box.row(align=True)
        for preset, text in (("MIXAMO", "Mixamo names"), ("SMPL", "SMPL names")):
            row.operator(MOGO_OT_map_preset.bl_idname, text=text).preset = preset
        box.template_list(
            "MOGO_UL_mapping", "", settings, "mapping", settings, "mapping_index", rows=4
        )
        box.operator(MOGO_OT_retarget.bl_idname, icon="MOD_ARMATURE")


CLASSES = (
    MOGO_PG_bone,
    MOGO_PG_settings,
    MOGO_OT_generate,
    MOGO_OT_map_preset,
    MOGO_OT_retarget,
    MOGO_OT_live,
    MOGO_UL_mapping,
    MOGO_PT_panel,
)
