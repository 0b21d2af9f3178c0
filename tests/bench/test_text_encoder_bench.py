"""The text-side benchmark's timing runs on the shipped bundle (its tables need the corpus);
its pass rate's seeds and options, and how it judges the caption a prompt is played as, on
stand-ins."""

from types import SimpleNamespace

import numpy as np

from mogo.bench.quality.semantic import SemanticItem
from mogo.bench.quality.text_encoder import encoder_ms, known_captions, pass_rate, played_rates
from mogo.generator import MotionGenerator


def test_the_encoder_timing_encodes_each_prompt():
    generator = MotionGenerator.load()
    assert encoder_ms(generator, ["someone tiptoes along the hall", "a dancer curtsies"]) > 0
    assert generator.text._encoded.cache_info().currsize >= 2  # each really went through


class _Recorder:
    """Stands in for a MotionGenerator: records each call and stands the body still."""

    fps = 20.0

    def __init__(self):
        self.calls = []

    def generate(self, prompt, seconds, seed, align, **sampling):
        self.calls.append((prompt, seed, sampling))
        return type("Motion", (), dict(joints=np.zeros((round(seconds * self.fps), 22, 3))))()


def test_pass_rate_draws_distinct_seeds_per_item_and_passes_the_sampling_options():
    items = [
        SemanticItem("a", "someone stands still.", "idle", dict(seconds=2.0), 0, 40),
        SemanticItem("b", "someone waves.", "wave", dict(hand="right", count=2), 0, 40),
    ]
    generator = _Recorder()
    rate, per = pass_rate(
        generator, items, ["stand", "wave"], [None, None], False, seeds=3, guidance=2.0
    )
    assert [(p, s) for p, s, _ in generator.calls] == [
        ("stand", 0),
        ("stand", 2),
        ("stand", 4),
        ("wave", 1),
        ("wave", 3),
        ("wave", 5),
    ]
    assert all(sampling == dict(guidance=2.0) for *_, sampling in generator.calls)
    # a body standing still is idle, and waves no hand
    assert per == dict(idle=[3, 3], wave=[0, 3]) and rate == 0.5


def test_the_caption_played_is_judged_by_the_segment_it_covers():
    train = [
        SemanticItem("a", "a person claps four times.", "clap", dict(count=4), 0, 40),
        SemanticItem(
            "b", "a person walks to the left.", "walk", dict(direction="left", speed="slow"), 0, 40
        ),
    ]
    known = known_captions(train)
    assert known == {
        "a person claps four times": ("clap", ("count", 4)),
        "a person walks to the left": ("walk", ("direction", "left")),
    }
    played = {
        "applauds twice": "a person claps four times",  # its action, another count
        "saunters left": "a person walks to the left",  # both
        "a person walks to the left.": None,  # played as written: not counted
        "waves twice": "a person claps twice, then waves",
    }  # several actions: neither
    generator = SimpleNamespace(known=lambda prompt: SimpleNamespace(played=played[prompt]))
    items = [
        SemanticItem("t", "", "clap", dict(count=2), 0, 40),
        SemanticItem("t", "", "walk", dict(direction="left", speed="fast"), 0, 40),
        SemanticItem("t", "", "walk", dict(direction="left"), 0, 40),
        SemanticItem("t", "", "wave", dict(hand="both", count=2), 0, 40),
    ]
    n, action, both = played_rates(generator, items, list(played), known)
    assert (n, action, both) == (3, 2 / 3, 1 / 3)
