import json
import re

import numpy as np
import pytest

from helpers import travelling_clip
from mogo.cli import main
from mogo.export.data.convert import read_clip
from mogo.motion.bvh import save_bvh
from mogo.motion.features import features_to_joints
from mogo.motion.mocap import resample
from mogo.motion.skeleton import KIT_21, SMPL_22


def test_convert_writes_a_humanml3d_folder(tmp_path):
    joints_dir = tmp_path / "mocap"
    joints_dir.mkdir()
    rng = np.random.default_rng(0)
    for k in range(6):
        np.save(joints_dir / f"take{k}.npy", travelling_clip(rng, frames=50, turn_degrees=90 * k))
    (joints_dir / "take0.txt").write_text("a person walks.#a/DET person/NOUN walk/VERB#0.0#0.0\n")
    out = tmp_path / "out"
    assert main(["data", "convert", "--joints", str(joints_dir), "--out", str(out)]) == 0
    ids = sum((p.read_text().split() for p in out.glob("*.txt")), [])
    assert sorted(ids) == [f"take{k}" for k in range(6)]
    for k in range(6):
        features = np.load(out / "new_joint_vecs" / f"take{k}.npy")
        joints = np.load(out / "new_joints" / f"take{k}.npy")
        assert features.shape == (49, 263) and joints.shape == (50, 22, 3)
        assert np.abs(features_to_joints(features) - joints[:-1]).max() < 1e-4
    assert np.load(out / "Mean.npy").shape == (263,)
    assert (out / "texts" / "take0.txt").read_text().startswith("a person walks.")


def test_convert_names_the_bad_file(tmp_path, capsys):
    joints_dir = tmp_path / "mocap"
    joints_dir.mkdir()
    np.save(joints_dir / "broken.npy", np.zeros((30, 17, 3)))
    assert main(["data", "convert", "--joints", str(joints_dir), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "broken.npy: shape (30, 17, 3), expected (T, 22, 3)" in err
    assert main(["data", "convert", "--joints", str(tmp_path / "nope"), "--out", "x"]) == 2


def test_resample_keeps_duration_and_endpoints():
    clip = np.random.default_rng(1).normal(size=(61, 22, 3))  # 2 s at 30 fps
    out = resample(clip, 30.0, 20.0)
    assert out.shape == (41, 22, 3)
    np.testing.assert_allclose(out[0], clip[0])
    np.testing.assert_allclose(out[-1], clip[-1], atol=1e-9)
    with pytest.raises(ValueError, match="fps must be positive"):
        resample(clip, 0.0, 20.0)


# -- what issue 18 found accepted or worded wrongly -----------------------------------------------
def _clip(frames=50):
    return travelling_clip(np.random.default_rng(3), frames=frames)


def _with_glitch(value):
    clip = _clip()
    clip[5, 0, 0] = value
    return clip


@pytest.mark.parametrize(
    "write,message",
    [
        (lambda p: p.write_text("hello"), "not a .npy array file"),
        (lambda p: np.savez(p.open("wb"), a=_clip()), "not a .npy array file"),
        (
            lambda p: (np.save(p, _clip()), p.write_bytes(p.read_bytes()[:500])),
            "its header claims an array of shape (50, 22, 3) (26400 bytes), the file holds 372 bytes",
        ),
        (
            lambda p: np.save(p, _clip() * 100),
            "from ankle to head along the bones, a person 0.5 "
            "to 2.5 m; in centimetres? divide by 100",
        ),
        (lambda p: np.save(p, _clip() * 1000), "in millimetres? divide by 1000"),
        (lambda p: np.save(p, _clip() / 0.0254), "in inches? divide by 39.37"),
        (
            lambda p: np.save(p, _clip() * 1e30),
            "e+30; joints are metres, within 10000 m of the origin",
        ),
        (lambda p: np.save(p, _with_glitch(1e30)), "coordinates up to 1e+30"),
        (lambda p: np.save(p, _with_glitch(np.nan)), "holds NaN or infinite values"),
        (lambda p: np.save(p, _with_glitch(-np.inf)), "holds NaN or infinite values"),
        (
            lambda p: np.save(p, _clip()[:, :21]),
            "shape (50, 21, 3), expected (T, 22, 3) for the humanml3d skeleton (--skeleton)",
        ),
        (lambda p: np.save(p, _clip()[:1]), "1 frame(s); a clip needs at least 2"),
        (lambda p: np.save(p, np.full((50, 22, 3), "a")), "holds <U1 values, expected joint"),
    ],
)
def test_a_bad_clip_among_good_ones_is_one_line_and_leaves_no_folder(
    tmp_path, capsys, write, message
):
    joints_dir = tmp_path / "mocap"
    joints_dir.mkdir()
    for k in range(3):
        np.save(joints_dir / f"good{k}.npy", _clip())
    write(joints_dir / "x.npy")
    out = tmp_path / "out"
    assert main(["data", "convert", "--joints", str(joints_dir), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"mogo: error: {joints_dir / 'x.npy'}: ") and err.count("\n") == 1
    assert message in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mocap"]  # no out, no staging


def test_a_bad_clip_message_in_full(tmp_path):
    np.save(tmp_path / "x.npy", _clip() * 100)
    with pytest.raises(ValueError, match=re.escape(f"{tmp_path / 'x.npy'}: the body measures")):
        read_clip(tmp_path / "x.npy", SMPL_22)


def test_metres_pass_for_both_skeletons(tmp_path):
    for skeleton in (SMPL_22, KIT_21):
        np.save(tmp_path / "x.npy", travelling_clip(np.random.default_rng(0), skeleton))
        assert read_clip(tmp_path / "x.npy", skeleton).shape[1:] == (skeleton.num_joints, 3)


@pytest.mark.parametrize("fps", ["nan", "0", "-1", "inf", "0.001"])
def test_a_bad_source_frame_rate_is_one_line(tmp_path, capsys, fps):
    joints_dir = tmp_path / "mocap"
    joints_dir.mkdir()
    np.save(joints_dir / "good.npy", _clip())
    assert (
        main(
            [
                "data",
                "convert",
                "--joints",
                str(joints_dir),
                "--out",
                str(tmp_path / "o"),
                "--fps",
                fps,
            ]
        )
        == 2
    )
    assert capsys.readouterr().err == (
        "mogo: error: the source frame rate (--fps) must be a "
        f"number of frames per second, at least 1, got "
        f"{float(fps)}\n"
    )
    assert not (tmp_path / "o").exists()


def test_a_failure_while_converting_leaves_no_folder(tmp_path, capsys):
    """Two frames at 1000 fps are one frame at 20: found only when resampling, after the
    other clips were written (into the staging folder, removed)."""
    joints_dir = tmp_path / "mocap"
    joints_dir.mkdir()
    np.save(joints_dir / "a.npy", _clip(frames=200))
    np.save(joints_dir / "b.npy", _clip()[:2])
    assert (
        main(
            [
                "data",
                "convert",
                "--joints",
                str(joints_dir),
                "--out",
                str(tmp_path / "o"),
                "--fps",
                "1000",
            ]
        )
        == 2
    )
    assert f"{joints_dir / 'b.npy'}: a clip needs at least 2 frames" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mocap"]


def test_an_out_folder_with_files_is_refused_and_an_empty_one_used(tmp_path, capsys):
    joints_dir = tmp_path / "mocap"
    joints_dir.mkdir()
    np.save(joints_dir / "good.npy", _clip())
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "keep.txt").write_text("my work")
    assert main(["data", "convert", "--joints", str(joints_dir), "--out", str(mine)]) == 2
    assert capsys.readouterr().err == (
        f"mogo: error: {mine}: exists and is not an empty "
        "folder; give a new --out (nothing is overwritten)\n"
    )
    assert [p.name for p in mine.iterdir()] == ["keep.txt"]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["data", "convert", "--joints", str(joints_dir), "--out", str(empty)]) == 0
    assert (empty / "Mean.npy").is_file()


def test_an_out_folder_that_cannot_be_made_is_one_line(tmp_path, capsys):
    joints_dir = tmp_path / "mocap"
    joints_dir.mkdir()
    np.save(joints_dir / "good.npy", _clip())
    (tmp_path / "file").write_text("x")
    assert (
        main(
            [
                "data",
                "convert",
                "--joints",
                str(joints_dir),
                "--out",
                str(tmp_path / "file" / "out"),
            ]
        )
        == 2
    )
    assert capsys.readouterr().err.startswith(
        f"mogo: error: {tmp_path / 'file' / 'out'}: cannot create it"
    )


# -- motion capture: BVH and DeepMimic files (issue 21) ----------------------------------------
DEEPMIMIC_STANDING = (
    [1 / 30, 0, 0.85, 0] + [1, 0, 0, 0] * 3 + ([1, 0, 0, 0, -0.2] + [1, 0, 0, 0] * 2 + [0.3]) * 2
)


def test_convert_reads_bvh_and_deepmimic_files_and_says_what_it_found(tmp_path, capsys):
    clips = tmp_path / "mocap"
    clips.mkdir()
    joints = travelling_clip(np.random.default_rng(4), frames=121)
    save_bvh(
        clips / "walk.bvh",
        resample(joints, 20.0, 60.0),
        SMPL_22,
        60.0,
        scale=100,
        bone_translations=True,
    )
    (clips / "walk.txt").write_text("a person walks.#a/DET person/NOUN walk/VERB#0.0#0.0\n")
    frames = [list(DEEPMIMIC_STANDING) for _ in range(31)]
    for t, frame in enumerate(frames):
        frame[1] = 0.04 * t  # drifts forward along +X
    (clips / "stand.txt").write_text(json.dumps({"Loop": "none", "Frames": frames}))
    out = tmp_path / "out"
    assert main(["data", "convert", "--joints", str(clips), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"walk.bvh: BVH, (SMPL|Mixamo) naming, centimetres, Y up, 60 fps", printed)
    assert "stand.txt: DeepMimic humanoid, metres, Y up, 30 fps" in printed
    assert np.load(out / "new_joints" / "walk.npy").shape == (121, 22, 3)  # back at 20 fps
    assert np.load(out / "new_joints" / "stand.npy").shape == (21, 22, 3)
    assert sorted(p.name for p in (out / "texts").iterdir()) == ["walk.txt"]


def test_convert_refuses_an_unmappable_bvh_in_one_line(tmp_path, capsys):
    clips = tmp_path / "mocap"
    clips.mkdir()
    (clips / "odd.bvh").write_text(
        "HIERARCHY\nROOT Body\n{\n OFFSET 0 0 0\n CHANNELS 3 Zrotation "
        "Xrotation Yrotation\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n"
        "0 0 0\n"
    )
    assert main(["data", "convert", "--joints", str(clips), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "odd.bvh: cannot map its skeleton onto the 22 joints" in err
    (tmp_path / "map.json").write_text('{"pelvis": 1}')
    assert (
        main(
            [
                "data",
                "convert",
                "--joints",
                str(clips),
                "--out",
                str(tmp_path / "o"),
                "--map",
                str(tmp_path / "map.json"),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert err.startswith("mogo: error: ") and "map.json: pelvis: expected a joint name" in err
    assert not (tmp_path / "o").exists()


SLOW_CONVERT = """
import sys, time
from mogo.export.data import convert
from mogo.cli import main

convert_clip = convert._convert_clip

def slow(*args):
    convert_clip(*args)
    print("converted", file=sys.stderr, flush=True)
    time.sleep(30)
convert._convert_clip = slow
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGHUP"])
def test_sigterm_while_converting_leaves_no_partial_folder(tmp_path, signal_name):
    """Old: SIGTERM left `.OUT.partial-*` behind for ever (only Ctrl-C cleaned up)."""
    import signal
    import subprocess
    import sys

    (tmp_path / "in").mkdir()
    np.save(tmp_path / "in" / "a.npy", _clip())
    script = tmp_path / "slow.py"
    script.write_text(SLOW_CONVERT)
    process = subprocess.Popen(
        [
            sys.executable,
            str(script),
            "data",
            "convert",
            "--joints",
            str(tmp_path / "in"),
            "--out",
            str(tmp_path / "out"),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    while "converted" not in process.stderr.readline():
        assert process.poll() is None, process.stderr.read()
    assert [p.name.startswith(".out.partial-") for p in tmp_path.iterdir()].count(True) == 1
    number = getattr(signal, signal_name)
    process.send_signal(number)
    _, error = process.communicate(timeout=60)
    assert process.returncode == 128 + number and "Traceback" not in error, error
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in", "slow.py"]
