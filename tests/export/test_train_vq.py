"""`mogo train vq` on a tiny HumanML3D-layout folder: the run it writes, exact resume, two
processes on gloo, and one-line errors."""

import os

import pytest
import torch

from helpers import interrupt_after_step, mogo_on_two_gloo_processes, records
from mogo.bundle import file_sha256
from mogo.cli import main
from mogo.export.models.runs import load_checkpoint, load_vq

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def train(data, out, *extra) -> int:
    return main(
        [
            "train",
            "vq",
            "--data",
            str(data),
            "--out",
            str(out),
            "--config",
            "tiny",
            "--batch-size",
            "4",
            "--crop-frames",
            "40",
            "--warmup",
            "2",
            "--log-every",
            "1",
            "--val-clips",
            "2",
            *map(str, extra),
        ]
    )


def test_cli_trains_and_writes_a_run_the_t2m_can_use(tiny_humanml3d, tmp_path):
    run = tmp_path / "vq"
    assert (
        train(
            tiny_humanml3d,
            run,
            "--steps",
            4,
            "--val-every",
            2,
            "--checkpoint-every",
            2,
            "--levels",
            2,
            "--causal",
        )
        == 0
    )
    assert [(r["kind"], r["step"]) for r in records(run)] == [
        ("train", 1),
        ("train", 2),
        ("val", 2),
        ("train", 3),
        ("train", 4),
        ("val", 4),
    ]
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


def test_whole_clips_and_a_weight_average_train_and_resume_exactly(
    tiny_humanml3d, tmp_path, monkeypatch
):
    args = (
        "--steps",
        5,
        "--val-every",
        2,
        "--checkpoint-every",
        2,
        "--whole-clips",
        "--weight-average",
        0.5,
        "--lr",
        1e-2,
        "--warmup",
        0,
    )
    assert train(tiny_humanml3d, tmp_path / "whole", *args) == 0
    state = load_checkpoint(tmp_path / "whole" / "checkpoint.pt")
    assert state["recipe"]["whole_clips"] and state["recipe"]["weight_average"] == 0.5
    interrupt_after_step(monkeypatch, 3)
    assert train(tiny_humanml3d, tmp_path / "split", *args) == 130
    monkeypatch.undo()
    assert train(tiny_humanml3d, tmp_path / "split", *args, "--resume") == 0
    assert records(tmp_path / "split") == records(tmp_path / "whole")


def test_best_pt_keeps_the_weight_average(tiny_humanml3d, tmp_path):
    run = tmp_path / "run"
    assert (
        train(
            tiny_humanml3d,
            run,
            "--steps",
            3,
            "--val-every",
            3,
            "--weight-average",
            0.5,
            "--lr",
            1e-2,
            "--warmup",
            0,
        )
        == 0
    )
    state, best = load_checkpoint(run / "checkpoint.pt"), load_checkpoint(run / "best.pt")
    averaged = state["averaged_parameters"]
    assert set(averaged) == {name for name, _ in load_vq(run).named_parameters()}
    assert all(torch.equal(averaged[n], best["model"][n]) for n in averaged)
    assert not all(torch.equal(averaged[n], state["model"][n]) for n in averaged)


def test_two_processes_on_gloo(tiny_humanml3d, tmp_path):
    run = tmp_path / "run"
    mogo_on_two_gloo_processes(
        "train",
        "vq",
        "--data",
        tiny_humanml3d,
        "--out",
        run,
        "--config",
        "tiny",
        "--batch-size",
        2,
        "--crop-frames",
        40,
        "--steps",
        3,
        "--val-every",
        3,
        "--val-clips",
        2,
        "--log-every",
        3,
    )
    assert load_checkpoint(run / "checkpoint.pt")["world_size"] == 2
    assert [(r["kind"], r["step"]) for r in records(run)] == [("train", 3), ("val", 3)]


def test_a_torchrun_worker_leaves_without_the_interpreter_teardown(tmp_path, monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")
    statuses = []
    monkeypatch.setattr(os, "_exit", statuses.append)
    assert main(["info"]) == 0  # not a training verb: torchrun does not run it
    assert (
        main(["train", "vq", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "run")])
        == 2
    )
    assert statuses == [2]


def test_init_fine_tunes_a_trained_model(tiny_humanml3d, tmp_path):
    base, tuned = tmp_path / "base", tmp_path / "tuned"
    assert train(tiny_humanml3d, base, "--steps", 3, "--val-every", 3, "--levels", 2) == 0
    assert (
        train(
            tiny_humanml3d,
            tuned,
            "--steps",
            2,
            "--val-every",
            2,
            "--init",
            base,
            "--lr",
            1e-12,
            "--crop-frames",
            48,
        )
        == 0
    )
    state = load_checkpoint(tuned / "checkpoint.pt")
    assert state["step"] == 2 and state["config"] == load_checkpoint(base / "best.pt")["config"]
    assert state["recipe"]["init"] == str((base / "best.pt").resolve())
    assert state["recipe"]["levels"] == 2 and state["recipe"]["crop_frames"] == 48
    before, after = load_vq(base).state_dict(), load_vq(tuned).state_dict()
    convolutions = [name for name in before if name.startswith(("encoder", "decoder"))]
    assert convolutions and all(
        torch.allclose(before[n], after[n], atol=1e-6) for n in convolutions
    )
    assert (
        train(tiny_humanml3d, tmp_path / "other", "--steps", 1, "--init", base, "--levels", 3) == 2
    )
    assert train(tiny_humanml3d, tuned, "--steps", 3, "--init", base, "--resume") == 2


def test_decoder_tuning_keeps_every_token(tiny_humanml3d, tmp_path):
    base, tuned = tmp_path / "base", tmp_path / "tuned"
    assert train(tiny_humanml3d, base, "--steps", 3, "--val-every", 3) == 0
    assert (
        train(
            tiny_humanml3d,
            tuned,
            "--steps",
            3,
            "--val-every",
            3,
            "--init",
            base,
            "--tune",
            "decoder",
            "--lr",
            1e-2,
            "--warmup",
            0,
        )
        == 0
    )
    recipe = load_checkpoint(tuned / "checkpoint.pt")["recipe"]
    assert recipe["tune"] == "decoder"
    assert recipe["tokens_sha256"] == file_sha256(base / "best.pt")
    again = tmp_path / "again"  # a fine-tune of a fine-tune keeps the same tokens
    assert train(tiny_humanml3d, again, "--steps", 1, "--init", tuned, "--tune", "decoder") == 0
    assert load_checkpoint(again / "best.pt")["recipe"]["tokens_sha256"] == recipe["tokens_sha256"]
    before, after = load_vq(base), load_vq(tuned)
    b, a = before.state_dict(), after.state_dict()
    assert all(torch.equal(b[n], a[n]) for n in b if not n.startswith("decoder"))
    assert not all(torch.equal(b[n], a[n]) for n in b if n.startswith("decoder"))
    x = torch.randn(2, 48, before.config.feature_dim)
    assert torch.equal(before.encode(x), after.encode(x))


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--steps", 1, "--init", "nowhere"], "no such VQ run folder"),
        (["--steps", 1, "--tune", "decoder"], "pass --init RUN"),
        (["--steps", 0], "--steps must be positive"),
        (["--steps", 1, "--resume"], "--resume: no checkpoint"),
        (
            ["--steps", 1, "--crop-frames", 41, "--down-factor", 2],
            "not a multiple of the down factor",
        ),
        (["--steps", 1, "--crop-frames", 500], "no clip has 500 frames"),
    ],
)
def test_bad_inputs_give_one_line_errors(extra, message, tiny_humanml3d, tmp_path, capsys):
    assert train(tiny_humanml3d, tmp_path / "run", *extra) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("mogo: error:") and message in error
    assert not (tmp_path / "run" / "checkpoint.pt").exists()
