"""`mogo bench long-streams`: do long streams keep doing what they were asked, on every path?

Streams of every action of the repertoire (mogo.bench.quality.stream_checks; or of those
chosen, e.g. the failing ones while a change is tried), `minutes` long, for several seeds,
through each path that makes motion (`--path`): `MotionStream` (re-anchoring off, the
behaviour before mogo.anchoring, and on), `generate` of the whole length, `play` schedules,
`continue_from` a clip, and `mogo serve` over real WebSocket connections, every stream at once.
Judged: the share of 10-s windows that pass the action's check, how fast a prompt switch shows
(streams switching between continuing actions every 10 s), how soon a one-off action (sit,
jump, bow, turn, kick) is under way after a switch from a walk or a `continue_from` of one, the
seams of re-anchoring (joint speed there against ordinary frames), drift (pelvis height band,
feet under the floor), foot sliding in contact against short clips of the same prompts, and
how far each path's frames are from `MotionStream`'s for the same prompt, seed and switches,
and how late a switch shows in the frames received (mogo.bench.quality.received_switch).
Markdown tables on stdout and in OUT/long_streams.md, the figures in OUT/long_streams.json,
the pass share by minute in OUT/long_streams.png.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time
from concurrent.futures import (
    FIRST_COMPLETED,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    wait,
)
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mogo.bench.quality.received_switch import received_table, visible
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
from mogo.bench.speed.plot import bar_chart, log_line_chart
from mogo.progress import Progress

WINDOW = 10 * FPS  # frames of a judged window
REACTION_WINDOW = 2 * FPS  # frames that show an action under way after a switch
SWITCH_EVERY = 10 * FPS  # frames between switches
PROMPT_SECONDS = 1.5  # the target: the new action under way within this
ONE_OFF_WINDOW = 4 * FPS  # frames that hold a whole one-off action (a sit goes down and up)
ONE_OFF_SECONDS = 2.0  # the target: a one-off action under way within this
ONE_OFF_LEAD = ("a person walks forward.", 5 * FPS)  # what a one-off action follows
MODES = {"off": False, "on": True}  # MotionStream's re-anchoring
PATHS = ("stream", "generate", "play", "continue", "serve")
LOW_LATENCY = ("stream", "serve")  # the paths --low-latency runs again with that decoder
KINDS = {  # the paths that can play each kind of schedule
    "action": ("stream", "generate", "play", "serve"),
    "switches": ("stream", "play", "continue", "serve"),
    "one-off": ("stream", "play", "continue", "serve"),
}
_generator = None


def _worker_generator(bundle: str | None):
    global _generator
    if _generator is None:
        from mogo import MotionGenerator

        _generator = MotionGenerator.load(bundle, threads=1)
    return _generator


@dataclass(frozen=True)
class Task:
    """One motion to make and judge: a kind of schedule through one path (MotionStream's in
    one re-anchoring mode)."""

    kind: str  # "action" (one prompt for minutes), "switches" or "one-off"
    path: str
    mode: str
    seed: int
    schedule: tuple[tuple[str, int], ...]  # (prompt, frames) entries
    action: str = ""  # the judged action (the one-off's, an action's); switches: none
    low_latency: bool = False  # paths "stream" and "serve": the bundle's low-latency decoder

    @property
    def column(self) -> str:
        name = f"stream, anchoring {self.mode}" if self.path == "stream" else self.path
        return name + ", low-latency decoder" * self.low_latency


@dataclass
class Made:
    """A path's motion for a schedule: its joints, the frames where each switch took effect,
    and what only a MotionStream tells (seams: frames where it re-anchored; fresh: how many of
    those were fresh clips)."""

    joints: np.ndarray
    switches: list[int]
    seams: list[int] | None = None
    fresh: int = 0
    step_seconds: list[float] = field(default_factory=list)  # by minute (or overall)
    received: list[int] | None = None  # frames the caller had at each switch (stream, serve)


def _stream(bundle, task: Task) -> Made:
    """A MotionStream through the schedule, switching once the steps drawn reach each entry's
    first frame (frames lag them by the decoder's lookahead). Path "continue": the first entry
    is a clip, `generate`d, and the stream goes on from it (`continue_from`)."""
    g, schedule = _worker_generator(bundle), list(task.schedule)
    lead = np.zeros((0, g.skeleton.num_joints, 3), np.float32)
    if task.path == "continue":
        clip = g.generate(schedule[0][0], seconds=schedule[0][1] / FPS, seed=task.seed)
        lead, schedule = clip.joints, schedule[1:]
    stream = g.stream(
        schedule[0][0], seed=task.seed, anchoring=MODES[task.mode], low_latency=task.low_latency
    )
    if task.path == "continue":
        stream.continue_from(clip)
    ends = np.cumsum([n for _, n in schedule])  # the stream's frames where each entry ends
    down, chunks, seams, minutes = g.down_factor, [], [], []
    received = [len(lead)] * (task.path == "continue")  # frames the caller had at each switch
    steps, start = 0, time.perf_counter()
    while sum(map(len, chunks)) < ends[-1]:
        k = len(stream.prompts)
        if k < len(schedule) and steps * down >= ends[k - 1]:
            stream.set_prompt(schedule[k][0])
            received.append(len(lead) + sum(map(len, chunks)))
        anchors = stream.anchor.anchors if stream.anchor else 0
        chunks.append(stream.step())
        steps += 1
        if stream.anchor and stream.anchor.anchors > anchors:
            seams.append(len(lead) + steps * down)
        if steps % (60 * FPS) == 0:
            minutes.append((time.perf_counter() - start) / (60 * FPS))
            start = time.perf_counter()
    switches = [len(lead)] * (task.path == "continue") + [
        len(lead) + f for f, _ in stream.prompts[1:]
    ]
    joints = np.concatenate([lead, *chunks])[: len(lead) + ends[-1]]
    fresh = stream.anchor.fresh if stream.anchor else 0
    return Made(joints, switches, seams, fresh, minutes, received)


def _generated(bundle, task: Task) -> Made:
    """`generate` of the whole length (one prompt)."""
    g = _worker_generator(bundle)
    ((prompt, frames),) = task.schedule
    start = time.perf_counter()
    motion = g.generate(prompt, seconds=frames / FPS, seed=task.seed)
    return Made(motion.joints, [], step_seconds=[_per_step(start, motion, g)])


def _played(bundle, task: Task) -> Made:
    """`play` of the schedule."""
    g = _worker_generator(bundle)
    start = time.perf_counter()
    motion = g.play([(p, n / FPS) for p, n in task.schedule], seed=task.seed)
    switches = [frame for frame, _ in motion.prompts[1:]]
    return Made(motion.joints, switches, step_seconds=[_per_step(start, motion, g)])


def _per_step(start: float, motion, generator) -> float:
    return (time.perf_counter() - start) / max(1, len(motion.joints) // generator.down_factor)


async def _served(url: str, task: Task) -> Made:
    """The schedule over one WebSocket of `mogo serve`: a switch sent once the frames received
    reach its entry's first frame, taking effect at the frame the server names (`switched`)."""
    import aiohttp

    chunks, switches, received, sent_at = [], [], 0, []
    (prompt, end), later = task.schedule[0], list(task.schedule[1:])
    start = {"prompt": prompt, "seed": task.seed, "binary": True}
    if task.low_latency:
        start["low_latency"] = True
    async with aiohttp.ClientSession() as session, session.ws_connect(url) as ws:
        await ws.send_json(start)
        asked = False
        while later or received < end:
            message = await ws.receive()
            if message.type == aiohttp.WSMsgType.BINARY:  # uint32 index, uint32 n, joints
                index, n = np.frombuffer(message.data[:8], "<u4")
                if index != received:
                    raise RuntimeError(f"{task}: frames {received}-{index - 1} were dropped")
                chunks.append(np.frombuffer(message.data[8:], "<f4").reshape(n, -1, 3))
                received += int(n)
            elif message.type != aiohttp.WSMsgType.TEXT:
                raise RuntimeError(f"{task}: the server closed the stream ({message.type})")
            elif (body := json.loads(message.data))["type"] == "error":
                raise RuntimeError(f"{task}: {body['error']}")
            elif body["type"] == "switched":
                switches.append(body["index"])
                end, asked = body["index"] + later.pop(0)[1], False
            if later and not asked and received >= end:
                await ws.send_json({"prompt": later[0][0]})
                sent_at.append(received)
                asked = True
    return Made(np.concatenate(chunks)[:end], switches, received=sent_at)


MAKERS = {"stream": _stream, "continue": _stream, "generate": _generated, "play": _played}


def schedules(
    paths: list[str],
    modes: list[str],
    actions,
    minutes: float,
    seeds: int,
    switches: int,
    one_offs: int,
) -> list[Task]:
    """Every task of a run: each action for `minutes`, `switches` switches between random
    continuing actions and each one-off action after a walk (`one_offs` seeds), through every
    path that can play them; MotionStream's in each re-anchoring mode."""
    runs = [(p, m) for p in paths for m in (modes if p == "stream" else ["on"])]
    tasks = []
    for path, mode in runs:
        if path in KINDS["action"]:
            frames = int(minutes * 60 * FPS)
            tasks += [
                Task("action", path, mode, s, ((a.prompt, frames),), a.name)
                for a in actions
                for s in range(seeds)
            ]
        if switches and path in KINDS["switches"]:
            tasks += [
                Task("switches", path, mode, s, _switching(s, switches)) for s in range(seeds)
            ]
        if path in KINDS["one-off"]:
            tasks += [
                Task("one-off", path, mode, s, (ONE_OFF_LEAD, (a.prompt, SWITCH_EVERY)), a.name)
                for a in actions
                if not a.continuing
                for s in range(one_offs)
            ]
    return tasks


def _switching(seed: int, switches: int) -> tuple[tuple[str, int], ...]:
    """`switches` + 1 random continuing actions, each different from the one before."""
    continuing = [a for a in REPERTOIRE if a.continuing]
    rng = np.random.default_rng(seed)
    order = [continuing[0]]
    while len(order) < switches + 1:
        step = 1 + rng.integers(len(continuing) - 1)
        order.append(continuing[(continuing.index(order[-1]) + step) % len(continuing)])
    return tuple((a.prompt, SWITCH_EVERY) for a in order)


def _by_name(name: str) -> Action:
    return next(a for a in REPERTOIRE if a.name == name)


def judge(bundle, task: Task, made: Made) -> dict:
    """A task's verdicts and figures (JSON-ready)."""
    row = dict(kind=task.kind, column=task.column, seed=task.seed, action=task.action)
    joints, starts = made.joints, made.switches
    if task.kind == "one-off":
        check = WindowCheck(_by_name(task.action), ONE_OFF_WINDOW)
        return row | dict(reaction=reaction_frames(check, joints[starts[0] :]))
    if task.kind == "switches":
        ends = starts[1:] + [len(joints)]
        prompts = [p for p, _ in task.schedule[1:]]
        checks = {p: WindowCheck(_prompted(p), REACTION_WINDOW) for p in set(prompts)}
        reactions = [
            reaction_frames(checks[p], joints[a:b])
            for p, a, b in zip(prompts, starts, ends, strict=True)
        ]
        seen = None if made.received is None else visible(starts, reactions, made.received)
        return row | dict(reactions=reactions, visible=seen)
    action = _by_name(task.action)
    short = _worker_generator(bundle).generate(action.prompt, seconds=5, seed=task.seed).joints
    speed = joint_speed(joints)
    seams = [f for f in made.seams or () if 1 <= f < len(speed)]
    return row | dict(
        passes=window_passes(WindowCheck(action, WINDOW), joints),
        drift=drift(joints),
        short_slide=drift(short)["slide"],
        seam_speed=[float(speed[f - 1]) for f in seams] if made.seams is not None else None,
        fresh=made.fresh,
        ordinary_p99=float(np.percentile(speed, 99)),
        step_seconds=made.step_seconds,
    )


def _prompted(prompt: str) -> Action:
    return next(a for a in REPERTOIRE if a.prompt == prompt)


def make_and_judge(bundle, task: Task) -> tuple[dict, Made]:
    """What a worker process runs for a path other than serve."""
    return _judged(bundle, task, MAKERS[task.path](bundle, task))


def _judged(bundle, task: Task, made: Made) -> tuple[dict, Made]:
    return judge(bundle, task, made), made


def measure(bundle: str | None, tasks: list[Task], jobs: int) -> dict:
    """Every task: the served ones all at once on one `mogo serve` (on a thread here, while
    the others run `jobs` at a time), then judged; each path's frames against MotionStream's
    for the same schedule and seed."""
    served = [t for t in tasks if t.path == "serve"]
    progress = Progress(len(tasks), "long streams", unit="streams")
    rows, made = [], {}
    with ProcessPoolExecutor(jobs) as pool, ThreadPoolExecutor(1) as thread:
        futures = {pool.submit(make_and_judge, bundle, t): t for t in tasks if t.path != "serve"}
        serving = thread.submit(_serve_all, bundle, served) if served else None
        pending = set(futures) | {serving} - {None}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                if future is serving:
                    for task, motion in zip(served, future.result(), strict=True):
                        judged = pool.submit(_judged, bundle, task, motion)
                        futures[judged] = task
                        pending.add(judged)
                    continue
                row, made[futures[future]] = future.result()
                rows.append(row)
                progress.update()
    progress.close()
    return dict(
        columns=list(dict.fromkeys(t.column for t in tasks)),
        rows=sorted(rows, key=lambda r: (r["column"], r["kind"], r["action"], r["seed"])),
        agreement=_agreement(made),
    )


def _serve_all(bundle: str | None, tasks: list[Task]) -> list[Made]:
    """The served tasks, every one at once, on a fresh `mogo serve` (the serve extra)."""
    from mogo.bench.speed.serve import serving

    async def run(url: str) -> list[Made]:
        return await asyncio.gather(*(_served(url, t) for t in tasks))

    with serving(bundle, len(tasks), threads=2) as (base, _):
        return asyncio.run(run(base.replace("http", "ws", 1) + "/v1/stream"))


AGREE = 1e-3  # metres: frames this close to MotionStream's are the same frames


def _agreement(made: dict[Task, Made]) -> dict[str, dict]:
    """Per path, how its frames compare with the re-anchored MotionStream's for the same
    schedule and seed, where its switches took effect at the same frames (a served switch
    lands where the client's timing puts it; `continue` plays its first entry as a clip,
    another motion by design): the motions compared, those within AGREE to the end, the
    largest difference among those (m), and the frame where each other one leaves it (a
    token drawn otherwise at a near tie: the motion goes its own way from there)."""
    reference = {
        (t.kind, t.seed, t.schedule, t.low_latency): m
        for t, m in made.items()
        if t.path == "stream" and t.mode == "on"
    }
    out: dict[str, dict] = {}
    for task, motion in made.items():
        ref = reference.get((task.kind, task.seed, task.schedule, task.low_latency))
        if task.path in ("stream", "continue") or ref is None or ref.switches != motion.switches:
            continue
        n = min(len(ref.joints), len(motion.joints))
        gaps = np.abs(motion.joints[:n] - ref.joints[:n]).max(axis=(1, 2))
        row = out.setdefault(task.column, dict(motions=0, agree=0, largest=0.0, leaves=[]))
        row["motions"] += 1
        if gaps.max() <= AGREE:
            row["agree"] += 1
            row["largest"] = max(row["largest"], float(gaps.max()))
        else:
            row["leaves"].append(int(np.argmax(gaps > AGREE)))
    return out


def _share(flags: list[bool]) -> str:
    return f"{np.mean(flags):.0%}" if flags else "-"


def _kind(result: dict, kind: str, column: str) -> list[dict]:
    return [r for r in result["rows"] if r["kind"] == kind and r["column"] == column]


def _columns(result: dict, kind: str) -> list[str]:
    return [c for c in result["columns"] if _kind(result, kind, c)]


def _cell(rows: list[dict], action: Action) -> str:
    passes = [r["passes"] for r in rows if r["action"] == action.name]
    if action.continuing:
        return _share([p for ps in passes for p in ps])
    happened = sum(ps[0] for ps in passes)
    return f"{_share([p for ps in passes for p in ps[1:]])} (happens {happened}/{len(passes)})"


def action_table(result: dict) -> str:
    """Per action, the share of 10-s windows passing on each path."""
    columns = _columns(result, "action")
    rows = {c: _kind(result, "action", c) for c in columns}
    names = {r["action"] for c in columns for r in rows[c]}
    lines = [
        "| action | prompt | " + " | ".join(columns) + " |",
        "|---|---|" + "---|" * len(columns),
    ]
    for action in (a for a in REPERTOIRE if a.name in names):
        kind = "" if action.continuing else " (one-off: hold)"
        cells = " | ".join(_cell(rows[c], action) for c in columns)
        lines.append(f"| {action.name}{kind} | {action.prompt} | {cells} |")
    for title, continuing in (("all continuing", True), ("all one-off holds", False)):
        cells = [_share(_window_verdicts(rows[c], continuing)) for c in columns]
        lines.append(f"| **{title}** | | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _window_verdicts(rows: list[dict], continuing: bool) -> list[bool]:
    """The verdicts of the windows of the action streams `rows` of continuing actions, or of
    one-off actions' holds (their first window, the action, left out)."""
    return [
        p
        for r in rows
        if _by_name(r["action"]).continuing == continuing
        for p in (r["passes"] if continuing else r["passes"][1:])
    ]


def _one_offs_under_way(rows: list[dict]) -> list[bool]:
    return [r["reaction"] is not None and r["reaction"] <= ONE_OFF_SECONDS * FPS for r in rows]


def _switches_under_way(rows: list[dict]) -> list[bool]:
    return [r is not None and r <= PROMPT_SECONDS * FPS for s in rows for r in s["reactions"]]


def paths_plot(result: dict, path: Path) -> None:
    """The headline shares side by side per path (bars): continuing actions' windows passing,
    one-off holds' windows, one-off actions under way within ONE_OFF_SECONDS, switches within
    PROMPT_SECONDS."""
    measures = {
        "continuing: windows passing": lambda c: _window_verdicts(_kind(result, "action", c), True),
        "one-off holds: windows passing": lambda c: _window_verdicts(
            _kind(result, "action", c), False
        ),
        f"one-off under way within {ONE_OFF_SECONDS:g} s": lambda c: _one_offs_under_way(
            _kind(result, "one-off", c)
        ),
        f"switch under way within {PROMPT_SECONDS:g} s": lambda c: _switches_under_way(
            _kind(result, "switches", c)
        ),
    }
    groups = {
        c: {name: 100 * float(np.mean(flags)) for name, f in measures.items() if (flags := f(c))}
        for c in result["columns"]
    }
    bar_chart(path, "long streams on every path", "% passing", groups)


def one_off_table(result: dict) -> str:
    """Per one-off action, how often it is under way within ONE_OFF_SECONDS of the switch
    (or of the clip's end, `continue`), on each path."""
    columns = _columns(result, "one-off")
    if not columns:
        return ""
    rows = {c: _kind(result, "one-off", c) for c in columns}
    lines = [
        "| one-off action after a walk | " + " | ".join(columns) + " |",
        "|---|" + "---|" * len(columns),
    ]

    def within(rows: list[dict]) -> str:
        ok = _one_offs_under_way(rows)
        return f"{sum(ok)}/{len(ok)}"

    names = [a.name for a in REPERTOIRE if not a.continuing]
    for name in (n for n in names if any(r["action"] == n for c in columns for r in rows[c])):
        cells = [within([r for r in rows[c] if r["action"] == name]) for c in columns]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    shares = [within(rows[c]) for c in columns]
    medians = [
        f"{np.median([np.inf if r['reaction'] is None else r['reaction'] / FPS for r in rows[c]]):.2f}"
        for c in columns
    ]
    lines.append(f"| **under way within {ONE_OFF_SECONDS:g} s** | " + " | ".join(shares) + " |")
    lines.append("| median start (s) | " + " | ".join(medians) + " |")
    return "\n".join(lines)


def figures_table(result: dict) -> str:
    """Switch reaction, seams, drift, foot sliding, step time and frames against
    MotionStream's, per path."""
    columns = [
        c for c in result["columns"] if _kind(result, "action", c) or _kind(result, "switches", c)
    ]
    lines = ["| figure | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
    rows: dict[str, dict[str, str]] = {}
    for c in columns:
        streams = _kind(result, "action", c)
        reactions = [r for s in _kind(result, "switches", c) for r in s["reactions"]]
        seconds = np.array([np.inf if r is None else r / FPS for r in reactions])
        figures = {**_switch_figures(seconds), **_stream_figures(streams)}
        figures[
            f"frames as `stream, anchoring on`'s, same decoder (within {1000 * AGREE:g} mm)"
        ] = _agreed(result.get("agreement", {}).get(c))
        for name, value in figures.items():
            rows.setdefault(name, {})[c] = value
    lines += [
        f"| {name} | " + " | ".join(values.get(c, "-") for c in columns) + " |"
        for name, values in rows.items()
    ]
    return "\n".join(lines)


def _agreed(row: dict | None) -> str:
    if row is None:
        return "-"
    text = f"{row['agree']} of {row['motions']} (largest {1000 * row['largest']:.3f} mm)"
    if row["leaves"]:
        leaves = np.array(row["leaves"]) / FPS
        text += f"; the others leave it at {leaves.min():.1f} s (median {np.median(leaves):.0f} s)"
    return text


def _stream_figures(streams: list[dict]) -> dict[str, str]:
    """The figures of a path's action streams ('-' without any)."""
    if not streams:
        return {}
    seams = [(s, r["ordinary_p99"]) for r in streams for s in r["seam_speed"] or ()]
    known = any(r["seam_speed"] is not None for r in streams)
    fresh = sum(r["fresh"] for r in streams)
    d = [r["drift"] for r in streams]
    firsts = [r["step_seconds"][0] for r in streams if r["step_seconds"]]
    lasts = [r["step_seconds"][-1] for r in streams if r["step_seconds"]]
    return {
        "seams: joint speed above the stream's 99th percentile": (
            f"{np.mean([s > p for s, p in seams]):.1%} of {len(seams)} ({fresh} fresh clips)"
            if seams
            else "none"
            if known
            else "-"
        ),
        "pelvis height, 1st-99th percentile, lowest / highest stream (m)": (
            f"{min(x['pelvis_low'] for x in d):.2f} / {max(x['pelvis_high'] for x in d):.2f}"
        ),
        "deepest foot under the floor (cm)": f"{100 * max(x['under_floor'] for x in d):.1f}",
        "foot sliding in contact, stream / 5-s clips (cm/s)": (
            f"{100 * np.mean([x['slide'] for x in d]):.1f} / "
            f"{100 * np.mean([r['short_slide'] for r in streams]):.1f}"
        ),
        "mean joint acceleration (m/s^2)": f"{np.mean([x['acceleration'] for x in d]):.2f}",
        "ms per step, first / last minute (serve: paced to real time)": (
            f"{1000 * np.mean(firsts):.2f} / {1000 * np.mean(lasts):.2f}" if firsts else "-"
        ),
    }


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
    path."""
    per_minute = 60 * FPS // WINDOW
    series = {}
    for c in _columns(result, "action"):
        for title, continuing in (("continuing", True), ("one-off hold", False)):
            rows = [
                r["passes"] if continuing else [None] + r["passes"][1:]
                for r in _kind(result, "action", c)
                if _by_name(r["action"]).continuing == continuing
            ]
            minutes = [
                [p for ps in rows for p in ps[m : m + per_minute] if p is not None]
                for m in range(0, max(map(len, rows), default=0), per_minute)
            ]
            if any(minutes):
                series[f"{c}: {title}"] = [
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
    """Saved runs (long_streams.json) as one result, e.g. a run of each path. A motion in
    several runs (the same path, kind, action and seed: the reference stream beside each) is
    counted once."""
    runs = [json.loads(Path(path).read_text()) for path in paths]
    rows: dict[tuple, dict] = {}
    for row in (row for r in runs for row in r["rows"]):
        rows.setdefault((row["column"], row["kind"], row["action"], row["seed"]), row)
    return dict(
        columns=list(dict.fromkeys(c for r in runs for c in r["columns"])),
        lengths={c: v for r in runs for c, v in r["lengths"].items()},
        rows=list(rows.values()),
        agreement={c: v for r in runs for c, v in r["agreement"].items()},
    )


def report(result: dict) -> str:
    runs = "; ".join(
        f"{c}: {minutes:.3g}-minute streams, {seeds} seed(s) per action"
        for c, (minutes, seeds) in result["lengths"].items()
    )
    kinds = {r["kind"] for r in result["rows"]}
    if "switches" in kinds:
        runs += f"; switches every {SWITCH_EVERY // FPS} s between continuing actions"
    if "one-off" in kinds:
        runs += f"; one-off actions {ONE_OFF_LEAD[1] // FPS} s into '{ONE_OFF_LEAD[0]}'"
    tables = [action_table(result), one_off_table(result), figures_table(result)]
    tables.append(received_table(result))
    return f"{runs}\n\n" + "\n\n".join(t for t in tables if t) + "\n"


def main(args: argparse.Namespace) -> None:
    minutes, seeds, switches, one_offs = (
        (1 / 3, 1, 1, 1) if args.quick else (args.minutes, args.seeds, args.switches, args.one_offs)
    )
    actions = (
        tuple(a for a in REPERTOIRE if a.name in args.actions)
        if args.actions
        else tuple(REPERTOIRE[k] for k in (0, -5))
        if args.quick
        else REPERTOIRE
    )
    if args.tables_from:
        result = merged(args.tables_from)
    else:
        tasks = schedules(args.path, args.modes, actions, minutes, seeds, switches, one_offs)
        if args.low_latency:  # MotionStream's and served tasks again, the low-latency decoder
            tasks += [replace(t, low_latency=True) for t in tasks if t.path in LOW_LATENCY]
        result = measure(args.bundle, tasks, args.jobs)
        result["lengths"] = {c: (minutes, seeds) for c in result["columns"]}
    text = report(result)
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "long_streams.md").write_text(text)
    (out / "long_streams.json").write_text(json.dumps(result, indent=1))
    plot(result, out / "long_streams.png")
    written = "long_streams.md, .json and .png"
    if len(result["columns"]) > 1:
        paths_plot(result, out / "long_streams_paths.png")
        written += ", long_streams_paths.png"
    print(f"wrote {written} in {out}")
