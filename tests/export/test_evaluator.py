import numpy as np
import pytest
import torch

from helpers import interrupt_after_step, records
from mogo.bench.quality.evaluator import OnnxEvaluator, TextMotionEvaluator
from mogo.cli import main
from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.export.models.evaluator import Evaluator, EvaluatorConfig
from mogo.export.models.runs import load_checkpoint
from mogo.export.models.text_encoder import encode_captions
from mogo.export.train import train_evaluator

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def train(data, out, *extra) -> int:
    return main(
        [
            "train",
            "evaluator",
            "--data",
            str(data),
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


def load_best(run) -> Evaluator:
    state = load_checkpoint(run / "best.pt")
    model = Evaluator(EvaluatorConfig(**state["config"]["model"]))
    model.load_state_dict(state["model"])
    return model.eval()


def test_trains_loss_falls_and_the_export_matches_torch(tiny_humanml3d, tmp_path):
    run = tmp_path / "run"
    assert (
        train(
            tiny_humanml3d,
            run,
            "--steps",
            60,
            "--lr",
            3e-3,
            "--warmup",
            5,
            "--val-every",
            30,
            "--log-every",
            10,
        )
        == 0
    )
    losses = [r["loss"] for r in records(run, "train")]
    assert losses[-1] < 0.7 * losses[0]  # the tiny captions repeat: a floor above zero
    assert [r["step"] for r in records(run, "val")] == [30, 60]
    assert {"r1", "r2", "r3", "matching"} <= set(records(run, "val")[0])

    evaluator = OnnxEvaluator(run / "evaluator")
    assert isinstance(evaluator, TextMotionEvaluator)
    model = load_best(run)
    folder = HumanML3DFolder(tiny_humanml3d)
    captions = ["a person walks forward.", "the person waves.", "someone jumps."]
    clips = [folder.features(f"{k:06d}") for k in (0, 5, 11)]
    clips[1] = clips[1][:9]  # shorter than the others: padded in the batch
    with torch.no_grad():
        text = model.embed_text(*encode_captions(evaluator.tokenizer, captions)).numpy()
        motion = np.concatenate(
            [
                model.embed_motion(
                    torch.from_numpy(folder.normalize(c))[None], torch.tensor([len(c)])
                ).numpy()
                for c in clips
            ]
        )
    assert np.abs(evaluator.embed_text(captions) - text).max() < 1e-4
    assert np.abs(evaluator.embed_motion(clips) - motion).max() < 1e-4
    assert np.allclose(np.linalg.norm(motion, axis=1), 1, atol=1e-5)
    assert evaluator.embed_motion(clips).shape == (3, 16)


def test_resume_continues_exactly(tiny_humanml3d, tmp_path, monkeypatch):
    monkeypatch.setattr(train_evaluator, "export_evaluator", lambda *a, **k: None)
    args = ("--steps", 7, "--val-every", 2, "--checkpoint-every", 2)
    assert train(tiny_humanml3d, tmp_path / "whole", *args) == 0
    interrupt_after_step(monkeypatch, 5)
    assert train(tiny_humanml3d, tmp_path / "split", *args) == 130
    monkeypatch.undo()
    monkeypatch.setattr(train_evaluator, "export_evaluator", lambda *a, **k: None)
    assert train(tiny_humanml3d, tmp_path / "split", *args, "--resume") == 0
    assert records(tmp_path / "split") == records(tmp_path / "whole")


@pytest.mark.parametrize(
    "case, message",
    [
        ("no_val", "val.txt: split file missing"),
        ("zero_steps", "--steps must be positive"),
        ("paper", "unknown config 'paper'"),
    ],
)
def test_bad_inputs_give_one_line_errors(case, message, tiny_humanml3d, tmp_path, capsys):
    extra = ["--steps", 0] if case == "zero_steps" else ["--steps", 1]
    if case == "no_val":
        (tiny_humanml3d / "val.txt").unlink()
    if case == "paper":
        extra = ["--steps", 1, "--config", "paper"]
    assert train(tiny_humanml3d, tmp_path / "run", *extra) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("mogo: error:") and message in error


def test_evaluator_folder_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no evaluator.json"):
        OnnxEvaluator(tmp_path)
