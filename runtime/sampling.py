"""Token sampling, specified exactly so that every path picks the same tokens (numpy only).

The torch reference generator and the CPU runtime both call `choose_token`, so given the same
logits they pick the same token. For one level at one step, in float64:

    logits -> guidance: uncond + s * (cond - uncond)    (skipped when s == 1)
           -> forbidden class set to -inf               (the end token while a length is forced)
           -> temperature 0: argmax (first maximum); else divide by temperature
           -> sort descending, stable (ties: lower id first)
           -> top-k: keep the first k                   (0 = off)
           -> softmax: exp(z - max), cumulative sum c   (never normalised; c[-1] is the total)
           -> top-p: keep entries whose preceding mass c - p is < top_p * c[-1]   (1 = off)
           -> inverse CDF: the first kept entry with c > uniform * c[-1]   (uniform < 1, so
              uniform * c[-1] < c[-1] in float64 too: some kept entry always qualifies)

The options (checked by Sampling itself, so the API and the command refuse the same values):
temperature 0 or from 1e-6 on, top_k >= 0 (any k above the number of classes keeps them all),
top_p in (0, 1], guidance finite with |s| <= 1e6. These bounds keep every step above finite in
float64 for any float32 logits; s < 1 is applied as written (s = 0: the unconditional logits).

Uniforms come from numpy.random.Generator(PCG64(seed)): at the start of every step,
`rng.random(num_levels)`, drawn whether or not every level ends up sampled; level l uses
entry l. A greedy run draws them too, so the stream never depends on the settings.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from numbers import Integral, Real

import numpy as np

from mogo.arguments import number_text

MIN_TEMPERATURE = 1e-6  # below it (but above 0) logits / temperature can overflow float64
MAX_GUIDANCE = 1e6  # beyond it uncond + s * (cond - uncond) can


class SamplingError(ValueError):
    """A sampling option out of its range: `option` (the field's name) and `problem`, so the
    `mogo` command can name its own flag (--top-p) where the API names the field (top_p)."""

    def __init__(self, option: str, problem: str):
        super().__init__(f"{option} {problem}")
        self.option, self.problem = option, problem


@dataclass(frozen=True)
class Sampling:
    """How each token is drawn: the one definition of the sampling options. The `mogo`
    command's flags (--top-p ...), the keyword options of MotionGenerator.generate/stream/play
    and the "defaults" of a bundle's manifest all use these fields' names; adding an option
    means a field here and its use in `choose_tokens`."""

    # Each field's metadata: its help, and the limits __post_init__ holds it to (low, high;
    # None: no limit), which a form such as the Blender panel shows. top_p's low is open, and
    # a temperature above 0 starts at MIN_TEMPERATURE.
    temperature: float = field(
        default=1.0,
        metadata=dict(
            help="divides the logits; 0 = greedy (the likeliest token)", low=0.0, high=None
        ),
    )
    top_k: int = field(
        default=0, metadata=dict(help="keep the k likeliest tokens; 0 = off", low=0, high=None)
    )
    top_p: float = field(
        default=1.0,
        metadata=dict(
            help="keep the likeliest tokens that hold this share of the probability; 1 = off",
            low=0.0,
            high=1.0,
        ),
    )
    guidance: float = field(
        default=1.0,
        metadata=dict(
            help="classifier-free guidance scale; 1 = off (conditional logits only), above 1 "
            "follows the prompt more, below 1 less (0 = the unconditional logits)",
            low=-MAX_GUIDANCE,
            high=MAX_GUIDANCE,
        ),
    )

    def __post_init__(self):
        for option in fields(Sampling):  # its own, not those of a subclass (manifest.Defaults)
            _store_number(self, option.name, type(option.default))
        for name in ("temperature", "top_p", "guidance"):
            if not math.isfinite(getattr(self, name)):
                raise SamplingError(name, f"must be finite, got {getattr(self, name)}")
        if self.temperature < 0:
            raise SamplingError("temperature", f"must be >= 0 (0 = greedy), got {self.temperature}")
        if 0 < self.temperature < MIN_TEMPERATURE:
            raise SamplingError(
                "temperature",
                f"must be 0 (greedy) or at least {MIN_TEMPERATURE:g}, got {self.temperature:g}",
            )
        if self.top_k < 0:
            raise SamplingError("top_k", f"must be >= 0 (0 = off), got {number_text(self.top_k)}")
        if not 0 < self.top_p <= 1:
            raise SamplingError("top_p", f"must be in (0, 1] (1 = off), got {self.top_p}")
        if abs(self.guidance) > MAX_GUIDANCE:
            raise SamplingError(
                "guidance",
                f"must be between -{MAX_GUIDANCE:.0f} and "
                f"{MAX_GUIDANCE:.0f}, got {self.guidance:g}",
            )

    @property
    def guided(self) -> bool:
        """Whether the unconditional logits are needed."""
        return self.guidance != 1.0

    @classmethod
    def from_defaults(cls, defaults: Mapping[str, object]) -> Sampling:
        """A bundle's sampling: the manifest's "defaults" (which hold other keys too, such as
        window and max_seconds), the fields' own defaults where it names none."""
        names = {option.name for option in fields(cls)}
        return cls().updated({name: value for name, value in defaults.items() if name in names})

    def updated(self, options: Mapping[str, object]) -> Sampling:
        """These options over this sampling; None means not given."""
        known = [option.name for option in fields(self)]
        unknown = sorted(set(options) - set(known))
        if unknown:
            raise TypeError(
                f"unknown sampling option {unknown[0]!r}; the options are {', '.join(known)}"
            )
        return replace(
            self, **{name: value for name, value in options.items() if value is not None}
        )


def _store_number(sampling: Sampling, name: str, kind: type) -> None:
    """A field given as any number (numpy's too) stored as its own type, int or float; no
    text, no bool."""
    value = getattr(sampling, name)
    if isinstance(value, bool) or not isinstance(value, Integral if kind is int else Real):
        raise TypeError(
            f"{name} must be {'an integer' if kind is int else 'a number'}, got "
            f"{type(value).__name__}"
        )
    try:
        object.__setattr__(sampling, name, kind(value))
    except OverflowError:  # an int beyond float's range
        raise SamplingError(name, "must be finite, got a number beyond float's range") from None


def make_rng(seed: int) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(seed))


def step_uniforms(rng: np.random.Generator, num_levels: int) -> np.ndarray:
    """The uniforms of one time step, (num_levels,) float64 in [0, 1)."""
    return rng.random(num_levels)


def choose_token(
    cond: np.ndarray,
    uncond: np.ndarray | None,
    uniform: float,
    sampling: Sampling,
    forbid: int | None = None,
) -> int:
    """One token id from one level's logits (K,): see the module docstring for the exact rule."""
    rows = None if uncond is None else np.asarray(uncond)[None]
    return int(
        choose_tokens(
            np.asarray(cond)[None],
            rows,
            np.array([uniform]),
            sampling,
            None if forbid is None else [forbid],
        )[0]
    )


def choose_tokens(
    cond: np.ndarray,
    uncond: np.ndarray | None,
    uniforms: np.ndarray,
    sampling: Sampling,
    forbid: list[int | None] | None = None,
) -> np.ndarray:
    """`choose_token` for several rows at once (the levels of a step, padded with -inf to one
    width): row by row the same arithmetic, in a fixed number of numpy calls."""
    z = np.asarray(cond, dtype=np.float64)
    if sampling.guided:
        if uncond is None:
            raise ValueError(f"guidance {sampling.guidance} needs unconditional logits")
        u = np.asarray(uncond, dtype=np.float64)
        with np.errstate(invalid="ignore"):  # padding: -inf in both stays -inf
            z = np.where(np.isneginf(z) & np.isneginf(u), -np.inf, u + sampling.guidance * (z - u))
    rows = np.arange(len(z))
    if forbid is not None and any(f is not None for f in forbid):
        z = z.copy()
        for row, token in enumerate(forbid):
            if token is not None:
                z[row, token] = -np.inf
    if sampling.temperature == 0:
        return np.argmax(z, axis=1)
    z = z / sampling.temperature
    z_sorted = _descending(z)
    keep = np.count_nonzero(np.isfinite(z_sorted), axis=1)
    if sampling.top_k:
        keep = np.minimum(keep, min(sampling.top_k, z.shape[1]))
    inside = np.arange(z.shape[1])[None] < keep[:, None]
    p = np.where(inside, np.exp(z_sorted - z_sorted[:, :1]), 0.0)
    c = np.cumsum(p, axis=1)
    if sampling.top_p < 1:
        keep = np.count_nonzero(inside & (c - p < sampling.top_p * c[rows, keep - 1, None]), axis=1)
    total = c[rows, keep - 1]
    index = np.count_nonzero(c <= (uniforms * total)[:, None], axis=1)
    return _column(z, z_sorted[rows, index], index)


def _descending(z: np.ndarray) -> np.ndarray:
    """Each row sorted, largest first. Values alone: a sort without the column order costs
    ~1/2 of an argsort of 512 logits with numpy's SIMD sorts (~1/5 for many rows), and the
    one column wanted is found afterwards (`_column`)."""
    return -np.sort(-z, axis=1)


def _column(z: np.ndarray, value: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Per row, the column at position `index` of the row sorted descending with ties lower
    id first, whose value is `value` (finite): among the columns equal to it, the one of rank
    index - (the number of larger values)."""
    equal = z == value[:, None]
    rank = index - np.count_nonzero(z > value[:, None], axis=1)
    if not rank.any():  # no row took a second entry of a tie: the first equal column
        return np.argmax(equal, axis=1)
    return np.argmax(np.cumsum(equal, axis=1) > rank[:, None], axis=1)
