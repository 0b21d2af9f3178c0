"""Fixtures of the server tests. The tests that need the serve extra skip themselves where it
is not installed (test_cli.py checks what `mogo serve` says then)."""

import importlib.util
import shutil
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from helpers import make_tiny_humanml3d
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
def low_latency_generator(generator, tmp_path_factory):
    """A generator whose bundle has a low-latency decoder (its level graphs are the shipped
    ones: `engine_parts` serve it): the shipped bundle where it has one, else the shipped
    bundle with one fine-tuned for two CPU steps (`mogo train vq --tune decoder`, `mogo
    export decoder`: ~15 s, the train extra), real graphs of a real lookahead."""
    if generator.manifest.vq.low_latency_decoder is not None:
        return generator
    if importlib.util.find_spec("torch") is None:
        pytest.skip("a low-latency decoder is trained with torch: pip install '.[train]'")
    root = tmp_path_factory.mktemp("low_latency")
    data = make_tiny_humanml3d(root / "data")
    for name in ("mean", "std"):  # the bundle's normalisation: its decoder is tuned
        shutil.copy(DEFAULT_BUNDLE / f"{name}.npy", data / f"{name.capitalize()}.npy")
    mogo = [sys.executable, "-m", "mogo"]
    train = ["train", "vq", "--out", str(root / "vq"), "--init", str(DEFAULT_BUNDLE)]
    train += ["--tune", "decoder", "--decoder-lookahead", "4", "--data", str(data)]
    train += ["--batch-size", "4", "--steps", "2", "--val-clips", "2", "--warmup", "0"]
    export = ["export", "decoder", "--vq", str(root / "vq"), "--bundle", str(DEFAULT_BUNDLE)]
    for command in (train + ["--crop-frames", "40"], export + ["--out", str(root / "bundle")]):
        subprocess.run([*mogo, *command], check=True, capture_output=True, timeout=300)
    return MotionGenerator.load(root / "bundle", threads=1)


@pytest.fixture(scope="session")
def centred_generator(generator, tmp_path_factory):
    """A generator whose bundle has no low-latency decoder: the shipped one, or a copy of it
    without its low-latency decoder where it has one."""
    if generator.manifest.vq.low_latency_decoder is None:
        return generator
    root = tmp_path_factory.mktemp("centred") / "bundle"
    shutil.copytree(DEFAULT_BUNDLE, root)
    manifest = read_manifest(root)
    (root / manifest.vq.low_latency_decoder.file).unlink()
    training = {k: v for k, v in manifest.training.items() if k != "vq_low_latency_decoder"}
    fp16 = manifest.fp16_storage and replace(
        manifest.fp16_storage, vq_low_latency_decoder_feature_max_abs_difference=None
    )
    vq = replace(manifest.vq, low_latency_decoder=None)
    write_manifest(root, replace(manifest, vq=vq, training=training, fp16_storage=fp16))
    return MotionGenerator.load(root, threads=1)


def assert_close(served: np.ndarray, local: np.ndarray) -> None:
    """Served frames against a local MotionStream's: the same decoding, to a float rounding."""
    np.testing.assert_allclose(served, local, atol=1e-5)
