import subprocess
import sys

import pytest

from helpers import make_tiny_humanml3d

BLOCK_TORCH = (
    "import sys\n"
    "class Block:\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name.split('.')[0] in ('torch', 'onnxscript') or name.startswith(BLOCKED):\n"
    "            raise ImportError(f'{name} is blocked in this test')\n"
    "sys.meta_path.insert(0, Block())\n")


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
        return subprocess.run([sys.executable, "-c", blocked + BLOCK_TORCH + script + check],
                              capture_output=True, text=True)
    return run


@pytest.fixture
def tiny_humanml3d(tmp_path):
    return make_tiny_humanml3d(tmp_path / "tiny")
