"""BVH joint names for your retargeting tool: Mixamo names (the default: Blender's and Unity's
name-based retargeting lines up bone for bone), SMPL names, metres or centimetres.

    python examples/retarget_names.py

The same on the command line: mogo generate "a person runs forward" --bvh-names smpl
--bvh-units cm --out out/  (and --bvh-bone-translations; docs/bvh.md has the rig).
"""

from mogo import MotionGenerator

generator = MotionGenerator.load(threads=2)
motion = generator.generate("a person runs forward", seconds=3, seed=4)
FILES = {
    "run_mixamo.bvh": {},  # Hips, Spine, LeftUpLeg, ...: metres
    "run_smpl_cm.bvh": {"naming": "smpl", "scale": 100},  # pelvis, ...: centimetres
    "run_exact.bvh": {"bone_translations": True},  # gives these joints back exactly
}
for path, options in FILES.items():
    written = motion.save_bvh(path, **options)
    joints = [
        line.split()[1]
        for line in written.read_text().splitlines()
        if line.strip().startswith(("ROOT", "JOINT"))
    ]
    print(f"{written}: {', '.join(joints[:4])}, ... ({len(joints)} joints)")
