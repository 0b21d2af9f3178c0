"""`mogo bench`: how fast MOGO generates on this machine, against the torch reference, the
public prototype's method and the hardware floor. Markdown tables on stdout; bench.json and
PNG plots in --out.

Two parts:
1. The product: a bundle (default: the shipped one) through the runtime's public API at each
   thread count: time to first frame (text encoding, prefill, the steps of the decoder's
   lookahead, one decode), a 196-frame clip end to end and its real-time factor, the step time
   along a 10,000-step stream (sliding window), the peak memory of a process that only runs
   the runtime, and the size on disk.
2. The step, per model size (the bundle's config and the paper's, random weights: the cost
   does not depend on them; exported the way a bundle's level graphs are): one whole time
   step (every level, sampling included) against the KV cache length, for onnxruntime fp32
   and int8, torch eager with the KV cache and torch eager recomputing the whole prefix at
   every step (the public prototype's method), at each thread count. The backends are timed
   round by round in turn, so the machine's own slow spells hit them alike. Each row has its
   floor: weight and cache bytes over the measured memory bandwidth, or FLOPs over the
   measured matrix FLOP/s, whichever is larger.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import resource
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import onnx
import torch

from mogo.bench.speed import machine
from mogo.bench.speed.plot import log_line_chart
from mogo.export.onnx.bundle import DEFAULT_SAMPLING, quantize_level_graph
from mogo.export.onnx.t2m_graphs import export_level
from mogo.export.models.t2m import T2M, T2MConfig
from mogo.bundle import Bundle
from mogo.manifest import Graph
from mogo.generator import (DEFAULT_BUNDLE, STREAM_DECODE_EVERY, MotionGenerator,
                                    MotionStream)
from mogo.sampling import choose_token
from mogo.motion.skeleton import MAX_FRAMES, MAX_SECONDS
from mogo.token_generator import TokenGenerator

PROMPT = "a person walks forward, then waves with the right hand."
CLIP_FRAMES = MAX_FRAMES  # HumanML3D's longest clip: 9.8 s at 20 fps
SPAN = 96  # steps averaged at each point of the long stream (a multiple of the decode burst)


@dataclass(frozen=True)
class Settings:
    threads: tuple[int, ...] = (1, 2)
    lengths: tuple[int, ...] = (1, 10, 50, 100, 200)  # KV cache lengths of the step tables
    long_steps: int = 10_000
    rounds: int = 15  # timed rounds per point (fewer where one call is slow)
    round_budget_s: float = 20.0  # a point stops adding rounds past this (3 at least)
    clip_repeats: int = 5
    sizes: tuple[str, ...] = ("bundle", "paper")


QUICK = Settings(lengths=(1, 8), long_steps=300, rounds=3, round_budget_s=2.0, clip_repeats=2,
                 sizes=("tiny",))


# -- timing -------------------------------------------------------------------------------------
def interleaved(calls: dict[str, Callable[[], object]], rounds: int, budget_s: float,
                warmup: int = 1) -> dict[str, float]:
    """Median seconds of each call, the calls timed one after another in every round, the
    order rotating; stops adding rounds once `budget_s` is spent (after 3 rounds at least)."""
    for call in calls.values():
        for _ in range(warmup):
            call()
    names = list(calls)
    times: dict[str, list[float]] = {name: [] for name in names}
    spent, done = 0.0, 0
    while done < rounds and (done < 3 or spent < budget_s):
        for name in names[done % len(names):] + names[:done % len(names)]:
            start = time.perf_counter()
            calls[name]()
            elapsed = time.perf_counter() - start
            times[name].append(elapsed)
            spent += elapsed
        done += 1
    return {name: float(np.median(values)) for name, values in times.items()}


def log(message: str) -> None:
    print(f"bench: {message}", file=sys.stderr, flush=True)


# -- part 1: the product ---------------------------------------------------------------------------
def time_to_first_frame(generator: MotionGenerator, seed: int) -> None:
    stream = generator.stream(PROMPT, seed=seed)
    while not len(stream.step()):
        pass


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
    rows = {t: dict(ttff_ms=1e3 * medians[f"ttff {t}"], clip_s=medians[f"clip {t}"],
                    real_time_factor=seconds / medians[f"clip {t}"]) for t in generators}
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
        means = {n: span_ms(step_times[t][n:n + SPAN]) for n in points}
        rows[t].update(stream_step_ms=means,
                       stream_flatness=old_over_fresh(streams[t], g.stream(PROMPT, seed=2)))
    bundle = Bundle.load(bundle_dir)
    return dict(threads=rows, disk_mb=sum(f.bytes for f in bundle.manifest.files.values())
                / 1e6, peak_rss_mib=runtime_peak_rss(bundle_dir), clip_seconds=seconds,
                window=bundle.manifest.defaults.window,
                binned_step_ms={t: binned(step_times[t]) for t in generators})


def span_ms(times: np.ndarray) -> float:
    """Milliseconds per step over a span: the median of its means over decode bursts (one
    decoder call every STREAM_DECODE_EVERY steps), so a stray slow step does not move it."""
    blocks = times[:len(times) - len(times) % STREAM_DECODE_EVERY]
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
    return [(int(a), 1e3 * float(times[a:b].mean())) for a, b in zip(edges[:-1], edges[1:])
            if b > a]


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
        "print(open('/proc/self/status').read() if sys.platform == 'linux' else '')\n")
    done = subprocess.run([sys.executable, "-c", script, str(bundle_dir)], capture_output=True,
                          text=True, check=True)
    # VmHWM is this process's own peak; ru_maxrss would carry the parent's over exec
    peaks = [line.split()[1] for line in done.stdout.splitlines() if line.startswith("VmHWM")]
    return int(peaks[0]) / 1024 if peaks else float("nan")  # kB; Linux only


# -- part 2: the step -------------------------------------------------------------------------------
def size_configs(bundle_dir: Path) -> dict[str, T2MConfig]:
    bundle_config = dict(Bundle.load(bundle_dir).manifest.t2m.config)
    return dict(bundle=T2MConfig(**bundle_config), paper=T2MConfig.paper(), tiny=T2MConfig.tiny())


def exported_model(config: T2MConfig, work: Path) -> tuple[T2M, Path, list[Graph]]:
    """The model with seed-0 random weights and its fp32 and int8 level graphs, exported once
    into `work` (keyed by the config and the torch version) and reused by later runs."""
    key = hashlib.sha256(json.dumps([asdict(config), torch.__version__]).encode()).hexdigest()
    folder = work / key[:16]
    torch.manual_seed(0)
    model = T2M(config).eval()
    index = folder / "graphs.json"
    if index.is_file():
        return model, folder, [Graph(g["file"], tuple(g["inputs"]), tuple(g["outputs"]))
                               for g in json.loads(index.read_text())]
    (folder / "int8").mkdir(parents=True, exist_ok=True)
    graphs = []
    for level in range(config.num_levels):
        log(f"exporting level {level + 1}/{config.num_levels} ({config.layers[level]} layers, "
            f"width {config.dim}) fp32 and int8 into {folder}")
        path = folder / f"level_{level}.onnx"
        graphs.append(export_level(model, level, path))
        quantize_level_graph(path, folder / "int8" / path.name)
    index.write_text(json.dumps([asdict(g) for g in graphs]))
    return model, folder, graphs


def onnx_step(generator: TokenGenerator, config: T2MConfig, length: int) -> Callable[[], None]:
    """One whole time step on onnxruntime with a cache of `length` slots (random values)."""
    rng = np.random.default_rng(length)
    prompt = rng.standard_normal((1, config.text_dim)).astype(np.float32)
    uncond = np.zeros(1, bool)
    token_ids = np.zeros((1, 1, config.num_levels), np.int64)
    position = np.array([length], np.int64)
    past_positions = np.arange(length, dtype=np.int64)
    caches = [[rng.standard_normal((1, heads, length, head_dim)).astype(np.float32)
               for _ in range(2 * layers)] for layers, heads, head_dim in generator.cache_shapes]

    def step() -> None:
        outputs = generator.each_level(lambda level: generator.run(
            level, prompt, uncond, token_ids, position, past_positions, caches[level]))
        for logits, _ in outputs:
            choose_token(logits[0], None, 0.5, DEFAULT_SAMPLING)

    return step


def torch_step(model: T2M, length: int, threads: int, cached: bool) -> Callable[[], None]:
    """One whole time step in torch eager: on a KV cache of `length` slots, or recomputing all
    `length` + 1 positions from scratch (no cache), as the public prototype does."""
    config = model.config
    g = torch.Generator().manual_seed(length)
    prompt = torch.randn(1, config.text_dim, generator=g)
    uncond = torch.zeros(1, dtype=torch.bool)
    positions = torch.tensor([length]) if cached else torch.arange(length + 1)
    token_ids = torch.zeros(1, len(positions), config.num_levels, dtype=torch.long)
    past_positions = torch.arange(length) if cached else None
    pasts = [[(torch.randn(1, config.heads[l], length, config.head_dim, generator=g),
               torch.randn(1, config.heads[l], length, config.head_dim, generator=g))
              for _ in range(config.layers[l])] if cached else None
             for l in range(config.num_levels)]

    @torch.inference_mode()
    def step() -> None:
        torch.set_num_threads(threads)
        for level in range(config.num_levels):
            logits, _ = model.level_forward(level, prompt, uncond, token_ids, positions,
                                            past_positions, pasts[level])
            choose_token(logits[0].numpy(), None, 0.5, DEFAULT_SAMPLING)

    return step


def step_backends(model: T2M, folder: Path, graphs: list[Graph],
                  threads: tuple[int, ...]) -> dict[str, tuple[str, int, Callable]]:
    """name -> (weights kind for the floor, cores used, factory(length) -> step callable)."""
    end = model.config.end_token
    backends = {}
    for kind, sub in (("fp32", folder), ("int8", folder / "int8")):
        paths = [sub / g.file for g in graphs]
        single = TokenGenerator(paths, graphs, end, intra_op_threads=1)
        for t in threads:
            generators = {f"onnxruntime {kind}, {t} thread{'s' * (t > 1)}": single}
            if t > 1:
                generators[f"onnxruntime {kind}, {t} threads"] = TokenGenerator(
                    paths, graphs, end, intra_op_threads=t)
                generators[f"onnxruntime {kind}, {t} level groups"] = single.with_level_workers(t)
            for name, generator in generators.items():
                backends[name] = (kind, t, lambda n, g=generator: onnx_step(g, model.config, n))
    for t in threads:
        plural = "s" * (t > 1)
        backends[f"torch eager + KV cache, {t} thread{plural}"] = (
            "fp32", t, lambda n, t=t: torch_step(model, n, t, cached=True))
        backends[f"torch eager, recompute, {t} thread{plural}"] = (
            "fp32 recompute", t, lambda n, t=t: torch_step(model, n, t, cached=False))
    return backends


def touched_weight_bytes(paths: list[Path]) -> int:
    """Bytes of the initializers a decode step reads in full: all but the tables only Gather
    reads (one row of a token embedding table per step)."""
    total = 0
    for path in paths:
        graph = onnx.load(path, load_external_data=False).graph
        readers: dict[str, set[str]] = {}
        for node in graph.node:
            for name in node.input:
                readers.setdefault(name, set()).add(node.op_type)
        for weight in graph.initializer:
            if readers.get(weight.name, set()) - {"Gather"}:
                total += onnx.numpy_helper.to_array(weight).nbytes
    return total


def step_flops(config: T2MConfig, length: int, positions: int = 1) -> float:
    """FLOPs of one step: every level's matrix products for `positions` new positions
    attending to `length` past ones plus themselves."""
    D, dh, R = config.dim, config.head_dim, config.max_relative_distance
    macs = 0
    for level in range(config.num_levels):
        H = config.heads[level]
        per_layer = 4 * D * H * dh + 2 * D * config.mlp_ratio * D  # qkv + proj + mlp
        attention = H * dh * (2 * (length + positions) + R + 1)  # q.k, a.v, q.phi
        macs += config.layers[level] * positions * (per_layer + attention)
        macs += D * config.num_classes(level) + D * config.text_dim  # head, prompt projection
    return 2.0 * macs


def kv_bytes(config: T2MConfig, length: int) -> int:
    """float32 key and value bytes of a `length`-slot cache, all levels."""
    return sum(4 * 2 * config.layers[l] * config.heads[l] * config.head_dim * length
               for l in range(config.num_levels))


def step_table(size: str, config: T2MConfig, work: Path, settings: Settings,
               bandwidth: dict[int, float], flops: dict[int, float]) -> dict:
    """Part 2 for one model size."""
    model, folder, graphs = exported_model(config, work)
    backends = step_backends(model, folder, graphs, settings.threads)
    weights = {"fp32": touched_weight_bytes([folder / g.file for g in graphs]),
               "int8": touched_weight_bytes([folder / "int8" / g.file for g in graphs])}
    weights["fp32 recompute"] = weights["fp32"]
    rows = {name: dict(kind=kind, threads=threads, step_ms={}, floor_ms={})
            for name, (kind, threads, _) in backends.items()}
    for length in settings.lengths:
        log(f"{size}: {len(backends)} backends at cache length {length}")
        calls = {name: factory(length) for name, (_, _, factory) in backends.items()}
        medians = interleaved(calls, settings.rounds, settings.round_budget_s)
        for name, seconds in medians.items():
            kind, threads = rows[name]["kind"], rows[name]["threads"]
            recompute = kind == "fp32 recompute"
            memory = weights[kind] + (0 if recompute else kv_bytes(config, length))
            compute = step_flops(config, 0 if recompute else length, length + 1 if recompute else 1)
            floor = max(memory / bandwidth[threads], compute / flops[threads])
            rows[name]["step_ms"][length] = 1e3 * seconds
            rows[name]["floor_ms"][length] = 1e3 * floor
    for row in rows.values():
        row["clip_s"] = clip_seconds(row["step_ms"])
    return dict(config=asdict(config), parameters=sum(p.numel() for p in model.parameters()),
                weight_mb={k: v / 1e6 for k, v in weights.items() if k != "fp32 recompute"},
                backends=rows)


def clip_seconds(step_ms: dict[int, float]) -> float:
    """A 196-step clip from the measured step times: step n has n cache slots (no window),
    its time linearly interpolated between the measured lengths."""
    lengths = sorted(step_ms)
    return float(np.interp(np.arange(CLIP_FRAMES), lengths,
                           [step_ms[n] for n in lengths]).sum()) / 1e3


# -- output --------------------------------------------------------------------------------------
def product_markdown(result: dict) -> str:
    rows = result["threads"]
    points = list(next(iter(rows.values()))["stream_step_ms"])
    lines = [f"| threads | time to first frame (ms) | {CLIP_FRAMES}-frame clip (ms) | "
             "real-time factor | " + " | ".join(f"stream step {n}+ (ms)" for n in points)
             + " | last / step 10, in turn |",
             "|---:|---:|---:|---:|" + "---:|" * len(points) + "---:|"]
    for t, row in rows.items():
        steps = " | ".join(f"{row['stream_step_ms'][n]:.2f}" for n in points)
        lines.append(f"| {t} | {row['ttff_ms']:.1f} | {1e3 * row['clip_s']:.1f} | "
                     f"{row['real_time_factor']:.0f}x | {steps} | {row['stream_flatness']:.2f} |")
    lines.append("")
    lines.append(f"Size on disk {result['disk_mb']:.1f} MB; peak RSS of a runtime-only process "
                 f"(load, one clip, 2,000 stream steps) {result['peak_rss_mib']:.0f} MiB. "
                 f"Stream steps: {SPAN} steps from each point, decoder bursts included, as "
                 f"the stream ran (the machine's own drift included); the last column steps the "
                 f"long stream and a fresh one at step 10 in turn. The sliding window holds "
                 f"{result['window']} steps.")
    return "\n".join(lines)


def step_markdown(size: str, result: dict) -> str:
    lengths = list(next(iter(result["backends"].values()))["step_ms"])
    reference = max(lengths)
    head = (f"| {size} model: backend | " + " | ".join(f"cache {n} (ms)" for n in lengths)
            + f" | {CLIP_FRAMES}-step clip (s) | floor at {reference} (ms) | measured / floor |")
    lines = [head, "|---|" + "---:|" * (len(lengths) + 3)]
    for name, row in result["backends"].items():
        cells = " | ".join(f"{row['step_ms'][n]:.2f}" for n in lengths)
        floor = row["floor_ms"][reference]
        lines.append(f"| {name} | {cells} | {row['clip_s']:.2f} | {floor:.2f} | "
                     f"{row['step_ms'][reference] / floor:.1f} |")
    c = result["config"]
    lines.append("")
    lines.append(f"{result['parameters'] / 1e6:.0f}M parameters (width {c['dim']}, layers "
                 f"{c['layers']}, heads {c['heads']}); weights read per step: "
                 + ", ".join(f"{k} {v:.0f} MB" for k, v in result["weight_mb"].items()) + ".")
    return "\n".join(lines)


def speedups(result: dict, threads: tuple[int, ...]) -> list[str]:
    """The issue's ratios, per thread count: best onnxruntime vs torch cached, per step at the
    longest cache, and per clip vs recomputation."""
    rows, lines = result["backends"], []
    reference = max(next(iter(rows.values()))["step_ms"])
    for t in threads:
        ort_rows = {n: r for n, r in rows.items()
                    if n.startswith("onnxruntime") and r["threads"] == t}
        best = min(ort_rows, key=lambda n: ort_rows[n]["step_ms"][reference])
        plural = "s" * (t > 1)
        cached = rows[f"torch eager + KV cache, {t} thread{plural}"]
        recompute = rows[f"torch eager, recompute, {t} thread{plural}"]
        lines.append(f"{t} thread{plural}: best onnxruntime ({best}) "
                     f"{cached['step_ms'][reference] / ort_rows[best]['step_ms'][reference]:.1f}x "
                     f"faster per step than torch eager with the cache (cache {reference}), "
                     f"{recompute['clip_s'] / ort_rows[best]['clip_s']:.0f}x faster per clip "
                     "than recomputing the prefix")
    return lines


def write_plots(out: Path, report: dict) -> list[Path]:
    paths = []
    for size, result in report["steps"].items():
        path = out / f"step_vs_cache_{size}.png"
        series = {name: [(max(n, 1), ms) for n, ms in row["step_ms"].items()]
                  for name, row in result["backends"].items()}
        log_line_chart(path, f"one time step, {size} model", "KV cache length (slots)",
                       "ms per step", series)
        paths.append(path)
    path = out / "long_stream.png"
    series = {f"{t} thread{'s' * (int(t) > 1)}": [(max(n, 1), ms) for n, ms in values]
              for t, values in report["product"]["binned_step_ms"].items()}
    log_line_chart(path, "stream step time along a long stream (bundle)", "step",
                   "ms per step", series)
    return paths + [path]


# -- command ------------------------------------------------------------------------------------
def run(bundle_dir: Path, out: Path, work: Path, settings: Settings) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    report: dict = dict(machine=machine.describe(), settings=asdict(settings), steps={})
    log("memory bandwidth and matrix FLOP/s")
    bandwidth = {t: machine.read_bandwidth(t) for t in settings.threads}
    flops = {t: machine.matmul_flops(t) for t in settings.threads}
    report["floors"] = dict(read_gb_per_s={t: b / 1e9 for t, b in bandwidth.items()},
                            matmul_gflop_per_s={t: f / 1e9 for t, f in flops.items()})
    report["product"] = product(bundle_dir, settings)
    configs = size_configs(bundle_dir)
    for size in settings.sizes:
        report["steps"][size] = step_table(size, configs[size], work, settings, bandwidth, flops)
    (out / "bench.json").write_text(json.dumps(report, indent=1) + "\n")
    plots = write_plots(out, report)
    print(f"## MOGO latency on {report['machine']}\n")
    print("Floors: memory read "
          + ", ".join(f"{v:.1f} GB/s ({t} thread{'s' * (t > 1)})"
                      for t, v in report["floors"]["read_gb_per_s"].items())
          + "; float32 matrix products "
          + ", ".join(f"{v:.0f} GFLOP/s ({t} thread{'s' * (t > 1)})"
                      for t, v in report["floors"]["matmul_gflop_per_s"].items()) + ".\n")
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
    base = QUICK if args.quick else Settings()
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
