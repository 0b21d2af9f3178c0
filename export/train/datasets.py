"""Torch datasets over a HumanML3D-layout folder (read and checked by
mogo.export.data.humanml3d.HumanML3DFolder): they feed the VQ (random fixed-length crops, or
whole clips batched by length) and the transformer (one item per caption, cut to its span).
Whole splits are held in memory, normalised, as the standard HumanML3D loaders do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import Dataset

from mogo.export.data.humanml3d import DatasetError, HumanML3DFolder
from mogo.motion.skeleton import MAX_FRAMES, MIN_FRAMES


class EpochSeeded(Dataset):
    """Random window starts that depend only on (seed, epoch, index): the same batches on every
    run and with any number of DataLoader workers. One generator draws every item's start for
    an epoch at once (a generator per item cost more than the rest of a VQ batch). Call
    `set_epoch` before each epoch (the workers copy the dataset when iteration starts, so not
    with persistent_workers)."""

    def __init__(self, seed: int):
        self.seed = seed
        self.epoch = 0

    def _set_room(self, room: np.ndarray) -> None:
        """room (N,): the number of possible starts of each item (1: always 0)."""
        self._room = np.asarray(room, dtype=np.int64)
        self.set_epoch(self.epoch)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch
        self._starts = np.random.default_rng([self.seed, epoch]).integers(0, self._room)

    def _start(self, index: int) -> int:
        return int(self._starts[index])


class MotionCropDataset(EpochSeeded):
    """One random window of `crop_frames` normalised frames per clip and epoch, for the VQ.

    Item: (crop_frames, D) float32 tensor. Clips shorter than the crop are skipped;
    `num_skipped` says how many.
    """

    def __init__(self, folder: HumanML3DFolder, split: str, crop_frames: int = 64, seed: int = 0):
        super().__init__(seed)
        if crop_frames < 1:
            raise ValueError(f"crop_frames must be at least 1, got {crop_frames}")
        self.crop_frames = crop_frames
        ids = folder.ids(split)
        clips = [folder.normalize(folder.features(i)) for i in ids]
        self.clips = [c for c in clips if len(c) >= crop_frames]
        self.num_skipped = len(clips) - len(self.clips)
        if not self.clips:
            raise DatasetError(
                f"{folder.root / f'{split}.txt'}: no clip has {crop_frames} "
                f"frames (the longest has {max(len(c) for c in clips)})"
            )
        if self.num_skipped:
            print(
                f"{split}: skipped {self.num_skipped} of {len(clips)} clips shorter than "
                f"{crop_frames} frames"
            )
        self._set_room(np.array([len(c) - crop_frames + 1 for c in self.clips]))

    def __len__(self) -> int:
        return len(self.clips)

    def __getitem__(self, index: int) -> torch.Tensor:
        clip = self.clips[index]
        start = self._start(index)
        return torch.from_numpy(clip[start : start + self.crop_frames].copy())


def whole_clip_features(
    folder: HumanML3DFolder, split: str, down_factor: int = 1, limit: int | None = None
) -> list[np.ndarray]:
    """The first `limit` clips of a split, normalised, each (T, D) cut to whole tokens of
    `down_factor` frames (clips shorter than one token are left out)."""
    clips = []
    for clip_id in folder.ids(split)[:limit]:
        features = folder.normalize(folder.features(clip_id))
        usable = len(features) - len(features) % down_factor
        if usable:
            clips.append(features[:usable])
    if not clips:
        raise DatasetError(
            f"{folder.root / f'{split}.txt'}: no clip of at least {down_factor} frames"
        )
    return clips


class WholeClipBatches(Dataset):
    """Whole clips, normalised, for training on what validation and the runtime decode: each
    item is a batch (b, T, D) of clips of one length T (no padding, which would change what
    the convolutions see at the ends), at most `batch_size` of them; the clips of a length are
    split into equal shares. Which clips share a batch depends only on (seed, epoch): call
    `set_epoch` before each epoch. Clips are cut to whole tokens of `down_factor` frames."""

    def __init__(
        self,
        folder: HumanML3DFolder,
        split: str,
        batch_size: int,
        seed: int = 0,
        down_factor: int = 1,
    ):
        if batch_size < 1:
            raise ValueError(f"batch_size must be at least 1, got {batch_size}")
        self.seed = seed
        self.clips = whole_clip_features(folder, split, down_factor)
        by_length: dict[int, list[int]] = {}
        for index, clip in enumerate(self.clips):
            by_length.setdefault(len(clip), []).append(index)
        self._by_length = [np.array(same) for _, same in sorted(by_length.items())]
        self._shares = [-(-len(same) // batch_size) for same in self._by_length]
        self.set_epoch(0)

    def set_epoch(self, epoch: int) -> None:
        rng = np.random.default_rng([self.seed, epoch])
        self._batches = [
            batch
            for same, shares in zip(self._by_length, self._shares, strict=False)
            for batch in np.array_split(rng.permutation(same), shares)
        ]

    def __len__(self) -> int:
        return len(self._batches)

    def __getitem__(self, index: int) -> torch.Tensor:
        return torch.from_numpy(np.stack([self.clips[i] for i in self._batches[index]]))


@dataclass(frozen=True)
class _Span:
    clip: int  # index into TextMotionDataset.clips
    start: int
    end: int  # exclusive, within the clip
    caption: str


class TextMotionDataset(EpochSeeded):
    """One item per (clip, caption): the caption's span of the clip, normalised.

    Spans shorter than `min_frames` are skipped (as are clips without a caption file);
    longer than `max_frames`, a random window of `max_frames` is taken each epoch.
    Item: dict(caption=str, motion=(T, D) float32 tensor, length=T, id=clip ID).
    """

    def __init__(
        self,
        folder: HumanML3DFolder,
        split: str,
        min_frames: int = MIN_FRAMES,
        max_frames: int = MAX_FRAMES,
        seed: int = 0,
    ):
        super().__init__(seed)
        if not 1 <= min_frames <= max_frames:
            raise ValueError(f"need 1 <= min_frames <= max_frames, got {min_frames}, {max_frames}")
        self.max_frames = max_frames
        self.ids: list[str] = []
        self.clips: list[np.ndarray] = []
        self.spans: list[_Span] = []
        self.num_uncaptioned = 0
        self.num_short = 0
        for clip_id in folder.ids(split):
            if not folder.has_captions(clip_id):
                self.num_uncaptioned += 1
                continue
            clip = folder.normalize(folder.features(clip_id))
            kept = 0
            for caption in folder.captions(clip_id):
                start, end = caption.span(len(clip))
                if end - start < min_frames:
                    self.num_short += 1
                    continue
                self.spans.append(_Span(len(self.clips), start, end, caption.text))
                kept += 1
            if kept:
                self.ids.append(clip_id)
                self.clips.append(clip)
        if not self.spans:
            raise DatasetError(
                f"{folder.root / f'{split}.txt'}: no captioned span of at least {min_frames} frames"
            )
        if self.num_short or self.num_uncaptioned:
            print(
                f"{split}: {len(self.spans)} caption spans; skipped {self.num_short} shorter "
                f"than {min_frames} frames and {self.num_uncaptioned} clips without texts/ID.txt"
            )
        self._set_room(np.array([max(1, s.end - s.start - max_frames + 1) for s in self.spans]))

    def __len__(self) -> int:
        return len(self.spans)

    def __getitem__(self, index: int) -> dict:
        span = self.spans[index]
        start, end = span.start, span.end
        if end - start > self.max_frames:
            start += self._start(index)
            end = start + self.max_frames
        motion = torch.from_numpy(self.clips[span.clip][start:end].copy())
        return dict(caption=span.caption, motion=motion, length=end - start, id=self.ids[span.clip])


def collate_text_motion(batch: list[dict]) -> dict:
    """Pad to the longest item: motion (B, Tmax, D) zero-padded, lengths (B,) int64,
    mask (B, Tmax) bool True on real frames, captions and ids as lists."""
    if not batch:
        raise ValueError("cannot collate an empty batch")
    lengths = torch.tensor([item["length"] for item in batch], dtype=torch.long)
    motion = torch.zeros(len(batch), int(lengths.max()), batch[0]["motion"].shape[-1])
    for row, item in enumerate(batch):
        motion[row, : item["length"]] = item["motion"]
    mask = torch.arange(motion.shape[1])[None, :] < lengths[:, None]
    return dict(
        motion=motion,
        lengths=lengths,
        mask=mask,
        captions=[item["caption"] for item in batch],
        ids=[item["id"] for item in batch],
    )
