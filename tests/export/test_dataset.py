import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from helpers import CLIP_FRAMES
from mogo.export.data.humanml3d import Caption, DatasetError, HumanML3DFolder, parse_caption_line
from mogo.export.train.datasets import (
    MotionCropDataset,
    TextMotionDataset,
    WholeClipBatches,
    collate_text_motion,
)
from mogo.motion.skeleton import KIT_21, SMPL_22


def test_folder_loads_layout(tiny_humanml3d):
    folder = HumanML3DFolder(tiny_humanml3d)
    assert folder.skeleton is SMPL_22 and folder.feature_dim == 263 and folder.fps == 20.0
    assert folder.ids("train") == [f"{k:06d}" for k in range(8)]
    assert folder.ids("test") == ["000010", "000011"]
    features = folder.features("000003")
    assert features.shape == (CLIP_FRAMES[3], 263) and features.dtype == np.float32
    with pytest.raises(ValueError, match="unknown split 'dev'"):
        folder.ids("dev")
    with pytest.raises(DatasetError, match="no such clip 'nope'"):
        folder.features("nope")


def test_kit_folder_uses_kit_skeleton_and_fps(tiny_humanml3d):
    for path in [
        tiny_humanml3d / "Mean.npy",
        tiny_humanml3d / "Std.npy",
        *(tiny_humanml3d / "new_joint_vecs").glob("*.npy"),
    ]:
        np.save(path, np.load(path)[..., :251])
    folder = HumanML3DFolder(tiny_humanml3d)
    assert folder.skeleton is KIT_21 and folder.feature_dim == 251
    wave = folder.captions("000000")[1]  # 0.5-2.5 s at 12.5 fps
    assert (wave.start_frame, wave.end_frame) == (6, 31)


def test_captions_and_spans(tiny_humanml3d):
    captions = HumanML3DFolder(tiny_humanml3d).captions("000000")
    assert captions[0] == Caption(
        "a person walks forward.",
        (("a", "DET"), ("person", "NOUN"), ("walk", "VERB"), ("forward", "ADV")),
        0,
        None,
    )
    assert (captions[1].start_frame, captions[1].end_frame) == (10, 50)
    assert captions[2].tokens == () and captions[2].end_frame is None  # nan#nan: whole clip


def test_parse_caption_line_edge_cases():
    kit = parse_caption_line("a man turns.#a/DET man/NOUN turn/VERB#1.0#3.0", 12.5, "x:1")
    assert (kit.start_frame, kit.end_frame) == (12, 37)
    assert parse_caption_line("odd#x/X#nan#2.0", 20, "x:1").end_frame == 40
    for bad, message in [
        ("no fields at all", "expected 'caption#"),
        ("a#a/DET#zero#1.0", "start time 'zero' is not a number"),
        ("a#a/DET#-1.0#1.0", "start time '-1.0' is not a time"),
        ("a#aDET#0.0#0.0", "token 'aDET' is not word/POS"),
    ]:
        with pytest.raises(DatasetError, match=f"^t.txt:4: {message}"):
            parse_caption_line(bad, 20, "t.txt:4")


def test_normalize_round_trip(tiny_humanml3d):
    folder = HumanML3DFolder(tiny_humanml3d)
    x = folder.features("000001")
    z = folder.normalize(x)
    np.testing.assert_allclose(folder.denormalize(z), x, atol=1e-5)
    boosted = HumanML3DFolder(tiny_humanml3d, root_contact_scale=5.0)
    np.testing.assert_allclose(boosted.std[:4] * 5, folder.std[:4])
    np.testing.assert_allclose(boosted.std[-4:] * 5, folder.std[-4:])
    np.testing.assert_array_equal(boosted.std[4:-4], folder.std[4:-4])
    with pytest.raises(ValueError, match="expected 263-dim features"):
        folder.normalize(np.zeros((3, 251)))


def test_motion_crops_are_seeded_per_epoch(tiny_humanml3d, capsys):
    folder = HumanML3DFolder(tiny_humanml3d)
    crops = MotionCropDataset(folder, "train", crop_frames=50, seed=3)
    assert len(crops) == 4 and crops.num_skipped == 4  # 40, 43, 46, 49 rows < 50
    assert "skipped 4 of 8 clips shorter than 50 frames" in capsys.readouterr().out
    batch = next(iter(DataLoader(crops, batch_size=4)))
    assert batch.shape == (4, 50, 263) and batch.dtype == torch.float32
    again = MotionCropDataset(folder, "train", crop_frames=50, seed=3)
    assert all(torch.equal(crops[i], again[i]) for i in range(4))
    first = [crops[i] for i in range(4)]
    crops.set_epoch(1)
    assert not all(torch.equal(a, crops[i]) for i, a in enumerate(first))
    clip = folder.normalize(folder.features("000007"))  # 61 rows: the crop is a window of it
    windows = [clip[s : s + 50] for s in range(12)]
    assert any(np.allclose(crops[3].numpy(), w) for w in windows)


def test_whole_clip_batches_hold_every_clip_once_an_epoch(tiny_humanml3d):
    folder = HumanML3DFolder(tiny_humanml3d)
    for length in (CLIP_FRAMES[1], CLIP_FRAMES[2]):  # two more train clips of each of two lengths
        for copy in ("a", "b"):
            np.save(
                tiny_humanml3d / "new_joint_vecs" / f"{length}{copy}.npy",
                folder.features("000007")[:length],
            )
    ids = [f"{k:06d}" for k in range(8)] + [f"{n}{c}" for n in CLIP_FRAMES[1:3] for c in "ab"]
    (tiny_humanml3d / "train.txt").write_text("".join(i + "\n" for i in ids))
    folder = HumanML3DFolder(tiny_humanml3d)
    batches = WholeClipBatches(folder, "train", batch_size=2, seed=5, down_factor=2)
    assert len(batches) == 10  # 8 lengths (cut to even); 3 clips of 42 and of 46: 2 batches each

    def epoch(dataset, n):
        dataset.set_epoch(n)
        return [dataset[i] for i in range(len(dataset))]

    first = epoch(batches, 0)
    assert all(1 <= len(b) <= 2 and b.shape[1] % 2 == 0 for b in first)
    rows = torch.cat([b.reshape(-1, b.shape[-1]) for b in first])
    expected = [folder.normalize(folder.features(i)) for i in ids]
    expected = np.concatenate([x[: len(x) - len(x) % 2] for x in expected])
    assert sorted(map(tuple, rows.numpy().round(5))) == sorted(map(tuple, expected.round(5)))
    again = WholeClipBatches(folder, "train", batch_size=2, seed=5, down_factor=2)
    assert all(torch.equal(a, b) for a, b in zip(first, epoch(again, 0), strict=False))
    assert any(
        not all(torch.equal(a, b) for a, b in zip(first, epoch(batches, n), strict=False))
        for n in range(1, 6)
    )  # which of 3 clips goes alone changes with the epoch


def test_text_motion_cuts_caption_spans(tiny_humanml3d, capsys):
    folder = HumanML3DFolder(tiny_humanml3d)
    data = TextMotionDataset(folder, "train", min_frames=40, max_frames=196)
    # 8 whole clips + 3 NaN (whole) captions + the 0.5-2.5 s spans of the 52- and 58-row clips.
    assert len(data) == 13 and data.num_short == 3
    assert "skipped 3 shorter than 40 frames" in capsys.readouterr().out
    waves = [item for item in data if item["caption"] == "the person waves."]
    assert [w["id"] for w in waves] == ["000004", "000006"]
    expected = folder.normalize(folder.features("000004"))[10:50]
    np.testing.assert_allclose(waves[0]["motion"].numpy(), expected)
    assert waves[0]["length"] == 40

    cropped = TextMotionDataset(folder, "train", min_frames=40, max_frames=45)
    assert max(item["length"] for item in cropped) == 45
    assert {item["motion"].shape[0] for item in cropped} <= set(range(40, 46))


def test_text_motion_skips_clips_without_texts(tiny_humanml3d):
    (tiny_humanml3d / "texts" / "000000.txt").unlink()
    data = TextMotionDataset(HumanML3DFolder(tiny_humanml3d), "train")
    assert data.num_uncaptioned == 1 and "000000" not in data.ids


def test_collate_pads_and_masks(tiny_humanml3d):
    data = TextMotionDataset(HumanML3DFolder(tiny_humanml3d), "train")
    batch = collate_text_motion([data[0], data[12], data[5]])
    lengths = [data[0]["length"], data[12]["length"], data[5]["length"]]
    assert batch["motion"].shape == (3, max(lengths), 263)
    assert batch["lengths"].tolist() == lengths
    assert batch["mask"].sum(1).tolist() == lengths
    for row, n in enumerate(lengths):
        assert not batch["mask"][row, n:].any()
        assert torch.all(batch["motion"][row, n:] == 0)
    assert batch["captions"][0] == data[0]["caption"] and batch["ids"][1] == data[12]["id"]


def _break(root, problem):
    if problem == "missing Std.npy":
        (root / "Std.npy").unlink()
        return "Std.npy: file missing"
    if problem == "wrong Mean shape":
        np.save(root / "Mean.npy", np.zeros(100, dtype=np.float32))
        return "Mean.npy: no skeleton has 100-dim features"
    if problem == "Std shape":
        np.save(root / "Std.npy", np.ones(251, dtype=np.float32))
        return r"Std.npy: shape \(251,\) does not match"
    if problem == "zero Std":
        np.save(root / "Std.npy", np.zeros(263, dtype=np.float32))
        return "Std.npy: 263 entries are zero or negative"
    if problem == "split ID without file":
        (root / "val.txt").write_text("000008\n000099\n")
        return "val.txt: 1 listed IDs have no new_joint_vecs/ID.npy: 000099"
    if problem == "missing split":
        (root / "test.txt").unlink()
        return "test.txt: split file missing"
    if problem == "missing texts folder":
        for f in (root / "texts").iterdir():
            f.unlink()
        (root / "texts").rmdir()
        return "texts: folder missing"
    raise AssertionError(problem)


@pytest.mark.parametrize(
    "problem",
    [
        "missing Std.npy",
        "wrong Mean shape",
        "Std shape",
        "zero Std",
        "split ID without file",
        "missing split",
        "missing texts folder",
    ],
)
def test_broken_layout_fails_up_front(tiny_humanml3d, problem):
    message = _break(tiny_humanml3d, problem)
    with pytest.raises(DatasetError, match=message):
        HumanML3DFolder(tiny_humanml3d)


def test_broken_clips_and_texts_name_the_file(tiny_humanml3d):
    bad = np.load(tiny_humanml3d / "new_joint_vecs" / "000002.npy")
    bad[5, 7] = np.nan
    np.save(tiny_humanml3d / "new_joint_vecs" / "000002.npy", bad)
    np.save(tiny_humanml3d / "new_joint_vecs" / "000009.npy", np.zeros((50, 251), np.float32))
    with (tiny_humanml3d / "texts" / "000011.txt").open("a") as f:
        f.write("a person jumps#a/DET person/NOUN#0.0\n")
    (tiny_humanml3d / "val.txt").write_text("")
    folder = HumanML3DFolder(tiny_humanml3d)
    with pytest.raises(DatasetError, match=r"000002\.npy: holds NaN or infinite values"):
        MotionCropDataset(folder, "train", crop_frames=40)
    with pytest.raises(DatasetError, match=r"000009\.npy: expected \(T, 263\) features"):
        folder.features("000009")
    with pytest.raises(DatasetError, match=r"000011\.txt:2: expected 'caption#word/POS"):
        TextMotionDataset(folder, "test")
    with pytest.raises(DatasetError, match=r"val\.txt: lists no clip IDs"):
        folder.ids("val")
    with pytest.raises(DatasetError, match="dataset folder not found"):
        HumanML3DFolder(tiny_humanml3d / "nope")
