"""What the panel and the scene both name, importable before the runtime is (no numpy)."""

RIG_KEY = "mogo_rig"  # our armature's custom property: the rest skeleton it was built for
