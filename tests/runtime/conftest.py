"""Fixtures the runtime tests share."""

import pytest

from helpers import bundle_with_old_text_side
from mogo import MotionGenerator


@pytest.fixture(scope="session")
def old_generator(tmp_path_factory):
    """The default bundle with the text side it was trained with (254 words, no sentence
    encoder): how older bundles read prompts, unknown-word warnings included."""
    return MotionGenerator.load(bundle_with_old_text_side(tmp_path_factory.mktemp("old")))
