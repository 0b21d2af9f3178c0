"""Fixtures of the server tests. The tests that need the serve extra skip themselves where it
is not installed (test_cli.py checks what `mogo serve` says then)."""

import shutil
from dataclasses import replace

import pytest

from mogo import MotionGenerator
from mogo.bundle import read_manifest, write_manifest
from mogo.generator import DEFAULT_BUNDLE


@pytest.fixture(scope="session")
def generator():
    return MotionGenerator.load(threads=1)


@pytest.fixture(scope="session")
def engine_parts(generator):
    """One Engine's level graphs (rewritten row-wise once), reused by every test's Engine."""
    pytest.importorskip("onnx")
    from mogo.serve.engine import Engine

    return Engine(generator).tokens


@pytest.fixture(scope="session")
def centred_generator(tmp_path_factory):
    """The shipped bundle without its low-latency decoder (a bundle of before it): its level
    graphs are the shipped ones, so `engine_parts` serve it."""
    root = tmp_path_factory.mktemp("centred") / "bundle"
    shutil.copytree(DEFAULT_BUNDLE, root)
    manifest = read_manifest(root)
    vq = manifest.vq
    dropped = {vq.low_latency_decoder.file, vq.low_latency_step.file}
    for name in dropped:
        (root / name).unlink()
    training = {k: v for k, v in manifest.training.items() if k != "vq_low_latency_decoder"}
    fp16 = replace(
        manifest.fp16_storage,
        files=tuple(f for f in manifest.fp16_storage.files if f not in dropped),
        vq_low_latency_decoder_feature_max_abs_difference=None,
    )
    vq = replace(vq, low_latency_decoder=None, low_latency_step=None)
    write_manifest(root, replace(manifest, vq=vq, training=training, fp16_storage=fp16))
    return MotionGenerator.load(root, threads=1)
