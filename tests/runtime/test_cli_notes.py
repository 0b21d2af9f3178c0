"""What `mogo generate` and `mogo stream` tell on stderr beside their output: `--align rules`
suggested where a prompt played as written is played as something else, and a stream's seed
when it was drawn at random."""

import json
import re
import subprocess
import sys

from mogo.cli import main

README_ALIGN_EXAMPLE = "make the guy stroll ahead and after that wave 3 times"


def generate_notes(tmp_path, capsys, prompt, *flags) -> list[str]:
    assert (
        main(
            [
                "generate",
                prompt,
                "--seconds",
                "1",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
                "--formats",
                "npy",
                *flags,
            ]
        )
        == 0
    )
    return capsys.readouterr().err.splitlines()


def test_a_prompt_of_several_steps_played_as_a_caption_is_told_of_align(tmp_path, capsys):
    (note,) = generate_notes(tmp_path, capsys, README_ALIGN_EXAMPLE)
    assert note.startswith("note: played as the known caption ")
    assert note.endswith(" (it reads as 2 steps: --align rules plays them one after another)")
    assert not [
        line
        for line in generate_notes(tmp_path, capsys, README_ALIGN_EXAMPLE, "--align", "rules")
        if "--align" in line
    ]


def test_a_far_prompt_is_told_of_align_where_generate_can_use_it(tmp_path, capsys):
    (note,) = generate_notes(tmp_path, capsys, "a person does a backflip")
    assert note.startswith("note: far from what this model knows")
    assert note.endswith(" (--align rules maps some other words onto the ones it knows)")
    assert main(["stream", "a person does a backflip", "--frames", "1", "--seed", "0"]) == 0
    (note,) = capsys.readouterr().err.splitlines()  # mogo stream has no --align
    assert note.startswith("note: far from what this model knows") and "--align" not in note
    # a prompt of one step played as a known caption: the note as before, nothing to add
    (note,) = generate_notes(tmp_path, capsys, "someone saunters forward")
    assert note.startswith("note: played as the known caption ") and "--align" not in note


def stream(*flags) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mogo", "stream", "a person jogs.", "--frames", "3", *flags],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_a_random_seed_of_a_stream_is_printed_and_gives_the_stream_again():
    drawn = stream()
    assert drawn.returncode == 0, drawn.stderr
    match = re.fullmatch(
        r"note: seed (\d+) \(random; --seed \1 streams this motion again\)\n", drawn.stderr
    )
    assert match, drawn.stderr
    again = stream("--seed", match.group(1))
    assert again.stderr == "" and again.stdout == drawn.stdout
    assert [json.loads(line)["frame"] for line in again.stdout.splitlines()] == [0, 1, 2]
