"""The one reader of the HumanML3D layout (numpy only): what eval and `mogo data show` read,
and its refusal of a malformed folder with the file named."""

import numpy as np
import pytest

from helpers import CLIP_FRAMES
from mogo.export.data.humanml3d import DatasetError, HumanML3DFolder


def test_a_tool_reads_only_the_splits_it_needs(tiny_humanml3d):
    (tiny_humanml3d / "train.txt").unlink()
    folder = HumanML3DFolder(tiny_humanml3d, splits=("test",))
    assert folder.ids("test") == ["000010", "000011"]
    with pytest.raises(ValueError, match="unknown split 'train'; expected one of test"):
        folder.ids("train")
    with pytest.raises(DatasetError, match=r"train\.txt: split file missing"):
        HumanML3DFolder(tiny_humanml3d)
    shown = HumanML3DFolder(tiny_humanml3d, splits=())  # `mogo data show`: one clip, no split
    assert shown.features("000004").shape == (CLIP_FRAMES[4], 263)
    assert shown.first_caption("000004") == "a person walks forward."
    (tiny_humanml3d / "texts" / "000004.txt").unlink()
    assert shown.first_caption("000004") == ""


def test_caption_spans_are_cut_to_the_clip(tiny_humanml3d):
    folder = HumanML3DFolder(tiny_humanml3d)
    whole, wave, _ = folder.captions("000000")
    assert whole.span(40) == (0, 40) and wave.span(40) == (10, 40) and wave.span(60) == (10, 50)


@pytest.mark.parametrize(
    "problem, message",
    [
        (
            "empty folder",
            r"new_joint_vecs: folder missing .*texts: folder missing .*test\.txt: split",
        ),
        ("joints", r"new_joints[/\\]000010\.npy: expected \(T, 22, 3\) joints"),
        ("joints missing", r"new_joints[/\\]000011\.npy: file missing"),
        ("caption", r"texts[/\\]000010\.txt:2: token 'aDET' is not word/POS"),
        ("pickle", r"Mean\.npy: not a readable \.npy array"),
    ],
)
def test_a_malformed_file_is_named(tiny_humanml3d, tmp_path, problem, message):
    root = tiny_humanml3d
    (root / "new_joints").mkdir()
    np.save(root / "new_joints" / "000010.npy", np.zeros((CLIP_FRAMES[10], 21, 3), np.float32))
    (root / "texts" / "000010.txt").write_text(
        "a walk.#a/DET walk/NOUN#0.0#0.0\na jump.#aDET#0.0#0.0\n"
    )
    if problem == "empty folder":
        root = tmp_path / "empty"
        root.mkdir()
    if problem == "pickle":
        np.save(root / "Mean.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    reads = {
        "joints": lambda folder: folder.joints("000010"),
        "joints missing": lambda folder: folder.joints("000011"),
        "caption": lambda folder: folder.first_caption("000010"),
    }
    with pytest.raises(DatasetError, match=message):
        folder = HumanML3DFolder(root, splits=("test",))  # the layout's files: up front
        reads[problem](folder)  # a clip's files: when read
