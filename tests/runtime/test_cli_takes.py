"""`mogo generate` for long takes: --formats names the files written, and a take from
LONG_TAKE_SECONDS on shows its progress on stderr (stdout stays what was written)."""

import re

import numpy as np
import pytest

from mogo import cli
from mogo.cli import main


def test_formats_writes_only_the_files_named(tmp_path, capsys):
    assert (
        main(
            [
                "generate",
                "a person walks forward.",
                "--seconds",
                "2",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
                "--formats",
                "npy, bvh",
            ]
        )
        == 0
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "a_person_walks_forward.bvh",
        "a_person_walks_forward.npy",
    ]
    assert np.load(tmp_path / "a_person_walks_forward.npy").shape == (40, 22, 3)
    printed = capsys.readouterr().out
    assert printed.count("wrote ") == 2


@pytest.mark.parametrize(
    "flags, message",
    [
        (
            ["--formats", "gif,fbx"],
            "--formats: no format 'fbx'; choose from bvh, glb, gif, npy, json",
        ),
        (["--formats", "npy,npy"], "--formats: name each format once, at least one; choose from"),
        (
            ["--formats", "npy", "--format", "glb"],
            "give --formats (it names the animation file too) or --format, not both",
        ),
    ],
)
def test_bad_formats_are_one_line_and_write_nothing(flags, message, tmp_path, capsys):
    assert (
        main(["generate", "a person walks.", "--seconds", "2", "--out", str(tmp_path), *flags]) == 2
    )
    error = capsys.readouterr().err
    assert error.startswith(f"mogo: error: {message}") and error.count("\n") == 1
    assert not list(tmp_path.iterdir())


def test_a_long_take_shows_its_progress_on_stderr(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "LONG_TAKE_SECONDS", 3.0)  # what 30 s would show, in less time
    assert (
        main(
            [
                "generate",
                "a person walks forward.",
                "--seconds",
                "3",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
                "--formats",
                "npy",
            ]
        )
        == 0
    )
    captured = capsys.readouterr()
    steps = [line for line in captured.err.splitlines() if line.startswith("generating: ")]
    assert len(steps) >= 5  # about every 10% where stderr is not a terminal
    done, total = map(int, re.match(r"generating: (\d+)/(\d+) ", steps[-1]).groups())
    assert done == total and total > 60  # 60 frames, and the decoder's right context
    assert "writing: npy (60 frames)\n" in captured.err
    assert "generating" not in captured.out and captured.out.count("wrote ") == 1
    assert (
        main(
            [
                "generate",
                "a person walks forward.",
                "--seconds",
                "2.9",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
                "--formats",
                "npy",
            ]
        )
        == 0
    )
    assert "generating" not in capsys.readouterr().err  # a short take: no progress


@pytest.mark.parametrize("how", ["prompts-file", "align"])
def test_a_long_played_take_shows_its_progress_too(how, tmp_path, capsys, monkeypatch):
    """A prompts file and an aligned prompt are played step by step (generator.play): the
    same progress line, over every step of the schedule."""
    monkeypatch.setattr(cli, "LONG_TAKE_SECONDS", 3.0)
    if how == "prompts-file":
        (tmp_path / "plan.txt").write_text("2 a person walks forward.\n1.5 a person jumps.\n")
        flags = ["--prompts-file", str(tmp_path / "plan.txt")]
    else:
        flags = ["walk ahead and then jump", "--align", "rules", "--seconds", "3.5"]
    assert (
        main(
            ["generate", *flags, "--seed", "0", "--out", str(tmp_path / "out"), "--formats", "npy"]
        )
        == 0
    )
    steps = [
        line for line in capsys.readouterr().err.splitlines() if line.startswith("generating: ")
    ]
    assert len(steps) >= 5 and re.match(r"generating: (\d+)/\1 \(100%\)", steps[-1]), steps
