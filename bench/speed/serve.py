"""`mogo bench-serve`: how many characters `mogo serve` streams in real time on this machine.

Starts `mogo serve` in its own process, warms it, times one client's first frame (start message
sent -> first frame received, the server otherwise idle), then for each N opens N WebSocket
clients at once, each with its own prompt and seed and one prompt switch, and for `seconds`
records when every frame arrives. Frame i of a client is due at t0 + i / fps, t0 the arrival of
its frame 0; a frame's lateness is how far past that it came (0 if in time). Per N: frames per
second per client (mean), p50 / p99 lateness over all frames, and the server's CPU use (its
process's user + system time over the wall time, in cores). N holds real time when every
client got >= 97% of the frame rate and p99 lateness stayed within one frame (50 ms).
The clients run on the same machine as the server: their own CPU use is part of the load.

`engine_cost` measures the compute alone, in this process, with no sockets: N streams
past their first frames stepped on the engine's clock, CPU time (all threads) per stream
step, wall time per tick and the cores used (CPU over wall). CPU time shows what N costs
even on a busy machine; 1000 / (fps * CPU ms) streams per core is the ceiling it sets.
`engine_first_frame` times a new stream's first frame on a warm engine, no sockets, in CPU
and wall time (`--engine-only` runs these two alone). `engine_profile` (`--profile N`) splits a stream step's
CPU among its parts (the level graphs, sampling, the VQ decoder, joints, foot planting).
"""
from __future__ import annotations

import asyncio
import cProfile
import json
import os
import pstats
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from mogo.bench.speed.plot import log_line_chart

PROMPTS = ["a person walks forward", "a person jogs in a circle", "a person jumps on the spot",
           "a person waves with the right hand", "a person squats", "a person kicks",
           "a person turns left", "a person claps", "a person runs forward", "a person bows"]
FPS = 20.0
WARM_CLIENTS = 4
PARTS = {  # the parts of a served stream step (--profile): the function whose time is each
    "level graphs (onnxruntime)": ("token_generator.py", "run"),
    "sampling": ("sampling.py", "choose_tokens"),
    "VQ decoder (onnxruntime)": ("stream_decoder.py", "_decode_windows"),
    "joints from features": ("motion/features.py", "push"),
    "foot planting": ("motion/feet.py", "push"),
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


async def client(url: str, k: int, seconds: float, switch_at: float | None,
                 binary: bool = False) -> list[float]:
    """One client's frame arrival times (seconds, monotonic), frame by frame; `binary`: frames
    as the protocol's binary bursts (a header of index and count, then float32 joints)."""
    import aiohttp

    arrivals: list[float] = []
    async with aiohttp.ClientSession() as session, session.ws_connect(url) as ws:
        await ws.send_json({"prompt": PROMPTS[k % len(PROMPTS)], "seed": k, "binary": binary})
        end = time.monotonic() + seconds
        switched = switch_at is None
        while (left := end - time.monotonic()) > 0:
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
    return arrivals


async def first_frame_ms(url: str) -> float:
    import aiohttp

    async with aiohttp.ClientSession() as session, session.ws_connect(url) as ws:
        start = time.monotonic()
        await ws.send_json({"prompt": PROMPTS[0], "seed": 0})
        while json.loads((await ws.receive()).data)["type"] != "frames":
            pass
        return (time.monotonic() - start) * 1e3


def measure(url: str, pid: int, clients: int, seconds: float, binary: bool = False) -> dict:
    """N clients at once; their frame rate and lateness, the server's CPU use."""
    async def run():
        return await asyncio.gather(*(client(url, k, seconds, seconds * (0.3 + 0.4 * k / clients),
                                             binary) for k in range(clients)))

    cpu, wall = cpu_seconds(pid), time.monotonic()
    arrivals = asyncio.run(run())
    cpu, wall = cpu_seconds(pid) - cpu, time.monotonic() - wall
    rates, late = [], []
    for times in arrivals:
        times = np.asarray(times)
        if len(times) < 2:
            rates.append(0.0)
            continue
        rates.append((len(times) - 1) / (times[-1] - times[0]) if times[-1] > times[0] else FPS)
        late.append(np.maximum(0.0, times - (times[0] + np.arange(len(times)) / FPS)))
    late = np.concatenate(late) if late else np.array([np.inf])
    row = dict(clients=clients, fps=float(np.mean(rates)), fps_min=float(np.min(rates)),
               p50_ms=float(np.percentile(late, 50) * 1e3),
               p99_ms=float(np.percentile(late, 99) * 1e3), cpu_cores=cpu / wall)
    row["real_time"] = row["fps_min"] >= 0.97 * FPS and row["p99_ms"] <= 1e3 / FPS
    return row


def engine_cost(clients: int, threads: int, ticks: int = 40,
                profile: cProfile.Profile | None = None) -> dict:
    """CPU ms per stream step and wall ms per tick of the Engine alone, streams past their
    first frames; `profile` records the measured ticks."""
    from mogo.generator import MotionGenerator
    from mogo.serve.engine import Engine

    generator = MotionGenerator.load(threads=threads)
    engine = Engine(generator, threads)
    for k in range(clients):
        engine.open(PROMPTS[k % len(PROMPTS)], k, generator.sampling(None), 0.0)
    now, ready = 0.0, engine.lead + 2 * generator.streaming_decoder().every  # frames flow

    def run_until(end: float) -> int:
        nonlocal now
        steps = 0
        while now < end:
            due = engine.due(now)
            if due:
                engine.round(due)
                steps += len(due)
            else:
                now += 1 / engine.fps
        return steps

    while min(s.steps for s in engine.streams.values()) < ready:
        run_until(now + 1 / engine.fps)
    cpu, wall = time.process_time(), time.perf_counter()
    if profile is not None:
        profile.enable()
    steps = run_until(now + ticks / engine.fps)
    if profile is not None:
        profile.disable()
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    engine.shutdown()
    return dict(clients=clients, steps=steps, cpu_ms_per_step=cpu * 1e3 / steps,
                wall_ms_per_tick=wall * 1e3 / ticks, cores=cpu / wall)


def engine_profile(clients: int) -> list[tuple[str, float]]:
    """Where a stream step's CPU goes: (part, ms per stream step) for the parts of PARTS, the
    rest (the engine's and streams' own Python) and the whole, from cProfile on one thread
    (cProfile's own cost inflates the Python-heavy parts)."""
    profile = cProfile.Profile()
    steps = engine_cost(clients, 1, profile=profile)["steps"]
    stats = pstats.Stats(profile).stats  # (file, line, name) -> (..., total, cumulative, ...)
    whole = sum(entry[2] for entry in stats.values())
    parts = [(part, sum(entry[3] for (file, _, name), entry in stats.items()
                        if file.endswith(module) and name == function))
             for part, (module, function) in PARTS.items()]
    parts.append(("the rest: the engine's and streams' Python", whole - sum(s for _, s in parts)))
    return [(part, seconds * 1e3 / steps) for part, seconds in parts + [("a stream step", whole)]]


def profile_table(rows: list[tuple[str, float]]) -> str:
    whole = rows[-1][1]
    lines = ["| part | CPU per stream step | share |", "|---|---:|---:|"]
    lines += [f"| {part} | {ms:.3f} ms | {100 * ms / whole:.0f}% |" for part, ms in rows]
    return "\n".join(lines)


def engine_first_frame(threads: int, repeats: int = 7) -> dict:
    """Median CPU and wall ms from a new stream's open to its first frame, one stream on a
    warm engine (its graphs have run once), no sockets."""
    from mogo.generator import MotionGenerator
    from mogo.serve.engine import Engine

    generator = MotionGenerator.load(threads=threads)
    engine = Engine(generator, threads)
    times = []
    for k in range(repeats + 1):  # the first one warms the graphs
        cpu, wall = time.process_time(), time.perf_counter()
        stream = engine.open(PROMPTS[0], k, generator.sampling(None), time.monotonic())
        while not engine.round(engine.due(time.monotonic())):
            pass
        times.append(((time.process_time() - cpu) * 1e3, (time.perf_counter() - wall) * 1e3))
        engine.close(stream)
    engine.shutdown()
    cpu, wall = np.median(times[1:], axis=0)
    return dict(cpu_ms=float(cpu), wall_ms=float(wall))


def engine_table(rows: list[dict]) -> str:
    lines = ["| streams | CPU per stream step | wall per tick (real time: <= 50 ms) | cores used |",
             "|---:|---:|---:|---:|"]
    lines += [f"| {r['clients']} | {r['cpu_ms_per_step']:.2f} ms | {r['wall_ms_per_tick']:.1f} ms "
              f"| {r['cores']:.2f} |" for r in rows]
    return "\n".join(lines)


def table(rows: list[dict]) -> str:
    lines = ["| clients | frames/s per client (mean / min) | lateness p50 | lateness p99 | "
             "server CPU (cores) | real time |", "|---:|---:|---:|---:|---:|:---:|"]
    for r in rows:
        lines.append(f"| {r['clients']} | {r['fps']:.1f} / {r['fps_min']:.1f} | "
                     f"{r['p50_ms']:.0f} ms | {r['p99_ms']:.0f} ms | {r['cpu_cores']:.2f} | "
                     f"{'yes' if r['real_time'] else 'no'} |")
    return "\n".join(lines)


def run(clients: list[int], seconds: float, threads: int | None, bundle: str | None,
        out: Path, binary: bool = False) -> dict:
    port = free_port()
    command = [sys.executable, "-m", "mogo", "serve", "--port", str(port), "--max-streams",
               str(max(*clients, WARM_CLIENTS) + 1)]
    command += ["--threads", str(threads)] if threads else []
    command += ["--bundle", bundle] if bundle else []
    server = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    try:
        if "mogo serve:" not in server.stderr.readline():
            raise RuntimeError("mogo serve did not start")
        url = f"http://127.0.0.1:{port}/v1/stream"
        measure(url, server.pid, WARM_CLIENTS, 4.0)  # warm: graphs run once, caches allocated
        first = sorted(asyncio.run(first_frame_ms(url)) for _ in range(7))
        rows = []
        for n in clients:
            rows.append(measure(url, server.pid, n, seconds, binary))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    finally:
        server.terminate()
        server.wait(timeout=30)
    held = [r["clients"] for r in rows if r["real_time"]]
    engine = [engine_cost(n, threads or 2) for n in clients]
    result = dict(first_frame_ms=first[len(first) // 2], rows=rows, engine=engine,
                  largest_real_time=max(held) if held else 0, seconds=seconds)
    out.mkdir(parents=True, exist_ok=True)
    (out / "serve_bench.json").write_text(json.dumps(result, indent=1))
    log_line_chart(out / "serve_bench.png", "mogo serve: N clients at once", "clients",
                   "see legend", {
                       "frames/s per client": [(r["clients"], max(r["fps"], 0.1)) for r in rows],
                       "p99 lateness, ms (min 1)": [(r["clients"], max(r["p99_ms"], 1.0))
                                                    for r in rows],
                       "server CPU, % of a core": [(r["clients"], max(100 * r["cpu_cores"], 1))
                                                   for r in rows]})
    return result


def engine_only(clients: list[int], threads: int | None, out: Path) -> dict:
    threads = threads or 2
    result = dict(threads=threads, first_frame=engine_first_frame(threads),
                  engine=[engine_cost(n, threads) for n in clients])
    out.mkdir(parents=True, exist_ok=True)
    (out / "serve_engine.json").write_text(json.dumps(result, indent=1))
    return result


def main_from_args(args) -> None:
    if args.profile:
        print(f"Where the CPU of a stream step goes: {args.profile} streams past their first "
              "frames, the engine alone on one thread, cProfile:\n")
        print(profile_table(engine_profile(args.profile)))
        return
    if args.engine_only:
        result = engine_only(args.clients, args.threads, Path(args.out))
        print(f"The engine alone (no sockets, {result['threads']} threads), streams past "
              "their first frames:\n")
        print(engine_table(result["engine"]))
        first = result["first_frame"]
        print(f"\nfirst frame, one stream, engine warm: {first['wall_ms']:.0f} ms wall, "
              f"{first['cpu_ms']:.0f} ms CPU (medians of 7)")
        print(f"wrote {Path(args.out) / 'serve_engine.json'}")
        return
    result = run(args.clients, args.seconds, args.threads, args.bundle, Path(args.out),
                 args.binary)
    print(table(result["rows"]))
    print("\nThe engine alone (no sockets), streams past their first frames:\n")
    print(engine_table(result["engine"]))
    print(f"\nfirst frame, one client, server warm: {result['first_frame_ms']:.0f} ms (median "
          f"of 7); largest N in real time: {result['largest_real_time']}")
    print(f"wrote {Path(args.out) / 'serve_bench.json'} and serve_bench.png")
