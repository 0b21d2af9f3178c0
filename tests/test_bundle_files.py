"""Bundle verification on a hand-made folder (no models needed): what is refused, and how."""
import json

import numpy as np
import pytest

from mogo.export.onnx.bundle import write_manifest
from mogo.bundle import MANIFEST, Bundle, BundleError


@pytest.fixture
def bundle(tmp_path):
    root = tmp_path / "bundle"
    root.mkdir()
    np.save(root / "mean.npy", np.zeros(263, np.float32))
    np.save(root / "std.npy", np.ones(263, np.float32))
    (root / "level_0.onnx").write_bytes(b"graph bytes " * 100)
    (root / "tokenizer.json").write_text("{}")
    manifest = dict(format="mogo-bundle", format_version=1, fps=20.0, skeleton="humanml3d",
                    feature_dim=263, normalization=dict(mean="mean.npy", std="std.npy"),
                    text=dict(tokenizer="tokenizer.json"),
                    t2m=dict(levels=[dict(file="level_0.onnx")]), vq={})
    write_manifest(root, manifest)
    return root


def _manifest(root):
    return json.loads((root / MANIFEST).read_text())


def test_a_good_bundle_loads(bundle):
    loaded = Bundle.load(bundle)
    assert loaded.fps == 20.0 and loaded.skeleton_name == "humanml3d"
    assert loaded.mean.shape == (263,) and loaded.std.dtype == np.float32
    assert set(_manifest(bundle)["files"]) == {"mean.npy", "std.npy", "level_0.onnx",
                                               "tokenizer.json"}


@pytest.mark.parametrize("damage,message", [
    (lambda r: (r / "level_0.onnx").unlink(), "level_0.onnx: missing"),
    (lambda r: (r / "level_0.onnx").write_bytes(b"graph bytes " * 50), "level_0.onnx: 600 bytes"),
    (lambda r: (r / "level_0.onnx").write_bytes(b"GRAPH BYTES " * 100),
     "level_0.onnx: sha256 does not match"),
    (lambda r: (r / MANIFEST).unlink(), "manifest.json: missing"),
    (lambda r: (r / MANIFEST).write_text("{not json"), "manifest.json: not valid JSON"),
])
def test_damage_is_refused_naming_the_file(bundle, damage, message):
    damage(bundle)
    with pytest.raises(BundleError, match=message):
        Bundle.load(bundle)


def _edit(root, change):
    manifest = _manifest(root)
    change(manifest)
    (root / MANIFEST).write_text(json.dumps(manifest))


def test_manifest_problems_are_refused(bundle, tmp_path):
    _edit(bundle, lambda m: m.update(format_version=99))
    with pytest.raises(BundleError, match="format version 99"):
        Bundle.load(bundle)
    _edit(bundle, lambda m: m.update(format_version=1))
    _edit(bundle, lambda m: m["files"].pop("level_0.onnx"))
    with pytest.raises(BundleError, match="refers to level_0.onnx but lists no checksum"):
        Bundle.load(bundle)
    _edit(bundle, lambda m: m["files"].update({"../escape": dict(bytes=0, sha256="")}))
    with pytest.raises(BundleError, match="leaves the bundle folder"):
        Bundle.load(bundle)
    with pytest.raises(BundleError, match="no such bundle folder"):
        Bundle.load(tmp_path / "nowhere")


def test_arrays_are_checked(bundle):
    np.save(bundle / "std.npy", np.zeros(263, np.float32))
    write_manifest(bundle, _manifest(bundle))
    with pytest.raises(BundleError, match="std.npy: has values <= 0"):
        Bundle.load(bundle)
    np.save(bundle / "std.npy", np.array([object()], dtype=object), allow_pickle=True)
    write_manifest(bundle, _manifest(bundle))
    with pytest.raises(BundleError, match="std.npy: not a plain .npy array"):
        Bundle.load(bundle)
