"""The pieces of `mogo train all` that are fast to check: a trainer's wall-time budget stops
it validated and checkpointed, and --resume goes on to the end; the command's bad input is one
line each. The whole pipeline end to end is `mogo train all --recipe tiny` (minutes on a CPU;
docs/model.md), too slow for this suite."""

import contextlib
import json

import pytest

from helpers import records
from mogo.cli import main
from mogo.export.models.runs import load_checkpoint
from mogo.export.models.sentence_encoder import ENCODER_FILES
from mogo.export.train.train_all import RECIPES

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
            "2",
            "--val-clips",
            "2",
            "--steps",
            "6",
            "--val-every",
            "100",
            *map(str, extra),
        ]
    )


def test_past_its_budget_a_run_stops_checkpointed_and_resumes_to_the_end(
    tiny_humanml3d, tmp_path, capsys
):
    run = tmp_path / "vq"
    assert train(tiny_humanml3d, run, "--max-minutes", 1e-6) == 0
    assert "stopped at step 2 of 6: past --max-minutes" in capsys.readouterr().out
    assert load_checkpoint(run / "checkpoint.pt")["step"] == 2
    assert [(r["kind"], r["step"]) for r in records(run)] == [("train", 2), ("val", 2)]
    assert train(tiny_humanml3d, run, "--resume") == 0
    assert load_checkpoint(run / "checkpoint.pt")["step"] == 6
    assert train(tiny_humanml3d, tmp_path / "other", "--max-minutes", 0) == 2
    assert "--max-minutes must be positive" in capsys.readouterr().err


@pytest.mark.parametrize(
    "extra,message",
    [
        (["--recipe", "huge"], "invalid choice: 'huge'"),
        (["--recipe", "tiny", "--budget", "0"], "--budget must be positive"),
        (["--recipe", "tiny"], "give --sentence-encoder DIR, or --minilm-int8 and --minilm-fp32"),
    ],
)
def test_bad_input_is_one_line(extra, message, tmp_path, capsys):
    with pytest.raises(SystemExit) if "huge" in extra else contextlib.nullcontext():
        assert main(["train", "all", "--out", str(tmp_path / "all"), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_an_encoder_folder_must_be_whole_and_the_corpus_the_recipes(tmp_path, capsys):
    folder = tmp_path / "encoder"
    folder.mkdir()
    (folder / "model.onnx").write_bytes(b"")
    assert (
        main(
            [
                "train",
                "all",
                "--recipe",
                "tiny",
                "--out",
                str(tmp_path / "a"),
                "--sentence-encoder",
                str(folder),
            ]
        )
        == 2
    )
    assert "not an encoder folder (no tokenizer.json, provenance.json" in capsys.readouterr().err
    assert not (tmp_path / "a" / "data").exists()
    for name in ENCODER_FILES:
        (folder / name).write_bytes(b"")
    data = tmp_path / "b" / "data"
    data.mkdir(parents=True)
    (data / "corpus.json").write_text(json.dumps(dict(corpus="v1", clips=5, seed=0)))
    assert (
        main(
            [
                "train",
                "all",
                "--recipe",
                "tiny",
                "--out",
                str(tmp_path / "b"),
                "--sentence-encoder",
                str(folder),
            ]
        )
        == 2
    )
    assert "holds another corpus than the recipe's" in capsys.readouterr().err


def test_every_recipe_trains_on_corpus_v2_within_its_budget():
    for recipe in RECIPES.values():
        assert recipe.corpus == "v2" and set(recipe.minutes) == {"vq", "t2m", "evaluator"}
    assert sum(RECIPES["tiny"].minutes.values()) <= 5
