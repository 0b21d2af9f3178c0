"""bench/training/train_cost: the FLOPs it counts scale with the batch, as the estimate of the
GPU recipe assumes, and a step costs what its model's size says."""

import pytest

from mogo.bench.training.train_cost import measure

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_flops_of_a_step_are_linear_in_the_batch():
    one, _ = measure("vq", 1)
    two, seconds = measure("vq", 2)
    assert two == pytest.approx(2 * one, rel=0.02) and seconds > 0
    # forward and backward of a 2.7M-parameter convolution stack over 64 frames: about
    # 6 x parameters x frames, within a factor of a few
    assert 1e8 < one < 1e11
