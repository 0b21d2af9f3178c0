"""Many prompts in one call: prompt k is drawn with seed + k, so any of them can be made again
alone with generate(prompt, seed=seed + k).

    python examples/batch.py

Writes one take per prompt (.bvh, .gif, .npy, .json) into takes/; a second run keeps the first
takes and numbers the new ones (take_0-2, ...).
"""

from mogo import MotionGenerator

PROMPTS = [
    "a person walks forward",
    "a person jumps on the spot",
    "a person sits down",
    "a person waves with the right hand",
]

generator = MotionGenerator.load(threads=2)
motions = generator.generate_batch(PROMPTS, seconds=4, seed=10)
for k, (prompt, motion) in enumerate(zip(PROMPTS, motions, strict=True)):
    bvh, *_ = motion.save_take("takes", f"take_{k}")  # all four files or none
    print(f"seed {motion.seed}  {prompt!r} -> {bvh}")
