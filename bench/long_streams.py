"""`mogo long-streams`: do long streams keep doing what they were asked?

Streams of every action of the repertoire (mogo.bench.quality.stream_checks; or of those
chosen, e.g. the failing ones while a change is tried), `minutes` long, for several seeds,
with re-anchoring off (the model runs on from step 0, the behaviour before
mogo.anchoring) and on: the share of 10-s windows that pass the action's check, how fast a
prompt switch shows (streams switching between continuing actions every 10 s), the seams of
re-anchoring (joint speed there against ordinary frames), drift (pelvis height band, feet
under the floor) and foot sliding in contact against short clips of the same prompts.
Markdown tables on stdout and in OUT/long_streams.md, the figures in OUT/long_streams.json,
the pass share by minute in OUT/long_streams.png.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from mogo.bench.quality.stream_checks import (
    FPS,
    REPERTOIRE,
    Action,
    WindowCheck,
    drift,
    joint_speed,
    reaction_frames,
    window_passes,
)
from mogo.bench.speed.plot import log_line_chart
from mogo.progress import Progress

WINDOW = 10 * FPS  # frames of a judged window
REACTION_WINDOW = 2 * FPS  # frames that show an action under way after a switch
SWITCH_EVERY = 10 * FPS  # frames between switches
PROMPT_SECONDS = 1.5  # the target: the new action under way within this
MODES = {"off": False, "on": True}
_generator = None


def _worker_generator(bundle: str | None):
    global _generator
    if _generator is None:
        from mogo import MotionGenerator

        _generator = MotionGenerator.load(bundle, threads=1)
    return _generator


def _stream(
    bundle, prompt: str, seed: int, anchoring: bool, frames: int, switches: list[str] = ()
) -> tuple[np.ndarray, list[int], list[float], int]:
    """A stream's joints, the frames where it re-anchored, seconds per step by minute and how
    many of the re-anchors were fresh clips."""
    stream = _worker_generator(bundle).stream(prompt, seed=seed, anchoring=anchoring)
    chunks, seams, minute_times, steps, start = [], [], [], 0, time.perf_counter()
    down = stream.generator.down_factor
    while sum(map(len, chunks)) < frames:
        if len(stream.prompts) <= len(switches) and steps * down >= SWITCH_EVERY * len(
            stream.prompts
        ):  # by steps drawn: frames lag them by the decoder's lookahead
            stream.set_prompt(switches[len(stream.prompts) - 1])
        anchors = stream.anchor.anchors if stream.anchor else 0
        chunks.append(stream.step())
        steps += 1
        if stream.anchor and stream.anchor.anchors > anchors:
            seams.append(steps * down)
        if steps % (60 * FPS) == 0:
            minute_times.append((time.perf_counter() - start) / (60 * FPS))
            start = time.perf_counter()
    fresh = stream.anchor.fresh if stream.anchor else 0
    return np.concatenate(chunks)[:frames], seams, minute_times, fresh


def run_action(bundle, action: Action, seed: int, mode: str, minutes: float) -> dict:
    frames = int(minutes * 60 * FPS)
    joints, seams, times, fresh = _stream(bundle, action.prompt, seed, MODES[mode], frames)
    short = _worker_generator(bundle).generate(action.prompt, seconds=5, seed=seed).joints
    speed = joint_speed(joints)
    seams = [f for f in seams if 1 <= f < len(speed)]
    return dict(
        action=action.name,
        seed=seed,
        mode=mode,
        passes=window_passes(WindowCheck(action, WINDOW), joints),
        drift=drift(joints),
        short_slide=drift(short)["slide"],
        seam_speed=[float(speed[f - 1]) for f in seams],
        fresh=fresh,
        ordinary_p99=float(np.percentile(speed, 99)),
        step_seconds=times,
    )


def run_switches(bundle, seed: int, mode: str, switches: int) -> dict:
    """A stream through `switches` random continuing actions, SWITCH_EVERY frames each."""
    continuing = [a for a in REPERTOIRE if a.continuing]
    rng = np.random.default_rng(seed)
    order = [continuing[0]]
    while len(order) < switches + 1:
        order.append(
            continuing[
                (continuing.index(order[-1]) + 1 + rng.integers(len(continuing) - 1))
                % len(continuing)
            ]
        )
    joints, *_ = _stream(
        bundle,
        order[0].prompt,
        seed,
        MODES[mode],
        SWITCH_EVERY * len(order),
        [a.prompt for a in order[1:]],
    )
    checks = {a.name: WindowCheck(a, REACTION_WINDOW) for a in set(order[1:])}
    reactions = [
        reaction_frames(checks[a.name], joints[k * SWITCH_EVERY : (k + 1) * SWITCH_EVERY])
        for k, a in enumerate(order)
        if k
    ]
    return dict(mode=mode, seed=seed, reactions=reactions)


def measure(
    bundle: str | None,
    minutes: float,
    seeds: int,
    switches: int,
    jobs: int,
    modes: list[str],
    actions: tuple[Action, ...] = REPERTOIRE,
) -> dict:
    with ProcessPoolExecutor(jobs) as pool:
        streams = [
            pool.submit(run_action, bundle, a, s, m, minutes)
            for m in modes
            for a in actions
            for s in range(seeds)
        ]
        switching = [
            pool.submit(run_switches, bundle, s, m, switches)
            for m in modes
            for s in range(seeds)
            if switches
        ]
        progress = Progress(len(streams) + len(switching), "long streams", unit="streams")
        for _ in as_completed(streams + switching):
            progress.update()
        progress.close()
        return dict(
            modes=modes,
            lengths={m: (minutes, seeds) for m in modes},
            streams=[f.result() for f in streams],
            switches=[f.result() for f in switching],
        )


def _share(flags: list[bool]) -> str:
    return f"{np.mean(flags):.0%}" if flags else "-"


def _cell(rows: list[dict], action: Action) -> str:
    passes = [r["passes"] for r in rows if r["action"] == action.name]
    if action.continuing:
        return _share([p for ps in passes for p in ps])
    happened = sum(ps[0] for ps in passes)
    return f"{_share([p for ps in passes for p in ps[1:]])} (happens {happened}/{len(passes)})"


def action_table(result: dict) -> str:
    """Per action, the share of 10-s windows passing in each mode."""
    modes, streams = result["modes"], result["streams"]
    by_mode = {m: [r for r in streams if r["mode"] == m] for m in modes}
    names = {r["action"] for r in streams}
    lines = [
        "| action | prompt | " + " | ".join(f"anchoring {m}" for m in modes) + " |",
        "|---|---|" + "---|" * len(modes),
    ]
    for action in (a for a in REPERTOIRE if a.name in names):
        kind = "" if action.continuing else " (one-off: hold)"
        lines.append(
            f"| {action.name}{kind} | {action.prompt} | "
            + " | ".join(_cell(by_mode[m], action) for m in modes)
            + " |"
        )
    for title, continuing in (("all continuing", True), ("all one-off holds", False)):
        cells = [
            _share(
                [
                    p
                    for r in by_mode[m]
                    for p in (r["passes"] if continuing else r["passes"][1:])
                    if _action(r).continuing == continuing
                ]
            )
            for m in modes
        ]
        lines.append(f"| **{title}** | | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _action(row: dict) -> Action:
    return next(a for a in REPERTOIRE if a.name == row["action"])


def figures_table(result: dict) -> str:
    """Switch reaction, seams, drift, foot sliding and step time, per mode."""
    lines = [
        "| figure | " + " | ".join(f"anchoring {m}" for m in result["modes"]) + " |",
        "|---|" + "---|" * len(result["modes"]),
    ]
    rows: dict[str, list[str]] = {}
    for mode in result["modes"]:
        streams = [r for r in result["streams"] if r["mode"] == mode]
        reactions = [r for s in result["switches"] if s["mode"] == mode for r in s["reactions"]]
        seconds = np.array([np.inf if r is None else r / FPS for r in reactions])
        seams = [(s, r["ordinary_p99"]) for r in streams for s in r["seam_speed"]]
        d = [r["drift"] for r in streams]
        times = [t for r in streams for t in r["step_seconds"]]
        firsts = [r["step_seconds"][0] for r in streams if r["step_seconds"]]
        lasts = [r["step_seconds"][-1] for r in streams if r["step_seconds"]]
        fresh = sum(r.get("fresh", 0) for r in streams)
        for name, value in {
            **_switch_figures(seconds),
            "seams: joint speed above the stream's 99th percentile": f"{np.mean([s > p for s, p in seams]):.1%} of {len(seams)} ({fresh} fresh "
            f"clips)"
            if seams
            else "none",
            "pelvis height, 1st-99th percentile, lowest / highest stream (m)": f"{min(x['pelvis_low'] for x in d):.2f} / {max(x['pelvis_high'] for x in d):.2f}",
            "deepest foot under the floor (cm)": f"{100 * max(x['under_floor'] for x in d):.1f}",
            "foot sliding in contact, stream / 5-s clips (cm/s)": f"{100 * np.mean([x['slide'] for x in d]):.1f} / "
            f"{100 * np.mean([r['short_slide'] for r in streams]):.1f}",
            "ms per step, first / last minute": f"{1000 * np.mean(firsts):.2f} / {1000 * np.mean(lasts):.2f}"
            if times
            else "-",
        }.items():
            rows.setdefault(name, []).append(value)
    lines += [f"| {name} | " + " | ".join(values) + " |" for name, values in rows.items()]
    return "\n".join(lines)


def _switch_figures(seconds: np.ndarray) -> dict[str, str]:
    """The switch rows of the figures table from reaction times (s; inf: never)."""
    if not len(seconds):
        return {}
    finite = seconds[np.isfinite(seconds)]
    return {
        "switches: new action under way within 1.5 s": f"{np.mean(seconds <= PROMPT_SECONDS):.0%} of {len(seconds)}",
        "switches: median / 90th percentile reaction (s)": " / ".join(
            f"{np.percentile(seconds, q, method='lower'):.2f}" for q in (50, 90)
        ),
        "switches: never under way within 10 s": f"{np.sum(~np.isfinite(seconds))}",
        "switches: mean reaction where it shows (s)": f"{finite.mean():.2f}"
        if len(finite)
        else "-",
    }


def plot(result: dict, path: Path) -> None:
    """Share of windows passing by minute of the stream (a last partial minute too),
    continuing actions and one-off holds (their first window, the action, left out), per
    mode."""
    per_minute = 60 * FPS // WINDOW
    series = {}
    for mode in result["modes"]:
        for title, continuing in (("continuing", True), ("one-off hold", False)):
            rows = [
                r["passes"] if continuing else [None] + r["passes"][1:]
                for r in result["streams"]
                if r["mode"] == mode and _action(r).continuing == continuing
            ]
            minutes = [
                [p for ps in rows for p in ps[m : m + per_minute] if p is not None]
                for m in range(0, max(map(len, rows), default=0), per_minute)
            ]
            if any(minutes):
                series[f"anchoring {mode}: {title}"] = [
                    (m + 1, 100 * float(np.mean(flags))) for m, flags in enumerate(minutes) if flags
                ]
    log_line_chart(
        path,
        "10-s windows doing what the prompt asks",
        "minute of the stream",
        "% of windows passing",
        series,
        log=False,
    )


def merged(paths: list[str]) -> dict:
    """Saved runs (long_streams.json) as one result, e.g. a run of each mode."""
    runs = [json.loads(Path(path).read_text()) for path in paths]
    return dict(
        modes=[m for r in runs for m in r["modes"]],
        lengths={m: r["lengths"][m] for r in runs for m in r["modes"]},
        streams=[s for r in runs for s in r["streams"]],
        switches=[s for r in runs for s in r["switches"]],
    )


def report(result: dict) -> str:
    runs = "; ".join(
        f"anchoring {m}: {minutes:.3g}-minute streams, {seeds} seed(s) per action"
        for m, (minutes, seeds) in result["lengths"].items()
    )
    return (
        f"{runs}; switches every {SWITCH_EVERY // FPS} s between continuing actions\n\n"
        f"{action_table(result)}\n\n{figures_table(result)}\n"
    )


def main(args: argparse.Namespace) -> None:
    minutes, seeds, switches = (
        (1 / 3, 1, 1) if args.quick else (args.minutes, args.seeds, args.switches)
    )
    actions = (
        tuple(a for a in REPERTOIRE if a.name in args.actions)
        if args.actions
        else tuple(REPERTOIRE[k] for k in (0, -5))
        if args.quick
        else REPERTOIRE
    )
    result = (
        merged(args.tables_from)
        if args.tables_from
        else measure(args.bundle, minutes, seeds, switches, args.jobs, args.modes, actions)
    )
    text = report(result)
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "long_streams.md").write_text(text)
    (out / "long_streams.json").write_text(json.dumps(result, indent=1))
    plot(result, out / "long_streams.png")
    print(f"wrote {out}/long_streams.md, .json and .png")
