"""Bring your own motion: joint-position clips (.npy), BVH files and DeepMimic motions ->
a HumanML3D-layout folder."""

from __future__ import annotations

import hashlib
import math
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mogo.export.data.normalization import feature_statistics
from mogo.motion.deepmimic import is_deepmimic
from mogo.motion.features import joints_to_features
from mogo.motion.mocap import (
    BODY_LENGTH_RANGE,
    UNITS,
    body_length,
    check_coordinates,
    check_length,
    read_mocap,
    resample,
)
from mogo.motion.rigs import Source
from mogo.motion.skeleton import SKELETONS, SMPL_22, Skeleton
from mogo.motion.untrusted import read_npy
from mogo.progress import Progress

SPLIT_FRACTIONS = (("train", 0.80), ("val", 0.05), ("test", 0.15))


def split_of(clip_id: str) -> str:
    """Deterministic split from a hash of the ID, so re-running never reshuffles clips."""
    point = int(hashlib.sha256(clip_id.encode()).hexdigest()[:8], 16) / 0xFFFFFFFF
    edge = 0.0
    for name, fraction in SPLIT_FRACTIONS:
        edge += fraction
        if point < edge:
            return name
    return SPLIT_FRACTIONS[-1][0]


MOCAP_SUFFIXES = (".bvh", ".txt", ".json")  # .txt: a DeepMimic motion, or a clip's caption


@dataclass(frozen=True)
class ClipReader:
    """How a folder's clips are read: the skeleton, the .npy clips' frame rate (None: the
    skeleton's), the rig map of BVH files whose joint names no built-in map knows."""

    skeleton: Skeleton
    source_fps: float | None = None
    mapping: dict[str, Source] | None = None

    def read(self, path: Path) -> tuple[np.ndarray, str | None]:
        """A clip's joints (T, J, 3) at the skeleton's frame rate, and what a motion-capture
        file was found to be (None for .npy); ValueError naming the file."""
        if path.suffix.lower() == ".npy":
            joints = read_clip(path, self.skeleton)
            fps, description = self.source_fps or self.skeleton.fps, None
            check_length(path, len(joints), fps)
        else:
            if self.skeleton is not SMPL_22:
                raise ValueError(
                    f"{path}: motion capture converts onto the humanml3d "
                    f"skeleton only, not {self.skeleton.name}"
                )
            clip = read_mocap(path, self.mapping)
            joints, fps, description = clip.joints, clip.fps, clip.description
            _check_joints(path, joints, self.skeleton)
        return resample(joints, fps, self.skeleton.fps), description


def clip_files(folder: Path) -> list[Path]:
    """The clips of a folder: .npy joints, .bvh files, DeepMimic motions (.txt or .json)."""
    files = []
    for path in sorted(p for p in folder.iterdir() if p.is_file()):
        suffix = path.suffix.lower()
        if suffix in (".npy", ".bvh") or (suffix in MOCAP_SUFFIXES and _is_motion(path)):
            files.append(path)
    return files


def _is_motion(path: Path) -> bool:
    with path.open("rb") as handle:
        return is_deepmimic(handle.read(4096).decode("utf-8", errors="replace"))


def convert_joint_folder(
    joints_dir: Path,
    out_dir: Path,
    skeleton_name: str = "humanml3d",
    source_fps: float | None = None,
    progress: bool = True,
    mapping: dict[str, Source] | None = None,
) -> None:
    """Convert every clip in `joints_dir` (see clip_files; .npy: T x J x 3, metres, Y up).

    Writes new_joint_vecs/, new_joints/, Mean.npy, Std.npy and train/val/test.txt; a caption
    file `ID.txt` beside a clip (HumanML3D text format) is copied to texts/. Says what each
    motion-capture file was found to be. All or nothing: the folder is built beside `out_dir`
    and renamed to it at the end, so a bad clip (refused naming its file) leaves no
    half-written folder; an `out_dir` that holds files is refused.
    """
    if source_fps is not None and not (math.isfinite(source_fps) and source_fps >= 1):
        raise ValueError(
            f"the source frame rate (--fps) must be a number of frames per second, "
            f"at least 1, got {source_fps}"
        )
    reader = ClipReader(SKELETONS[skeleton_name], source_fps, mapping)
    if not joints_dir.is_dir():
        raise NotADirectoryError(f"joint folder not found: {joints_dir}")
    files = clip_files(joints_dir)
    if not files:
        raise ValueError(f"no .npy, .bvh or DeepMimic motion files in {joints_dir}")
    if out_dir.is_file() or (out_dir.is_dir() and any(out_dir.iterdir())):
        raise ValueError(
            f"{out_dir}: exists and is not an empty folder; give a new --out "
            "(nothing is overwritten)"
        )
    for path in files:  # every clip checked before the long part starts
        description = reader.read(path)[1]
        if description:
            print(f"{path.name}: {description}")
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.partial-", dir=out_dir.parent))
    except OSError as error:
        raise ValueError(f"{out_dir}: cannot create it ({error.strerror or error})") from None
    try:
        splits = _convert_into(staging, files, reader, progress)
        if out_dir.is_dir():
            out_dir.rmdir()  # empty, checked above
        staging.rename(out_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    counts = ", ".join(f"{len(ids)} {name}" for name, ids in splits.items())
    print(f"converted {len(files)} clips into {out_dir} ({counts})")


def _convert_into(
    out_dir: Path, files: list[Path], reader: ClipReader, progress: bool
) -> dict[str, list[str]]:
    for sub in ("new_joint_vecs", "new_joints", "texts"):
        (out_dir / sub).mkdir()
    splits: dict[str, list[str]] = {name: [] for name, _ in SPLIT_FRACTIONS}
    bar = Progress(len(files), "converting", enabled=progress)
    try:
        for path in files:
            _convert_clip(path, out_dir, reader)
            splits[split_of(path.stem)].append(path.stem)
            bar.update()
    finally:  # the line ends before an error is printed
        bar.close()

    mean, std = feature_statistics(
        np.load(out_dir / "new_joint_vecs" / f"{i}.npy")
        for i in splits["train"] or [p.stem for p in files]
    )
    np.save(out_dir / "Mean.npy", mean)
    np.save(out_dir / "Std.npy", std)
    for name, ids in splits.items():
        (out_dir / f"{name}.txt").write_text("".join(f"{i}\n" for i in ids))
    return splits


def _convert_clip(path: Path, out_dir: Path, reader: ClipReader) -> None:
    joints = reader.read(path)[0]
    try:
        features, canonical = joints_to_features(joints, reader.skeleton)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    np.save(out_dir / "new_joint_vecs" / f"{path.stem}.npy", features)
    np.save(out_dir / "new_joints" / f"{path.stem}.npy", canonical)
    caption = path.with_suffix(".txt")
    if caption.is_file() and caption != path and not _is_motion(caption):
        shutil.copyfile(caption, out_dir / "texts" / f"{path.stem}.txt")


def read_clip(path: Path, skeleton: Skeleton) -> np.ndarray:
    """A clip file's joints (T, J, 3) float64, or ValueError naming the file: not a .npy array,
    the wrong shape, not finite numbers, or not in metres (judged by the body's size)."""
    joints = read_npy(path)  # its size checked against the file's before reading
    if not (np.issubdtype(joints.dtype, np.floating) or np.issubdtype(joints.dtype, np.integer)):
        raise ValueError(f"{path}: holds {joints.dtype} values, expected joint positions (numbers)")
    expected = (skeleton.num_joints, 3)
    if joints.ndim != 3 or joints.shape[1:] != expected:
        raise ValueError(
            f"{path}: shape {joints.shape}, expected (T, {expected[0]}, 3) for the "
            f"{skeleton.name} skeleton (--skeleton)"
        )
    if len(joints) < 2:
        raise ValueError(f"{path}: {len(joints)} frame(s); a clip needs at least 2")
    joints = joints.astype(np.float64)
    _check_joints(path, joints, skeleton)
    return joints


def _check_joints(path: Path, joints: np.ndarray, skeleton: Skeleton) -> None:
    check_coordinates(path, joints)
    _check_metres(path, joints, skeleton)


def _check_metres(path: Path, joints: np.ndarray, skeleton: Skeleton) -> None:
    """The body (mogo.motion.mocap.body_length) must be a person's, in metres."""
    body = body_length(joints, skeleton)
    low, high = BODY_LENGTH_RANGE
    if low <= body <= high:
        return
    fits = [
        (abs(math.log(body / factor / 1.5)), unit, factor)
        for unit, factor in UNITS[1:]
        if body > 0 and low <= body / factor <= high
    ]
    hint = (
        f"; in {min(fits)[1]}? divide by {min(fits)[2]:.4g}"
        if fits
        else "; the joints must be in metres"
    )
    raise ValueError(
        f"{path}: the body measures {body:.3g} from ankle to head along the "
        f"bones, a person {low:g} to {high:g} m{hint}"
    )
