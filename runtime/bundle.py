"""Reading a model bundle: a folder of ONNX graphs, a tokenizer, normalisation arrays and the
manifest.json that describes them.

Loading runs no code from the bundle (JSON, ONNX, .npy with allow_pickle=False) and trusts no
file it cannot vouch for: every file the manifest names must be listed with its size and
sha256, and must match, before any session is created. Everything the runtime knows about a
model (sizes, graph names, fps, skeleton, decoder context) comes from here, never from code.
"""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FORMAT = "mogo-bundle"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"


class BundleError(ValueError):
    """A bundle that cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class Bundle:
    root: Path
    manifest: dict
    mean: np.ndarray  # (D,) float32
    std: np.ndarray  # (D,) float32

    @classmethod
    def load(cls, root: str | os.PathLike) -> Bundle:
        root = Path(root)
        if not root.is_dir():
            raise BundleError(f"{root}: no such bundle folder")
        manifest = read_manifest(root)
        verify_files(root, manifest)
        mean = _array(root, manifest["normalization"]["mean"])
        std = _array(root, manifest["normalization"]["std"])
        dim = manifest["feature_dim"]
        for name, array in (("mean", mean), ("std", std)):
            if array.shape != (dim,):
                raise BundleError(f"{root / manifest['normalization'][name]}: shape "
                                  f"{array.shape}, expected ({dim},)")
        if np.any(std <= 0):
            raise BundleError(f"{root / manifest['normalization']['std']}: has values <= 0")
        return cls(root, manifest, mean, std)

    def path(self, name: str) -> Path:
        return self.root / name

    @property
    def fps(self) -> float:
        return float(self.manifest["fps"])

    @property
    def skeleton_name(self) -> str:
        return self.manifest["skeleton"]


def read_manifest(root: Path) -> dict:
    path = root / MANIFEST
    if not path.is_file():
        raise BundleError(f"{path}: missing; a bundle folder holds a {MANIFEST}")
    try:
        manifest = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise BundleError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise BundleError(f"{path}: not a {FORMAT} manifest")
    version = manifest.get("format_version")
    if version != FORMAT_VERSION:
        raise BundleError(f"{path}: format version {version!r}; this runtime reads version "
                          f"{FORMAT_VERSION} (re-export the bundle, or upgrade mogo)")
    for key in ("files", "fps", "skeleton", "feature_dim", "normalization", "text", "t2m", "vq"):
        if key not in manifest:
            raise BundleError(f"{path}: has no {key!r} entry")
    return manifest


def verify_files(root: Path, manifest: dict) -> None:
    """Every file the manifest refers to is listed, present, of its size and sha256."""
    files = manifest["files"]
    for name in sorted(set(files) | _referenced_files(manifest)):
        if Path(name).is_absolute() or ".." in Path(name).parts:
            raise BundleError(f"{root / MANIFEST}: file name {name!r} leaves the bundle folder")
        if name not in files:
            raise BundleError(f"{root / MANIFEST}: refers to {name} but lists no checksum for it")
    for name, entry in sorted(files.items()):
        path = root / name
        if not path.is_file():
            raise BundleError(f"{path}: missing from the bundle")
        size = path.stat().st_size
        if size != entry["bytes"]:
            raise BundleError(f"{path}: {size} bytes, the manifest says {entry['bytes']} "
                              "(truncated or replaced)")
        if file_sha256(path) != entry["sha256"]:
            raise BundleError(f"{path}: sha256 does not match the manifest (corrupted or altered)")


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _referenced_files(manifest: dict) -> set[str]:
    """Every value under a "file" key or in "normalization", anywhere in the manifest."""
    found = set(manifest["normalization"].values())

    def walk(node) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if key in ("file", "tokenizer") and isinstance(value, str):
                    found.add(value)
                else:
                    walk(value)
        elif isinstance(node, list):
            for value in node:
                walk(value)

    walk({k: v for k, v in manifest.items() if k != "files"})
    return found


def _array(root: Path, name: str) -> np.ndarray:
    path = root / name
    try:
        array = np.load(path, allow_pickle=False)
    except ValueError as error:
        raise BundleError(f"{path}: not a plain .npy array ({error})") from None
    if not np.all(np.isfinite(array)):
        raise BundleError(f"{path}: contains NaN or infinite values")
    return array.astype(np.float32)
