"""Left/right mirroring of clips and captions (how HumanML3D makes its M-prefixed copies)."""

from __future__ import annotations

import re

import numpy as np

from .skeleton import Skeleton

_SWAPS = {
    "left": "right",
    "right": "left",
    "lefthand": "righthand",
    "righthand": "lefthand",
    "leftward": "rightward",
    "rightward": "leftward",
    "leftwards": "rightwards",
    "rightwards": "leftwards",
    "clockwise": "counterclockwise",
    "counterclockwise": "clockwise",
    "counter-clockwise": "clockwise",
    "anticlockwise": "clockwise",
    "anti-clockwise": "clockwise",
}
_WORD = re.compile(
    r"\b(" + "|".join(sorted(map(re.escape, _SWAPS), key=len, reverse=True)) + r")\b", re.IGNORECASE
)


def mirror_joints(joints: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """Reflect joint positions (..., J, 3) through the YZ plane and swap left/right joints."""
    if joints.shape[-2] != skeleton.num_joints:
        raise ValueError(
            f"expected {skeleton.num_joints} joints for the {skeleton.name} "
            f"skeleton, got {joints.shape[-2]}"
        )
    mirrored = joints[..., skeleton.mirror_permutation(), :].copy()
    mirrored[..., 0] *= -1
    return mirrored


def mirror_text(text: str) -> str:
    """Swap left/right (and clockwise/counterclockwise) words, keeping their capitalisation."""

    def swap(match: re.Match) -> str:
        word = match.group(0)
        out = _SWAPS[word.lower()]
        if word.isupper():
            return out.upper()
        if word[0].isupper():
            return out[0].upper() + out[1:]
        return out

    return _WORD.sub(swap, text)
