"""`mogo bench latency`: how fast MOGO generates on this machine, against the torch reference, the
public prototype's method and the hardware floor. Markdown tables on stdout; bench.json and
PNG plots in --out.

Two parts:
1. The product: a bundle (default: the shipped one) through the runtime's public API at each
   thread count: time to first frame (text encoding, prefill, the steps of the decoder's
   lookahead and of foot planting's (mogo.motion.feet), two decodes), a 196-frame clip end to end and its real-time factor, the step time
   along a 10,000-step stream (sliding window), the peak memory of a process that only runs
   the runtime, and the size on disk.
2. The step (bench/speed/step.py), per model size (the bundle's config and the paper's, random
   weights: the cost does not depend on them; exported the way a bundle's level graphs are):
   one whole time step (every level, sampling included) against the KV cache length, for
   onnxruntime fp32 and int8, torch eager with the KV cache and torch eager recomputing the
   whole prefix at every step (the public prototype's method), at each thread count. The
   backends are timed round by round in turn, so the machine's own slow spells hit them alike.
   Each row has its floor: weight and cache bytes over the measured memory bandwidth, or FLOPs
   over the measured matrix FLOP/s, whichever is larger.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from mogo.bench.speed import machine
from mogo.bench.speed.plot import log_line_chart
from mogo.bench.speed.quick import PROMPT, time_to_first_frame
from mogo.bench.speed.step import CLIP_FRAMES, size_configs, step_table
from mogo.bench.speed.timing import SMOKE, Settings, interleaved, log
from mogo.bundle import Bundle
from mogo.generator import DEFAULT_BUNDLE, STREAM_DECODE_EVERY, MotionGenerator, MotionStream
from mogo.motion.skeleton import MAX_SECONDS

SPAN = 96  # steps averaged at each point of the long stream (a multiple of the decode burst)


# -- part 1: the product ---------------------------------------------------------------------------
def product(bundle_dir: Path, settings: Settings) -> dict:
    """Part 1 for one bundle: a dict of measurements, per thread count where it applies."""
    generators = {t: MotionGenerator.load(bundle_dir, threads=t) for t in settings.threads}
    seconds = CLIP_FRAMES / next(iter(generators.values())).fps
    log(f"time to first frame and {CLIP_FRAMES}-frame clips, threads {settings.threads}")
    calls = {}
    for t, g in generators.items():
        calls[f"ttff {t}"] = lambda g=g: time_to_first_frame(g, seed=0)
        calls[f"clip {t}"] = lambda g=g: g.generate(PROMPT, seconds=seconds, seed=0)
    medians = interleaved(calls, settings.clip_repeats, settings.round_budget_s)
    rows = {
        t: dict(
            ttff_ms=1e3 * medians[f"ttff {t}"],
            clip_s=medians[f"clip {t}"],
            real_time_factor=seconds / medians[f"clip {t}"],
        )
        for t in generators
    }
    log(f"a {settings.long_steps}-step stream per thread count, stepped in turn")
    streams = {t: g.stream(PROMPT, seed=1) for t, g in generators.items()}
    step_times = {t: np.zeros(settings.long_steps) for t in generators}
    for n in range(settings.long_steps):
        for t, stream in streams.items():
            start = time.perf_counter()
            stream.step()
            step_times[t][n] = time.perf_counter() - start
    points = long_stream_points(settings.long_steps)
    for t, g in generators.items():
        means = {n: span_ms(step_times[t][n : n + SPAN]) for n in points}
        rows[t].update(
            stream_step_ms=means,
            stream_flatness=old_over_fresh(streams[t], g.stream(PROMPT, seed=2)),
        )
    bundle = Bundle.load(bundle_dir)
    return dict(
        threads=rows,
        disk_mb=bundle.manifest.total_bytes / 1e6,
        peak_rss_mib=runtime_peak_rss(bundle_dir),
        clip_seconds=seconds,
        window=bundle.manifest.defaults.window,
        binned_step_ms={t: binned(step_times[t]) for t in generators},
    )


def span_ms(times: np.ndarray) -> float:
    """Milliseconds per step over a span: the median of its means over decode bursts (one
    decoder call every STREAM_DECODE_EVERY steps), so a stray slow step does not move it."""
    blocks = times[: len(times) - len(times) % STREAM_DECODE_EVERY]
    return 1e3 * float(np.median(blocks.reshape(-1, STREAM_DECODE_EVERY).mean(1)))


def old_over_fresh(old: MotionStream, fresh: MotionStream) -> float:
    """Step time of the long stream over that of a fresh one at step 10, the two stepped in
    turn for SPAN steps: the machine's own drift over the minutes the long stream ran (seen:
    +20% and more) hits both alike, so only the stream's age can show."""
    for _ in range(10):
        fresh.step()
    times = np.zeros((2, SPAN))
    for k in range(SPAN):
        for row, stream in enumerate((old, fresh)):
            start = time.perf_counter()
            stream.step()
            times[row, k] = time.perf_counter() - start
    return span_ms(times[0]) / span_ms(times[1])


def long_stream_points(steps: int) -> list[int]:
    """Where the long stream's step time is read: early (cache < window), then decades."""
    points = [0, 10] + [n for n in (100, 1000) if n + SPAN <= steps] + [steps - SPAN]
    return sorted(set(p for p in points if 0 <= p <= steps - SPAN))


def binned(times: np.ndarray, bins: int = 50) -> list[tuple[int, float]]:
    """(first step, mean ms) of equal bins of the stream, for the plot."""
    edges = np.linspace(0, len(times), bins + 1).astype(int)
    return [
        (int(a), 1e3 * float(times[a:b].mean()))
        for a, b in zip(edges[:-1], edges[1:], strict=False)
        if b > a
    ]


def runtime_peak_rss(bundle_dir: Path) -> float:
    """Peak RSS (MiB) of a fresh process that imports only the runtime, loads the bundle,
    generates a clip and streams 2,000 steps: what an application embedding it pays."""
    script = (
        "import sys\n"
        "from mogo.generator import MotionGenerator\n"
        "g = MotionGenerator.load(sys.argv[1])\n"
        f"g.generate({PROMPT!r}, seconds={MAX_SECONDS!r}, seed=0)\n"
        f"s = g.stream({PROMPT!r}, seed=0)\n"
        "for _ in range(2000): s.step()\n"
        "assert 'torch' not in sys.modules\n"
        "print(open('/proc/self/status').read() if sys.platform == 'linux' else '')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(bundle_dir)], capture_output=True, text=True, check=True
    )
    # VmHWM is this process's own peak; ru_maxrss would carry the parent's over exec
    peaks = [line.split()[1] for line in done.stdout.splitlines() if line.startswith("VmHWM")]
    return int(peaks[0]) / 1024 if peaks else float("nan")  # kB; Linux only


# -- output --------------------------------------------------------------------------------------
def product_markdown(result: dict) -> str:
    rows = result["threads"]
    points = list(next(iter(rows.values()))["stream_step_ms"])
    lines = [
        f"| threads | time to first frame (ms) | {CLIP_FRAMES}-frame clip (ms) | "
        "real-time factor | "
        + " | ".join(f"stream step {n}+ (ms)" for n in points)
        + " | last / step 10, in turn |",
        "|---:|---:|---:|---:|" + "---:|" * len(points) + "---:|",
    ]
    for t, row in rows.items():
        steps = " | ".join(f"{row['stream_step_ms'][n]:.2f}" for n in points)
        lines.append(
            f"| {t} | {row['ttff_ms']:.1f} | {1e3 * row['clip_s']:.1f} | "
            f"{row['real_time_factor']:.0f}x | {steps} | {row['stream_flatness']:.2f} |"
        )
    lines.append("")
    lines.append(
        f"Size on disk {result['disk_mb']:.1f} MB; peak RSS of a runtime-only process "
        f"(load, one clip, 2,000 stream steps) {result['peak_rss_mib']:.0f} MiB. "
        f"Stream steps: {SPAN} steps from each point, decoder bursts included, as "
        f"the stream ran (the machine's own drift included); the last column steps the "
        f"long stream and a fresh one at step 10 in turn. The sliding window holds "
        f"{result['window']} steps."
    )
    return "\n".join(lines)


def step_markdown(size: str, result: dict) -> str:
    lengths = list(next(iter(result["backends"].values()))["step_ms"])
    reference = max(lengths)
    head = (
        f"| {size} model: backend | "
        + " | ".join(f"cache {n} (ms)" for n in lengths)
        + f" | {CLIP_FRAMES}-step clip (s) | floor at {reference} (ms) | measured / floor |"
    )
    lines = [head, "|---|" + "---:|" * (len(lengths) + 3)]
    for name, row in result["backends"].items():
        cells = " | ".join(f"{row['step_ms'][n]:.2f}" for n in lengths)
        floor = row["floor_ms"][reference]
        lines.append(
            f"| {name} | {cells} | {row['clip_s']:.2f} | {floor:.2f} | "
            f"{row['step_ms'][reference] / floor:.1f} |"
        )
    c = result["config"]
    lines.append("")
    lines.append(
        f"{result['parameters'] / 1e6:.0f}M parameters (width {c['dim']}, layers "
        f"{c['layers']}, heads {c['heads']}); weights read per step: "
        + ", ".join(f"{k} {v:.0f} MB" for k, v in result["weight_mb"].items())
        + "."
    )
    return "\n".join(lines)


def speedups(result: dict, threads: tuple[int, ...]) -> list[str]:
    """The issue's ratios, per thread count: best onnxruntime vs torch cached, per step at the
    longest cache, and per clip vs recomputation."""
    rows, lines = result["backends"], []
    reference = max(next(iter(rows.values()))["step_ms"])
    for t in threads:
        ort_rows = {
            n: r for n, r in rows.items() if n.startswith("onnxruntime") and r["threads"] == t
        }
        best = min(ort_rows, key=lambda n: ort_rows[n]["step_ms"][reference])
        plural = "s" * (t > 1)
        cached = rows[f"torch eager + KV cache, {t} thread{plural}"]
        recompute = rows[f"torch eager, recompute, {t} thread{plural}"]
        lines.append(
            f"{t} thread{plural}: best onnxruntime ({best}) "
            f"{cached['step_ms'][reference] / ort_rows[best]['step_ms'][reference]:.1f}x "
            f"faster per step than torch eager with the cache (cache {reference}), "
            f"{recompute['clip_s'] / ort_rows[best]['clip_s']:.0f}x faster per clip "
            "than recomputing the prefix"
        )
    return lines


def write_plots(out: Path, report: dict) -> list[Path]:
    paths = []
    for size, result in report["steps"].items():
        path = out / f"step_vs_cache_{size}.png"
        series = {
            name: [(max(n, 1), ms) for n, ms in row["step_ms"].items()]
            for name, row in result["backends"].items()
        }
        log_line_chart(
            path, f"one time step, {size} model", "KV cache length (slots)", "ms per step", series
        )
        paths.append(path)
    path = out / "long_stream.png"
    series = {
        f"{t} thread{'s' * (int(t) > 1)}": [(max(n, 1), ms) for n, ms in values]
        for t, values in report["product"]["binned_step_ms"].items()
    }
    log_line_chart(
        path, "stream step time along a long stream (bundle)", "step", "ms per step", series
    )
    return paths + [path]


# -- command ------------------------------------------------------------------------------------
def run(bundle_dir: Path, out: Path, work: Path, settings: Settings) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    report: dict = dict(machine=machine.describe(), settings=asdict(settings), steps={})
    log("memory bandwidth and matrix FLOP/s")
    bandwidth = {t: machine.read_bandwidth(t) for t in settings.threads}
    flops = {t: machine.matmul_flops(t) for t in settings.threads}
    report["floors"] = dict(
        read_gb_per_s={t: b / 1e9 for t, b in bandwidth.items()},
        matmul_gflop_per_s={t: f / 1e9 for t, f in flops.items()},
    )
    report["product"] = product(bundle_dir, settings)
    configs = size_configs(bundle_dir)
    for size in settings.sizes:
        report["steps"][size] = step_table(size, configs[size], work, settings, bandwidth, flops)
    (out / "bench.json").write_text(json.dumps(report, indent=1) + "\n")
    plots = write_plots(out, report)
    print(f"## MOGO latency on {report['machine']}\n")
    print(
        "Floors: memory read "
        + ", ".join(
            f"{v:.1f} GB/s ({t} thread{'s' * (t > 1)})"
            for t, v in report["floors"]["read_gb_per_s"].items()
        )
        + "; float32 matrix products "
        + ", ".join(
            f"{v:.0f} GFLOP/s ({t} thread{'s' * (t > 1)})"
            for t, v in report["floors"]["matmul_gflop_per_s"].items()
        )
        + ".\n"
    )
    print(f"### The bundle through the runtime ({bundle_dir})\n")
    print(product_markdown(report["product"]) + "\n")
    for size, result in report["steps"].items():
        print(f"### One time step, {size} model (random weights)\n")
        print(step_markdown(size, result) + "\n")
        print("\n".join(f"- {line}" for line in speedups(result, settings.threads)) + "\n")
    print(f"Written: {out / 'bench.json'}, " + ", ".join(str(p) for p in plots))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    log(f"done; this benchmark process peaked at {peak:.0f} MiB")
    return report


def settings_from_args(args: argparse.Namespace) -> Settings:
    base = SMOKE if args.smoke else Settings()
    changes = {}
    if args.threads:
        changes["threads"] = tuple(args.threads)
    if args.lengths:
        changes["lengths"] = tuple(args.lengths)
    if args.long_steps is not None:
        changes["long_steps"] = args.long_steps
    if args.no_paper:
        changes["sizes"] = tuple(s for s in base.sizes if s != "paper")
    settings = Settings(**{**asdict(base), **changes})
    if min(settings.threads) < 1 or min(settings.lengths) < 1:
        raise ValueError("--threads and --lengths take numbers >= 1")
    if settings.long_steps < 2 * SPAN:
        raise ValueError(f"--long-steps must be at least {2 * SPAN}, got {settings.long_steps}")
    return settings


def main_from_args(args: argparse.Namespace) -> None:
    bundle_dir = Path(args.bundle) if args.bundle else DEFAULT_BUNDLE
    run(bundle_dir, Path(args.out), Path(args.work), settings_from_args(args))
