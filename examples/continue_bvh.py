"""Your own motion capture, continued by the model: a BVH read in, a stream going on from its
end, the result written as a new BVH.

    python examples/continue_bvh.py [your.bvh]

Without a file it first makes walk.bvh with generate, as a stand-in for your mocap. Any BVH
with SMPL, Mixamo or CMU joint names reads as it is (unit and up axis detected); other rigs
name their joints in a mapping file (Motion.from_file's `mapping`, docs/real_motion.md).
"""

import sys

from mogo import Motion, MotionGenerator

generator = MotionGenerator.load(threads=2)
if len(sys.argv) > 1:
    path = sys.argv[1]
else:
    path = generator.generate("a person walks forward", seconds=4, seed=0).save_bvh("walk.bvh")
walk = Motion.from_file(path)  # 20 fps, our 22 joints, on the floor at the origin
stream = generator.stream("a person jumps", seed=3)
stream.continue_from(walk)  # before the first step: the clip's tokens become the past
stream.advance(100)  # 100 token steps kept for finish() (5 s: a frame a step here)
motion = stream.finish()  # the new frames only, going on from the clip's last pose
print(
    f"{walk.seconds:.1f} s read from {path}, {motion.seconds:.1f} s more:",
    motion.save_bvh("continued.bvh"),
)
