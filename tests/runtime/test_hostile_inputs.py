"""Hostile command-line input (issue 39): prompts files that never end or ask for hours of
work, control, escape and bidi characters in prompts and names, lone surrogates from a
terminal in another encoding, an ASCII-only terminal. Each through a real `mogo` process,
bounded in time: one `mogo: error:` line before any work, or output that shows what it is."""

import os
import subprocess
import sys

import pytest

from mogo import MotionGenerator


def mogo(*args, env=None, timeout=120):
    """`mogo ARGS` in a fresh process: (status, stdout, stderr). Arguments may be bytes (as a
    terminal in another encoding passes them)."""
    done = subprocess.run(
        [
            os.fsencode(sys.executable),
            b"-m",
            b"mogo",
            *(a if isinstance(a, bytes) else os.fsencode(a) for a in args),
        ],
        capture_output=True,
        timeout=timeout,
        env=None if env is None else os.environ | env,
    )
    return (
        done.returncode,
        done.stdout.decode("utf-8", "replace"),
        done.stderr.decode("utf-8", "replace"),
    )


def refused(*args, **options) -> str:
    status, _, error = mogo(*args, **options)
    assert status == 2 and error.startswith("mogo: error: ") and error.count("\n") == 1, error
    return error


def plan(tmp_path, text):
    (tmp_path / "plan.txt").write_text(text, encoding="utf-8")
    return [
        "generate",
        "--prompts-file",
        str(tmp_path / "plan.txt"),
        "--out",
        str(tmp_path / "out"),
    ]


@pytest.mark.parametrize(
    "text, message",
    [
        ("1 a person walks.\n" * 10_000, "plan.txt:101: more than 100 prompts in one schedule"),
        (
            "600 a person walks.\n600 a person jumps.\n",
            "plan.txt: the schedule's lengths add up to 1200 s; at most 600 in one call",
        ),
        (
            "2 a person walks.\n# rest\n0.01 a person jumps.\n",
            "plan.txt:3: seconds must be at least 0.05 (one token step, 1 frame at 20 fps), got 0.01",
        ),
        ("2 a person walks.\n\n601 a person jumps.\n", "plan.txt:3: seconds must be at most 600"),
        (
            "2 a person walks.\n2 \u200b\u200b\u200b\n",
            "plan.txt:2: the prompt is empty (only invisible characters)",
        ),
    ],
)
def test_a_prompts_file_too_big_is_refused_by_file_and_line(tmp_path, text, message):
    """Old: 10,000 lines ran for over 300 s, two 600-s lines 1200 s, and length errors named
    schedule[N]."""
    assert message in refused(*plan(tmp_path, text))
    assert not (tmp_path / "out").exists()


def test_a_prompts_file_that_never_ends_is_refused(tmp_path):
    """Old: --prompts-file /dev/zero read for ever."""
    error = refused("generate", "--prompts-file", "/dev/zero", "--out", str(tmp_path), timeout=60)
    assert error == (
        "mogo: error: /dev/zero: larger than 1024 KiB; a prompts file holds at "
        "most 100 lines 'SECONDS PROMPT'\n"
    )


@pytest.mark.parametrize(
    "prompt, message",
    [
        ("\u200b\u200b\u200b", "the prompt is empty (only invisible characters)"),
        (
            b"a person walks caf\xe9",
            "text is not valid Unicode: a lone surrogate '\\udce9' at character 18",
        ),
    ],
)
def test_an_invisible_or_undecodable_prompt_is_one_line(tmp_path, prompt, message):
    """Old: zero-width spaces were a prompt; a Latin-1 byte was a 27-line traceback."""
    assert refused("generate", prompt, "--out", str(tmp_path)) == f"mogo: error: {message}\n"


def test_the_api_refuses_a_lone_surrogate_in_its_own_words():
    generator = MotionGenerator.load()
    for call in (
        lambda: generator.generate("a person walks caf\udce9", seconds=1),
        lambda: generator.stream("caf\udce9 walks"),
        lambda: generator.play([("a person walks", 1), ("\udce9", 1)]),
    ):
        with pytest.raises(ValueError, match="not valid Unicode: a lone surrogate"):
            call()


@pytest.mark.parametrize(
    "name", ["clip\u202egpj.exe", "clip\x1b[2Jx", "two\nlines", "zero\u200bwidth", b"caf\xe9"]
)
def test_a_name_with_control_bidi_or_invisible_characters_is_refused(tmp_path, name):
    error = refused("generate", "a person walks.", "--out", str(tmp_path), "--name", name)
    assert "--name must be a file name without control, invisible or bidirectional" in error
    assert not any(c in error for c in "\u202e\x1b\u200b")
    assert list(tmp_path.iterdir()) == []


def test_control_characters_never_reach_the_terminal(tmp_path):
    """Old: a prompt's newline printed a fake "wrote /etc/passwd" line; escapes went raw."""
    out = tmp_path / "out\x1b[31m\nwrote "
    status, printed, error = mogo(
        "generate",
        "a person walks.\nwrote /etc/passwd \x1b[2J",
        "--seconds",
        "1",
        "--seed",
        "1",
        "--out",
        str(out),
    )
    assert status == 0, error
    assert not any(c in printed + error for c in "\x1b\u202e")
    lines = printed.splitlines()
    assert [line for line in lines if line.startswith("wrote ")] == [
        f"wrote {tmp_path}/out\\x1b[31m\\nwrote /a_person_walks_wrote_etc_passwd_2j{suffix}"
        for suffix in (".bvh", ".gif", ".npy", ".json")
    ]
    assert "for: a person walks. wrote /etc/passwd [2J" in printed
    assert len(list(out.iterdir())) == 4


def test_an_ascii_only_terminal_gets_escapes_not_an_error_after_the_work(tmp_path):
    """Old: exit 2 and an encoding error once the whole take was written."""
    status, printed, error = mogo(
        "generate",
        "a person walks to the café",
        "--seconds",
        "1",
        "--out",
        str(tmp_path),
        env={"PYTHONIOENCODING": "ascii"},
    )
    assert (status, error) == (0, "") or status == 0 and error.startswith("note: "), error
    assert "for: a person walks to the caf\\xe9" in printed
    assert len(list(tmp_path.iterdir())) == 4


def test_a_number_too_long_to_print_is_named_by_its_size():
    """Old: "Exceeds the limit (4300 digits) for integer string conversion" from inside the
    message that was to name the number."""
    generator = MotionGenerator.load()
    huge = 10**5000
    for call, message in (
        (
            lambda: generator.generate("a person walks.", seconds=huge),
            "seconds must be at most 600 in one call, got an integer of 16610 bits",
        ),
        (
            lambda: generator.generate("a person walks.", seconds=1, top_k=-huge),
            r"top_k must be >= 0 \(0 = off\), got an integer of 16610 bits",
        ),
        (
            lambda: generator.stream("a person walks.").advance(-huge),
            "steps must be >= 0, got an integer of 16610 bits",
        ),
    ):
        with pytest.raises(ValueError, match=message):
            call()
