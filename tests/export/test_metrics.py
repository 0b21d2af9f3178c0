import numpy as np
import pytest

from mogo.export.data import metrics


def gaussian(rng, n, mean, std):
    """n samples whose sample mean and (ddof=1) covariance are exactly `mean` and diag(std^2)."""
    x = rng.normal(size=(n, len(mean)))
    x -= x.mean(0)
    x = x @ np.linalg.inv(np.linalg.cholesky(np.cov(x, rowvar=False))).T
    return x * std + mean


def test_fid_known_answers():
    rng = np.random.default_rng(0)
    d = 8
    a = gaussian(rng, 500, np.zeros(d), np.ones(d))
    assert metrics.fid(a, a) == pytest.approx(0, abs=1e-9)
    shift = np.arange(d) / 4
    b = gaussian(rng, 700, shift, np.ones(d))
    assert metrics.fid(a, b) == pytest.approx(np.sum(shift**2), abs=1e-8)
    s1, s2 = np.linspace(0.5, 2, d), np.linspace(3, 1, d)
    c, e = gaussian(rng, 600, np.zeros(d), s1), gaussian(rng, 600, np.ones(d), s2)
    assert metrics.fid(c, e) == pytest.approx(d + np.sum((s1 - s2) ** 2), abs=1e-8)
    assert metrics.fid(c, e) == pytest.approx(metrics.fid(e, c), abs=1e-8)


def test_fid_full_covariance_matches_the_closed_form():
    """A non-diagonal case against tr(S1 + S2 - 2 (S1 S2)^1/2) from the eigenvalues of S1 S2."""
    rng = np.random.default_rng(1)
    a = rng.normal(size=(400, 5)) @ rng.normal(size=(5, 5))
    b = rng.normal(size=(400, 5)) @ rng.normal(size=(5, 5)) + 1
    s1, s2 = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
    cross = np.sum(np.sqrt(np.linalg.eigvals(s1 @ s2).real.clip(0)))
    expected = np.sum((a.mean(0) - b.mean(0)) ** 2) + np.trace(s1 + s2) - 2 * cross
    assert metrics.fid(a, b) == pytest.approx(expected, rel=1e-8)


def test_r_precision_perfect_and_chance():
    rng = np.random.default_rng(0)
    one_hot = np.eye(64)
    assert np.allclose(metrics.r_precision(one_hot, one_hot, rng), [1, 1, 1])
    assert np.allclose(metrics.r_precision(one_hot, 0.9 * one_hot, rng), [1, 1, 1])
    text, motion = rng.normal(size=(32 * 400, 16)), rng.normal(size=(32 * 400, 16))
    assert np.allclose(metrics.r_precision(text, motion, rng), [1 / 32, 2 / 32, 3 / 32], atol=0.006)


def test_r_precision_counts_ranks_within_the_batch():
    """One batch of 64 pairs on a line: captions 10 i see a decoy motion (10 i + 0.5) nearer
    than their own (10 i + 1), so rank 2; the decoys' own captions sit on them, so rank 1."""
    base = 10 * np.arange(32.0)[:, None]
    text = np.concatenate([base, base + 0.5])
    motion = np.concatenate([base + 1, base + 0.5])
    ranked = metrics.r_precision(text, motion, np.random.default_rng(0), batch=64)
    assert np.allclose(ranked, [0.5, 1, 1])


def test_matching_score_diversity_multimodality_known_points():
    text = np.zeros((4, 3))
    motion = np.array([[3.0, 4, 0], [0, 0, 5], [1, 0, 0], [0, 2, 0]])
    assert metrics.matching_score(text, motion) == pytest.approx((5 + 5 + 1 + 2) / 4)
    square = np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]] * 100) * 2
    rng = np.random.default_rng(0)
    value = metrics.diversity(square, rng)
    # pairs of corners of a 2 x 2 square: distances 0, 2, 2, 2 sqrt 2 equally likely
    assert value == pytest.approx((0 + 2 + 2 + 2 * np.sqrt(2)) / 4, abs=0.15)
    assert metrics.diversity(np.full((300, 2), 7.0), rng) == 0
    same = np.repeat(rng.normal(size=(5, 1, 4)), 30, axis=1)
    assert metrics.multimodality(same, rng) == 0
    two = np.zeros((3, 30, 2))
    two[:, 15:, 0] = 1  # half the generations at 0, half at 1: distance 1 half of the time
    assert metrics.multimodality(two, rng) == pytest.approx(0.5, abs=0.15)


def test_repeat_with_interval():
    mean, interval = metrics.repeat_with_interval(lambda k: float(k % 2), times=20)
    assert mean == pytest.approx(0.5) and interval == pytest.approx(1.96 * 0.5 / np.sqrt(20))
    mean, interval = metrics.repeat_with_interval(lambda k: np.array([1.0, k]), times=4)
    assert np.allclose(mean, [1, 1.5]) and interval[0] == 0


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: metrics.fid(np.zeros((5, 2)), np.zeros((5, 3))), "sizes differ"),
        (
            lambda: metrics.r_precision(np.eye(8), np.eye(8), np.random.default_rng(0)),
            "at least one batch",
        ),
        (lambda: metrics.diversity(np.zeros((10, 2)), np.random.default_rng(0)), "at least 300"),
        (
            lambda: metrics.multimodality(np.zeros((4, 5, 2)), np.random.default_rng(0)),
            "generations >= 10",
        ),
        (lambda: metrics.matching_score(np.zeros((4, 2)), np.zeros((3, 2))), "differ in shape"),
    ],
)
def test_bad_inputs(call, message):
    with pytest.raises(ValueError, match=message):
        call()
