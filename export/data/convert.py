"""Bring your own motion: joint-position clips -> a HumanML3D-layout folder."""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np

from mogo.export.data.normalization import feature_statistics
from mogo.motion.features import joints_to_features
from mogo.motion.skeleton import SKELETONS
from mogo.progress import Progress

SPLIT_FRACTIONS = (("train", 0.80), ("val", 0.05), ("test", 0.15))


def resample(joints: np.ndarray, source_fps: float, target_fps: float) -> np.ndarray:
    """Linear resampling of a clip (T, J, 3) from one frame rate to another."""
    if source_fps <= 0:
        raise ValueError(f"source fps must be positive, got {source_fps}")
    if source_fps == target_fps:
        return joints
    duration = (joints.shape[0] - 1) / source_fps
    times = np.arange(0.0, duration + 1e-9, 1.0 / target_fps)
    source_times = np.arange(joints.shape[0]) / source_fps
    flat = joints.reshape(joints.shape[0], -1)
    columns = [np.interp(times, source_times, flat[:, k]) for k in range(flat.shape[1])]
    return np.stack(columns, axis=-1).reshape((len(times),) + joints.shape[1:])


def split_of(clip_id: str) -> str:
    """Deterministic split from a hash of the ID, so re-running never reshuffles clips."""
    point = int(hashlib.sha256(clip_id.encode()).hexdigest()[:8], 16) / 0xFFFFFFFF
    edge = 0.0
    for name, fraction in SPLIT_FRACTIONS:
        edge += fraction
        if point < edge:
            return name
    return SPLIT_FRACTIONS[-1][0]


def convert_joint_folder(joints_dir: Path, out_dir: Path, skeleton_name: str = "humanml3d",
                         source_fps: float | None = None, progress: bool = True) -> None:
    """Convert every `*.npy` (T x J x 3, metres, Y up) in `joints_dir`.

    Writes new_joint_vecs/, new_joints/, Mean.npy, Std.npy and train/val/test.txt; a caption
    file `ID.txt` beside a clip (HumanML3D text format) is copied to texts/.
    """
    skeleton = SKELETONS[skeleton_name]
    if not joints_dir.is_dir():
        raise NotADirectoryError(f"joint folder not found: {joints_dir}")
    files = sorted(joints_dir.glob("*.npy"))
    if not files:
        raise ValueError(f"no .npy files in {joints_dir}")
    for sub in ("new_joint_vecs", "new_joints", "texts"):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)

    splits: dict[str, list[str]] = {name: [] for name, _ in SPLIT_FRACTIONS}
    bar = Progress(len(files), "converting", enabled=progress)
    for path in files:
        clip_id = path.stem
        try:
            joints = np.load(path, allow_pickle=False)
            if source_fps is not None:
                joints = resample(joints, source_fps, skeleton.fps)
            features, canonical = joints_to_features(joints, skeleton)
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from None
        np.save(out_dir / "new_joint_vecs" / f"{clip_id}.npy", features)
        np.save(out_dir / "new_joints" / f"{clip_id}.npy", canonical)
        caption = path.with_suffix(".txt")
        if caption.exists():
            shutil.copyfile(caption, out_dir / "texts" / f"{clip_id}.txt")
        splits[split_of(clip_id)].append(clip_id)
        bar.update()
    bar.close()

    mean, std = feature_statistics(
        np.load(out_dir / "new_joint_vecs" / f"{i}.npy") for i in splits["train"] or
        [p.stem for p in files])
    np.save(out_dir / "Mean.npy", mean)
    np.save(out_dir / "Std.npy", std)
    for name, ids in splits.items():
        (out_dir / f"{name}.txt").write_text("".join(f"{i}\n" for i in ids))
    counts = ", ".join(f"{len(ids)} {name}" for name, ids in splits.items())
    print(f"converted {len(files)} clips into {out_dir} ({counts})")
