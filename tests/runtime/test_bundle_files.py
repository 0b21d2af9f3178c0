"""Bundle verification on a hand-made folder (no models needed): what is refused, and how; the
manifest schema (mogo.manifest) on it and on the shipped bundle; damaged graphs on a copy of
the shipped bundle."""

import dataclasses
import json
import os
import re
import shutil

import numpy as np
import pytest

from mogo.bundle import MANIFEST, Bundle, BundleError, file_sha256, read_manifest, write_manifest
from mogo.cli import main
from mogo.generator import DEFAULT_BUNDLE, MotionGenerator
from mogo.manifest import (
    T2M,
    VQ,
    DecoderGraph,
    Defaults,
    Graph,
    Manifest,
    MotionFormat,
    Normalization,
    Text,
)
from mogo.motion.skeleton import SMPL_22

GRAPHS = ("text_encoder.onnx", "level_0.onnx", "vq_encoder.onnx", "vq_decoder.onnx")


def small_manifest() -> Manifest:
    """A manifest of the hand-made folder: one level, the HumanML3D skeleton."""
    return Manifest(
        motion=MotionFormat.of(SMPL_22, Normalization(mean="mean.npy", std="std.npy")),
        text=Text(
            tokenizer="tokenizer.json",
            max_length=8,
            kind="SmallTextEncoder",
            encoder=Graph(
                "text_encoder.onnx", ("token_ids", "attention_mask"), ("prompt_embedding",)
            ),
        ),
        t2m=T2M(
            config=dict(dim=16, text_dim=16, max_relative_distance=8),
            levels=(Graph("level_0.onnx", ("prompt",), ("logits",)),),
        ),
        vq=VQ(
            config=dict(feature_dim=263, levels=1, codebook_size=8, down_factor=1),
            encoder=Graph("vq_encoder.onnx", ("features",), ("ids",)),
            decoder=DecoderGraph("vq_decoder.onnx", ("ids",), ("features",), 2, 2),
        ),
        defaults=Defaults(
            temperature=1.0, top_k=0, top_p=0.9, guidance=1.0, window=16, max_seconds=9.8
        ),
    )


@pytest.fixture
def bundle(tmp_path):
    root = tmp_path / "bundle"
    root.mkdir()
    np.save(root / "mean.npy", np.zeros(263, np.float32))
    np.save(root / "std.npy", np.ones(263, np.float32))
    for name in GRAPHS:
        (root / name).write_bytes(b"graph bytes " * 100)
    (root / "tokenizer.json").write_text("{}")
    write_manifest(root, small_manifest())
    return root


def _manifest(root):
    return json.loads((root / MANIFEST).read_text())


def test_a_good_bundle_loads(bundle):
    loaded = Bundle.load(bundle)
    assert loaded.manifest.fps == 20.0 and loaded.manifest.motion.skeleton.name == "humanml3d"
    assert loaded.mean.shape == (263,) and loaded.std.dtype == np.float32
    assert set(_manifest(bundle)["files"]) == {"mean.npy", "std.npy", "tokenizer.json", *GRAPHS}
    with pytest.raises(dataclasses.FrozenInstanceError):
        loaded.root = bundle.parent  # verified as it is: never pointed elsewhere afterwards


@pytest.mark.parametrize(
    "damage,message",
    [
        (lambda r: (r / "level_0.onnx").unlink(), "level_0.onnx: missing"),
        (
            lambda r: (r / "level_0.onnx").write_bytes(b"graph bytes " * 50),
            "level_0.onnx: 600 bytes",
        ),
        (
            lambda r: (r / "level_0.onnx").write_bytes(b"graph bytes " * 101),
            "level_0.onnx: 1212 bytes, the manifest says 1200",
        ),
        (
            lambda r: (r / "level_0.onnx").write_bytes(b"GRAPH BYTES " * 100),
            "level_0.onnx: sha256 does not match",
        ),
        # a listed sha256 that is not the file's, sorting below it and above it
        (
            lambda r: _edit(r, lambda m: m["files"]["level_0.onnx"].update(sha256="0" * 64)),
            "level_0.onnx: sha256 does not match",
        ),
        (
            lambda r: _edit(r, lambda m: m["files"]["level_0.onnx"].update(sha256="f" * 64)),
            "level_0.onnx: sha256 does not match",
        ),
        (lambda r: (r / MANIFEST).unlink(), "manifest.json: missing"),
        (lambda r: (r / MANIFEST).write_text("{not json"), "manifest.json: not valid JSON"),
    ],
)
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
    _edit(bundle, lambda m: m.update(format_version=2))
    _edit(bundle, lambda m: m["files"].pop("level_0.onnx"))
    with pytest.raises(BundleError, match="refers to level_0.onnx but lists no checksum"):
        Bundle.load(bundle)
    with pytest.raises(BundleError, match="no such bundle folder"):
        Bundle.load(tmp_path / "nowhere")


def _skeleton(m):
    return m["motion"]["skeleton"]


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda m: m["t2m"]["levels"][0].pop("file"), "t2m.levels[0].file: missing"),
        (lambda m: m.pop("defaults"), "defaults: missing"),
        (lambda m: m["motion"].update(fps="20"), "motion.fps: expected a number, got '20'"),
        (lambda m: m["defaults"].update(top_k=True), "defaults.top_k: expected an integer"),
        (lambda m: m["defaults"].update(temprature=1.0), "defaults.temprature: unknown key"),
        (
            lambda m: m["text"]["encoder"].update(inputs="token_ids"),
            "text.encoder.inputs: expected a list",
        ),
        (lambda m: m["vq"]["decoder"].pop("lookahead"), "vq.decoder.lookahead: missing"),
        (
            lambda m: m["vq"]["config"].pop("down_factor"),
            "vq.config.down_factor: missing or not a positive integer",
        ),
        (
            lambda m: m["vq"]["config"].update(feature_dim=251),
            "vq.config.feature_dim: 251, the feature layout (motion.features) has 263",
        ),
        (lambda m: m["vq"]["config"].update(levels=2), "t2m.levels: 1 graphs for 2 VQ levels"),
        (
            lambda m: _skeleton(m)["face_joints"].pop(),
            "motion.skeleton.face_joints: 3 items, expected 4",
        ),
        (lambda m: _skeleton(m)["parents"].reverse(), "motion.skeleton.parents: [19, 18, 17"),
        (
            lambda m: _skeleton(m)["rest_offsets"].pop(),
            "motion.skeleton.rest_offsets: 21 rows for 22 joints",
        ),
        (lambda m: m["motion"]["features"][3].update(stop=66), "motion.features: not the layout"),
        (
            lambda m: m.update(format_version=1),
            "format version 1; this runtime reads version 2 "
            "(re-export the bundle with `mogo export`",
        ),
    ],
)
def test_a_manifest_off_the_schema_is_refused_naming_the_key(bundle, change, message):
    _edit(bundle, change)
    with pytest.raises(BundleError, match=re.escape(f"manifest.json: {message}")):
        Bundle.load(bundle)


def test_the_manifest_reads_back_what_was_written(bundle):
    manifest = write_manifest(bundle, small_manifest())
    assert Manifest.from_json(json.loads(manifest.dumps())) == manifest == read_manifest(bundle)
    assert "rest_offsets" in _skeleton(_manifest(bundle)) and "int8" not in _manifest(bundle)


def test_the_shipped_bundle_is_in_the_current_form_with_the_runtimes_skeleton():
    text = (DEFAULT_BUNDLE / MANIFEST).read_text()
    manifest = Manifest.from_json(json.loads(text))
    assert manifest.dumps() == text  # what `mogo export` would write
    skeleton = manifest.skeleton()
    assert skeleton.joint_names == SMPL_22.joint_names and skeleton.chains == SMPL_22.chains
    assert np.array_equal(skeleton.parents, SMPL_22.parents) and skeleton.fps == SMPL_22.fps
    for name in ("raw_offsets", "rest_offsets"):
        assert np.array_equal(getattr(skeleton, name), getattr(SMPL_22, name)), name
    assert manifest.feature_dim == SMPL_22.feature_dim and manifest.end_token == 512


def test_arrays_are_checked(bundle):
    np.save(bundle / "std.npy", np.zeros(263, np.float32))
    write_manifest(bundle, read_manifest(bundle))
    with pytest.raises(BundleError, match="std.npy: has values <= 0"):
        Bundle.load(bundle)
    np.save(bundle / "std.npy", np.array([object()], dtype=object), allow_pickle=True)
    write_manifest(bundle, read_manifest(bundle))
    with pytest.raises(BundleError, match="std.npy: holds Python objects, not numbers"):
        Bundle.load(bundle)


# -- what issue 18 found accepted or worded wrongly -----------------------------------------------
@pytest.mark.parametrize(
    "change,message",
    [
        (lambda m: m["files"]["level_0.onnx"].pop("sha256"), "files.level_0.onnx.sha256: missing"),
        (lambda m: m["motion"]["normalization"].pop("mean"), "motion.normalization.mean: missing"),
        (
            lambda m: m["files"]["level_0.onnx"].update(bytes="1200"),
            "files.level_0.onnx.bytes: expected an integer, got '1200'",
        ),
        (lambda m: m["motion"].update(fps="twenty"), "motion.fps: expected a number, got 'twenty'"),
        (lambda m: m["motion"].update(fps=0), "motion.fps: 0.0, must be > 0"),
        (lambda m: m["defaults"].update(top_k=-5), "defaults.top_k: top_k must be >= 0"),
        (
            lambda m: m["defaults"].update(temperature=-1.0),
            "defaults.temperature: temperature must",
        ),
        (
            lambda m: m["defaults"].update(guidance=float("nan")),
            "defaults.guidance: expected a finite number, got nan",
        ),
        (lambda m: m["defaults"].update(top_p=float("inf")), "defaults.top_p: expected a finite"),
        (lambda m: m["defaults"].update(window=0), "defaults.window: 0, must be > 0"),
        (lambda m: m["defaults"].update(max_seconds=-1), "defaults.max_seconds: -1.0, must be > 0"),
        (
            lambda m: m["vq"]["decoder"].update(lookahead=-2),
            "vq.decoder.lookahead: -2, must be >= 0",
        ),
        (lambda m: m["text"].update(max_length=0), "text.max_length: 0, must be > 0"),
        (lambda m: m.update(format_version="2"), "format_version: expected an integer, got '2'"),
        (lambda m: m.pop("format_version"), "format_version: missing"),
    ],
)
def test_a_bad_value_in_the_manifest_names_the_file_and_key(bundle, change, message):
    _edit(bundle, change)
    with pytest.raises(BundleError, match=re.escape(f"{bundle / MANIFEST}: {message}")):
        Bundle.load(bundle)


def test_a_bundle_path_that_is_no_bundle_folder_gets_one_line(bundle, tmp_path):
    (tmp_path / "file").write_text("x")
    (tmp_path / "zz").write_text("x")  # names sorting before and after manifest.json
    (tmp_path / "empty").mkdir()
    for path, message in (
        (tmp_path / "file", "a file, not a bundle folder"),
        (tmp_path / "zz", "a file, not a bundle folder"),
        (bundle / MANIFEST, f"a file, not a bundle folder; give its folder, {bundle}"),
        (
            tmp_path / "empty",
            "an empty folder; a bundle folder holds a manifest.json and the files it lists",
        ),
    ):
        with pytest.raises(BundleError, match=re.escape(f"{path}: {message}") + "$"):
            Bundle.load(path)


@pytest.mark.parametrize("denied", [os.R_OK, os.X_OK])
def test_an_unreadable_bundle_folder_is_refused_naming_it(bundle, monkeypatch, denied):
    """A folder that cannot be listed (no r) or entered (no x); os.access stands in for the
    permission bits (root reads any folder)."""
    monkeypatch.setattr("mogo.bundle.os.access", lambda path, mode: not mode & denied)
    with pytest.raises(BundleError, match=re.escape(f"{bundle}: no permission to read")):
        Bundle.load(bundle)


def test_a_manifest_that_cannot_be_read_is_one_line_naming_it(bundle, monkeypatch):
    """Permission denied on manifest.json; _open_file stands in (root reads any file)."""

    def denied(path, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr("mogo.motion.untrusted._open_file", denied)
    with pytest.raises(
        BundleError, match=re.escape(f"{bundle / MANIFEST}: cannot read it (Permission denied)")
    ):
        Bundle.load(bundle)


@pytest.fixture
def shipped_copy(tmp_path):
    root = tmp_path / "shipped"
    shutil.copytree(DEFAULT_BUNDLE, root)
    return root


def test_a_damaged_graph_with_a_matching_sha256_is_one_line_naming_it(shipped_copy, capsys):
    """The manifest re-written after the damage: the checksums pass, onnxruntime does not."""
    graph = shipped_copy / "level_0.onnx"
    graph.write_bytes(graph.read_bytes()[:100_000])
    write_manifest(shipped_copy, read_manifest(shipped_copy))
    message = (
        f"{graph}: not a valid ONNX graph: Failed to load model because protobuf parsing failed."
    )
    with pytest.raises(BundleError, match=re.escape(message)):
        MotionGenerator.load(shipped_copy)
    assert main(["info", str(shipped_copy)]) == 2  # info opens the graphs it calls verified
    assert capsys.readouterr().err == f"mogo: error: {message}\n"


def test_graph_names_off_the_manifest_are_refused_naming_the_file(shipped_copy):
    _edit(shipped_copy, lambda m: m["text"]["encoder"]["inputs"].__setitem__(0, "tokens"))
    with pytest.raises(
        BundleError,
        match=re.escape(
            f"{shipped_copy / 'text_encoder.onnx'}: the graph's inputs are not the manifest's "
            "(number 0 is 'token_ids', the manifest says 'tokens')"
        ),
    ):
        MotionGenerator.load(shipped_copy)
    shutil.copy(shipped_copy / "level_1.onnx", shipped_copy / "level_0.onnx")
    _edit(shipped_copy, lambda m: m["text"]["encoder"]["inputs"].__setitem__(0, "token_ids"))
    write_manifest(shipped_copy, read_manifest(shipped_copy))
    with pytest.raises(
        BundleError,
        match=re.escape(
            f"{shipped_copy / 'level_0.onnx'}: the graph's inputs are not the manifest's"
        ),
    ):
        Bundle.load(shipped_copy).open_graphs()


def test_a_damaged_tokenizer_is_one_line_naming_it(shipped_copy):
    (shipped_copy / "tokenizer.json").write_text("{not a tokenizer")
    write_manifest(shipped_copy, read_manifest(shipped_copy))
    with pytest.raises(
        BundleError,
        match=re.escape(f"{shipped_copy / 'tokenizer.json'}: not valid JSON (line 1, column 2: "),
    ):
        MotionGenerator.load(shipped_copy)


def test_info_says_what_it_checked(capsys):
    assert main(["info"]) == 0
    assert "sha256 verified; 12 graphs open with the manifest's names" in capsys.readouterr().out


@pytest.mark.parametrize(
    "write,message",
    [
        (lambda p: p.write_text("hello"), "mean.npy: not a .npy array file"),
        (lambda p: p.write_bytes(b"\xff" * 300), "mean.npy: not a .npy array file"),
        (
            lambda p: p.write_bytes(p.read_bytes()[:200]),
            "mean.npy: its header claims an array of shape (263,) (1052 bytes), the file holds 72 "
            "bytes",
        ),
        (
            lambda p: np.save(p, np.full(263, "a")),
            "mean.npy: holds <U1 values, expected real numbers",
        ),
        (lambda p: np.save(p, np.full(263, 1e300)), "mean.npy: holds NaN or infinite values"),
    ],
)
def test_a_bad_normalisation_array_is_one_line_naming_it(bundle, write, message):
    write(bundle / "mean.npy")
    write_manifest(bundle, read_manifest(bundle))
    with pytest.raises(BundleError, match=re.escape(message)):
        Bundle.load(bundle)


def test_a_manifest_nested_too_deeply_is_one_line(bundle):
    (bundle / MANIFEST).write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(BundleError, match="manifest.json: JSON nested too deeply"):
        Bundle.load(bundle)


# -- the loader's refusals, one each (issue 24: each could be deleted with no test failing) -------
def _listed(root, name, source):
    """List `name` in the manifest with the size and sha256 of `source`, a real file."""
    entry = dict(bytes=source.stat().st_size, sha256=file_sha256(source))
    _edit(root, lambda m: m["files"].update({name: entry}))


@pytest.mark.parametrize("name", ["/etc/hostname", "../x", "a/../../x", "a/../x", "./../x"])
def test_a_file_name_leaving_the_folder_is_refused(bundle, name):
    _listed(bundle, name, bundle / "mean.npy")
    with pytest.raises(BundleError, match=re.escape(f"{name!r} leaves the bundle folder") + "$"):
        Bundle.load(bundle)  # refused by name, before the file system is asked


@pytest.mark.parametrize("absolute", [True, False])
def test_an_outside_file_named_and_listed_with_its_sha256_is_refused_by_name(bundle, absolute):
    """The forged manifest: its mean.npy outside the folder, named as the mean and listed with
    a matching size and sha256, is refused by its name before the file system is asked."""
    outside = bundle.parent / "mean.npy"
    shutil.copy(bundle / "mean.npy", outside)
    name = str(outside) if absolute else "../mean.npy"
    _edit(bundle, lambda m: m["motion"]["normalization"].update(mean=name))
    _listed(bundle, name, outside)
    with pytest.raises(BundleError, match=re.escape(f"{name!r} leaves the bundle folder") + "$"):
        Bundle.load(bundle)


@pytest.mark.parametrize("key", ["mean", "tokenizer"])
def test_a_referenced_file_outside_the_folder_is_refused(bundle, key):
    outside = str(bundle.parent / "elsewhere")
    section = "motion" if key == "mean" else "text"
    _edit(
        bundle,
        lambda m: (m[section]["normalization"] if key == "mean" else m[section]).update(
            {key: outside}
        ),
    )
    with pytest.raises(BundleError, match=re.escape(f"{outside!r} leaves the bundle folder") + "$"):
        Bundle.load(bundle)


def test_a_symlinked_file_pointing_outside_is_refused(bundle):
    outside = bundle.parent / "mean.npy"
    shutil.move(bundle / "mean.npy", outside)
    (bundle / "mean.npy").symlink_to(outside)  # size and sha256 match the manifest
    with pytest.raises(BundleError, match=re.escape("'mean.npy' leaves the bundle folder")):
        Bundle.load(bundle)


def test_a_symlinked_folder_pointing_outside_is_refused(bundle):
    (bundle.parent / "outside").mkdir()
    shutil.copy(bundle / "mean.npy", bundle.parent / "outside" / "mean.npy")
    (bundle / "sub").symlink_to(bundle.parent / "outside", target_is_directory=True)
    _edit(bundle, lambda m: m["motion"]["normalization"].update(mean="sub/mean.npy"))
    _listed(bundle, "sub/mean.npy", bundle / "mean.npy")
    with pytest.raises(BundleError, match=re.escape("'sub/mean.npy' leaves the bundle folder")):
        Bundle.load(bundle)


def test_a_symlink_inside_the_folder_and_a_linked_bundle_folder_load(bundle, tmp_path):
    (bundle / "sub").mkdir()
    shutil.move(bundle / "mean.npy", bundle / "sub" / "mean.npy")
    (bundle / "mean.npy").symlink_to(bundle / "sub" / "mean.npy")
    (tmp_path / "link").symlink_to(bundle, target_is_directory=True)
    assert Bundle.load(tmp_path / "link").mean.shape == (263,)


@pytest.mark.parametrize("name", ["tokenizer.json", "mean.npy", "std.npy", *GRAPHS])
def test_every_file_the_runtime_reads_must_be_listed_with_its_sha256(bundle, name):
    _edit(bundle, lambda m: m["files"].pop(name))
    with pytest.raises(BundleError, match=re.escape(f"refers to {name} but lists no checksum")):
        Bundle.load(bundle)


@pytest.mark.parametrize(
    "file,array,message",
    [
        ("mean.npy", np.zeros(262), "mean.npy: shape (262,), expected (263,)"),
        ("std.npy", np.ones(264), "std.npy: shape (264,), expected (263,)"),
        ("mean.npy", np.zeros((263, 1)), "mean.npy: shape (263, 1), expected (263,)"),
        ("std.npy", np.ones((1, 263)), "std.npy: shape (1, 263), expected (263,)"),
        ("mean.npy", np.r_[np.zeros(262), np.nan], "mean.npy: holds NaN or infinite values"),
        ("std.npy", np.r_[np.ones(262), np.inf], "std.npy: holds NaN or infinite values"),
        ("std.npy", np.r_[np.ones(262), np.nan], "std.npy: holds NaN or infinite values"),
        ("std.npy", np.r_[np.ones(262), -1.0], "std.npy: has values <= 0"),
    ],
)
def test_normalisation_arrays_of_the_wrong_shape_or_not_finite_are_refused(
    bundle, file, array, message
):
    np.save(bundle / file, array.astype(np.float32))
    write_manifest(bundle, read_manifest(bundle))
    with pytest.raises(BundleError, match=re.escape(message)):
        Bundle.load(bundle)


@pytest.mark.parametrize("tag", ["mogo-bundl", "other-bundle", None, 2])
def test_a_wrong_format_tag_is_refused(bundle, tag):
    _edit(bundle, lambda m: m.update(format=tag) if tag is not None else m.pop("format"))
    with pytest.raises(BundleError, match=re.escape("manifest.json: not a mogo-bundle manifest")):
        Bundle.load(bundle)


def test_a_symlink_loop_is_one_line(bundle):
    (bundle / "mean.npy").unlink()
    (bundle / "loop").symlink_to(bundle / "mean.npy")
    (bundle / "mean.npy").symlink_to(bundle / "loop")
    with pytest.raises(BundleError, match="mean.npy: missing from the bundle"):
        Bundle.load(bundle)
