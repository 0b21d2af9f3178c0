"""What every `mogo bench` measurement shares: its settings, the interleaved timer, the log."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Settings:
    threads: tuple[int, ...] = (1, 2)
    lengths: tuple[int, ...] = (1, 10, 50, 100, 200)  # KV cache lengths of the step tables
    long_steps: int = 10_000
    rounds: int = 15  # timed rounds per point (fewer where one call is slow)
    round_budget_s: float = 20.0  # a point stops adding rounds past this (3 at least)
    clip_repeats: int = 5
    sizes: tuple[str, ...] = ("bundle", "paper")


SMOKE = Settings(
    lengths=(1, 8), long_steps=300, rounds=3, round_budget_s=2.0, clip_repeats=2, sizes=("tiny",)
)


def interleaved(
    calls: dict[str, Callable[[], object]], rounds: int, budget_s: float, warmup: int = 1
) -> dict[str, float]:
    """Median seconds of each call, the calls timed one after another in every round, the
    order rotating; stops adding rounds once `budget_s` is spent (after 3 rounds at least)."""
    for call in calls.values():
        for _ in range(warmup):
            call()
    names = list(calls)
    times: dict[str, list[float]] = {name: [] for name in names}
    spent, done = 0.0, 0
    while done < rounds and (done < 3 or spent < budget_s):
        for name in names[done % len(names) :] + names[: done % len(names)]:
            start = time.perf_counter()
            calls[name]()
            elapsed = time.perf_counter() - start
            times[name].append(elapsed)
            spent += elapsed
        done += 1
    return {name: float(np.median(values)) for name, values in times.items()}


def log(message: str) -> None:
    print(f"bench: {message}", file=sys.stderr, flush=True)
