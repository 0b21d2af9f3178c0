"""`mogo bench serve`: how many characters `mogo serve` streams in real time on this machine.

Starts `mogo serve` in its own process and the clients in another (so the server's event loop
and the clients' never share a process), warms the server, then:

- bursts: for each burst size B, B WebSocket clients connect at once to the idle server; each
  one's first-frame latency (start message sent -> first frame received). Percentiles over the
  clients (B = 1 repeated 7 times). With `--beside N` the burst comes while N clients stream
  (arrived over 2 s, settled 3 s): their p99 lateness over the frames after the burst's start
  says whether the burst made them fall behind.
- counts: for each N, N clients arrive spread evenly over `spread` seconds, each with its own
  prompt and seed and one prompt switch, and for `seconds` record when every frame arrives.
  Frame i of a client is due at t0 + i / fps, t0 the arrival of its frame 0; a frame's
  lateness is how far past that it came (0 if in time). Per N: frames per second per client
  (mean and min), p50 / p99 lateness over all frames, first-frame latency p50 / p99, and the
  server's CPU use (its process's user + system time over the wall time, in cores). N holds
  real time when every client got >= 97% of the frame rate and p99 lateness stayed within one
  frame (50 ms).

With `--low-latency` every burst and count runs twice in turn on the same server, the clients
asking for the centred decoder, then for the bundle's low-latency one (the protocol's
"low_latency": true): the two compared in one run, under the same load.

Frames are binary (the protocol's "binary": true) unless asked for JSON. Between counts the
bench waits until the server's /v1/health reports no stream left, so each count starts from
an empty server. The clients run on the same machine: their CPU use is part of the load.

`engine_costs` measures the compute alone, in this process, with no sockets: N streams
past their first frames stepped on the engine's clock, CPU time (all threads) per stream
step, wall time per tick and the cores used (CPU over wall), each count on an engine of its
own, one after another. CPU time shows what N costs even on a busy machine; 1000 / (fps *
CPU ms) streams per core is the ceiling it sets.
`engine_first_frame` times a new stream's first frame on a warm engine, no sockets, in CPU
and wall time, and splits its CPU among the parts of a step (`--engine-only` runs these two
alone). `engine_profile` (`--profile N`) splits a stream step's CPU among its parts (the level
graphs, sampling, the VQ decoder, joints, foot planting).
"""

from __future__ import annotations

import asyncio
import cProfile
import json
import math
import multiprocessing
import os
import pstats
import socket
import subprocess
import sys
import time
import urllib.request
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from mogo.bench.speed.plot import log_line_chart
from mogo.motion.skeleton import SMPL_22

PROMPTS = [
    "a person walks forward",
    "a person jogs in a circle",
    "a person jumps on the spot",
    "a person waves with the right hand",
    "a person squats",
    "a person kicks",
    "a person turns left",
    "a person claps",
    "a person runs forward",
    "a person bows",
]
FPS = SMPL_22.fps  # the shipped bundle's: the server's clock ticks at it
DECODERS = {False: "centred", True: "low latency"}  # a stream's "low_latency" -> its name
BESIDE_SPREAD, BESIDE_SETTLE, BESIDE_AFTER = 2.0, 3.0, 10.0  # --beside: the streaming clients
# arrive over 2 s, the burst 3 s later, and they stream 10 s past it
WARM_CLIENTS = 4
PARTS = {  # the parts of a served stream step (--profile): the functions whose time is each
    "level graphs (onnxruntime)": {("token_generator.py", "run")},
    "sampling": {("sampling.py", "choose_tokens")},
    # windows (the centred decoder), or a token a call (a low-latency decoder's step graph)
    "VQ decoder (onnxruntime)": {
        ("stream_decoder.py", "_decode_windows"),
        ("stream_decoder.py", "_step_many"),
    },
    "joints from features": {("motion/features.py", "joints_together")},
    "foot planting": {("motion/feet.py", "push_together")},
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def serving(bundle: str | None, max_streams: int, threads: int | None = None, workers: int = 1):
    """`mogo serve` in its own process on a free loopback port, for the `with` block: yields
    its base URL and process id (with `workers` > 1, the parent of its workers)."""
    port = free_port()
    command = [sys.executable, "-m", "mogo", "serve", "--port", str(port)]
    command += ["--max-streams", str(max_streams), "--workers", str(workers)]
    command += ["--threads", str(threads)] if threads else []
    command += ["--bundle", bundle] if bundle else []
    server = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    try:
        if "mogo serve:" not in server.stderr.readline():
            raise RuntimeError("mogo serve did not start")
        yield f"http://127.0.0.1:{port}", server.pid
    finally:
        server.terminate()
        server.wait(timeout=30)


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds so far of a process and its children (`mogo serve --workers`:
    the workers; Linux /proc)."""
    children = Path(f"/proc/{pid}/task/{pid}/children")
    total = 0
    for task in [pid, *(map(int, children.read_text().split()) if children.exists() else [])]:
        fields = Path(f"/proc/{task}/stat").read_text().rsplit(")", 1)[1].split()
        total += int(fields[11]) + int(fields[12])
    return total / os.sysconf("SC_CLK_TCK")


async def client(
    url: str,
    k: int,
    seconds: float,
    switch_at: float | None,
    binary: bool = True,
    delay: float = 0.0,
    first_only: bool = False,
    low_latency: bool = False,
) -> tuple[float, list[float]]:
    """One client, `delay` seconds from now: its first-frame latency (seconds from its start
    message) and its frame arrival times (seconds, monotonic), frame by frame, for `seconds`
    (or until the first frame, `first_only`); `binary`: frames as the protocol's binary bursts
    (a header of index and count, then float32 joints), else JSON; `low_latency`: its stream
    asks for the bundle's low-latency decoder."""
    import aiohttp

    await asyncio.sleep(delay)
    arrivals: list[float] = []
    async with aiohttp.ClientSession() as session, session.ws_connect(url) as ws:
        sent = time.monotonic()
        start = {"prompt": PROMPTS[k % len(PROMPTS)], "seed": k, "binary": binary}
        await ws.send_json(start | ({"low_latency": True} if low_latency else {}))
        end = sent + seconds
        switched = switch_at is None
        while (left := end - time.monotonic()) > 0 and not (first_only and arrivals):
            try:
                message = await asyncio.wait_for(ws.receive(), left)
            except asyncio.TimeoutError:
                break
            if message.type == aiohttp.WSMsgType.BINARY:  # uint32 index, uint32 n, joints
                arrivals += [time.monotonic()] * int.from_bytes(message.data[4:8], "little")
            elif (body := json.loads(message.data))["type"] == "frames":
                arrivals += [time.monotonic()] * len(body["joints"])
            elif body["type"] == "error":
                raise RuntimeError(f"client {k}: {body['error']}")
            if not switched and arrivals and time.monotonic() > end - seconds + switch_at:
                await ws.send_json({"prompt": PROMPTS[(k + 3) % len(PROMPTS)]})
                switched = True
    return (arrivals[0] - sent if arrivals else math.inf), arrivals


def clients_process(
    url: str,
    delays: list[float],
    seconds: float,
    binary: bool,
    firsts: int = 0,
    low_latency: bool = False,
) -> list[tuple[float, list[float]]]:
    """What the clients' process runs: one client a delay, all on one event loop; the last
    `firsts` want their first frame alone, the others stream for `seconds`, client k
    switching its prompt once, between 30% and 70% of them."""

    async def run():
        n = len(delays)
        return await asyncio.gather(
            *(
                client(
                    url,
                    k,
                    seconds,
                    None if first else seconds * (0.3 + 0.4 * k / n),
                    binary,
                    delay,
                    first,
                    low_latency,
                )
                for k, delay in enumerate(delays)
                for first in [k >= n - firsts]
            )
        )

    return asyncio.run(run())


def wait_until_empty(base: str, timeout: float = 60.0) -> None:
    """Until the server's /v1/health reports no stream: the clients of a count have closed
    their sockets, but the server frees their streams once it reads the close."""
    deadline = time.monotonic() + timeout
    while True:
        with urllib.request.urlopen(f"{base}/v1/health", timeout=10) as answer:
            streams = json.load(answer)["streams"]
        if streams == 0:
            return
        if time.monotonic() > deadline:
            raise RuntimeError(
                f"mogo serve still holds {streams} streams {timeout:.0f} s after its clients left"
            )
        time.sleep(0.1)


def percentiles_ms(seconds: list[float]) -> dict:
    """p50, p90, p99 and max, each a value measured (no interpolation): a client that got no
    frame (inf) makes them inf, not NaN."""
    values = np.asarray(seconds) * 1e3
    percentiles = {f"p{q}": float(np.percentile(values, q, method="higher")) for q in (50, 90, 99)}
    return dict(percentiles, max=float(values.max()))


def burst(
    pool: ProcessPoolExecutor,
    base: str,
    size: int,
    binary: bool,
    low_latency: bool = False,
    beside: int = 0,
) -> dict:
    """`size` clients connecting at once (size 1: 7 times), to the idle server or while
    `beside` clients stream (settled first); their first-frame latencies, and the streaming
    clients' lateness after the burst began."""
    settled = BESIDE_SPREAD + BESIDE_SETTLE  # the burst's delay where others stream
    delays = [BESIDE_SPREAD * k / max(beside, 1) for k in range(beside)]
    delays += [settled if beside else 0.0] * size
    firsts, late = [], []
    for _ in range(7 if size == 1 else 1):
        results = pool.submit(
            clients_process,
            f"{base}/v1/stream",
            delays,
            settled + BESIDE_AFTER if beside else 60.0,
            binary,
            size,
            low_latency,
        ).result()
        arrived = [(first, times) for first, times in results[beside:] if times]
        firsts += [first for first, _ in results[beside:]]
        start = min((times[0] - first for first, times in arrived), default=math.inf)
        late += [t for _, times in results[:beside] for t in _lateness(times, start)]
        wait_until_empty(base)
    row = dict(burst=size, decoder=DECODERS[low_latency], first_frame_ms=percentiles_ms(firsts))
    if beside:  # no frame after the burst's start (none came): inf, never a pass
        late_ms = np.percentile(late, 99, method="higher") * 1e3 if late else math.inf
        row |= dict(beside=beside, beside_p99_ms=float(late_ms))
    return row


def _lateness(times: list[float], since: float) -> list[float]:
    """How late each frame of a client came (seconds; frame i due at its first frame's
    arrival + i / FPS), for the frames that arrived from `since` on."""
    times = np.asarray(times)
    late = np.maximum(0.0, times - (times[0] + np.arange(len(times)) / FPS))
    return list(late[times >= since])


def measure(
    pool: ProcessPoolExecutor,
    base: str,
    pid: int,
    clients: int,
    seconds: float,
    spread: float,
    binary: bool = True,
    low_latency: bool = False,
) -> dict:
    """N clients arriving evenly over `spread` seconds; their frame rate, lateness and first
    frames, the server's CPU use."""
    delays = [spread * k / clients for k in range(clients)]
    cpu, wall = cpu_seconds(pid), time.monotonic()
    results = pool.submit(
        clients_process, f"{base}/v1/stream", delays, seconds, binary, 0, low_latency
    ).result()
    cpu, wall = cpu_seconds(pid) - cpu, time.monotonic() - wall
    wait_until_empty(base)
    rates, late = [], []
    for _, times in results:
        times = np.asarray(times)
        if len(times) < 2:
            rates.append(0.0)
            continue
        rates.append((len(times) - 1) / (times[-1] - times[0]) if times[-1] > times[0] else FPS)
        late.append(_lateness(times, -math.inf))
    late = np.concatenate(late) if late else np.array([np.inf])
    row = dict(
        clients=clients,
        decoder=DECODERS[low_latency],
        fps=float(np.mean(rates)),
        fps_min=float(np.min(rates)),
        p50_ms=float(np.percentile(late, 50, method="higher") * 1e3),
        p99_ms=float(np.percentile(late, 99, method="higher") * 1e3),
        cpu_cores=cpu / wall,
        first_frame_ms=percentiles_ms([first for first, _ in results]),
    )
    row["real_time"] = row["fps_min"] >= 0.97 * FPS and row["p99_ms"] <= 1e3 / FPS
    return row


class _EngineRun:
    """`clients` streams on an Engine of their own, stepped on its clock past their first
    frames (every decoder window full: a steady state), then `ticks` at a time."""

    def __init__(
        self,
        clients: int,
        threads: int,
        low_latency: bool,
        bundle: str | None,
        signed: bool | None = None,
    ):
        """signed: the level graphs' weights int8 or uint8 (None: the server's choice)."""
        from mogo.generator import MotionGenerator
        from mogo.serve.engine import Engine, pooled_tokens
        from mogo.serve.rowwise import signed_products_exact

        generator = MotionGenerator.load(bundle, threads=threads)
        self.clients, self.low_latency = clients, low_latency
        signed = signed_products_exact() if signed is None else signed
        self.weights = "int8" if signed else "uint8"
        self.engine = Engine(generator, threads, pooled_tokens(generator, signed))
        for k in range(clients):
            stream = self.engine.open(
                PROMPTS[k % len(PROMPTS)], k, generator.sampling(None), 0.0, low_latency=low_latency
            )
        d = stream.decoder
        self.now, ready = 0.0, max(stream.lead, d.left_context + d.lookahead) + 2 * d.every
        while min(s.steps for s in self.engine.streams.values()) < ready:
            self.ticks(1)

    def ticks(self, ticks: int) -> int:
        """Step `ticks` ticks of the clock; the stream steps taken."""
        end, steps = self.now + ticks / self.engine.fps, 0
        while self.now < end:
            due = self.engine.due(self.now)
            if due:
                self.engine.round(due)
                steps += len(due)
            else:
                self.now += 1 / self.engine.fps
        return steps


def engine_costs(
    runs: list[tuple[int, bool]] | list[tuple[int, bool, bool | None]],
    threads: int,
    bundle: str | None = None,
    ticks: int = 40,
    profile: cProfile.Profile | None = None,
) -> list[dict]:
    """For each (clients, low_latency[, signed weights]) of `runs`, one after another, each on
    an engine of its own: CPU ms per stream step and wall ms per tick of the Engine alone over
    `ticks`; `profile` records the measured ticks. (Engines stepped in turn in one process
    were tried: a lone stream's step read 12-17% more beside a 200-stream engine than alone,
    whatever the warm-up, docs/history.md.)"""
    rows = []
    for run in runs:
        engine = _EngineRun(run[0], threads, run[1], bundle, *run[2:])
        cpu, wall = time.process_time(), time.perf_counter()
        if profile is not None:
            profile.enable()
        steps = engine.ticks(ticks)
        if profile is not None:
            profile.disable()
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
        engine.engine.shutdown()
        rows.append(
            dict(
                clients=engine.clients,
                decoder=DECODERS[engine.low_latency],
                weights=engine.weights,
                steps=steps,
                cpu_ms_per_step=cpu * 1e3 / steps,
                wall_ms_per_tick=wall * 1e3 / ticks,
                cores=cpu / wall,
            )
        )
    return rows


def engine_profile(
    clients: int, bundle: str | None = None, low_latency: bool = False
) -> list[tuple[str, float]]:
    """Where a stream step's CPU goes: (part, ms per stream step) for the parts of PARTS, the
    rest (the engine's and streams' own Python) and the whole, from cProfile on one thread
    (cProfile's own cost inflates the Python-heavy parts)."""
    profile = cProfile.Profile()
    (steps,) = engine_costs([(clients, low_latency)], 1, bundle, 40, profile)
    return _split(profile, steps["steps"], "a stream step")


def _split(profile: cProfile.Profile, per: int, whole_name: str) -> list[tuple[str, float]]:
    """A profile's CPU as (part, ms per `per`): the parts of PARTS, the rest, the whole."""
    stats = pstats.Stats(profile).stats  # (file, line, name) -> (..., total, cumulative, ...)
    whole = sum(entry[2] for entry in stats.values())
    parts = [
        (
            part,
            sum(
                entry[3]
                for (file, _, name), entry in stats.items()
                if any(file.endswith(module) and name == f for module, f in functions)
            ),
        )
        for part, functions in PARTS.items()
    ]
    parts.append(("the rest: the engine's and streams' Python", whole - sum(s for _, s in parts)))
    return [(part, seconds * 1e3 / per) for part, seconds in parts + [(whole_name, whole)]]


def profile_table(rows: list[tuple[str, float]], per: str = "CPU per stream step") -> str:
    whole = rows[-1][1]
    lines = [f"| part | {per} | share |", "|---|---:|---:|"]
    lines += [f"| {part} | {ms:.3f} ms | {100 * ms / whole:.0f}% |" for part, ms in rows]
    return "\n".join(lines)


def engine_first_frame(
    threads: int, repeats: int = 7, bundle: str | None = None, low_latency: bool = False
) -> dict:
    """Median CPU and wall ms from a new stream's open to its first frame, one stream on a
    warm engine (its graphs have run once), no sockets; the token steps it took, and where
    its CPU went (cProfile over the repeats, a separate pass: ms per first frame)."""
    from mogo.generator import MotionGenerator
    from mogo.serve.engine import Engine

    generator = MotionGenerator.load(bundle, threads=threads)
    engine = Engine(generator, threads)

    def first_frame(k: int) -> int:
        stream = engine.open(
            PROMPTS[0], k, generator.sampling(None), time.monotonic(), low_latency=low_latency
        )
        while not engine.round(engine.due(time.monotonic())):
            pass
        engine.close(stream)
        return stream.steps

    times = []
    for k in range(repeats + 1):  # the first one warms the graphs
        cpu, wall = time.process_time(), time.perf_counter()
        steps = first_frame(k)
        times.append(((time.process_time() - cpu) * 1e3, (time.perf_counter() - wall) * 1e3))
    profile = cProfile.Profile()
    profile.enable()
    for k in range(repeats):
        first_frame(k)
    profile.disable()
    engine.shutdown()
    cpu, wall = np.median(times[1:], axis=0)
    return dict(
        decoder=DECODERS[low_latency],
        cpu_ms=float(cpu),
        wall_ms=float(wall),
        steps=steps,
        parts=_split(profile, repeats, "a first frame"),
    )


def engine_table(rows: list[dict]) -> str:
    lines = [
        "| streams | decoder | weights | CPU per stream step | wall per tick (real time: <= 50 ms) "
        "| cores used |",
        "|---:|:---|:---|---:|---:|---:|",
    ]
    lines += [
        f"| {r['clients']} | {r['decoder']} | {r['weights']} | {r['cpu_ms_per_step']:.2f} ms "
        f"| {r['wall_ms_per_tick']:.1f} ms | {r['cores']:.2f} |"
        for r in rows
    ]
    return "\n".join(lines)


def table(rows: list[dict]) -> str:
    lines = [
        "| clients | decoder | frames/s per client (mean / min) | lateness p50 | lateness p99 | "
        "first frame p50 / p99 | server CPU (cores) | real time |",
        "|---:|:---|---:|---:|---:|---:|---:|:---:|",
    ]
    for r in rows:
        first = r["first_frame_ms"]
        lines.append(
            f"| {r['clients']} | {r['decoder']} | {r['fps']:.1f} / {r['fps_min']:.1f} | "
            f"{r['p50_ms']:.0f} ms | {r['p99_ms']:.0f} ms | {first['p50']:.0f} / "
            f"{first['p99']:.0f} ms | {r['cpu_cores']:.2f} | "
            f"{'yes' if r['real_time'] else 'no'} |"
        )
    return "\n".join(lines)


def burst_table(rows: list[dict]) -> str:
    """The bursts' first frames; where others streamed beside, their p99 lateness after it."""
    beside = any("beside" in r for r in rows)
    extra = " | clients streaming | their lateness p99 after it" if beside else ""
    lines = [
        f"| clients arriving at once | decoder | first frame p50 | p90 | p99 | max{extra} |",
        "|---:|:---|---:|---:|---:|---:|" + "---:|---:|" * beside,
    ]
    lines += [
        f"| {r['burst']} | {r['decoder']} | "
        + " | ".join(f"{r['first_frame_ms'][p]:.0f} ms" for p in ("p50", "p90", "p99", "max"))
        + (f" | {r['beside']} | {r['beside_p99_ms']:.0f} ms" if beside else "")
        + " |"
        for r in rows
    ]
    return "\n".join(lines)


def run(
    clients: list[int],
    bursts: list[int],
    seconds: float,
    spread: float,
    threads: int | None,
    bundle: str | None,
    out: Path,
    binary: bool = True,
    low_latency: bool = False,
    beside: int = 0,
) -> dict:
    """`low_latency`: every burst and count twice in turn, centred then low-latency clients;
    `beside`: each burst while that many clients stream."""
    decoders = [False, True] if low_latency else [False]
    most = max(*clients, *(b + beside for b in bursts), WARM_CLIENTS)
    with (
        serving(bundle, most, threads) as (base, pid),
        ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool,
    ):
        for low in decoders:  # graphs run once
            measure(pool, base, pid, WARM_CLIENTS, 4.0, 0.0, binary, low)
        bursts_measured = []
        for size in bursts:
            for low in decoders:
                bursts_measured.append(burst(pool, base, size, binary, low, beside))
                print(burst_table(bursts_measured[-1:]).splitlines()[-1], flush=True)
        rows = []
        for n in clients:
            for low in decoders:
                rows.append(measure(pool, base, pid, n, seconds, spread, binary, low))
                print(table(rows[-1:]).splitlines()[-1], flush=True)
    engine = engine_costs([(n, low) for n in clients for low in decoders], threads or 2, bundle)
    largest = {}
    for low in decoders:
        held = [r["clients"] for r in rows if r["real_time"] and r["decoder"] == DECODERS[low]]
        largest[DECODERS[low]] = max(held, default=0)
    result = dict(
        bursts=bursts_measured,
        rows=rows,
        engine=engine,
        largest_real_time=largest,
        seconds=seconds,
        spread=spread,
        binary=binary,
    )
    out.mkdir(parents=True, exist_ok=True)
    (out / "serve_bench.json").write_text(json.dumps(result, indent=1))
    _charts(out, rows, bursts_measured, spread)
    return result


def _charts(out: Path, rows: list[dict], bursts: list[dict], spread: float) -> None:
    """serve_bench.png (the counts) and serve_bursts.png, a line per decoder measured; a
    value that is not finite (no client of a count got two frames) is left out."""
    names = sorted({r["decoder"] for r in rows + bursts})

    def line(measured: list[dict], x: str, value, floor: float, name: str) -> list:
        return [
            (r[x], max(value(r), floor))
            for r in measured
            if r["decoder"] == name and math.isfinite(value(r))
        ]

    def named(series: str, name: str) -> str:
        return series if len(names) == 1 else f"{series}, {name}"

    log_line_chart(
        out / "serve_bench.png",
        f"mogo serve: N clients arriving over {spread:g} s",
        "clients",
        "see legend",
        {
            named(series, name): line(rows, "clients", value, floor, name)
            for name in names
            for series, value, floor in (
                ("frames/s per client", lambda r: r["fps"], 0.1),
                ("p99 lateness, ms (min 1)", lambda r: r["p99_ms"], 1.0),
                ("server CPU, % of a core", lambda r: 100 * r["cpu_cores"], 1.0),
            )
        },
    )
    beside = max((r.get("beside", 0) for r in bursts), default=0)
    log_line_chart(
        out / "serve_bursts.png",
        "mogo serve: first frame of clients arriving at once"
        + (f", while {beside} clients stream" if beside else ""),
        "clients arriving at once",
        "first frame, ms",
        {
            named(p, name): line(bursts, "burst", lambda r, p=p: r["first_frame_ms"][p], 1.0, name)
            for name in names
            for p in ("p50", "p99", "max")
        },
    )


def weights_note() -> str:
    """Which int8 products the engine's level graphs use on this CPU (mogo.serve.rowwise)."""
    from mogo.serve.rowwise import signed_products_exact

    if signed_products_exact():
        return "level graphs' weights: int8 (this CPU multiplies uint8 by int8 exactly)"
    return "level graphs' weights: uint8 (this CPU's uint8 by int8 products saturate)"


def engine_only(
    clients: list[int],
    threads: int | None,
    out: Path,
    bundle=None,
    low_latency=False,
    both_weights=False,
) -> dict:
    threads = threads or 2
    decoders = [False, True] if low_latency else [False]
    weights = [True, False] if both_weights else [None]
    result = dict(
        threads=threads,
        first_frame=[
            engine_first_frame(threads, bundle=bundle, low_latency=low) for low in decoders
        ],
        engine=engine_costs(
            [(n, low, w) for n in clients for low in decoders for w in weights], threads, bundle
        ),
    )
    out.mkdir(parents=True, exist_ok=True)
    (out / "serve_engine.json").write_text(json.dumps(result, indent=1))
    return result


def main_from_args(args) -> None:
    if args.profile:
        print(
            f"Where the CPU of a stream step goes: {args.profile} streams past their first "
            f"frames ({DECODERS[args.low_latency]} decoder), the engine alone on one thread, "
            "cProfile:\n"
        )
        print(profile_table(engine_profile(args.profile, args.bundle, args.low_latency)))
        print(f"\n{weights_note()}")
        return
    if args.engine_only:
        result = engine_only(
            args.clients,
            args.threads,
            Path(args.out),
            args.bundle,
            args.low_latency,
            args.both_weights,
        )
        print(
            f"The engine alone (no sockets, {result['threads']} threads), streams past "
            "their first frames:\n"
        )
        print(engine_table(result["engine"]))
        for first in result["first_frame"]:
            print(
                f"\nfirst frame, one stream, {first['decoder']} decoder, engine warm: "
                f"{first['wall_ms']:.0f} ms wall, {first['cpu_ms']:.0f} ms CPU (medians of 7), "
                f"{first['steps']} token steps; its CPU (cProfile):\n"
            )
            print(profile_table(first["parts"], "CPU per first frame"))
        print(f"wrote {Path(args.out) / 'serve_engine.json'}")
        return
    result = run(
        args.clients,
        args.burst,
        args.seconds,
        args.spread,
        args.threads,
        args.bundle,
        Path(args.out),
        not args.json,
        args.low_latency,
        args.beside,
    )
    where = f"while {args.beside} clients stream" if args.beside else "on the idle server"
    print(
        f"Clients arriving at once {where} ({'JSON' if args.json else 'binary'} "
        "frames), first-frame latency:\n"
    )
    print(burst_table(result["bursts"]))
    print(f"\nN clients arriving over {args.spread:g} s, {args.seconds:g} s each:\n")
    print(table(result["rows"]))
    print("\nThe engine alone (no sockets), streams past their first frames:\n")
    print(engine_table(result["engine"]))
    for name, largest in result["largest_real_time"].items():
        print(f"\nlargest N in real time, {name} decoder: {largest}")
    print(f"wrote {Path(args.out) / 'serve_bench.json'}, serve_bench.png and serve_bursts.png")
