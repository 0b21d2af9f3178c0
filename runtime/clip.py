"""A generated motion and the files it can be written as (npy, BVH, GIF, JSON)."""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mogo.align import Alignment
from mogo.motion import bvh, render
from mogo.motion.skeleton import Skeleton


@dataclass
class Motion:
    features: np.ndarray  # (T, D) float32, un-normalised HumanML3D-layout features
    joints: np.ndarray  # (T, J, 3) float32, metres, Y up
    fps: float
    tokens: np.ndarray  # (n, L) int64, the token steps the features were decoded from
    skeleton: Skeleton
    prompts: list[tuple[int, str]] = field(default_factory=list)  # (first frame, text)
    seed: int | None = None
    alignment: Alignment | None = None  # the steps prompt alignment made of the user's text

    @property
    def seconds(self) -> float:
        return len(self.joints) / self.fps

    @property
    def caption(self) -> str:
        return ", then ".join(text for _, text in self.prompts)

    def save_npy(self, path: str | os.PathLike) -> Path:
        """Joint positions (T, J, 3) float32, as HumanML3D's new_joints/ holds them."""
        path = _writable(path)
        np.save(path, self.joints.astype(np.float32))
        return path

    def save_features(self, path: str | os.PathLike) -> Path:
        """The 263-dim features (T, D), as HumanML3D's new_joint_vecs/ holds them."""
        path = _writable(path)
        np.save(path, self.features.astype(np.float32))
        return path

    def save_bvh(self, path: str | os.PathLike, scale: float = 1.0,
                 bone_translations: bool = False) -> Path:
        """A BVH with per-joint rotations, in metres (scale=100 for centimetres);
        bone_translations=True adds per-joint position channels, so the file gives these
        joints back exactly despite the bone-length jitter of generated motion."""
        path = _writable(path)
        bvh.save_bvh(path, self.joints, self.skeleton, self.fps, scale, bone_translations)
        return path

    def save_gif(self, path: str | os.PathLike) -> Path:
        """A stick-figure animation with the caption and a floor grid."""
        return render.save_gif(self.joints, _writable(path), self.caption, self.fps,
                               self.skeleton)

    def save_json(self, path: str | os.PathLike) -> Path:
        """Everything a web viewer needs: skeleton, fps, prompts and joints per frame (and
        the aligned steps, when prompt alignment made them)."""
        path = _writable(path)
        document = dict(
            fps=self.fps, skeleton=self.skeleton.name,
            joint_names=list(self.skeleton.joint_names),
            parents=[int(p) for p in self.skeleton.parents],
            prompts=[dict(frame=frame, text=text) for frame, text in self.prompts],
            seed=self.seed, frames=np.round(self.joints, 5).tolist())
        if self.alignment is not None:
            document["alignment"] = self.alignment.as_dict()
        path.write_text(json.dumps(document) + "\n")
        return path


def _writable(path: str | os.PathLike) -> Path:
    """The path, its folder made; a clear error where the folder cannot be written."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise PermissionError(f"cannot create the output folder {path.parent}: "
                              f"{error.strerror}") from None
    if not os.access(path.parent, os.W_OK):
        raise PermissionError(f"the output folder {path.parent} is not writable")
    return path
