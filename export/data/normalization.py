"""Mean/Std of motion features, written beside a dataset as Mean.npy / Std.npy."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

STD_FLOOR = 1e-2  # dims that never vary (e.g. a contact flag always 0) would divide by ~0


def feature_statistics(
    clips: Iterable[np.ndarray], std_floor: float = STD_FLOOR
) -> tuple[np.ndarray, np.ndarray]:
    """Per-dimension mean and std over all frames of all clips (each (T, D)), in float64
    accumulation, returned as float32 with the std floored at `std_floor`."""
    count = 0
    total = None
    total_sq = None
    for clip in clips:
        clip = np.asarray(clip, dtype=np.float64)
        if total is None:
            total = np.zeros(clip.shape[-1])
            total_sq = np.zeros(clip.shape[-1])
        count += clip.shape[0]
        total += clip.sum(axis=0)
        total_sq += (clip**2).sum(axis=0)
    if total is None or count == 0:
        raise ValueError("no frames to compute feature statistics from")
    mean = total / count
    std = np.sqrt(np.maximum(total_sq / count - mean**2, 0.0))
    return mean.astype(np.float32), np.maximum(std, std_floor).astype(np.float32)
