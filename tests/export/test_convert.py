import numpy as np
import pytest

from mogo.cli import main
from mogo.export.data.convert import resample
from mogo.motion.features import features_to_joints

from helpers import travelling_clip


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
    assert "broken.npy" in err and "joints must be" in err
    assert main(["data", "convert", "--joints", str(tmp_path / "nope"), "--out", "x"]) == 2


def test_resample_keeps_duration_and_endpoints():
    clip = np.random.default_rng(1).normal(size=(61, 22, 3))  # 2 s at 30 fps
    out = resample(clip, 30.0, 20.0)
    assert out.shape == (41, 22, 3)
    np.testing.assert_allclose(out[0], clip[0])
    np.testing.assert_allclose(out[-1], clip[-1], atol=1e-9)
    with pytest.raises(ValueError, match="fps must be positive"):
        resample(clip, 0.0, 20.0)
