import weakref

import numpy as np
import pytest
from PIL import Image, ImageFont

from helpers import travelling_clip
from mogo.cli import main
from mogo.motion.render import _wrap, iter_frames, render_frames, save_gif, write_gif
from mogo.motion.skeleton import KIT_21, SMPL_22


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


def test_the_streamed_gif_holds_every_frame_and_only_a_few_at_a_time(tmp_path):
    joints = travelling_clip(np.random.default_rng(1), SMPL_22, frames=300, turn_degrees=90)
    drawn = render_frames(joints, "a person walks")
    alive = []

    def images():  # each image yielded is dropped by the writer before long
        for image in iter_frames(joints, "a person walks"):
            alive[:] = [ref for ref in alive if ref() is not None]
            assert len(alive) <= 3
            alive.append(weakref.ref(image))
            yield image

    with open(tmp_path / "clip.gif", "wb") as file:
        write_gif(file, images(), duration_ms=50.0)
    with Image.open(tmp_path / "clip.gif") as gif:
        assert gif.n_frames == 300 and gif.info["loop"] == 0 and gif.info["duration"] == 50
        for t in (0, 1, 150, 299):
            gif.seek(t)
            assert np.array_equal(
                np.asarray(gif.convert("RGB")), np.asarray(drawn[t].convert("RGB"))
            )


@pytest.mark.parametrize(
    "caption, cut", [("walk " * 4000, True), ("w" * 20000, True), (" \n" * 10000 + "jump", False)]
)
def test_a_caption_of_any_length_wraps_into_three_lines_that_fit(caption, cut):
    font = ImageFont.load_default(size=13)
    lines = _wrap(caption, font, 304, max_lines=3)
    assert 1 <= len(lines) <= 3 and all(font.getlength(line) <= 304 for line in lines)
    assert lines[-1].endswith("...") == cut  # 20,000 characters: once quadratic, now instant
    assert _wrap("a person walks forward", font, 304, 3) == ["a person walks forward"]
