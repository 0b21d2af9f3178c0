"""Bundles altered with their checksums brought up to date (so only content checks can catch
them): each is one BundleError line naming the file, before any work, never a crash, a hang
nor a graph reading bytes no checksum vouches for; `mogo info` says "verified" only for what
it read (issue 39; docs/security.md, "Bundles")."""

import hashlib
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from mogo import MotionGenerator
from mogo.bundle import Bundle, BundleError
from mogo.generator import DEFAULT_BUNDLE
from mogo.manifest import MANIFEST


@pytest.fixture
def copy(tmp_path):
    root = tmp_path / "bundle"
    shutil.copytree(DEFAULT_BUNDLE, root)
    return root


def put(root, name, data):
    """A file of the bundle replaced, its size and sha256 in the manifest brought up to date."""
    path = root / name
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    manifest = json.loads((root / MANIFEST).read_text())
    manifest["files"][name] = {
        "bytes": path.stat().st_size,
        "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
    }
    (root / MANIFEST).write_text(json.dumps(manifest))


def edit_manifest(root, change):
    manifest = json.loads((root / MANIFEST).read_text())
    change(manifest)
    (root / MANIFEST).write_text(json.dumps(manifest))


def info(root):
    done = subprocess.run(
        [sys.executable, "-m", "mogo", "info", str(root)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    return done.returncode, done.stdout, done.stderr


def graph(nodes, inputs, outputs, initializers=()):
    onnx = pytest.importorskip("onnx", reason="pip install 'mogo-edge[serve]' (onnx)")
    model = onnx.helper.make_model(
        onnx.helper.make_graph(nodes, "g", inputs, outputs, list(initializers)),
        opset_imports=[onnx.helper.make_opsetid("", 17)],
    )
    model.ir_version = 8
    return model


def test_a_decoder_reading_floats_is_refused_at_load(copy):
    onnx = pytest.importorskip("onnx", reason="pip install 'mogo-edge[serve]' (onnx)")
    T = onnx.TensorProto
    put(
        copy,
        "vq_decoder.onnx",
        graph(
            [onnx.helper.make_node("Identity", ["ids"], ["features"])],
            [onnx.helper.make_tensor_value_info("ids", T.FLOAT, ["batch", "tokens", 6])],
            [onnx.helper.make_tensor_value_info("features", T.FLOAT, ["batch", "tokens", 6])],
        ).SerializeToString(),
    )
    message = (
        f"{copy / 'vq_decoder.onnx'}: input ids is tensor(float) of shape ['batch', "
        "'tokens', 6]; the manifest's model needs tensor(int64) with a last axis of 6"
    )
    with pytest.raises(BundleError) as error:
        MotionGenerator.load(copy)
    assert str(error.value) == message
    assert info(copy) == (2, "", f"mogo: error: {message}\n")


def test_a_text_encoder_of_the_wrong_width_is_refused_before_any_token(copy):
    """Widths fixed in the graph are checked as it opens; those it leaves open (here: the
    prompt's length), on the first prompt."""
    onnx = pytest.importorskip("onnx", reason="pip install 'mogo-edge[serve]' (onnx)")
    T, make = onnx.TensorProto, onnx.helper.make_node
    for name, outputs in (
        ("text_encoder.onnx", ["prompt_embedding", "sentence_embedding"]),
        ("trained_text_encoder.onnx", ["prompt_embedding"]),
    ):
        nodes = [
            make("Cast", ["token_ids"], ["f"], to=T.FLOAT),
            make("ReduceMean", ["f"], ["m"], keepdims=1),
            make("Shape", ["token_ids"], ["size"]),
        ]
        nodes += [make("Tile", ["m", "size"], [out]) for out in outputs]
        put(
            copy,
            name,
            graph(
                nodes,
                [
                    onnx.helper.make_tensor_value_info(n, T.INT64, ["b", "s"])
                    for n in ("token_ids", "attention_mask")
                ],
                [onnx.helper.make_tensor_value_info(out, T.FLOAT, None) for out in outputs],
            ).SerializeToString(),
        )
    generator = MotionGenerator.load(copy)
    with pytest.raises(
        BundleError,
        match=r"text_encoder.onnx: output prompt_embedding has "
        r"shape \(1, 6\); the manifest's model needs a last "
        "axis of 128",
    ):
        generator.generate("a person walks forward", seconds=1)
    put(
        copy,
        "text_encoder.onnx",
        graph(
            [
                make("Cast", ["token_ids"], ["f"], to=T.FLOAT),
                make("ReduceMean", ["f"], ["m"], keepdims=1),
                make("Tile", ["m", "five"], ["prompt_embedding"]),
                make("Tile", ["m", "wide"], ["sentence_embedding"]),
            ],
            [
                onnx.helper.make_tensor_value_info(n, T.INT64, ["b", "s"])
                for n in ("token_ids", "attention_mask")
            ],
            [
                onnx.helper.make_tensor_value_info("prompt_embedding", T.FLOAT, ["b", 5]),
                onnx.helper.make_tensor_value_info("sentence_embedding", T.FLOAT, ["b", 384]),
            ],
            [
                onnx.numpy_helper.from_array(np.array([1, n], np.int64), name)
                for name, n in (("five", 5), ("wide", 384))
            ],
        ).SerializeToString(),
    )
    with pytest.raises(
        BundleError,
        match=r"text_encoder.onnx: output prompt_embedding is "
        r"tensor\(float\) of shape \[1, 5\]; the manifest's "
        "model needs tensor.float. with a last axis of 128",
    ):
        MotionGenerator.load(copy)


def test_external_data_in_an_unlisted_file_is_refused(copy):
    """Old: loaded unchecked, and `mogo info` said "sha256 verified" after it was edited."""
    onnx = pytest.importorskip("onnx", reason="pip install 'mogo-edge[serve]' (onnx)")
    T, make = onnx.TensorProto, onnx.helper.make_node
    weights = onnx.TensorProto()
    weights.name, weights.data_type = "w", T.FLOAT
    weights.dims.extend([1])
    weights.data_location = T.EXTERNAL
    for key, value in (("location", "unlisted.bin"), ("offset", "0"), ("length", "4")):
        entry = weights.external_data.add()
        entry.key, entry.value = key, value
    (copy / "unlisted.bin").write_bytes(np.float32(1.0).tobytes())
    put(
        copy,
        "vq_decoder.onnx",
        graph(
            [
                make("Cast", ["ids"], ["f"], to=T.FLOAT),
                make("Add", ["f", "w"], ["g"]),
                make("Concat", ["g"] * 44, ["h"], axis=2),
                make("Slice", ["h", "start", "end", "axis"], ["features"]),
            ],
            [onnx.helper.make_tensor_value_info("ids", T.INT64, ["batch", "tokens", 6])],
            [onnx.helper.make_tensor_value_info("features", T.FLOAT, ["batch", "tokens", 263])],
            [weights]
            + [
                onnx.numpy_helper.from_array(np.array([v], np.int64), name)
                for name, v in (("start", 0), ("end", 263), ("axis", 2))
            ],
        ).SerializeToString(),
    )
    message = (
        f"{copy / 'vq_decoder.onnx'}: keeps weights in another file (ONNX external "
        "data); a bundle's graphs hold all their weights"
    )
    with pytest.raises(BundleError) as error:
        MotionGenerator.load(copy)
    assert str(error.value) == message
    assert info(copy) == (2, "", f"mogo: error: {message}\n")
    os.chdir(copy)  # not even the working folder's copy of the file is read
    with pytest.raises(BundleError, match="keeps weights in another file"):
        Bundle.load(copy).open_graphs()


@pytest.mark.parametrize(
    "change, message",
    [
        (
            lambda m: m["t2m"]["config"].pop("max_relative_distance"),
            "t2m.config.max_relative_distance: missing or not a positive integer",
        ),
        (
            lambda m: m["vq"]["decoder"].update(lookahead=10**7),
            "vq.decoder.lookahead: 10000000 token steps, must be at most 1024",
        ),
        (lambda m: m["motion"].update(fps=1e6), "motion.fps: 1000000.0, must be at most 1000"),
        (
            lambda m: m["vq"]["config"].update(codebook_size=10**100),
            r"vq.config.codebook_size: missing or not a positive integer \(at most 1048576\)",
        ),
        (
            lambda m: m["defaults"].update(max_seconds=1e6),
            "defaults.max_seconds: 1000000.0, must be at most 600",
        ),
    ],
)
def test_manifest_numbers_are_bounded(copy, change, message):
    edit_manifest(copy, change)
    with pytest.raises(BundleError, match=message):
        Bundle.load(copy)


def test_manifest_numbers_are_checked_against_the_graphs(copy):
    edit_manifest(copy, lambda m: m["vq"]["config"].update(codebook_size=10**6))
    with pytest.raises(
        BundleError,
        match=r"level_0.onnx: output logits is tensor\(float\) of "
        r"shape \['batch', 513\]; the manifest's model needs "
        "tensor.float. with a last axis of 1000001",
    ):
        MotionGenerator.load(copy)


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("tokenizer.json", None, r"a tokenizer with a regular expression \('\(\.\+\)\+"),
        ("repertoire.json", json.dumps(list(range(4000))), "not a list of captions"),
        ("repertoire.json", "[" * 100_000 + "]" * 100_000, "JSON nested too deeply"),
    ],
)
def test_text_files_are_checked_by_generate_and_info_alike(copy, name, content, message):
    """Old: a backtracking regex hung every prompt; captions of the wrong type crashed; `mogo
    info` said "verified" without reading either."""
    if content is None:
        tokenizer = json.loads((copy / name).read_text())
        tokenizer["pre_tokenizer"] = {
            "type": "Split",
            "pattern": {"Regex": "(.+)+\\d"},
            "behavior": "Isolated",
            "invert": False,
        }
        content = json.dumps(tokenizer)
    put(copy, name, content)
    with pytest.raises(BundleError, match=message):
        MotionGenerator.load(copy)
    status, printed, error = info(copy)
    assert status == 2 and printed == "" and error.count("\n") == 1
    assert error.startswith(f"mogo: error: {copy / name}: ")


def test_a_manifest_that_is_a_link_out_of_the_bundle_is_refused(copy, tmp_path):
    outside = tmp_path / "outside.json"
    shutil.move(copy / MANIFEST, outside)
    os.symlink(outside, copy / MANIFEST)
    with pytest.raises(BundleError, match=f"{copy / MANIFEST}: a symbolic link \\(to {outside}\\)"):
        Bundle.load(copy)


def test_info_says_what_it_verified():
    status, printed, error = info(DEFAULT_BUNDLE)
    assert status == 0, error
    assert (
        "sha256 verified; 12 graphs open with the manifest's names and types; tokenizers and "
        "repertoire read"
    ) in printed


def test_info_shows_a_bundles_own_text_escaped(copy):
    """The manifest's free text (a trainer's recipe) may hold terminal escapes: shown as
    escapes, never sent to the terminal raw."""

    def recipe(manifest):
        part = next(iter(manifest["training"]))
        manifest["training"][part]["recipe"]["lr"] = "\x1b[2J\x1b]0;owned\x07"

    edit_manifest(copy, recipe)
    status, printed, error = info(copy)
    assert status == 0, error
    assert "\x1b" not in printed and "\x07" not in printed
    assert "lr \\x1b[2J\\x1b]0;owned\\x07" in printed
