"""`mogo data show`: one clip of a HumanML3D-layout folder as a stick-figure GIF.

Runtime dependencies only (no torch), so it works after a plain `pip install .`.
"""

from __future__ import annotations

from pathlib import Path

from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.motion.features import features_to_joints
from mogo.motion.render import save_gif


def show_clip(data_dir: Path, clip_id: str, gif_path: Path) -> Path:
    """Write clip `clip_id` as a GIF captioned with its ID and first caption.

    The joints are recovered from new_joint_vecs/ID.npy, not read from new_joints/, so the
    GIF shows exactly what the model trains on (and would show a broken feature file as such).
    """
    folder = HumanML3DFolder(data_dir, splits=())
    joints = features_to_joints(folder.features(clip_id), folder.skeleton)
    caption = folder.first_caption(clip_id)
    return save_gif(joints, gif_path, f"{clip_id}: {caption}" if caption else clip_id)
