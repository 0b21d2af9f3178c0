import json
from pathlib import Path

import numpy as np
import pytest

from mogo.export.data.animator import CORPORA, Segment
from mogo.export.data.caption_templates import JOINERS, TEMPLATES
from mogo.export.data.corpus import heldout_pairs, mirror_segment, synthesize_corpus
from mogo.export.data.humanml3d import parse_caption_line
from mogo.motion.features import features_to_joints
from mogo.motion.mirror import mirror_joints, mirror_text
from mogo.motion.skeleton import MAX_FRAMES, MIN_FRAMES, SMPL_22

CLIPS = 24
SEED = 3


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "corpus"
    synthesize_corpus(out, CLIPS, SEED, progress=False, workers=1)
    return out


def _ids(corpus: Path, split: str) -> list[str]:
    return (corpus / f"{split}.txt").read_text().split()


def _program(corpus: Path, clip_id: str) -> dict:
    return json.loads((corpus / "programs" / f"{clip_id}.json").read_text())


def test_layout_is_complete(corpus):
    ids = [i for split in ("train", "val", "test") for i in _ids(corpus, split)]
    originals = [f"{k:06d}" for k in range(CLIPS)]
    assert sorted(ids) == sorted(originals + ["M" + i for i in originals])
    for sub, suffix in (
        ("new_joint_vecs", ".npy"),
        ("new_joints", ".npy"),
        ("texts", ".txt"),
        ("programs", ".json"),
    ):
        assert sorted(p.name for p in (corpus / sub).iterdir()) == sorted(i + suffix for i in ids)
    summary = json.loads((corpus / "corpus.json").read_text())
    assert summary["clips"] == CLIPS and summary["seed"] == SEED
    assert sum(summary["ids_per_split"].values()) == 2 * CLIPS
    assert np.load(corpus / "Mean.npy").shape == (263,)
    assert np.load(corpus / "Std.npy").min() >= summary["std_floor"]


def test_features_recover_the_canonical_joints(corpus):
    for clip_id in ("000000", "M000000", "000005", "M000017"):
        features = np.load(corpus / "new_joint_vecs" / f"{clip_id}.npy")
        joints = np.load(corpus / "new_joints" / f"{clip_id}.npy")
        assert features.dtype == np.float32 and joints.dtype == np.float32
        assert MIN_FRAMES <= joints.shape[0] <= MAX_FRAMES
        assert joints.shape[1:] == (22, 3) and features.shape == (joints.shape[0] - 1, 263)
        assert _program(corpus, clip_id)["frames"] == joints.shape[0]
        np.testing.assert_allclose(features_to_joints(features), joints[:-1], atol=1e-4)


def test_caption_lines_parse_and_match_the_program(corpus):
    for path in sorted((corpus / "texts").iterdir()):
        program = _program(corpus, path.stem)
        lines = path.read_text().splitlines()
        assert len(lines) == len(program["captions"])
        assert len(lines) == (3 if len(program["segments"]) == 1 else 2 + len(program["segments"]))
        for k, (line, caption) in enumerate(zip(lines, program["captions"], strict=False)):
            parsed = parse_caption_line(line, 20.0, f"{path}:{k + 1}")
            assert parsed.text == caption["text"] and parsed.text.endswith(".")
            if caption["span"] is None:
                assert (parsed.start_frame, parsed.end_frame) == (0, None)
            else:
                assert [parsed.start_frame, parsed.end_frame] == caption["span"]
        spans = [s["span"] for s in program["segments"]]
        assert spans[0][0] == 0 and spans[-1][1] <= program["frames"]
        assert all(a[1] == b[0] for a, b in zip(spans[:-1], spans[1:], strict=False))


def test_mirrored_copies(corpus):
    for clip_id in ("000000", "000001", "000002"):
        original, mirror = _program(corpus, clip_id), _program(corpus, "M" + clip_id)
        assert mirror["mirror_of"] == clip_id and mirror["split"] == original["split"]
        joints = np.load(corpus / "new_joints" / f"{clip_id}.npy")
        mirrored = np.load(corpus / "new_joints" / f"M{clip_id}.npy")
        np.testing.assert_allclose(mirror_joints(joints, SMPL_22), mirrored, atol=1e-4)
        texts = (corpus / "texts" / f"{clip_id}.txt").read_text().splitlines()
        assert (corpus / "texts" / f"M{clip_id}.txt").read_text().splitlines() == [
            mirror_text(line) for line in texts
        ]
        for a, b in zip(original["segments"], mirror["segments"], strict=False):
            assert mirror_segment(Segment(a["primitive"], a["params"])).params == b["params"]


def test_mirror_segment_swaps_sides_and_turns():
    assert mirror_segment(
        Segment("walk", {"direction": "left", "speed": "fast", "steps": 4, "turn": 90})
    ).params == {"direction": "right", "speed": "fast", "steps": 4, "turn": -90}
    assert mirror_segment(Segment("punch", {"hand": "right", "count": 2})).params == {
        "hand": "left",
        "count": 2,
    }
    assert mirror_segment(Segment("turn", {"angle": -45})).params == {"angle": 45}


def test_heldout_pairs_and_templates_stay_out_of_train_and_val(corpus):
    summary = json.loads((corpus / "corpus.json").read_text())
    pairs = {tuple(p) for p in summary["heldout_pairs"]}
    assert pairs == set(heldout_pairs(SEED)) and pairs != set(heldout_pairs(SEED + 1))
    heldout_ids = set(summary["heldout_templates"])
    assert heldout_ids == {t.id for name in CORPORA["v1"] for t in TEMPLATES[name] if t.heldout} | {
        j.id for j in JOINERS if j.heldout
    }
    for split in ("train", "val"):
        for clip_id in _ids(corpus, split):
            program = _program(corpus, clip_id)
            names = [s["primitive"] for s in program["segments"]]
            assert not set(zip(names[:-1], names[1:], strict=False)) & pairs
            assert program["caption_pool"] == "train"
            assert not {i for c in program["captions"] for i in c["template_ids"]} & heldout_ids


def test_same_seed_same_files_whatever_the_workers(corpus, tmp_path):
    again = tmp_path / "again"
    synthesize_corpus(again, CLIPS, SEED, progress=False, workers=2)
    files = sorted(p.relative_to(corpus) for p in corpus.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for name in files:
        assert (corpus / name).read_bytes() == (again / name).read_bytes(), name


def test_refuses_a_folder_in_use(corpus):
    with pytest.raises(ValueError, match="not empty"):
        synthesize_corpus(corpus, CLIPS, SEED, progress=False, workers=1)
