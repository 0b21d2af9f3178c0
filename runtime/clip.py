"""A generated motion and the files it can be written as (npy, BVH, GIF, JSON), each one whole
(see mogo.files), and the four of them as one take."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from mogo import files
from mogo.align import Alignment
from mogo.arguments import checked_bool
from mogo.motion import bvh, glb, mocap, render, rigs
from mogo.motion.features import joints_to_features
from mogo.motion.skeleton import SMPL_22, Skeleton

# What a take may hold, in the order written: the animation as a skeleton (BVH) or a skinned
# mannequin (GLB), a stick-figure GIF, the joints as .npy, everything as JSON.
FORMATS = ("bvh", "glb", "gif", "npy", "json")
TAKE = ("bvh", "gif", "npy", "json")  # a take unless told otherwise
ANIMATIONS = ("bvh", "glb")


@dataclass
class Motion:
    features: np.ndarray  # (T, D) float32, un-normalised HumanML3D-layout features, as decoded
    # (T - 1 rows for a clip read from a file: see from_file)
    joints: np.ndarray  # (T, J, 3) float32, metres, Y up; feet planted unless plant_feet=False
    fps: float
    tokens: np.ndarray  # (n, L) int64, the token steps the features were decoded from
    skeleton: Skeleton
    prompts: list[tuple[int, str]] = field(default_factory=list)  # (first frame, text)
    seed: int | None = None
    alignment: Alignment | None = None  # the steps prompt alignment made of the user's text

    @classmethod
    def from_file(cls, path: str | os.PathLike, mapping: str | os.PathLike | None = None) -> Motion:
        """A motion-capture file as a Motion at 20 fps on the 22-joint skeleton, e.g. to go on
        from with MotionStream.continue_from: a BVH (any rig with SMPL, Mixamo or CMU joint
        names; unit and up axis detected) or a DeepMimic motion (see mogo.motion.mocap).
        `mapping`: a JSON file naming the rig's joint for each of ours (mogo.motion.rigs).
        The clip is put on the floor at the origin, facing +Z, as HumanML3D clips are.
        `joints` has every frame of the file (at 20 fps); `features` one row fewer, as
        HumanML3D's new_joint_vecs have beside new_joints: a row holds the velocities to the
        next frame, which the last frame does not have."""
        rig = None if mapping is None else rigs.read_mapping(mapping)
        clip = mocap.read_mocap(path, rig)
        joints = mocap.resample(clip.joints, clip.fps, SMPL_22.fps)
        try:
            features, canonical = joints_to_features(joints, SMPL_22)
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from None
        return cls(
            features,
            canonical,
            SMPL_22.fps,
            np.zeros((0, 0), np.int64),
            SMPL_22,
            [(0, Path(path).name)],
        )

    @property
    def seconds(self) -> float:
        return len(self.joints) / self.fps

    @property
    def caption(self) -> str:
        return ", then ".join(text for _, text in self.prompts)

    def save_npy(self, path: str | os.PathLike) -> Path:
        """Joint positions (T, J, 3) float32, as HumanML3D's new_joints/ holds them. As with
        numpy.save, ".npy" is added to a name without it; the path written is returned."""
        return _save(_npy_path(path), partial(_write_array, self.joints))

    def save_features(self, path: str | os.PathLike) -> Path:
        """The 263-dim features (T, D), as HumanML3D's new_joint_vecs/ holds them (".npy" is
        added as by save_npy)."""
        return _save(_npy_path(path), partial(_write_array, self.features))

    def save_bvh(
        self,
        path: str | os.PathLike,
        scale: float = 1.0,
        bone_translations: bool = False,
        naming: str = "mixamo",
    ) -> Path:
        """A BVH of the bundle's rigid T-pose character with per-joint rotations, in metres
        (scale=100 for centimetres), joints named as in mogo.motion.bvh.NAMINGS;
        bone_translations=True adds per-joint position channels, so the file gives these
        joints back exactly despite the bone-length jitter of generated motion."""
        return _save(
            Path(path),
            partial(
                self._write_bvh, scale=scale, bone_translations=bone_translations, naming=naming
            ),
        )

    def save_glb(self, path: str | os.PathLike, naming: str = "mixamo") -> Path:
        """A GLB (binary glTF): a mannequin skinned to the BVH's rigid character, animated by
        its joint rotations; three.js, Blender and engines play it as it is."""
        return _save(Path(path), partial(self._write_glb, naming=naming))

    def save_gif(self, path: str | os.PathLike) -> Path:
        """A stick-figure animation with the caption and a floor grid."""
        return _save(Path(path), self._write_gif)

    def save_json(self, path: str | os.PathLike) -> Path:
        """Everything a web viewer needs: skeleton, fps, prompts and joints per frame (and
        the aligned steps, when prompt alignment made them). Strict JSON: no NaN."""
        return _save(Path(path), self._write_json)

    def save_take(
        self,
        folder: str | os.PathLike,
        name: str,
        overwrite: bool = False,
        bone_translations: bool = False,
        scale: float = 1.0,
        naming: str = "mixamo",
        formats: Sequence[str] = TAKE,
    ) -> list[Path]:
        """The files of this motion as one take, written all or none: by default the .bvh,
        .gif, .npy and .json; `formats` names others (any of FORMATS, e.g. ("glb", "npy"): a
        long take need not write a GIF). An earlier take named `name` is kept (this one is
        named name-2, name-3, ...: the first free), unless overwrite=True replaces it. Returns
        the paths written. The other options are save_bvh's (naming: save_glb's too)."""
        suffixes = take_suffixes(formats)
        overwrite = checked_bool(overwrite, "overwrite")
        bvh.check_options(scale, bone_translations, naming)  # before any file is written
        folder = check_take(folder, name, overwrite, formats=formats)
        writers = dict(
            bvh=partial(
                self._write_bvh, scale=scale, bone_translations=bone_translations, naming=naming
            ),
            glb=partial(self._write_glb, naming=naming),
            gif=self._write_gif,
            npy=partial(_write_array, self.joints),
            json=self._write_json,
        )
        names = (
            [[folder / (name + suffix) for suffix in suffixes]]
            if overwrite
            else files.numbered(folder, name, suffixes)
        )
        return files.write_all(
            [writers[suffix[1:]] for suffix in suffixes], names, replace=overwrite
        )

    def _write_bvh(
        self,
        path: Path,
        scale: float = 1.0,
        bone_translations: bool = False,
        naming: str = "mixamo",
    ) -> None:
        bvh.save_bvh(path, self.joints, self.skeleton, self.fps, scale, bone_translations, naming)

    def _write_glb(self, path: Path, naming: str = "mixamo") -> None:
        glb.save_glb(path, self.joints, self.skeleton, self.fps, bvh.joint_names(naming))

    def _write_gif(self, path: Path) -> None:
        render.save_gif(self.joints, path, self.caption, self.fps, self.skeleton)

    def _write_json(self, path: Path) -> None:
        self.skeleton.checked_joints(self.joints)  # finite: JSON has no NaN
        if not math.isfinite(self.fps) or self.fps <= 0:
            raise ValueError(f"fps must be a positive number, got {self.fps}")
        document = dict(
            fps=float(self.fps),
            skeleton=self.skeleton.name,
            joint_names=list(self.skeleton.joint_names),
            parents=[int(p) for p in self.skeleton.parents],
            prompts=[dict(frame=int(frame), text=text) for frame, text in self.prompts],
            seed=None if self.seed is None else int(self.seed),
            frames=np.round(self.joints, 5).tolist(),
        )
        if self.alignment is not None:
            document["alignment"] = self.alignment.as_dict()
        with open(path, "w", encoding="utf-8") as file:
            file.write(json.dumps(document, allow_nan=False) + "\n")


def take_suffixes(formats: Sequence[str] = TAKE) -> tuple[str, ...]:
    """The files of a take of `formats` (each of FORMATS at most once), in FORMATS' order."""
    if isinstance(formats, str) or not isinstance(formats, Sequence):
        raise TypeError(f"formats must be a list of names, got {type(formats).__name__}")
    choose = f"choose from {', '.join(FORMATS)}"
    if unknown := [f for f in formats if f not in FORMATS]:
        raise ValueError(f"no format {unknown[0]!r}; {choose}")
    if not formats or len(set(formats)) < len(formats):
        raise ValueError(f"name each format once, at least one; {choose}")
    return tuple(f".{f}" for f in FORMATS if f in formats)


def check_take(
    folder: str | os.PathLike,
    name: str | None,
    overwrite: bool = False,
    what: str = "name",
    formats: Sequence[str] = TAKE,
) -> Path:
    """The checks save_take makes, for a caller to make before the work of generating: the
    formats are known, the folder takes files, the name is a plain file name, nothing but
    files is to be replaced. `what` names the name in messages (e.g. "--name")."""
    suffixes = take_suffixes(formats)
    folder = files.check_folder(folder)
    if name is not None:
        files.check_name(name, folder, suffixes, what)
        if overwrite:
            files.check_replaceable(folder / (name + suffix) for suffix in suffixes)
    return folder


def _save(path: Path, write: files.Writer) -> Path:
    """One file, whole: it replaces the file there only once written completely."""
    return files.write_all([write], [[path]], replace=True)[0]


def _npy_path(path: str | os.PathLike) -> Path:
    path = Path(path)
    return path if path.name.endswith(".npy") else path.with_name(path.name + ".npy")


def _write_array(array: np.ndarray, path: Path) -> None:
    with open(path, "wb") as file:  # a file, not a name: numpy would add ".npy" to a name
        np.save(file, np.asarray(array, dtype=np.float32))
