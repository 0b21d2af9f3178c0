"""Reading a model bundle: a folder of ONNX graphs, a tokenizer, normalisation arrays and the
manifest.json that describes them.

Loading runs no code from the bundle (JSON, ONNX, .npy with allow_pickle=False) and trusts no
file it cannot vouch for: every file the manifest names must be listed with its size and
sha256, and must match, before any session is created. Everything the runtime knows about a
model (sizes, graph names, fps, skeleton, decoder context) comes from the manifest (its schema:
mogo.manifest), never from code.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mogo._session import graph_session
from mogo.manifest import MANIFEST, BundleError, FileEntry, Manifest, io_types
from mogo.motion import untrusted


@dataclass(frozen=True)
class Bundle:
    root: Path
    manifest: Manifest
    mean: np.ndarray  # (D,) float32
    std: np.ndarray  # (D,) float32

    @classmethod
    def load(cls, root: str | os.PathLike) -> Bundle:
        root = Path(root)
        if not root.is_dir():
            hint = f"; give its folder, {root.parent}" if root.name == MANIFEST else ""
            raise BundleError(
                f"{root}: "
                + (
                    f"a file, not a bundle folder{hint}"
                    if root.exists()
                    else "no such bundle folder"
                )
            )
        if not os.access(root, os.R_OK | os.X_OK):
            raise BundleError(f"{root}: no permission to read this bundle folder")
        manifest = read_manifest(root)
        verify_files(root, manifest)
        norm = manifest.motion.normalization
        mean, std = read_array(root / norm.mean), read_array(root / norm.std)
        for name, array in ((norm.mean, mean), (norm.std, std)):
            if array.shape != (manifest.feature_dim,):
                raise BundleError(
                    f"{root / name}: shape {array.shape}, expected ({manifest.feature_dim},)"
                )
        if np.any(std <= 0):
            raise BundleError(f"{root / norm.std}: has values <= 0")
        return cls(root, manifest, mean, std)

    def path(self, name: str) -> Path:
        return self.root / name

    def open_graphs(self) -> int:
        """Opens every graph as the runtime does (onnxruntime parses it; its input and output
        names, types and fixed sizes are checked against the manifest), which a matching sha256
        does not vouch for:
        the manifest may have been written after a graph was damaged. Returns how many."""
        for graph in self.manifest.graphs():
            graph_session(self.path(graph.file), graph, types=io_types(self.manifest, graph))
        return len(self.manifest.graphs())


def read_manifest(root: Path) -> Manifest:
    path = root / MANIFEST
    if not path.is_file():
        if root.is_dir() and not any(root.iterdir()):
            raise BundleError(
                f"{root}: an empty folder; a bundle folder holds a {MANIFEST} "
                "and the files it lists"
            )
        raise BundleError(f"{path}: missing; a bundle folder holds a {MANIFEST}")
    if path.is_symlink():  # what vouches for every other file must itself be in the folder
        raise BundleError(
            f"{path}: a symbolic link (to {os.path.realpath(path)}); the "
            "manifest must be a file of the bundle folder"
        )
    try:
        data = untrusted.read_json(path, "manifest")
    except ValueError as error:
        raise BundleError(str(error)) from None
    return Manifest.from_json(data, str(path))


def write_manifest(root: Path, manifest: Manifest) -> Manifest:
    """The manifest with the size and sha256 of every file in `root`, written as its
    manifest.json (what `mogo export` does last); returns it."""
    files = {
        p.name: FileEntry(bytes=p.stat().st_size, sha256=file_sha256(p))
        for p in sorted(Path(root).iterdir())
        if p.is_file() and p.name != MANIFEST
    }
    manifest = replace(manifest, files=files)
    (Path(root) / MANIFEST).write_text(manifest.dumps())
    return manifest


def verify_files(root: Path, manifest: Manifest) -> None:
    """Every file the manifest refers to is listed, present, of its size and sha256."""
    files = manifest.files
    for name in sorted(set(files) | manifest.referenced_files()):
        if Path(name).is_absolute() or ".." in Path(name).parts:
            raise BundleError(f"{root / MANIFEST}: file name {name!r} leaves the bundle folder")
        if name not in files:
            raise BundleError(f"{root / MANIFEST}: refers to {name} but lists no checksum for it")
    inside = Path(os.path.realpath(root))  # realpath, unlike resolve, takes a link loop too
    for name, entry in sorted(files.items()):
        path, target = root / name, Path(os.path.realpath(root / name))
        if not target.is_relative_to(inside):  # a symbolic link on the way out
            raise BundleError(
                f"{root / MANIFEST}: file name {name!r} leaves the bundle folder "
                f"(a symbolic link to {target})"
            )
        if not path.is_file():
            raise BundleError(f"{path}: missing from the bundle")
        size = path.stat().st_size
        if size != entry.bytes:
            raise BundleError(
                f"{path}: {size} bytes, the manifest says {entry.bytes} (truncated or replaced)"
            )
        if file_sha256(path) != entry.sha256:
            raise BundleError(f"{path}: sha256 does not match the manifest (corrupted or altered)")


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_array(path: Path) -> np.ndarray:
    """A .npy array of the bundle as float32; BundleError unless it is an array of finite real
    numbers (read by mogo.motion.untrusted.read_npy: sizes checked, no pickle)."""
    try:
        array = untrusted.read_npy(path)
    except ValueError as error:
        raise BundleError(str(error)) from None
    if not np.issubdtype(array.dtype, np.number) or np.issubdtype(array.dtype, np.complexfloating):
        raise BundleError(f"{path}: holds {array.dtype} values, expected real numbers")
    with np.errstate(over="ignore"):
        array = array.astype(np.float32)
    return untrusted.checked_finite(array, str(path), BundleError, " (as float32)")
