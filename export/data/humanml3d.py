"""The HumanML3D layout, read with numpy alone: the one reader of a dataset folder (HumanML3D,
KIT-ML, `mogo data synth` or `mogo data convert`) for training, evaluation and `mogo data show`.

    new_joint_vecs/ID.npy   (T, D) features          Mean.npy, Std.npy   (D,) statistics
    texts/ID.txt            captions, one a line     train.txt, val.txt, test.txt   clip IDs
    new_joints/ID.npy       (T, J, 3) joints, read only by the tools that need them

A caption line is `caption#word/POS ...#start#end`. Everything that breaks the layout is a
DatasetError naming the file (and the line).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mogo.motion.skeleton import Skeleton, skeleton_for_feature_dim
from mogo.motion.untrusted import checked_finite

SPLITS = ("train", "val", "test")


class DatasetError(ValueError):
    """A dataset folder that breaks the HumanML3D layout; the message names the file."""


@dataclass(frozen=True)
class Caption:
    text: str
    tokens: tuple[tuple[str, str], ...]  # (word, part of speech) pairs; may be empty
    start_frame: int
    end_frame: int | None  # exclusive; None: to the end of the clip

    def span(self, rows: int) -> tuple[int, int]:
        """The feature rows [start, end) it covers in a clip of `rows` rows."""
        return self.start_frame, rows if self.end_frame is None else min(self.end_frame, rows)


def parse_caption_line(line: str, fps: float, where: str) -> Caption:
    """Parse `caption#word/POS word/POS ...#start#end` (start/end in seconds).

    As in the standard loaders, a NaN time counts as 0.0 and 0.0#0.0 means the whole clip;
    otherwise the caption covers feature rows [int(start * fps), int(end * fps)).
    `where` ("path:line") prefixes every error.
    """
    fields = line.rstrip("\r\n").rsplit("#", 3)
    if len(fields) != 4 or not fields[0].strip():
        raise DatasetError(f"{where}: expected 'caption#word/POS ...#start#end', got {line!r}")
    text, tokens_field, start_field, end_field = fields
    tokens = []
    for token in tokens_field.split():
        word, slash, pos = token.rpartition("/")
        if not slash or not word or not pos:
            raise DatasetError(f"{where}: token {token!r} is not word/POS")
        tokens.append((word, pos))
    times = []
    for name, field in (("start", start_field), ("end", end_field)):
        try:
            seconds = float(field)
        except ValueError:
            raise DatasetError(f"{where}: {name} time {field!r} is not a number") from None
        if math.isnan(seconds):
            seconds = 0.0
        if not math.isfinite(seconds) or seconds < 0:
            raise DatasetError(f"{where}: {name} time {field!r} is not a time in seconds")
        times.append(seconds)
    start, end = times
    if start == 0.0 and end == 0.0:
        return Caption(text.strip(), tuple(tokens), 0, None)
    return Caption(text.strip(), tuple(tokens), int(start * fps), int(end * fps))


def format_caption_line(
    text: str,
    start_seconds: float = 0.0,
    end_seconds: float = 0.0,
    tokens: tuple[tuple[str, str], ...] = (),
) -> str:
    """One text-file line; 0.0#0.0 marks a caption of the whole clip."""
    if "#" in text or "\n" in text:
        raise ValueError(f"a caption may not contain '#' or a newline: {text!r}")
    token_field = " ".join(f"{word}/{pos}" for word, pos in tokens)
    return (
        f"{text}#{token_field}#{float(round(start_seconds, 3))!r}#{float(round(end_seconds, 3))!r}"
    )


class HumanML3DFolder:
    """A dataset folder, its layout checked up front (`splits`: the split files to read; the
    tools that need only the test split read only that one), so a broken folder fails before
    any work with the file and the problem named.

    `root_contact_scale` > 1 divides the Std of the root dims (0:4) and of the foot contacts
    (last 4) by it, so those features count that much more in a reconstruction loss (the
    T2M/T2M-GPT training code uses 5). The default 1 is plain (x - Mean) / Std. `.mean` and
    `.std` are the statistics actually used, i.e. what a model trained on them must be
    exported with.
    """

    def __init__(
        self,
        root: str | os.PathLike,
        root_contact_scale: float = 1.0,
        splits: tuple[str, ...] = SPLITS,
    ):
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: dataset folder not found")
        unknown = [name for name in splits if name not in SPLITS]
        if unknown:
            raise ValueError(f"unknown split {unknown[0]!r}; expected one of {', '.join(SPLITS)}")
        missing = [
            f"{self.root / sub}: folder missing (HumanML3D layout)"
            for sub in ("new_joint_vecs", "texts")
            if not (self.root / sub).is_dir()
        ]
        missing += [
            f"{self.root / f'{name}.txt'}: split file missing"
            for name in splits
            if not (self.root / f"{name}.txt").is_file()
        ]
        if missing:  # all of them at once: a folder that is not the layout at all says so
            raise DatasetError("; ".join(missing))
        if not root_contact_scale > 0:
            raise ValueError(f"root_contact_scale must be positive, got {root_contact_scale}")
        self.skeleton, self.mean, self.std = self._statistics(root_contact_scale)
        available = {p.stem for p in (self.root / "new_joint_vecs").glob("*.npy")}
        self._splits = {name: self._read_split(name, available) for name in splits}

    @property
    def feature_dim(self) -> int:
        return self.skeleton.feature_dim

    @property
    def fps(self) -> float:
        return self.skeleton.fps

    def ids(self, split: str) -> list[str]:
        if split not in self._splits:
            raise ValueError(f"unknown split {split!r}; expected one of {', '.join(self._splits)}")
        if not self._splits[split]:
            raise DatasetError(f"{self.root / f'{split}.txt'}: lists no clip IDs")
        return list(self._splits[split])

    def features(self, clip_id: str) -> np.ndarray:
        """Raw (unnormalised) features (T, D) float32 of one clip."""
        path = self.root / "new_joint_vecs" / f"{clip_id}.npy"
        if not path.is_file():
            raise DatasetError(f"{path}: no such clip {clip_id!r}")
        features = _load_array(path)
        if features.ndim != 2 or features.shape[1] != self.feature_dim or len(features) == 0:
            raise DatasetError(
                f"{path}: expected (T, {self.feature_dim}) features with T >= 1, "
                f"got shape {features.shape}"
            )
        return features

    def joints(self, clip_id: str) -> np.ndarray:
        """Joint positions (T, J, 3) float32 of one clip, from new_joints/."""
        path = self.root / "new_joints" / f"{clip_id}.npy"
        joints = _load_array(path)
        if joints.shape[1:] != (self.skeleton.num_joints, 3):
            raise DatasetError(
                f"{path}: expected (T, {self.skeleton.num_joints}, 3) joints, "
                f"got shape {joints.shape}"
            )
        return joints

    def has_captions(self, clip_id: str) -> bool:
        return (self.root / "texts" / f"{clip_id}.txt").is_file()

    def captions(self, clip_id: str) -> list[Caption]:
        path = self.root / "texts" / f"{clip_id}.txt"
        if not path.is_file():
            raise DatasetError(f"{path}: no caption file for clip {clip_id!r}")
        lines = path.read_text(encoding="utf-8").splitlines()
        return [
            parse_caption_line(line, self.fps, f"{path}:{number}")
            for number, line in enumerate(lines, 1)
            if line.strip()
        ]

    def first_caption(self, clip_id: str) -> str:
        """The text of the clip's first caption ("" where it has none)."""
        captions = self.captions(clip_id) if self.has_captions(clip_id) else []
        return captions[0].text if captions else ""

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """(x - mean) / std over the last axis."""
        return (self._checked(x) - self.mean) / self.std

    def denormalize(self, x: np.ndarray) -> np.ndarray:
        return self._checked(x) * self.std + self.mean

    def _checked(self, x: np.ndarray) -> np.ndarray:
        if x.shape[-1] != self.feature_dim:
            raise ValueError(
                f"expected {self.feature_dim}-dim features, got shape {tuple(x.shape)}"
            )
        return x

    def _statistics(self, root_contact_scale: float) -> tuple[Skeleton, np.ndarray, np.ndarray]:
        """Mean.npy's size names the skeleton; Std.npy must match it and be positive."""
        mean = _load_array(self.root / "Mean.npy")
        if mean.ndim != 1:
            raise DatasetError(
                f"{self.root / 'Mean.npy'}: expected a vector (D,), got shape {mean.shape}"
            )
        try:
            skeleton = skeleton_for_feature_dim(mean.shape[0])
        except ValueError as error:
            raise DatasetError(f"{self.root / 'Mean.npy'}: {error}") from None
        std = _load_array(self.root / "Std.npy")
        if std.shape != mean.shape:
            raise DatasetError(
                f"{self.root / 'Std.npy'}: shape {std.shape} does not match Mean.npy's {mean.shape}"
            )
        if np.any(std <= 0):
            raise DatasetError(
                f"{self.root / 'Std.npy'}: {int(np.sum(std <= 0))} entries are zero or negative"
            )
        std[:4] /= root_contact_scale  # std is a fresh float32 copy from _load_array
        std[-4:] /= root_contact_scale
        return skeleton, mean, std

    def _read_split(self, name: str, available: set[str]) -> list[str]:
        path = self.root / f"{name}.txt"
        ids = []
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            clip_id = line.strip()
            if not clip_id:
                continue
            if "/" in clip_id or "\\" in clip_id or clip_id in (".", ".."):
                raise DatasetError(f"{path}:{number}: {clip_id!r} is not a clip ID")
            ids.append(clip_id)
        missing = [i for i in ids if i not in available]
        if missing:
            shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
            raise DatasetError(
                f"{path}: {len(missing)} listed IDs have no new_joint_vecs/ID.npy: {shown}"
            )
        return ids


def _load_array(path: Path) -> np.ndarray:
    """A finite numeric .npy as float32 (no pickle), or a DatasetError naming the file."""
    if not path.is_file():
        raise DatasetError(f"{path}: file missing")
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as error:
        raise DatasetError(f"{path}: not a readable .npy array ({error})") from None
    if not np.issubdtype(array.dtype, np.number):
        raise DatasetError(f"{path}: expected numbers, got dtype {array.dtype}")
    return checked_finite(array, str(path), DatasetError).astype(np.float32)
