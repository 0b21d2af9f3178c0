"""The text-to-motion metrics of Guo et al. (2022), in numpy only, on evaluator embeddings.

Every paper in the field reports these on the same protocol (docs/evaluation.md):
Euclidean distances between embeddings; R-precision in shuffled batches of 32 (each caption
ranks its own motion among the batch's 32, the 31 others being distractors); MM-Dist the mean
distance of matched caption and motion; FID the Frechet distance of the two embedding
Gaussians; Diversity the mean distance of 300 random pairs of motions; MultiModality the mean
distance of 10 random pairs among the generations of one caption. Each is repeated (20 times)
and reported as mean and 95% interval, 1.96 * std / sqrt(times).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

R_PRECISION_BATCH = 32
DIVERSITY_PAIRS = 300
MULTIMODALITY_PAIRS = 10
REPEATS = 20


def _symmetric_sqrt(matrix: np.ndarray) -> np.ndarray:
    """The square root of a symmetric positive semi-definite matrix, by eigen-decomposition
    (tiny negative eigenvalues from rounding are clipped to zero)."""
    values, vectors = np.linalg.eigh(matrix)
    return (vectors * np.sqrt(np.clip(values, 0, None))) @ vectors.T


def fid(real: np.ndarray, fake: np.ndarray) -> float:
    """Frechet distance between Gaussians fitted to two sets of embeddings (N, D):
    |mu_r - mu_f|^2 + tr(S_r + S_f - 2 (S_r S_f)^1/2).

    tr((S_r S_f)^1/2) is computed as tr((A S_f A)^1/2) with A = S_r^1/2: the same eigenvalues,
    but a symmetric matrix, so no complex square root (and no scipy) is needed."""
    real, fake = _checked(real, "real"), _checked(fake, "fake")
    if real.shape[1] != fake.shape[1]:
        raise ValueError(f"embedding sizes differ: {real.shape[1]} and {fake.shape[1]}")
    mu_r, mu_f = real.mean(0), fake.mean(0)
    cov_r, cov_f = np.cov(real, rowvar=False), np.cov(fake, rowvar=False)
    root_r = _symmetric_sqrt(cov_r)
    cross = np.trace(_symmetric_sqrt(root_r @ cov_f @ root_r))
    distance = np.sum((mu_r - mu_f) ** 2) + np.trace(cov_r) + np.trace(cov_f) - 2 * cross
    return max(0.0, float(distance))  # rounding can leave -1e-12 for identical sets


def pairwise_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distances (N, M) between the rows of a (N, D) and b (M, D)."""
    squared = (a * a).sum(1)[:, None] - 2 * a @ b.T + (b * b).sum(1)[None, :]
    return np.sqrt(np.clip(squared, 0, None))


def r_precision(
    text: np.ndarray,
    motion: np.ndarray,
    rng: np.random.Generator,
    batch: int = R_PRECISION_BATCH,
    top_k: int = 3,
) -> np.ndarray:
    """Top-1..top_k retrieval rates (top_k,): the pairs (text[i], motion[i]) are shuffled and cut
    into batches of `batch` (a last partial batch is dropped, as the standard loaders do); each
    caption ranks the batch's motions by distance and hits at k when its own is among the k
    nearest (ties counted against it). Chance is k / batch."""
    text, motion = _checked_pair(text, motion)
    if len(text) < batch:
        raise ValueError(f"R-precision needs at least one batch of {batch} pairs, got {len(text)}")
    order = rng.permutation(len(text))
    hits, count = np.zeros(top_k), 0
    for first in range(0, len(order) - batch + 1, batch):
        rows = order[first : first + batch]
        distances = pairwise_distances(text[rows], motion[rows])
        own = np.diag(distances)[:, None]
        rank = (distances <= own).sum(1) - 1  # others at least as near as the own motion
        hits += (rank[:, None] < np.arange(1, top_k + 1)[None, :]).sum(0)
        count += batch
    return hits / count


def matching_score(text: np.ndarray, motion: np.ndarray) -> float:
    """MM-Dist: the mean Euclidean distance between each caption and its own motion."""
    text, motion = _checked_pair(text, motion)
    return float(np.linalg.norm(text - motion, axis=1).mean())


def diversity(
    embeddings: np.ndarray, rng: np.random.Generator, pairs: int = DIVERSITY_PAIRS
) -> float:
    """Mean distance between `pairs` random pairs of motions (two independent draws of indices
    without replacement, as in the reference code)."""
    embeddings = _checked(embeddings, "embeddings")
    if len(embeddings) < pairs:
        raise ValueError(
            f"diversity over {pairs} pairs needs at least {pairs} motions, got {len(embeddings)}"
        )
    first = rng.choice(len(embeddings), pairs, replace=False)
    second = rng.choice(len(embeddings), pairs, replace=False)
    return float(np.linalg.norm(embeddings[first] - embeddings[second], axis=1).mean())


def multimodality(
    embeddings: np.ndarray, rng: np.random.Generator, pairs: int = MULTIMODALITY_PAIRS
) -> float:
    """embeddings (N captions, R generations, D): the mean distance of `pairs` random pairs of
    generations of the same caption, averaged over captions."""
    embeddings = np.asarray(embeddings, np.float64)
    if embeddings.ndim != 3 or embeddings.shape[1] < pairs:
        raise ValueError(
            f"multimodality needs (captions, generations >= {pairs}, D) "
            f"embeddings, got shape {embeddings.shape}"
        )
    n, r = embeddings.shape[:2]
    first = np.stack([rng.choice(r, pairs, replace=False) for _ in range(n)])
    second = np.stack([rng.choice(r, pairs, replace=False) for _ in range(n)])
    rows = np.arange(n)[:, None]
    return float(np.linalg.norm(embeddings[rows, first] - embeddings[rows, second], axis=-1).mean())


def repeat_with_interval(
    fn: Callable[[int], float | np.ndarray], times: int = REPEATS
) -> tuple[np.ndarray, np.ndarray]:
    """fn(repeat index) -> a value (or an array of values); -> (mean, 95% interval) over
    `times` repeats, the interval 1.96 * std / sqrt(times) (population std, as the reference
    code's np.std)."""
    if times < 1:
        raise ValueError(f"times must be at least 1, got {times}")
    values = np.array([np.asarray(fn(k), np.float64) for k in range(times)])
    return values.mean(0), 1.96 * values.std(0) / np.sqrt(times)


def _checked(x: np.ndarray, name: str) -> np.ndarray:
    x = np.asarray(x, np.float64)
    if x.ndim != 2 or len(x) < 2:
        raise ValueError(f"{name}: expected embeddings (N >= 2, D), got shape {x.shape}")
    return x


def _checked_pair(text: np.ndarray, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    text, motion = _checked(text, "text"), _checked(motion, "motion")
    if text.shape != motion.shape:
        raise ValueError(
            f"text and motion embeddings differ in shape: {text.shape} and {motion.shape}"
        )
    return text, motion
