"""Fixtures of the server tests: skipped where the serve extra is not installed."""
import pytest

pytest.importorskip("aiohttp")
pytest.importorskip("onnx")

from mogo import MotionGenerator  # noqa: E402
from mogo.serve.engine import Engine  # noqa: E402


@pytest.fixture(scope="session")
def generator():
    return MotionGenerator.load(threads=1)


@pytest.fixture(scope="session")
def engine_parts(generator):
    """One Engine's level graphs (rewritten row-wise once), reused by every test's Engine."""
    return Engine(generator).stepper.tokens
