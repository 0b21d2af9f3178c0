"""Fixtures of the server tests. The tests that need the serve extra skip themselves where it
is not installed (test_cli.py checks what `mogo serve` says then)."""

import pytest

from mogo import MotionGenerator


@pytest.fixture(scope="session")
def generator():
    return MotionGenerator.load(threads=1)


@pytest.fixture(scope="session")
def engine_parts(generator):
    """One Engine's level graphs (rewritten row-wise once), reused by every test's Engine."""
    pytest.importorskip("onnx")
    from mogo.serve.engine import Engine

    return Engine(generator).tokens
