"""The README's Python blocks run as pasted: each one in a fresh interpreter, in an empty
folder, on the default bundle. A block that talks to `mogo serve` on its default port gets a
real server on a free port instead (8765 may be taken on a shared machine)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import served

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"^```python\n(.*?)^```$", README.read_text(), re.M | re.S)
DEFAULT_SERVER = "127.0.0.1:8765"  # mogo serve's default address, as the README writes it


def test_the_readme_has_python_blocks():
    assert len(BLOCKS) >= 2


@pytest.mark.parametrize("block", BLOCKS, ids=[f"block{k}" for k in range(len(BLOCKS))])
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
