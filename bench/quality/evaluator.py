"""Text and motion embeddings for the metrics, without torch.

`TextMotionEvaluator` is the seam: anything with `embed_text(captions)` and
`embed_motion(features_list)` (raw, unnormalised HumanML3D features, one (T, D) array a clip)
can score a bundle, e.g. a wrapper around the official HumanML3D evaluator. `OnnxEvaluator`
runs the folder `mogo train evaluator` exports (evaluator.json, two ONNX graphs, tokenizer,
the mean/std its motion input is normalised with) on onnxruntime.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
from tokenizers import Tokenizer

from mogo._session import cpu_session

MANIFEST = "evaluator.json"
BATCH = 64


@runtime_checkable
class TextMotionEvaluator(Protocol):
    embed_dim: int

    def embed_text(self, captions: Sequence[str]) -> np.ndarray:
        """-> (N, embed_dim) float32."""

    def embed_motion(self, features: Sequence[np.ndarray]) -> np.ndarray:
        """Raw features, one (T, D) array a clip -> (N, embed_dim) float32."""


class OnnxEvaluator:
    """An exported `mogo train evaluator` folder on onnxruntime."""

    def __init__(self, folder: str | os.PathLike, threads: int = 1):
        self.folder = Path(folder)
        path = self.folder / MANIFEST
        if not path.is_file():
            raise FileNotFoundError(
                f"{self.folder}: no {MANIFEST} (an evaluator folder is "
                f"RUN/evaluator of `mogo train evaluator`)"
            )
        manifest = json.loads(path.read_text())
        if manifest.get("format") != "mogo-evaluator":
            raise ValueError(f"{path}: not a mogo evaluator manifest")
        self.manifest = manifest
        self.embed_dim = int(manifest["embed_dim"])
        self.feature_dim = int(manifest["feature_dim"])
        self.min_frames, self.max_frames = int(manifest["min_frames"]), int(manifest["max_frames"])
        self.tokenizer = Tokenizer.from_file(str(self.folder / manifest["tokenizer"]))
        self.mean = np.load(self.folder / manifest["mean"], allow_pickle=False)
        self.std = np.load(self.folder / manifest["std"], allow_pickle=False)
        self._text = cpu_session(self.folder / manifest["text"]["file"], threads)
        self._motion = cpu_session(self.folder / manifest["motion"]["file"], threads)
        self._text_names = manifest["text"]["inputs"]
        self._motion_names = manifest["motion"]["inputs"]

    def embed_text(self, captions: Sequence[str]) -> np.ndarray:
        out = []
        for first in range(0, len(captions), BATCH):
            encodings = self.tokenizer.encode_batch(list(captions[first : first + BATCH]))
            ids = np.array([e.ids for e in encodings], np.int64)
            mask = np.array([e.attention_mask for e in encodings], np.int64)
            out.append(
                self._text.run(None, dict(zip(self._text_names, (ids, mask), strict=False)))[0]
            )
        return np.concatenate(out) if out else np.zeros((0, self.embed_dim), np.float32)

    def embed_motion(self, features: Sequence[np.ndarray]) -> np.ndarray:
        """Clips longer than the evaluator's max_frames are cut to their first max_frames;
        batches are formed from clips of similar length (less padding), results in order."""
        clips = [self._checked(np.asarray(f, np.float32), k) for k, f in enumerate(features)]
        order = np.argsort([len(c) for c in clips], kind="stable")
        out = np.zeros((len(clips), self.embed_dim), np.float32)
        for first in range(0, len(order), BATCH):
            rows = order[first : first + BATCH]
            lengths = np.array([len(clips[r]) for r in rows], np.int64)
            batch = np.zeros((len(rows), lengths.max(), self.feature_dim), np.float32)
            for i, r in enumerate(rows):
                batch[i, : lengths[i]] = (clips[r] - self.mean) / self.std
            out[rows] = self._motion.run(
                None, dict(zip(self._motion_names, (batch, lengths), strict=False))
            )[0]
        return out

    def _checked(self, clip: np.ndarray, index: int) -> np.ndarray:
        if clip.ndim != 2 or clip.shape[1] != self.feature_dim:
            raise ValueError(
                f"motion {index}: expected features (T, {self.feature_dim}), got shape {clip.shape}"
            )
        if len(clip) < self.min_frames:
            raise ValueError(
                f"motion {index}: {len(clip)} frames, the evaluator needs at least "
                f"{self.min_frames}"
            )
        return clip[: self.max_frames]
