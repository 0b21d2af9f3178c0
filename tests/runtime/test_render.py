import numpy as np
import pytest
from PIL import Image

from mogo.cli import main
from mogo.motion.render import render_frames, save_gif
from mogo.motion.skeleton import KIT_21, SMPL_22

from helpers import travelling_clip


@pytest.mark.parametrize("skeleton", [SMPL_22, KIT_21])
def test_gif_has_one_frame_per_frame(tmp_path, skeleton):
    joints = travelling_clip(np.random.default_rng(0), skeleton, frames=30, turn_degrees=90)
    path = save_gif(joints, tmp_path / "clip.gif", caption="a person walks in a curve")
    with Image.open(path) as gif:
        assert gif.n_frames == 30 and gif.size == (320, 320)
        assert gif.info["duration"] == pytest.approx(1000 / skeleton.fps, abs=10)
        colours = {c for _, c in gif.convert("RGB").getcolors(1 << 16)}
    assert (38, 110, 200) in colours and (214, 68, 48) in colours  # left and right limbs


def test_render_rejects_bad_joints():
    with pytest.raises(ValueError, match="cannot infer a skeleton for 17 joints"):
        render_frames(np.zeros((5, 17, 3)))
    with pytest.raises(ValueError, match=r"joints must be \(T, J, 3\)"):
        render_frames(np.zeros((5, 22)))
    joints = np.zeros((5, 22, 3))
    joints[2, 3, 1] = np.inf
    with pytest.raises(ValueError, match="NaN or infinite"):
        render_frames(joints)


def test_data_show_writes_gif(tiny_humanml3d, tmp_path, capsys):
    gif = tmp_path / "out" / "000004.gif"
    assert main(["data", "show", "000004", "--data", str(tiny_humanml3d), "--gif", str(gif)]) == 0
    with Image.open(gif) as image:
        assert image.n_frames == 52  # one frame per feature row
    assert main(["data", "show", "999", "--data", str(tiny_humanml3d), "--gif", str(gif)]) == 2
    assert "no such clip '999'" in capsys.readouterr().err
    assert main(["data", "show", "000004", "--data", str(tmp_path), "--gif", str(gif)]) == 2
    assert "new_joint_vecs: folder missing" in capsys.readouterr().err
