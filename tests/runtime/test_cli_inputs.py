"""Bad input to `mogo generate`, `mogo stream` and `mogo info` gets one `mogo: error:` line
naming the flag or file:line, exit status 2; prompts the model reads only in part get a `note:`
line on stderr; `mogo --version`; `mogo info` without the build machine's paths."""

import json
from importlib.metadata import version

import numpy as np
import pytest

from helpers import bundle_with_old_text_side
from mogo.cli import main


def refused(args, capsys) -> str:
    """The one error line of a refused command (argparse's own errors included)."""
    try:
        status = main(args)
    except SystemExit as exit:
        status = exit.code
    error = capsys.readouterr().err
    assert status == 2 and error.startswith("mogo: error: ") and error.count("\n") == 1, error
    return error


SAMPLING_FLAGS = [
    (["--guidance", "nan"], "--guidance must be finite, got nan"),
    (["--guidance", "inf"], "--guidance must be finite, got inf"),
    (["--guidance", "1e300"], "--guidance must be between -1000000 and 1000000"),
    (["--temperature", "inf"], "--temperature must be finite, got inf"),
    (["--temperature", "nan"], "--temperature must be finite, got nan"),
    (["--temperature", "1e-320"], r"--temperature must be 0 (greedy) or at least 1e-06"),
    (["--top-p", "nan"], "--top-p must be finite, got nan"),
    (["--top-p", "2"], "--top-p must be in (0, 1]"),
    (["--top-k", "-1"], "--top-k must be >= 0"),
    (["--top-k", "1.5"], "argument --top-k: invalid int value: '1.5'"),
    (["--no-such-flag"], "unrecognized arguments: --no-such-flag"),
]


@pytest.mark.parametrize(
    "flags,message",
    SAMPLING_FLAGS
    + [
        (
            ["--seconds", "0.01"],
            "seconds must be at least 0.05 (one token step, 1 frame at 20 fps)",
        ),
        (["--seconds", "inf"], "seconds must be at most 600"),
        (
            ["--seconds", "x"],
            "argument --seconds: invalid float value: 'x' (see mogo generate --help)",
        ),
    ],
)
def test_bad_values_to_generate_name_their_flag_on_one_line(flags, message, tmp_path, capsys):
    assert message in refused(
        ["generate", "a person walks.", *flags, "--out", str(tmp_path)], capsys
    )
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "flags,message",
    SAMPLING_FLAGS
    + [
        (["--frames", "x"], "argument --frames: invalid int value: 'x' (see mogo stream --help)"),
    ],
)
def test_bad_values_to_stream_name_their_flag_on_one_line(flags, message, capsys):
    assert message in refused(["stream", "a person jogs.", *flags], capsys)
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("timeout", ["inf", "1e300", "nan", "-1", "0"])
def test_a_bad_llm_timeout_is_refused(timeout, monkeypatch, tmp_path, capsys):
    """inf and 1e300 were a traceback (socket), nan and -1 a note about the server."""
    monkeypatch.setenv("MOGO_LLM_URL", "http://127.0.0.1:9/v1")
    assert "the LLM timeout must be a positive number of seconds up to 3600" in refused(
        [
            "generate",
            "walk forward then wave",
            "--align",
            "llm",
            "--llm-timeout",
            timeout,
            "--out",
            str(tmp_path),
        ],
        capsys,
    )


def test_a_command_missing_is_one_line_too(capsys):
    assert "the following arguments are required: COMMAND" in refused([], capsys)


def test_top_k_beyond_the_classes_is_top_k_off(tmp_path, capsys):
    """--top-k 2**70 was an OverflowError traceback."""
    for name, flags in (("huge", ["--top-k", str(2**70)]), ("off", [])):
        assert (
            main(
                [
                    "generate",
                    "a person jumps.",
                    "--seconds",
                    "1",
                    "--seed",
                    "3",
                    "--out",
                    str(tmp_path),
                    "--name",
                    name,
                    *flags,
                ]
            )
            == 0
        )
    np.testing.assert_array_equal(np.load(tmp_path / "huge.npy"), np.load(tmp_path / "off.npy"))


def test_one_frame_is_one_frame(tmp_path, capsys):
    assert (
        main(
            [
                "generate",
                "a person jumps.",
                "--seconds",
                "0.05",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    assert "(1 frame, seed 0)" in capsys.readouterr().out
    assert np.load(tmp_path / "a_person_jumps.npy").shape == (1, 22, 3)


@pytest.fixture(scope="module")
def old_bundle(tmp_path_factory) -> str:
    """A text encoder trained with the model (254 words): the unknown-word notes are its."""
    return bundle_with_old_text_side(tmp_path_factory.mktemp("old"))


@pytest.mark.parametrize("prompt", ["xyzzy", "🙂", "一个人在走路", "walked"])
def test_a_prompt_with_no_known_word_is_refused(prompt, old_bundle, tmp_path, capsys):
    for args in (
        ["generate", prompt, "--seconds", "1", "--out", str(tmp_path)],
        ["stream", prompt, "--frames", "1"],
    ):
        args += ["--bundle", old_bundle]
        error = refused(args, capsys)
        assert f"the model knows no word of the prompt {prompt!r}" in error
        assert "--align rules" in error
    assert not list(tmp_path.iterdir())


def test_unknown_words_and_a_cut_prompt_are_noted_on_stderr(old_bundle, tmp_path, capsys):
    assert (
        main(
            [
                "generate",
                "a person xyzzy walks forward 🙂",
                "--seconds",
                "1",
                "--seed",
                "0",
                "--out",
                str(tmp_path),
                "--bundle",
                old_bundle,
            ]
        )
        == 0
    )
    printed = capsys.readouterr()
    assert printed.err == "note: the model does not know 'xyzzy', '🙂': their meaning is lost\n"
    assert "note:" not in printed.out
    long = "a person walks forward, " * 13 + "then jumps."
    assert main(["stream", long, "--frames", "2", "--seed", "0", "--bundle", old_bundle]) == 0
    printed = capsys.readouterr()
    assert printed.err.startswith(
        "note: the prompt is 69 tokens long and the model reads only "
        "64: everything after 'walks forward, a person walks' is ignored"
    )
    assert printed.err.count("\n") == 1
    assert [json.loads(line)["frame"] for line in printed.out.splitlines()] == [0, 1]


def schedule_file(tmp_path, content: bytes):
    path = tmp_path / "plan.txt"
    path.write_bytes(content)
    return [
        "generate",
        "--prompts-file",
        str(path),
        "--seed",
        "1",
        "--out",
        str(tmp_path),
        "--name",
        "plan",
    ]


@pytest.mark.parametrize(
    "content,message",
    [
        (
            b"2 a person walks.\nnan a person jumps.\n",
            "plan.txt:2: the seconds must be a positive number, got 'nan'",
        ),
        (b"# plan\n-1 a person jumps.\n", "plan.txt:2: the seconds must be a positive number"),
        (b"0 a person jumps.\n", "plan.txt:1: the seconds must be a positive number, got '0'"),
        (b"inf a person jumps.\n", "plan.txt:1: the seconds must be a positive number, got 'inf'"),
        (b"2 a person walks.\n\n3\n", "plan.txt:3: no prompt after the seconds"),
        (b"a person walks\n", "plan.txt:1: expected 'SECONDS PROMPT', got 'a person walks'"),
        (
            b"2 a person walks.\n1 a person caf\xe9 jumps.\n",
            "plan.txt:2: not UTF-8 text (byte 0xe9)",
        ),
        (b"# only a comment\n", "plan.txt: no 'SECONDS PROMPT' lines"),
    ],
)
def test_a_bad_prompts_file_is_named_by_file_and_line(content, message, tmp_path, capsys):
    assert message in refused(schedule_file(tmp_path, content), capsys)
    assert not (tmp_path / "plan.npy").exists()


def test_a_prompts_file_may_separate_with_tabs_and_start_with_a_bom(tmp_path, capsys):
    content = "\ufeff2\ta person walks forward.\n1.5 \t a person jumps.\n".encode()
    assert main(schedule_file(tmp_path, content)) == 0
    assert np.load(tmp_path / "plan.npy").shape == (70, 22, 3)


def test_version(capsys):
    with pytest.raises(SystemExit) as exit:
        main(["--version"])
    assert exit.value.code == 0 and capsys.readouterr().out == f"mogo {version('mogo-edge')}\n"


def test_info_shows_no_path_of_the_machine_that_built_the_bundle(capsys):
    assert main(["info"]) == 0
    printed = capsys.readouterr().out
    assert "/work/" not in printed.replace(printed.splitlines()[0], "")  # but this bundle's own
    assert "fine-tuned from bundle_v2 (a path on the build machine)" in printed
    assert "1 frame per token" in printed and "frame(s)" not in printed
