"""Bring your own motion: joint-position clips -> a HumanML3D-layout folder."""
from __future__ import annotations

import hashlib
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np

from mogo.export.data.normalization import feature_statistics
from mogo.motion.features import joints_to_features
from mogo.motion.skeleton import SKELETONS, Skeleton
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
    file `ID.txt` beside a clip (HumanML3D text format) is copied to texts/. All or nothing:
    the folder is built beside `out_dir` and renamed to it at the end, so a bad clip (refused
    naming its file) leaves no half-written folder; an `out_dir` that holds files is refused.
    """
    skeleton = SKELETONS[skeleton_name]
    if source_fps is not None and not (math.isfinite(source_fps) and source_fps >= 1):
        raise ValueError(f"the source frame rate (--fps) must be a number of frames per second, "
                         f"at least 1, got {source_fps}")
    if not joints_dir.is_dir():
        raise NotADirectoryError(f"joint folder not found: {joints_dir}")
    files = sorted(p for p in joints_dir.glob("*.npy") if p.is_file())
    if not files:
        raise ValueError(f"no .npy files in {joints_dir}")
    if out_dir.is_file() or (out_dir.is_dir() and any(out_dir.iterdir())):
        raise ValueError(f"{out_dir}: exists and is not an empty folder; give a new --out "
                         "(nothing is overwritten)")
    for path in files:  # every clip checked before the long part starts
        read_clip(path, skeleton)
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.partial-", dir=out_dir.parent))
    except OSError as error:
        raise ValueError(f"{out_dir}: cannot create it ({error.strerror or error})") from None
    try:
        splits = _convert_into(staging, files, skeleton, source_fps, progress)
        if out_dir.is_dir():
            out_dir.rmdir()  # empty, checked above
        staging.rename(out_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    counts = ", ".join(f"{len(ids)} {name}" for name, ids in splits.items())
    print(f"converted {len(files)} clips into {out_dir} ({counts})")


def _convert_into(out_dir: Path, files: list[Path], skeleton: Skeleton,
                  source_fps: float | None, progress: bool) -> dict[str, list[str]]:
    for sub in ("new_joint_vecs", "new_joints", "texts"):
        (out_dir / sub).mkdir()
    splits: dict[str, list[str]] = {name: [] for name, _ in SPLIT_FRACTIONS}
    bar = Progress(len(files), "converting", enabled=progress)
    try:
        for path in files:
            _convert_clip(path, out_dir, skeleton, source_fps)
            splits[split_of(path.stem)].append(path.stem)
            bar.update()
    finally:  # the line ends before an error is printed
        bar.close()

    mean, std = feature_statistics(
        np.load(out_dir / "new_joint_vecs" / f"{i}.npy") for i in splits["train"] or
        [p.stem for p in files])
    np.save(out_dir / "Mean.npy", mean)
    np.save(out_dir / "Std.npy", std)
    for name, ids in splits.items():
        (out_dir / f"{name}.txt").write_text("".join(f"{i}\n" for i in ids))
    return splits


def _convert_clip(path: Path, out_dir: Path, skeleton: Skeleton,
                  source_fps: float | None) -> None:
    joints = read_clip(path, skeleton)
    try:
        if source_fps is not None:
            joints = resample(joints, source_fps, skeleton.fps)
        features, canonical = joints_to_features(joints, skeleton)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    np.save(out_dir / "new_joint_vecs" / f"{path.stem}.npy", features)
    np.save(out_dir / "new_joints" / f"{path.stem}.npy", canonical)
    caption = path.with_suffix(".txt")
    if caption.is_file():
        shutil.copyfile(caption, out_dir / "texts" / f"{path.stem}.txt")


# a person's ankle-to-head length along the bones, metres (about 1.5 for 1.7 m tall)
BODY_LENGTH_RANGE = (0.5, 2.5)
UNITS = (("centimetres", 100.0), ("millimetres", 1000.0), ("inches", 1 / 0.0254),
         ("feet", 1 / 0.3048))
MAX_COORDINATE = 1e4  # metres; beyond, float32 features lose the millimetre


def read_clip(path: Path, skeleton: Skeleton) -> np.ndarray:
    """A clip file's joints (T, J, 3) float64, or ValueError naming the file: not a .npy array,
    the wrong shape, not finite numbers, or not in metres (judged by the body's size)."""
    try:
        with path.open("rb") as handle:
            is_npy = handle.read(len(np.lib.format.MAGIC_PREFIX)) == np.lib.format.MAGIC_PREFIX
        joints = np.load(path, allow_pickle=False) if is_npy else None
    except OSError as error:
        raise ValueError(f"{path}: cannot read it ({error.strerror or error})") from None
    except (ValueError, EOFError) as error:
        raise ValueError(f"{path}: not a plain .npy array ({error})") from None
    if joints is None:
        raise ValueError(f"{path}: not a .npy array file")
    if not (np.issubdtype(joints.dtype, np.floating) or np.issubdtype(joints.dtype, np.integer)):
        raise ValueError(f"{path}: holds {joints.dtype} values, expected joint positions "
                         "(numbers)")
    expected = (skeleton.num_joints, 3)
    if joints.ndim != 3 or joints.shape[1:] != expected:
        raise ValueError(f"{path}: shape {joints.shape}, expected (T, {expected[0]}, 3) for the "
                         f"{skeleton.name} skeleton (--skeleton)")
    if len(joints) < 2:
        raise ValueError(f"{path}: {len(joints)} frame(s); a clip needs at least 2")
    joints = joints.astype(np.float64)
    if not np.all(np.isfinite(joints)):
        raise ValueError(f"{path}: holds NaN or infinite coordinates")
    if np.abs(joints).max() > MAX_COORDINATE:
        raise ValueError(f"{path}: coordinates up to {np.abs(joints).max():.3g}; joints are "
                         f"metres, within {MAX_COORDINATE:g} m of the origin")
    _check_metres(path, joints, skeleton)
    return joints


def _check_metres(path: Path, joints: np.ndarray, skeleton: Skeleton) -> None:
    """The median over frames of the bone path ankle -> root -> head must be a person's."""
    bones = np.linalg.norm(joints[:, 1:] - joints[:, skeleton.parents[1:]], axis=-1)
    lengths = np.concatenate([np.zeros((len(joints), 1)), bones], axis=1)  # by child joint
    path_length = np.zeros(len(joints))
    for end in (skeleton.right_foot[0], skeleton.joint_names.index("head")):
        while end > 0:
            path_length += lengths[:, end]
            end = skeleton.parents[end]
    body = float(np.median(path_length))
    low, high = BODY_LENGTH_RANGE
    if low <= body <= high:
        return
    fits = [(abs(math.log(body / factor / 1.5)), unit, factor) for unit, factor in UNITS
            if body > 0 and low <= body / factor <= high]
    hint = (f"; in {min(fits)[1]}? divide by {min(fits)[2]:.4g}" if fits
            else "; the joints must be in metres")
    raise ValueError(f"{path}: the body measures {body:.3g} from ankle to head along the "
                     f"bones, a person {low:g} to {high:g} m{hint}")
