"""The suite's two sizes: `python -m pytest` runs the fast part (the runtime, the CLI, the
server and its fault tests: minutes on 2 cores); `python -m pytest --full` also runs the tests
marked slow, which CI runs: training and ONNX export (torch), the benches, Blender, the
portable bundle."""

import subprocess
import sys
from pathlib import Path

import pytest

from helpers import make_tiny_humanml3d

# every test there is slow: torch training, whole benches, the portable bundle's export and
# its JavaScript port in Node and Chromium
SLOW_FOLDERS = {"export", "bench", "portable"}


def pytest_addoption(parser):
    parser.addoption(
        "--full",
        action="store_true",
        help="the full suite (what CI runs): also the tests marked slow",
    )


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "slow: run only with --full (tests/export, tests/bench "
        "and tests/portable are slow as a whole)",
    )


def pytest_collection_modifyitems(config, items):
    tests = Path(__file__).parent
    for item in items:
        if Path(item.path).relative_to(tests).parts[0] in SLOW_FOLDERS:
            item.add_marker(pytest.mark.slow)
    if config.getoption("--full"):
        return
    slow = [item for item in items if item.get_closest_marker("slow")]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if not item.get_closest_marker("slow")]
        config.stash[_LEFT_OUT] = len(slow)


_LEFT_OUT = pytest.StashKey[int]()


def pytest_terminal_summary(terminalreporter, config):
    left_out = config.stash.get(_LEFT_OUT, 0)
    if left_out:
        terminalreporter.write_line(
            f"{left_out} slow tests were not run: add --full for the whole suite (what CI runs)",
            yellow=True,
        )


BLOCK_TORCH = (
    "import sys\n"
    "class Block:\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name.split('.')[0] in ('torch', 'onnxscript') or name.startswith(BLOCKED):\n"
    "            raise ImportError(f'{name} is blocked in this test')\n"
    "sys.meta_path.insert(0, Block())\n"
)


@pytest.fixture
def one_torch_thread():
    """Tiny models on shared cores: one intra-op thread is ~10x faster than two fighting."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def run_without_torch():
    """Runs a Python script in a fresh interpreter where torch and onnxscript (and with
    `block_export`, mogo.export) cannot be imported; ends by checking torch was never loaded."""

    def run(script: str, block_export: bool = True) -> subprocess.CompletedProcess:
        blocked = f"BLOCKED = {('mogo.export',) if block_export else ()!r}\n"
        check = "assert 'torch' not in sys.modules\n"
        return subprocess.run(
            [sys.executable, "-c", blocked + BLOCK_TORCH + script + check],
            capture_output=True,
            text=True,
        )

    return run


@pytest.fixture
def tiny_humanml3d(tmp_path):
    return make_tiny_humanml3d(tmp_path / "tiny")
