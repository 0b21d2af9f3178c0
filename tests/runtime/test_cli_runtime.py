"""`mogo generate`, `mogo stream` and `mogo info` on the default bundle: files, output, errors."""

import json
import subprocess
import sys
from dataclasses import fields

import numpy as np
import pytest

from mogo.cli import build_parser, main
from mogo.motion.bvh import NAMINGS
from mogo.motion.mocap import read_bvh
from mogo.motion.skeleton import SMPL_22
from mogo.sampling import Sampling


def test_generate_writes_the_files_and_says_where(tmp_path, capsys):
    out = tmp_path / "out"
    assert (
        main(
            [
                "generate",
                "a person walks forward, then waves",
                "--seconds",
                "3",
                "--seed",
                "0",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    stem = out / "a_person_walks_forward_then_waves"
    printed = capsys.readouterr().out
    for suffix in (".bvh", ".gif", ".npy", ".json"):
        assert stem.with_suffix(suffix).is_file() and f"wrote {stem}{suffix}" in printed
    joints = np.load(stem.with_suffix(".npy"))
    assert joints.shape == (60, 22, 3)
    assert "seed 0" in printed
    clip = read_bvh(stem.with_suffix(".bvh"))
    recovered = np.empty_like(clip.positions)
    recovered[:, [NAMINGS["mixamo"].index(name) for name in clip.names]] = clip.positions
    assert clip.fps == pytest.approx(20.0) and clip.names[:2] == ("Hips", "LeftUpLeg")
    # The BVH skeleton is rigid, of the corpus's proportions; decoded joints are not quite
    # (bones wobble by ~2 cm), so forward kinematics gives them back within about a
    # centimetre on average, not everywhere (docs/bvh.md).
    error = np.linalg.norm(recovered - joints, axis=-1)
    assert error.mean() < 0.015 and error.max() < 0.1
    document = json.loads(stem.with_suffix(".json").read_text())
    assert len(document["frames"]) == 60 and document["fps"] == 20.0
    assert (
        main(
            [
                "generate",
                "a person walks forward, then waves",
                "--seconds",
                "3",
                "--seed",
                "0",
                "--out",
                str(out),
                "--bvh-bone-translations",
                "--overwrite",
                "--bvh-names",
                "smpl",
                "--bvh-units",
                "cm",
            ]
        )
        == 0
    )
    clip = read_bvh(stem.with_suffix(".bvh"))  # with the bones' stretch: exact
    recovered[:, [SMPL_22.joint_names.index(name) for name in clip.names]] = clip.positions
    assert np.linalg.norm(recovered / 100.0 - joints, axis=-1).max() < 1e-4


def test_a_prompts_file_plays_one_motion(tmp_path, capsys):
    schedule = tmp_path / "plan.txt"
    schedule.write_text("# seconds prompt\n2 a person walks forward.\n\n1.5 a person jumps.\n")
    assert (
        main(
            [
                "generate",
                "--prompts-file",
                str(schedule),
                "--seed",
                "1",
                "--out",
                str(tmp_path),
                "--name",
                "plan",
            ]
        )
        == 0
    )
    assert np.load(tmp_path / "plan.npy").shape == (70, 22, 3)
    assert "a person walks forward., then a person jumps." in capsys.readouterr().out


@pytest.mark.parametrize("low_latency", [[], ["--low-latency"]])
def test_stream_prints_json_lines(low_latency):
    result = subprocess.run(
        [sys.executable, "-m", "mogo", "stream", "a person jogs.", "--frames", "5", "--seed", "2"]
        + low_latency,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stderr
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert [line["frame"] for line in lines] == [0, 1, 2, 3, 4]
    assert np.array(lines[0]["joints"]).shape == (22, 3)


def test_every_sampling_field_is_a_flag_of_generate_and_stream(capsys):
    options = fields(Sampling)
    flags = [f"--{option.name.replace('_', '-')}" for option in options]
    for verb in ("generate", "stream"):
        given = [word for flag in flags for word in (flag, "1")]
        args = build_parser().parse_args([verb, "walk", *given])
        assert all(getattr(args, o.name) == type(o.default)(1) for o in options)
        assert all(
            getattr(build_parser().parse_args([verb, "walk"]), o.name) is None for o in options
        )  # not given: the bundle's default
        with pytest.raises(SystemExit):
            build_parser().parse_args([verb, "--help"])
        shown = "".join(capsys.readouterr().out.split())  # wrapped at any width
        assert all(
            flag in shown and "".join(option.metadata["help"].split()) in shown
            for flag, option in zip(flags, options, strict=False)
        )


def test_info_describes_the_default_bundle(capsys):
    assert main(["info"]) == 0
    printed = capsys.readouterr().out
    assert "humanml3d skeleton, 263-dim features, 20 fps" in printed
    assert "sha256 verified" in printed and "level_0.onnx" in printed


@pytest.mark.parametrize(
    "args,message",
    [
        (["generate", ""], "the prompt is empty"),
        (["generate", "   "], "the prompt is empty"),
        (["generate", "walk", "--seconds", "0"], "seconds must be a positive number"),
        (["generate", "walk", "--seconds", "100000"], "at most 600"),
        (["generate", "walk", "--temperature", "-1"], "temperature must be >= 0"),
        (["generate", "walk", "--top-p", "2"], "--top-p must be in"),
        (["generate", "walk", "--bundle", "/nonexistent/bundle"], "no such bundle folder"),
        (["generate"], "give a prompt"),
        (["stream", "walk", "--frames", "0"], "--frames must be at least 1"),
        (["generate", "walk", "--threads", "0"], "--threads must be at least 1"),
        (["info", "/nonexistent/bundle"], "no such bundle folder"),
    ],
)
def test_bad_input_gives_one_line_and_exit_2(args, message, capsys):
    assert main(args) == 2
    error = capsys.readouterr().err
    assert error.startswith("mogo: error: ") and message in error and error.count("\n") == 1


def test_thread_count_does_not_change_the_motion(tmp_path):
    for threads in ("1", "2"):
        assert (
            main(
                [
                    "generate",
                    "a person jumps.",
                    "--seconds",
                    "2",
                    "--seed",
                    "4",
                    "--out",
                    str(tmp_path / threads),
                    "--threads",
                    threads,
                ]
            )
            == 0
        )
    np.testing.assert_array_equal(
        np.load(tmp_path / "1" / "a_person_jumps.npy"),
        np.load(tmp_path / "2" / "a_person_jumps.npy"),
    )


def test_unwritable_output_folder_and_bad_prompts_file(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["generate", "walk", "--seconds", "1", "--out", str(blocker / "out")]) == 2
    error = capsys.readouterr().err
    assert f"{blocker}: not a folder (so {blocker / 'out'} cannot be made in it)" in error
    schedule = tmp_path / "plan.txt"
    schedule.write_text("a person walks\n")
    assert main(["generate", "--prompts-file", str(schedule)]) == 2
    assert "plan.txt:1: expected 'SECONDS PROMPT'" in capsys.readouterr().err
