import json
import os
import subprocess
import sys

import numpy as np
import pytest

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


def mogo_on_two_gloo_processes(*args) -> None:
    """`mogo ARGS` under torchrun, two CPU processes on gloo. On failure the message holds what
    both printed, with every thread's Python stack should one of them abort."""
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node",
               "2", "-m", "mogo", *map(str, args), "--device", "cpu"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=180,
                          env=dict(os.environ, OMP_NUM_THREADS="1", PYTHONFAULTHANDLER="1"))
    assert done.returncode == 0, f"stdout:\n{done.stdout[-3000:]}\nstderr:\n{done.stderr[-8000:]}"


def records(run, kind=None) -> list[dict]:
    """A training run's metrics.jsonl records, without the timings."""
    lines = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in ("seconds", "steps_per_s")}
            for r in lines if kind is None or r["kind"] == kind]


def interrupt_after_step(monkeypatch, stop_step: int) -> None:
    """Make training stop like Ctrl-C right after logging `stop_step`, before any checkpoint
    of it: what a resumed run must recover from."""
    from mogo.export.train.training import MetricsLog

    write = MetricsLog.write

    def interrupted(self, kind, step, **values):
        write(self, kind, step, **values)
        if step == stop_step:
            raise KeyboardInterrupt

    monkeypatch.setattr(MetricsLog, "write", interrupted)


@pytest.fixture
def run_without_torch():
    """Runs a Python script in a fresh interpreter where torch and onnxscript (and with
    `block_export`, mogo.export) cannot be imported; ends by checking torch was never loaded."""
    def run(script: str, block_export: bool = True) -> subprocess.CompletedProcess:
        blocked = f"BLOCKED = {('mogo.export',) if block_export else ('torch',)!r}\n"
        check = "assert 'torch' not in sys.modules\n"
        return subprocess.run([sys.executable, "-c", blocked + BLOCK_TORCH + script + check],
                              capture_output=True, text=True)
    return run

CLIP_FRAMES = [40 + 3 * k for k in range(12)]  # 40 .. 73 feature rows
SPLITS = {"train": range(0, 8), "val": range(8, 10), "test": range(10, 12)}


def caption_lines(k: int) -> list[str]:
    """Every clip: one whole-clip caption; even clips: a 0.5-2.5 s span (rows 10..50);
    every third clip: NaN times and no tokens (whole clip); clip 1: a 1 s span (20 rows)."""
    lines = ["a person walks forward.#a/DET person/NOUN walk/VERB forward/ADV#0.0#0.0"]
    if k % 2 == 0:
        lines.append("the person waves.#the/DET person/NOUN wave/VERB#0.5#2.5")
    if k % 3 == 0:
        lines.append("someone jumps.##nan#nan")
    if k == 1:
        lines.append("a short kick.#a/DET short/ADJ kick/NOUN#0.0#1.0")
    return lines


def make_tiny_humanml3d(root):
    """A 12-clip HumanML3D-layout folder of random 263-dim features (IDs 000000..000011)."""
    (root / "new_joint_vecs").mkdir(parents=True)
    (root / "texts").mkdir()
    rng = np.random.default_rng(0)
    clips = []
    for k, frames in enumerate(CLIP_FRAMES):
        features = rng.normal(scale=0.05, size=(frames, 263)).astype(np.float32)
        features[:, 3] += 0.9  # root height
        np.save(root / "new_joint_vecs" / f"{k:06d}.npy", features)
        (root / "texts" / f"{k:06d}.txt").write_text("\n".join(caption_lines(k)) + "\n")
        clips.append(features)
    stacked = np.concatenate(clips)
    np.save(root / "Mean.npy", stacked.mean(0))
    np.save(root / "Std.npy", stacked.std(0))
    for name, ks in SPLITS.items():
        (root / f"{name}.txt").write_text("".join(f"{k:06d}\n" for k in ks))
    return root


@pytest.fixture
def tiny_humanml3d(tmp_path):
    return make_tiny_humanml3d(tmp_path / "tiny")
