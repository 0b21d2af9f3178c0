"""The portable bundle, built once from the default bundle (it is not committed: 86 MB)."""

import pytest

from mogo import MotionGenerator
from mogo.generator import DEFAULT_BUNDLE


@pytest.fixture(scope="session")
def portable_bundle(tmp_path_factory):
    from mogo.export.onnx.portable import export_portable

    out = tmp_path_factory.mktemp("portable") / "bundle"
    export_portable(DEFAULT_BUNDLE, out)
    return out


@pytest.fixture(scope="session")
def portable_generator(portable_bundle):
    return MotionGenerator.load(portable_bundle)
