"""The text-side benchmark's timing runs on the shipped bundle (its tables need the corpus)."""
from mogo.bench.quality.text_encoder import encoder_ms
from mogo.generator import MotionGenerator


def test_the_encoder_timing_encodes_each_prompt():
    generator = MotionGenerator.load()
    assert encoder_ms(generator, ["someone tiptoes along the hall", "a dancer curtsies"]) > 0
    assert generator.text._encoded.cache_info().currsize >= 2  # each really went through

