"""Figures the docs take from the shipped bundle's manifest, checked against it, so a new bundle
cannot leave an old size behind on one page."""

import json
import re
from pathlib import Path

import pytest

from mogo import DEFAULT_BUNDLE
from mogo.manifest import MANIFEST, Manifest

ROOT = Path(__file__).resolve().parents[1]
BUNDLE_SIZE = {  # page -> how it writes the shipped bundle's size in MB
    "README.md": r"`runtime/default_bundle/` \((\d+\.\d) MB\)",
    "docs/model.md": r"\*\*Bundle\*\*: (\d+\.\d) MB",
    "docs/performance.md": r"Size on\s+disk (\d+\.\d) MB",
    "docs/portable.md": r"\| int8 \(shipped\) \| \d+ \| (\d+\.\d) \|",
    "docs/text_encoder.md": r"the\s+bundle is (\d+\.\d) MB",
}


@pytest.mark.parametrize("page", BUNDLE_SIZE)
def test_the_bundle_size_is_the_manifests(page):
    manifest = Manifest.from_json(json.loads((Path(DEFAULT_BUNDLE) / MANIFEST).read_text()))
    size = f"{sum(entry.bytes for entry in manifest.files.values()) / 1e6:.1f}"
    written = re.search(BUNDLE_SIZE[page], (ROOT / page).read_text())
    assert written, f"{page} no longer writes the bundle's size as {BUNDLE_SIZE[page]!r}"
    assert written[1] == size, f"{page} says {written[1]} MB; the manifest's files are {size} MB"
