"""MOGO: text to 3D human motion, token by token, on a CPU.

    from mogo import MotionGenerator

    generator = MotionGenerator.load(threads=2)          # the bundle shipped with the package
    motion = generator.generate("a person walks forward", seconds=4, seed=0)
    motion.save_bvh("walk.bvh")

    stream = generator.stream("a person jogs forward", seed=1)   # endless, keeps jogging
    for frame in stream.frames(200):                     # (22, 3) joints, metres, Y up
        ...

Everything here runs on numpy + onnxruntime + tokenizers + pillow; nothing imports torch.
The names below are the public API; every other module is the runtime's own business.
Which of their members are public and which are shared inside mogo only: docs/api.md.
"""

from mogo.align import Alignment
from mogo.anchoring import Anchoring
from mogo.arguments import PromptWarning, UnfamiliarPromptWarning, UnknownPromptWarning
from mogo.bundle import BundleError
from mogo.clip import Motion
from mogo.generator import DEFAULT_BUNDLE, MotionGenerator, MotionStream
from mogo.sampling import Sampling

__all__ = [
    "MotionGenerator",
    "MotionStream",
    "Motion",
    "Sampling",
    "Alignment",
    "BundleError",
    "PromptWarning",
    "UnfamiliarPromptWarning",
    "UnknownPromptWarning",
    "DEFAULT_BUNDLE",
    "Anchoring",
]
