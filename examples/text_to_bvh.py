"""Text to a BVH, and a GIF to look at: the main job.

    python examples/text_to_bvh.py

Writes walk_and_wave.bvh and walk_and_wave.gif in the current folder. Blender imports the BVH
with File > Import > Motion Capture (tick Update Scene FPS: the file is 20 fps).
"""

from mogo import MotionGenerator

generator = MotionGenerator.load(threads=2)  # the default bundle, shipped with the package
prompt = "a person walks forward, then waves with the right hand"
motion = generator.generate(prompt, seconds=6, seed=0)  # a seed gives the same motion again
print(motion.save_bvh("walk_and_wave.bvh"), f"{motion.seconds:.1f} s, seed {motion.seed}")
print(motion.save_gif("walk_and_wave.gif"))
