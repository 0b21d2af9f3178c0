"""`mogo bench deploy` (docs/deploy.md): characters `mogo serve` streams in real time against
its number of server processes (`--workers`), and what resuming a stream costs.

- processes: for each worker count W, `mogo serve --workers W` in its own process and the
  clients in another, measured as `mogo bench serve` measures a count (mogo.bench.speed.serve:
  N clients arriving over `spread` seconds, each with one switch; real time = every client
  >= 97% of the frame rate and p99 lateness within a frame); the CPU is that of the server and
  its workers together.
- resume: streams of several prompts and seeds run to a random step (20-200), then
  `MotionStream.state()` and `MotionGenerator.resume(state)` are timed (the resume warm, as on
  a server that already embedded the prompt): wall ms, the token steps it replays after its
  prefill (TokenStream.rebuild), the state's size.
"""

from __future__ import annotations

import json
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from mogo.bench.speed.serve import PROMPTS, WARM_CLIENTS, measure, serving

SPREAD = 2.0  # seconds the clients of a count arrive over


def processes(workers: int, clients: list[int], seconds: float) -> list[dict]:
    """One row per client count, for `mogo serve --workers workers`."""
    rows = []
    with (
        serving(None, max(*clients, WARM_CLIENTS * workers), workers=workers) as (base, pid),
        ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool,
    ):
        measure(pool, base, pid, WARM_CLIENTS * workers, 4.0, 0.0)  # warm each worker
        for n in clients:
            rows.append(dict(measure(pool, base, pid, n, seconds, SPREAD), workers=workers))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
            time.sleep(1.0)  # health asks one worker: let the others free their streams
    return rows


def resume_cost(streams: int = 16, seed: int = 0) -> dict:
    from mogo import MotionGenerator

    generator = MotionGenerator.load()
    rng = np.random.default_rng(seed)
    resume_ms, state_ms, replayed, chars = [], [], [], []
    for k in range(streams):
        stream = generator.stream(PROMPTS[k % len(PROMPTS)], seed=k)
        for _ in range(int(rng.integers(20, 200))):
            stream.step()
        start = time.perf_counter()
        state = stream.state()
        state_ms.append(1e3 * (time.perf_counter() - start))
        generator.resume(state)  # the prompt's embedding, as a server holds it
        start = time.perf_counter()
        generator.resume(state)
        resume_ms.append(1e3 * (time.perf_counter() - start))
        replayed.append(len(stream.tokens.positions) - stream.tokens.prefilled)
        chars.append(len(state))

    def spread(values: list[float]) -> dict:
        return {q: float(np.percentile(values, p)) for q, p in (("p50", 50), ("p90", 90))} | {
            "max": float(np.max(values))
        }

    return dict(
        streams=streams,
        resume_ms=spread(resume_ms),
        state_ms=spread(state_ms),
        replayed_steps=spread(replayed),
        state_chars=spread(chars),
        worst=dict(ms=max(resume_ms), steps=replayed[int(np.argmax(resume_ms))]),
    )


def table(rows: list[dict]) -> str:
    lines = [
        "| workers | clients | frames/s per client (mean / min) | lateness p99 | "
        "first frame p50 | server CPU (cores) | real time |",
        "|---:|---:|---:|---:|---:|---:|:---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['workers']} | {r['clients']} | {r['fps']:.1f} / {r['fps_min']:.1f} | "
            f"{r['p99_ms']:.0f} ms | {r['first_frame_ms']['p50']:.0f} ms | "
            f"{r['cpu_cores']:.2f} | {'yes' if r['real_time'] else 'no'} |"
        )
    return "\n".join(lines)


def resume_table(r: dict) -> str:
    lines = ["| | p50 | p90 | max |", "|---|---:|---:|---:|"]
    for name, key, unit in (
        ("resume (warm)", "resume_ms", " ms"),
        ("state()", "state_ms", " ms"),
        ("token steps replayed after the prefill", "replayed_steps", ""),
        ("state size", "state_chars", " chars"),
    ):
        lines.append(
            f"| {name} | "
            + " | ".join(f"{r[key][q]:.1f}{unit}" for q in ("p50", "p90", "max"))
            + " |"
        )
    return "\n".join(lines)


def main_from_args(args) -> None:
    resume = resume_cost()
    print(resume_table(resume), flush=True)
    rows = [row for w in args.workers for row in processes(w, args.clients, args.seconds)]
    largest = {
        w: max([r["clients"] for r in rows if r["workers"] == w and r["real_time"]], default=0)
        for w in args.workers
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "deploy_bench.json").write_text(
        json.dumps(dict(resume=resume, rows=rows, largest_real_time=largest), indent=1)
    )
    print(table(rows))
    print("largest count in real time, by workers:", largest)
