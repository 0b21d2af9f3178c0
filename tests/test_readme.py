"""The Python blocks of the README and of docs/serve.md (its clients) run as pasted: each one
in a fresh interpreter, in an empty folder, on the default bundle. A block that talks to
`mogo serve` on its default port gets a real server on a free port instead (8765 may be taken
on a shared machine)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import served

ROOT = Path(__file__).resolve().parents[1]
PAGES = ["README.md", "docs/serve.md"]
BLOCKS = {
    page: re.findall(r"^```python\n(.*?)^```$", (ROOT / page).read_text(), re.M | re.S)
    for page in PAGES
}
DEFAULT_SERVER = "127.0.0.1:8765"  # mogo serve's default address, as the pages write it


@pytest.mark.parametrize("page", PAGES)
def test_the_page_has_python_blocks(page):
    assert BLOCKS[page]


@pytest.mark.parametrize(
    "block",
    [block for page in PAGES for block in BLOCKS[page]],
    ids=[f"{page}:{k}" for page in PAGES for k in range(len(BLOCKS[page]))],
)
def test_the_block_runs_as_pasted(block, tmp_path):
    if DEFAULT_SERVER in block:
        pytest.importorskip("aiohttp", reason='needs the serve extra: pip install -e ".[serve]"')
        with served() as port:
            run(block.replace(DEFAULT_SERVER, f"127.0.0.1:{port}"), tmp_path)
    else:
        run(block, tmp_path)


def run(block: str, folder: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-c", block], cwd=folder, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, f"the block failed:\n{block}\n{done.stderr[-3000:]}"
