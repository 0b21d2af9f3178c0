"""`mogo bench real-motion` on a stand-in for pybullet's wheel: a zip in the cache folder holding two
small DeepMimic clips where the wheel keeps its motions (no download, no pybullet)."""

import json
import zipfile

import numpy as np
from PIL import Image

from mogo.bench.quality.real_motion import MOTIONS, deepmimic_clips, errors_mm
from mogo.cli import main

STANDING = (
    [1 / 30, 0, 0.85, 0] + [1, 0, 0, 0] * 3 + ([1, 0, 0, 0, -0.2] + [1, 0, 0, 0] * 2 + [0.3]) * 2
)


def _clip(frames: int, step: float) -> str:
    rows = [list(STANDING) for _ in range(frames)]
    for t, row in enumerate(rows):
        row[1] = step * t  # drifting forward
    return json.dumps({"Loop": "wrap", "Frames": rows})


def _fake_wheel(cache):
    cache.mkdir()
    with zipfile.ZipFile(cache / "pybullet-0.0-py3-none-any.whl", "w") as wheel:
        wheel.writestr(MOTIONS + "humanoid3d_walk.txt", _clip(40, 0.04))
        wheel.writestr(MOTIONS + "walker/turn_left0.txt", _clip(36, 0.02))
        wheel.writestr(MOTIONS + "laikago_walk.txt", "{}")  # a dog: not a humanoid clip
        wheel.writestr("pybullet_data/other.txt", "")


def test_the_clips_are_read_out_of_the_cached_wheel(tmp_path):
    _fake_wheel(tmp_path / "cache")
    clips = deepmimic_clips(tmp_path / "cache")
    assert [p.name for p in clips] == ["humanoid3d_walk.txt", "walker_turn_left0.txt"]


def test_the_error_splits_into_pose_and_trajectory():
    rng = np.random.default_rng(0)
    original = rng.normal(size=(10, 22, 3))
    moved = original + [0.3, 0, 0.4]  # the same pose, half a metre away
    assert np.allclose(errors_mm(original, moved), (500, 0, 500))
    bent = original.copy()
    bent[:, 5] += [0, 0.22, 0]  # one joint of 22 off by 22 cm, the root in place
    assert np.allclose(errors_mm(original, bent), (10, 10, 0))


def test_real_motion_writes_the_table_gifs_and_sheet(tmp_path, capsys):
    _fake_wheel(tmp_path / "cache")
    out = tmp_path / "out"
    assert (
        main(["bench", "real-motion", "--out", str(out), "--cache", str(tmp_path / "cache")]) == 0
    )
    printed = capsys.readouterr().out
    assert "| walk | 1.3 |" in printed and "| **median** of 2 |" in printed
    assert (out / "real_motion.md").read_text().startswith("| clip | seconds | MPJPE (mm) |")
    assert sorted(p.name for p in out.glob("*.gif")) == ["walk.gif", "walker_turn_left0.gif"]
    with Image.open(out / "contact_sheet.png") as sheet:
        assert sheet.height == 2 * 2 * 96
