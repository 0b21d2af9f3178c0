"""Hostile motion, mapping and array files: every size bounded before anything is allocated,
each problem one line naming the file, never a hang, a traceback nor numpy's own words
(issue 39; docs/security.md)."""

import json
import os
import struct
import subprocess
import sys

import numpy as np
import pytest

from helpers import travelling_clip
from mogo import Motion
from mogo.motion.deepmimic import _LAYOUT
from mogo.motion.mocap import read_bvh, read_mocap
from mogo.motion.rigs import read_mapping
from mogo.motion.skeleton import SMPL_22
from mogo.motion.untrusted import read_npy


@pytest.fixture
def bvh_text(tmp_path):
    """A BVH as `mogo generate` writes it, of 20 frames at 20 fps."""
    joints = travelling_clip(np.random.default_rng(0), SMPL_22, frames=20).astype(np.float32)
    clip = Motion(
        features=np.zeros((20, 263), np.float32),
        joints=joints,
        fps=20.0,
        tokens=np.zeros((5, 6), np.int64),
        skeleton=SMPL_22,
    )
    return clip.save_bvh(tmp_path / "walk.bvh").read_text()


def first_value(text, value):
    """The BVH with its first motion value replaced."""
    head, values = text.split("Frame Time: 0.05000000\n")
    return f"{head}Frame Time: 0.05000000\n{value} {values.split(' ', 1)[1]}"


def edited(text, old, new):
    assert old in text
    return text.replace(old, new, 1)


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda t: edited(t, "CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS -2"),
            r"CHANNELS must be followed by a count, got '-2'",
        ),
        (
            lambda t: edited(
                t,
                "CHANNELS 3 Zrotation Xrotation Yrotation",
                "CHANNELS 3 Zrotation Zrotation Yrotation",
            ),
            "from 1 to 6 different channels",
        ),
        (
            lambda t: edited(t, "Frame Time: 0.05000000", "Frame Time: 100000"),
            r"20 frames at 1e-05 fps \(2e\+06 s\); clips read in are at most 3600 s",
        ),
        (
            lambda t: edited(t, "Frame Time: 0.05000000", "Frame Time: 1e-300"),
            "Frame Time: must be at least 0.0001 s",
        ),
        (
            lambda t: (
                "\n".join(
                    line for line in t.split("MOTION")[0].splitlines() if "CHANNELS" not in line
                )
                + "\nMOTION\nFrames: 100000000\n"
                "Frame Time: 0.05\n"
            ),
            "no joint has CHANNELS",
        ),
        (lambda t: edited(t, "Frames: 20", "Frames: 100000000"), "100000000 frames at 20 fps"),
        (
            lambda t: edited(t, "Frames: 20", "Frames: " + "9" * 5000),
            "Frames: must be followed by a count, got '99999",
        ),
        (
            lambda t: edited(
                t,
                "End Site\n          {\n",
                "End Site\n          {\n CHANNELS 3 Xrotation Yrotation Zrotation\n",
            ),
            "CHANNELS in an End Site",
        ),
        (
            lambda t: edited(t, "OFFSET 0.000000 0.880122 0.000000", "OFFSET 0 nan 0"),
            "'nan': values must be finite numbers",
        ),
        (lambda t: first_value(t, "1.7e308"), "coordinates up to 1.7e"),
        (lambda t: first_value(t, "zz"), "'zz' is not a number"),
        (lambda t: edited(t, "JOINT LeftUpLeg\n  {", "JOINT LeftUpLeg\n"), "not a readable BVH"),
    ],
)
def test_a_hostile_bvh_is_one_line_naming_it(tmp_path, bvh_text, edit, message):
    path = tmp_path / "bad.bvh"
    path.write_text(edit(bvh_text))
    with _no_warnings():
        with pytest.raises(ValueError, match=message) as error:
            read_mocap(path)
    assert str(error.value).startswith(f"{path}: ") and "\n" not in str(error.value)


class _no_warnings:
    """Fails on any warning (numpy's RuntimeWarning included) inside the block."""

    def __enter__(self):
        import warnings

        self._catch = warnings.catch_warnings()
        self._catch.__enter__()
        warnings.simplefilter("error")

    def __exit__(self, *exc):
        self._catch.__exit__(*exc)


def test_an_end_site_never_changes_its_joints_channels(tmp_path, bvh_text):
    """Old: CHANNELS inside an End Site replaced the channels of the joint two back."""
    text = edited(bvh_text, "End Site\n          {\n", "End Site\n          {\n CHANNELS 0\n")
    (tmp_path / "x.bvh").write_text(text)
    with pytest.raises(ValueError, match="CHANNELS in an End Site"):
        read_bvh(tmp_path / "x.bvh")


def deepmimic(path, frames=3, duration=0.05, **changes):
    """A DeepMimic file of a person standing still."""
    row = [duration, 0, 0.9, 0, 1, 0, 0, 0]
    for _, width in _LAYOUT:
        row += [1, 0, 0, 0] if width == 4 else [0.0]
    rows = [row] * frames
    document = {"Loop": "none", "Frames": rows} | changes
    path.write_text(json.dumps(document))
    return path


@pytest.mark.parametrize(
    "write, message",
    [
        (lambda p: deepmimic(p, duration=1e9), r"3 frames at 1e-09 fps"),
        (
            lambda p: deepmimic(p, Frames=[[0.1] + [0.0] * 43] * 2),
            r"NaN or infinite values \(numbers too large",
        ),
        (
            lambda p: p.write_text('{"Frames": ' + "[" * 100_000 + "]" * 100_000 + "}"),
            "JSON nested too deeply",
        ),
        (
            lambda p: p.write_text('{"Frames": [[' + "1" * 5000 + "]]}"),
            "a number in the JSON is too long to read",
        ),
        (
            lambda p: p.write_text('{"Frames": [[' + "1" * 400 + "," + "0," * 42 + "0]]}"),
            "at least 2 rows of 44 numbers",
        ),
        (lambda p: deepmimic(p, Frames=[[0.1] * 44, [0.1] * 43]), "at least 2 rows of 44 numbers"),
        (lambda p: deepmimic(p, Frames=[[0.1] * 44, [0.1] * 43 + [[1]]]), "rows of 44 numbers"),
        (
            lambda p: deepmimic(p, Frames=[[10**400] + [0.1] * 43] * 2),
            "holds NaN or infinite values",
        ),
        (lambda p: deepmimic(p, Frames=[[0.1, 1e300] + [1] * 42] * 2), "coordinates up to 1e"),
    ],
)
def test_a_hostile_deepmimic_file_is_one_line_naming_it(tmp_path, write, message):
    path = tmp_path / "clip.txt"
    write(path)
    with _no_warnings():
        with pytest.raises(ValueError, match=message) as error:
            read_mocap(path)
    assert str(error.value).startswith(f"{path}: ") and "\n" not in str(error.value)


@pytest.mark.parametrize(
    "text, message",
    [
        ("[" * 100_000 + "]" * 100_000, "JSON nested too deeply"),
        ('{"pelvis": ' + "9" * 5000 + "}", "too long to read"),
        ('{"pelvis": [["Hips"], "Spine", 0.5]}', r"pelvis: expected a joint name or \[name"),
        ('{"pelvis": ["Hips", "Spine", 1e999]}', r"pelvis: expected a joint name"),
        ('{"pelvis": ["Hips", "Spine", true]}', r"pelvis: expected a joint name"),
    ],
)
def test_a_hostile_mapping_file_is_one_line_naming_it(tmp_path, text, message):
    path = tmp_path / "map.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as error:
        read_mapping(path)
    assert str(error.value).startswith(f"{path}: ") and "\n" not in str(error.value)


def npy_claiming(path, shape, dtype="<f8", payload=b"\0" * 1000):
    header = f"{{'descr': '{dtype}', 'fortran_order': False, 'shape': {shape}, }}"
    header += " " * ((64 - (10 + len(header) + 1) % 64) % 64) + "\n"
    path.write_bytes(
        b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + payload
    )
    return path


def test_a_npy_header_is_checked_against_the_file_before_allocating(tmp_path):
    path = npy_claiming(tmp_path / "clip.npy", (10**12, 22, 3))
    with pytest.raises(
        ValueError,
        match=r"its header claims an array of shape \(1000000000000, "
        r"22, 3\) \(528000000000000 bytes\), the file holds 1000",
    ):
        read_npy(path)
    np.save(tmp_path / "objects.npy", np.array([{}, []], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError) as error:
        read_npy(tmp_path / "objects.npy")
    assert "holds Python objects" in str(error.value) and "allow_pickle" not in str(error.value)
    with pytest.raises(ValueError, match="not a plain .npy array"):
        read_npy(npy_claiming(tmp_path / "odd.npy", "(" + "9" * 5000 + ",)"))
    np.save(tmp_path / "fine.npy", np.arange(6.0).reshape(2, 3))
    np.testing.assert_array_equal(read_npy(tmp_path / "fine.npy"), np.arange(6.0).reshape(2, 3))


def test_devices_and_fifos_are_refused_not_read_for_ever(tmp_path):
    os.mkfifo(tmp_path / "clip.bvh")
    for path in (tmp_path / "clip.bvh", "/dev/zero"):
        with pytest.raises(ValueError, match="not a regular file"):
            read_mocap(path)
        with pytest.raises(ValueError, match="not a regular file"):
            read_npy(path)


def convert(tmp_path, *extra):
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "mogo",
            "data",
            "convert",
            "--joints",
            str(tmp_path / "in"),
            "--out",
            str(tmp_path / "out"),
            *extra,
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize(
    "name, write",
    [
        (
            "clip.bvh",
            lambda p, bvh: p.write_text(
                edited(bvh, "CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS -2")
            ),
        ),
        (
            "clip.bvh",
            lambda p, bvh: p.write_text(
                edited(bvh, "Frame Time: 0.05000000", "Frame Time: 100000")
            ),
        ),
        ("clip.npy", lambda p, bvh: npy_claiming(p, (10**12, 22, 3))),
        ("clip.txt", lambda p, bvh: deepmimic(p, duration=1e9)),
    ],
)
def test_data_convert_refuses_a_hostile_clip_in_one_line(tmp_path, bvh_text, name, write):
    """Old: CHANNELS -2 hung for ever, the others asked for GBs to TBs of memory."""
    (tmp_path / "in").mkdir()
    write(tmp_path / "in" / name, bvh_text)
    done = convert(tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith(f"mogo: error: {tmp_path / 'in' / name}: ")
    assert done.stderr.count("\n") == 1 and not (tmp_path / "out").exists()


def test_data_convert_with_a_deep_mapping_file_is_one_line(tmp_path, bvh_text):
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "clip.bvh").write_text(bvh_text)
    (tmp_path / "map.json").write_text("[" * 100_000 + "]" * 100_000)
    done = convert(tmp_path, "--map", str(tmp_path / "map.json"))
    assert (done.returncode, done.stderr) == (
        2,
        f"mogo: error: {tmp_path / 'map.json'}: JSON nested too deeply\n",
    )


def test_motion_from_file_bounds_a_long_clip(tmp_path):
    with pytest.raises(ValueError, match="clips read in are at most"):
        Motion.from_file(deepmimic(tmp_path / "long.txt", duration=7200))
