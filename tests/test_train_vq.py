"""`mogo train vq` on a tiny HumanML3D-layout folder: the run it writes, exact resume, two
processes on gloo, and one-line errors."""
import os
import subprocess
import sys

import pytest
import torch

from conftest import interrupt_after_step, records
from mogo.export.cli import main
from mogo.export.train_t2m import load_vq
from mogo.export.training import load_checkpoint


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def train(data, out, *extra) -> int:
    return main(["train", "vq", "--data", str(data), "--out", str(out), "--config", "tiny",
                 "--batch-size", "4", "--crop-frames", "40", "--warmup", "2", "--log-every", "1",
                 "--val-clips", "2", *map(str, extra)])


def test_cli_trains_and_writes_a_run_the_t2m_can_use(tiny_humanml3d, tmp_path):
    run = tmp_path / "vq"
    assert train(tiny_humanml3d, run, "--steps", 4, "--val-every", 2, "--checkpoint-every", 2,
                 "--levels", 2, "--causal") == 0
    assert [(r["kind"], r["step"]) for r in records(run)] == [
        ("train", 1), ("train", 2), ("val", 2), ("train", 3), ("train", 4), ("val", 4)]
    val = records(run, "val")[-1]
    assert len(val["mpjpe_mm_by_levels"]) == 2 and val["mpjpe_mm"] > 0
    state = load_checkpoint(run / "checkpoint.pt")
    assert state["step"] == 4 and state["optimizer"] is not None
    assert state["config"]["levels"] == 2 and state["config"]["causal"]
    assert state["recipe"]["levels"] == 2
    model = load_vq(run)
    assert not model.training and model.config.levels == 2
    assert torch.equal(model.mean, load_checkpoint(run / "best.pt")["model"]["mean"])


def test_resume_continues_exactly(tiny_humanml3d, tmp_path, monkeypatch):
    args = ("--steps", 7, "--val-every", 2, "--checkpoint-every", 2)
    assert train(tiny_humanml3d, tmp_path / "whole", *args) == 0
    interrupt_after_step(monkeypatch, 5)  # logged, but never checkpointed
    assert train(tiny_humanml3d, tmp_path / "split", *args) == 130
    monkeypatch.undo()
    assert train(tiny_humanml3d, tmp_path / "split", *args, "--resume") == 0
    assert records(tmp_path / "split") == records(tmp_path / "whole")
    assert train(tiny_humanml3d, tmp_path / "split", *args, "--resume", "--levels", 2) == 2


def test_two_processes_on_gloo(tiny_humanml3d, tmp_path):
    run = tmp_path / "run"
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone",
               "--nproc_per_node", "2", "-m", "mogo.export.cli", "train", "vq",
               "--data", str(tiny_humanml3d), "--out", str(run), "--config", "tiny",
               "--batch-size", "2", "--crop-frames", "40", "--steps", "3", "--val-every", "3",
               "--val-clips", "2", "--log-every", "3", "--device", "cpu"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=180,
                          env=dict(os.environ, OMP_NUM_THREADS="1"))
    assert done.returncode == 0, done.stderr[-3000:]
    assert load_checkpoint(run / "checkpoint.pt")["world_size"] == 2
    assert [(r["kind"], r["step"]) for r in records(run)] == [("train", 3), ("val", 3)]


@pytest.mark.parametrize("extra, message", [
    (["--steps", 0], "--steps must be positive"),
    (["--steps", 1, "--resume"], "--resume: no checkpoint"),
    (["--steps", 1, "--crop-frames", 41, "--down-factor", 2], "not a multiple of the down factor"),
    (["--steps", 1, "--crop-frames", 500], "no clip has 500 frames"),
])
def test_bad_inputs_give_one_line_errors(extra, message, tiny_humanml3d, tmp_path, capsys):
    assert train(tiny_humanml3d, tmp_path / "run", *extra) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("mogo: error:") and message in error
    assert not (tmp_path / "run" / "checkpoint.pt").exists()
