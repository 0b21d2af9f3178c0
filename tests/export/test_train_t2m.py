import os
from dataclasses import asdict, replace

import numpy as np
import pytest
import torch

from helpers import interrupt_after_step, mogo_on_two_gloo_processes, records
from mogo.cli import main
from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.export.models.generate_torch import generate
from mogo.export.models.runs import load_checkpoint, load_t2m, load_vq
from mogo.export.models.t2m import T2MConfig
from mogo.export.models.text_encoder import encode_captions
from mogo.export.models.vq import MoSAVQ, VQConfig
from mogo.export.train import train_t2m
from mogo.export.train.datasets import MotionCropDataset
from mogo.export.train.options import T2MTrainOptions
from mogo.export.train.training import save_checkpoint

TRAIN_SPANS, VAL_SPANS = 13, 4  # the tiny_humanml3d captions of at least 40 frames


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture
def vq_run(tiny_humanml3d, tmp_path):
    """A tiny MoSA-VQ, untrained but for codebooks initialised from the data (so tokens vary)."""
    folder = HumanML3DFolder(tiny_humanml3d)
    torch.manual_seed(0)
    config = VQConfig.tiny()
    model = MoSAVQ(config, folder.mean, folder.std)
    crops = torch.stack(list(MotionCropDataset(folder, "train", crop_frames=40)))
    with torch.no_grad():
        model.train()(crops)
    save_checkpoint(tmp_path / "vq" / "checkpoint.pt", model, None, 0, asdict(config))
    return tmp_path / "vq"


def train(data, vq, out, *extra) -> int:
    return main(
        [
            "train",
            "t2m",
            "--data",
            str(data),
            "--vq",
            str(vq),
            "--out",
            str(out),
            "--config",
            "tiny",
            "--batch-size",
            "4",
            "--log-every",
            "1",
            *map(str, extra),
        ]
    )


def test_cli_trains_and_writes_the_run(tiny_humanml3d, vq_run, tmp_path):
    run = tmp_path / "run"
    assert (
        train(tiny_humanml3d, vq_run, run, "--steps", 4, "--val-every", 2, "--checkpoint-every", 2)
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
    assert set(records(run)[-1]) == {"kind", "step", "loss", "acc_0", "acc_1", "acc_2"}
    state = load_checkpoint(run / "checkpoint.pt")
    assert state["step"] == 4 and state["optimizer"] is not None
    assert state["config"]["vq"]["sha256"] == train_t2m.file_sha256(vq_run / "checkpoint.pt")
    assert load_checkpoint(run / "best.pt")["optimizer"] is None

    caches = {
        split: np.load(run / "tokens" / f"{split}.npz", allow_pickle=False)
        for split in ("train", "val")
    }
    assert len(caches["train"]["captions"]) == TRAIN_SPANS
    assert len(caches["val"]["captions"]) == VAL_SPANS
    train_cache = caches["train"]
    assert train_cache["tokens"].shape[1] == 3 and train_cache["tokens"].max() < 16
    assert train_cache["offsets"][-1] == len(train_cache["tokens"])
    assert all(train_cache[name].dtype != object for name in train_cache.files)

    t2m, text_encoder, tokenizer = load_t2m(run)
    assert not t2m.training and not text_encoder.training
    with torch.no_grad():
        prompt = text_encoder.encode(*encode_captions(tokenizer, ["a person walks forward."]))
    assert generate(t2m, prompt[0], num_frames=3).shape == (3, 3)


def test_token_cache_is_reused_until_the_vq_changes(tiny_humanml3d, vq_run, tmp_path):
    folder = HumanML3DFolder(tiny_humanml3d)
    vq = load_vq(vq_run)
    recipe = dict(T2MTrainOptions.recipe_defaults(), preset="tiny")

    def prepare(sha):
        return train_t2m._prepare(
            tmp_path, folder, vq, recipe, sha, fresh=False, device=torch.device("cpu")
        )

    cache = tmp_path / "tokens" / "val.npz"
    prepare("a" * 64)
    os.utime(cache, (0, 0))
    prepare("a" * 64)
    assert cache.stat().st_mtime == 0
    prepare("b" * 64)
    assert cache.stat().st_mtime > 0 and str(np.load(cache)["vq_sha256"]) == "b" * 64


def test_resume_continues_exactly(tiny_humanml3d, vq_run, tmp_path, monkeypatch):
    args = ("--steps", 7, "--val-every", 2, "--checkpoint-every", 2)
    assert train(tiny_humanml3d, vq_run, tmp_path / "whole", *args) == 0

    interrupt_after_step(monkeypatch, 5)  # logged, but never checkpointed
    assert train(tiny_humanml3d, vq_run, tmp_path / "split", *args) == 130
    assert records(tmp_path / "split")[-1]["step"] == 5
    monkeypatch.undo()
    # 13 spans, batch 4: 3 steps an epoch, so step 4 resumes mid-epoch
    assert train(tiny_humanml3d, vq_run, tmp_path / "split", *args, "--resume") == 0
    assert records(tmp_path / "split") == records(tmp_path / "whole")
    assert train(tiny_humanml3d, vq_run, tmp_path / "split", *args, "--resume", "--lr", 1e-3) == 2


def test_two_processes_on_gloo(tiny_humanml3d, vq_run, tmp_path):
    run = tmp_path / "run"
    mogo_on_two_gloo_processes(
        "train",
        "t2m",
        "--data",
        tiny_humanml3d,
        "--vq",
        vq_run,
        "--out",
        run,
        "--config",
        "tiny",
        "--batch-size",
        2,
        "--steps",
        3,
        "--val-every",
        3,
    )
    for name in (
        "checkpoint.pt",
        "best.pt",
        "metrics.jsonl",
        "tokenizer.json",
        "tokens/train.npz",
        "tokens/val.npz",
    ):
        assert (run / name).is_file(), name
    assert load_checkpoint(run / "checkpoint.pt")["config"]["world_size"] == 2
    assert [(r["kind"], r["step"]) for r in records(run)] == [("train", 3), ("val", 3)]


def test_tiny_overfit_loss_drops(tiny_humanml3d, vq_run, tmp_path, monkeypatch):
    """Memorising 13 sequences, without the token corruption that is there to prevent it."""
    monkeypatch.setitem(
        train_t2m.PRESETS, "tiny", lambda: replace(T2MConfig.tiny(), token_corruption=0.0)
    )
    run = tmp_path / "run"
    assert (
        train(
            tiny_humanml3d,
            vq_run,
            run,
            "--steps",
            200,
            "--lr",
            3e-3,
            "--warmup",
            10,
            "--val-every",
            200,
            "--log-every",
            20,
        )
        == 0
    )
    first, *_, last = [r["loss"] for r in records(run, "train")]
    assert last < 0.5 * first


@pytest.mark.parametrize(
    "case, message",
    [
        ("no_vq", "no such VQ run folder"),
        ("empty_data", "folder missing"),
        ("zero_steps", "--steps must be positive"),
        ("resume_nothing", "--resume: no checkpoint"),
    ],
)
def test_bad_inputs_give_one_line_errors(case, message, tiny_humanml3d, vq_run, tmp_path, capsys):
    data, vq, extra = tiny_humanml3d, vq_run, ["--steps", 1]
    if case == "no_vq":
        vq = tmp_path / "missing"
    elif case == "empty_data":
        data = tmp_path / "empty"
        data.mkdir()
    elif case == "zero_steps":
        extra = ["--steps", 0]
    else:
        extra.append("--resume")
    assert train(data, vq, tmp_path / "run", *extra) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("mogo: error:") and message in error
    assert not (tmp_path / "run" / "checkpoint.pt").exists()
