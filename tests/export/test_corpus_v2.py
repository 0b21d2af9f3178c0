"""Corpus v2: its new primitives animate validly, their captions say the action, the corpus is
the same from the same seed, and steps vary as a person's do."""

import json

import numpy as np
import pytest

from mogo.export.data.animator import CORPORA, Segment, animate, sample_segment
from mogo.export.data.captions import caption_segment
from mogo.export.data.corpus import synthesize_corpus
from mogo.motion.skeleton import MAX_FRAMES, MIN_FRAMES, SMPL_22

NEW = tuple(p for p in CORPORA["v2"] if p not in CORPORA["v1"])
# Words one of which every caption of the primitive says (train and held-out pools).
SAYS = {
    "crouch_walk": ("crouch", "low"),
    "tiptoe": ("tiptoe", "toes", "balls of"),
    "march": ("march", "high knees"),
    "limp": ("limp", "hurt", "hobbl"),
    "skip": ("skip",),
    "carry": ("carr", "holding", "load"),
    "stumble": ("stumbl", "footing", "stagger"),
    "hop": ("hop", "bounc"),
    "step_up": ("step", "stair"),
    "crawl": ("crawl", "all fours"),
    "lie_down": ("lie", "back", "reclin"),
    "pick_up": ("pick", "lift"),
    "push": ("push", "shove", "press"),
    "pull": ("pull", "heav"),
    "throw": ("throw", "hurl"),
    "point": ("point", "indicat"),
    "look_around": ("look", "glanc", "survey"),
    "shrug": ("shrug",),
    "salute": ("salut",),
    "dance": ("danc", "groov"),
    "uppercut": ("uppercut", "upward"),
    "duck": ("duck",),
}


def test_v2_has_at_least_36_primitives_and_keeps_v1():
    assert len(CORPORA["v2"]) >= 36 and set(CORPORA["v1"]) < set(CORPORA["v2"])
    assert set(SAYS) == set(NEW)


@pytest.mark.parametrize("primitive", NEW)
def test_every_new_primitive_animates_validly(primitive):
    rng = np.random.default_rng(7)
    for _ in range(4):
        segments = [sample_segment(primitive, rng), sample_segment(primitive, rng)]
        animation = animate(segments, rng, natural=True)
        joints = animation.joints
        assert joints.dtype == np.float32 and joints.shape[1:] == (22, 3)
        assert np.all(np.isfinite(joints))
        assert animation.spans[-1][1] == len(joints)
        joints = joints.astype(np.float64)
        bones = np.linalg.norm(joints[:, 1:] - joints[:, SMPL_22.parents[1:]], axis=-1)
        assert np.ptp(bones, axis=0).max() < 1e-4
        assert abs(joints[:, [7, 8, 10, 11], 1].min()) < 0.03 and joints[..., 1].min() > -0.01
        # Every segment moves the body; none is a still frame.
        for start, end in animation.spans:
            assert np.ptp(joints[start:end], axis=0).max() > 0.1


@pytest.mark.parametrize("primitive", NEW)
@pytest.mark.parametrize("pool", ["train", "heldout"])
def test_captions_say_the_action(primitive, pool):
    rng = np.random.default_rng(8)
    for _ in range(60):
        text = caption_segment(sample_segment(primitive, rng), rng, pool).text
        assert any(word in text for word in SAYS[primitive]), text


def test_captions_say_the_side():
    rng = np.random.default_rng(9)
    for _ in range(30):
        for primitive in ("hop", "throw", "uppercut", "limp", "salute"):
            segment = sample_segment(primitive, rng)
            side = segment.params.get("hand") or segment.params.get("foot")
            text = caption_segment(segment, rng).text
            assert side in text or not {"left", "right"} & set(text.split()), text


def test_natural_steps_vary_and_v1_steps_do_not():
    """In v2 no two strides of a walk are alike; v1's are clockwork."""
    walk = Segment("walk", {"direction": "forward", "speed": "normal", "steps": 10, "turn": 0})

    def strides(natural: bool) -> np.ndarray:
        ankle = animate([walk], np.random.default_rng(3), natural).joints[:, 7].astype(float)
        planted = ankle[:, 1] < ankle[:, 1].min() + 0.002
        starts = np.flatnonzero(np.diff(planted.astype(int)) == 1) + 1
        ends = np.flatnonzero(np.diff(planted.astype(int)) == -1) + 1
        spots = [
            ankle[s:e, [0, 2]].mean(0) for s, e in zip(starts, ends[ends > starts[0]], strict=False)
        ]
        return np.linalg.norm(np.diff(spots, axis=0), axis=-1)[:-1]  # the last one closes

    assert np.ptp(strides(False)) < 0.002
    natural = strides(True)
    assert len(natural) >= 2 and np.ptp(natural) > 0.01


def test_v2_corpus_is_the_same_from_its_seed(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    summary = synthesize_corpus(a, 12, 4, progress=False, workers=1, corpus="v2")
    synthesize_corpus(b, 12, 4, progress=False, workers=2, corpus="v2")
    assert summary["corpus"] == "v2" and summary["primitives"] == len(CORPORA["v2"])
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for name in files:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    for path in (a / "programs").iterdir():
        program = json.loads(path.read_text())
        assert all(s["primitive"] in CORPORA["v2"] for s in program["segments"])
        assert MIN_FRAMES <= program["frames"] <= MAX_FRAMES
    with pytest.raises(ValueError, match="v3"):
        synthesize_corpus(tmp_path / "c", 1, 0, progress=False, corpus="v3")
