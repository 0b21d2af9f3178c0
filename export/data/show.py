"""`mogo data show`: one clip of a HumanML3D-layout folder as a stick-figure GIF.

Runtime dependencies only (no torch), so it works after a plain `pip install .`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mogo.export.data.humanml3d import parse_caption_line
from mogo.motion.features import features_to_joints
from mogo.motion.render import save_gif


def show_clip(data_dir: Path, clip_id: str, gif_path: Path) -> Path:
    """Write clip `clip_id` as a GIF captioned with its ID and first caption.

    The joints are recovered from new_joint_vecs/ID.npy, not read from new_joints/, so the
    GIF shows exactly what the model trains on (and would show a broken feature file as such).
    """
    data_dir = Path(data_dir)
    features_dir = data_dir / "new_joint_vecs"
    if not features_dir.is_dir():
        raise FileNotFoundError(f"{features_dir}: folder missing; is {data_dir} a "
                                f"HumanML3D-layout dataset folder?")
    path = features_dir / f"{clip_id}.npy"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no clip {clip_id!r} in {data_dir}")
    try:
        features = np.load(path, allow_pickle=False)
        if not np.all(np.isfinite(features)):
            raise ValueError("contains NaN or infinite values")
        joints = features_to_joints(features)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    if joints.ndim != 3:
        raise ValueError(f"{path}: expected one clip (T, D), got shape {features.shape}")
    caption = first_caption(data_dir / "texts" / f"{clip_id}.txt")
    return save_gif(joints, gif_path, f"{clip_id}: {caption}" if caption else clip_id)


def first_caption(path: Path) -> str:
    """The caption text of the first line of a HumanML3D text file ("" if there is none)."""
    if not path.is_file():
        return ""
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if line.strip():
            return parse_caption_line(line, fps=20.0, where=f"{path}:{number}").text
    return ""
