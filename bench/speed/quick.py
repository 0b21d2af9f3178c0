"""`mogo bench quick`: what to expect on this machine, in under a minute, with the base install
(no torch). The CPU and the instruction sets that pick onnxruntime's kernels (the bundle's level
graphs are int8: VNNI does their multiply-adds in one instruction, plain AVX2 in several), then
the shipped bundle's time to first frame, a 9.8-s clip and one token step (the six level graphs
at batch 1 and the sampler), at 1 and 2 threads, beside the README's figures; and the first
frame of a low-latency stream where the bundle has that decoder.

    mogo bench quick [--bundle DIR] [--threads 1 2]
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

import onnxruntime

from mogo.bench.speed import avx2_only
from mogo.bench.speed.timing import interleaved, log
from mogo.generator import DEFAULT_BUNDLE, MotionGenerator
from mogo.motion.skeleton import MAX_FRAMES

PROMPT = "a person walks forward, then waves with the right hand."
# The README's Performance table: threads -> (time to first frame in ms, 9.8-s clip in s).
README = {1: (101.0, 0.523), 2: (101.0, 0.402)}
README_MACHINE = (
    "a 2-core Intel Xeon VM, Sapphire Rapids class (AVX2, AVX-512, AVX-512 VNNI, AMX), 2026-11-27"
)
# /proc/cpuinfo flag -> name: what onnxruntime's int8 and float kernels are chosen by.
FEATURES = {
    "avx2": "AVX2",
    "avx512f": "AVX-512",
    "avx512_vnni": "AVX-512 VNNI",
    "avx_vnni": "AVX-VNNI",
    "amx_int8": "AMX-INT8",
    "asimd": "NEON",
    "asimddp": "NEON dot product",
}
VNNI = {"avx512_vnni", "avx_vnni", "asimddp"}  # int8 dot products in one instruction
TOKEN_STEPS = 16  # token steps per timed call
ROUNDS, BUDGET_S = 7, 10.0  # a round past the budget only if fewer than 3 ran


def cpu() -> tuple[str, set[str] | None]:
    """The CPU's model name and its /proc/cpuinfo flags (None where there is no such file),
    less those `mogo bench avx2` hides where it runs this process."""
    try:
        with open("/proc/cpuinfo") as info:
            lines = [line.split(":", 1) for line in info if ":" in line]
    except OSError:
        return platform.processor() or platform.machine(), None
    fields = {}
    for key, value in lines:  # the first processor's
        fields.setdefault(key.strip(), value.strip())
    model = fields.get("model name") or fields.get("Model") or platform.machine()
    flags = set((fields.get("flags") or fields.get("Features") or "").split())
    if avx2_only.masked():
        return f"{model} (AVX-512, AVX-VNNI and AMX hidden)", {
            f for f in flags if not avx2_only.hidden(f)
        }
    return model, flags


def features_line(flags: set[str] | None) -> str:
    if flags is None:
        return "instruction sets unknown (no /proc/cpuinfo)"
    arm = "asimd" in flags
    names = [flag for flag in FEATURES if (flag.startswith("asimd")) == arm]
    return ", ".join(f"{FEATURES[flag]} {'yes' if flag in flags else 'no'}" for flag in names)


def time_to_first_frame(generator: MotionGenerator, seed: int, low_latency: bool = False) -> None:
    """A new stream up to its first frame (the prompt encoded, the decoder's and the feet's
    lookahead drawn, decoded); `low_latency`: decoded by the bundle's low-latency decoder."""
    stream = generator.stream(PROMPT, seed=seed, low_latency=low_latency)
    while not len(stream.step()):
        pass


def token_steps(generator: MotionGenerator):
    """A call that draws TOKEN_STEPS token steps of one stream (past its prefill, the bundle's
    window, never ending): the level graphs' share of every frame."""
    tokens = generator.tokens.start(
        generator.embed([PROMPT])[0],
        seed=0,
        sampling=generator.sampling(),
        window=generator.defaults.window,
        allow_end=False,
    )
    tokens.step()

    def run() -> None:
        for _ in range(TOKEN_STEPS):
            tokens.step()

    return run


def measure(bundle: Path, threads: tuple[int, ...]) -> dict[int, dict[str, float | None]]:
    """threads -> first_ms, clip_s, step_ms, low_latency_first_ms (None: the bundle has no
    such decoder): medians of interleaved rounds."""
    generators = {t: MotionGenerator.load(bundle, threads=t) for t in threads}
    seconds = MAX_FRAMES / next(iter(generators.values())).fps
    calls = {}
    for t, g in generators.items():
        calls[f"first {t}"] = lambda g=g: time_to_first_frame(g, seed=0)
        calls[f"clip {t}"] = lambda g=g: g.generate(PROMPT, seconds=seconds, seed=0)
        calls[f"step {t}"] = token_steps(g)
        if g.manifest.vq.low_latency_decoder is not None:
            calls[f"low {t}"] = lambda g=g: time_to_first_frame(g, seed=0, low_latency=True)
    log(f"first frame, a {seconds:g}-s clip and {TOKEN_STEPS} token steps, threads {threads}")
    medians = interleaved(calls, ROUNDS, BUDGET_S)
    return {
        t: dict(
            first_ms=1e3 * medians[f"first {t}"],
            low_latency_first_ms=1e3 * medians[f"low {t}"] if f"low {t}" in medians else None,
            clip_s=medians[f"clip {t}"],
            step_ms=1e3 * medians[f"step {t}"] / TOKEN_STEPS,
        )
        for t in threads
    }


def report(rows: dict[int, dict[str, float | None]], model: str, flags: set[str] | None) -> str:
    lines = [
        f"this machine: {model}, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}, onnxruntime {onnxruntime.__version__}",
        f"  {features_line(flags)}",
        f"README: {README_MACHINE}",
        "",
        "| threads | first frame, here / README | 9.8-s clip, here / README "
        "| token step (6 level graphs), here | first frame, low-latency decoder |",
        "|---:|---:|---:|---:|---:|",
    ]
    for t, row in rows.items():
        first, clip = README.get(t, (None, None))
        low = row["low_latency_first_ms"]
        lines.append(
            f"| {t} | {_beside(row['first_ms'], first, '{:.0f} ms')} | "
            f"{_beside(row['clip_s'], clip, '{:.3f} s')} | {row['step_ms']:.2f} ms | "
            f"{'-' if low is None else f'{low:.0f} ms'} |"
        )
    lines.append("")
    lines.append(
        f"Medians of {ROUNDS} interleaved rounds at most; other work on this machine slows them."
    )
    if flags is not None and not flags & VNNI:
        lines.append(
            "No VNNI here: the bundle's int8 level graphs run on slower integer "
            "kernels than on the README's kind of machine (docs/performance.md)."
        )
    return "\n".join(lines)


def _beside(here: float, readme: float | None, unit: str) -> str:
    """'62 ms / 51 ms (1.2x)': this machine's figure, the README's, how many times slower."""
    if readme is None:
        return f"{unit.format(here)} / -"
    return f"{unit.format(here)} / {unit.format(readme)} ({here / readme:.1f}x)"


def main(bundle: str | None, threads: list[int] | None) -> None:
    threads = tuple(threads) if threads else (1, 2) if (os.cpu_count() or 1) > 1 else (1,)
    if min(threads) < 1:
        raise ValueError("--threads takes numbers >= 1")
    model, flags = cpu()
    rows = measure(Path(bundle) if bundle else DEFAULT_BUNDLE, threads)
    print(report(rows, model, flags))
