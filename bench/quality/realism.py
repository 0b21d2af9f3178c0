"""How human the animator moves: `python -m mogo.bench.quality.realism [--cache C] [--out DIR]
[--clips N]`.

The measures a person's eye reads in walking, running, jumping and kicking, taken alike from
corpus v1's animator, corpus v2's and pybullet's real DeepMimic clips (real_motion fetches
them): speed, step length (over the leg's length) and cadence, pelvis bob and sway, arm swing,
knee flexion in stance and in swing, foot clearance, a jump's crouch, flight and rise, a kick's
height and timing, and how alike successive steps are. Numpy only, no model. Prints the
markdown table (each animator measure the mean over N random performers doing the same
segment) and writes OUT/realism.md and OUT/realism_sheet.png: per move a row of real frames,
then v1's, then v2's; and OUT/corpus_v2_sheet.png, a row per primitive v2 adds.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from mogo.bench.quality.real_motion import deepmimic_clips
from mogo.clip import Motion
from mogo.export.data.animator import CORPORA, Segment, animate, sample_segment
from mogo.motion.features import facing_directions
from mogo.motion.render import Camera, render_frames
from mogo.motion.skeleton import SMPL_22

FPS = SMPL_22.fps
PELVIS, KNEES, ANKLES, WRISTS = 0, (4, 5), (7, 8), (20, 21)
HIPS, FEET = (1, 2), (7, 8, 10, 11)
PLANTED = 0.03  # m: an ankle this close to its lowest height bears weight
AIRBORNE = 0.05  # m: every foot joint this far above its lowest, the body is in the air
# The segment each real clip is measured against (forward, straight, at normal speed).
MOVES = {
    "walk": (
        ("humanoid3d_walk", "walker_0walk_forward"),
        Segment("walk", {"direction": "forward", "speed": "normal", "steps": 8, "turn": 0}),
    ),
    "run": (
        ("humanoid3d_run",),
        Segment("run", {"direction": "forward", "speed": "fast", "steps": 8, "turn": 0}),
    ),
    "jump": (("humanoid3d_jump",), Segment("jump", {"forward": True, "count": 1})),
    "kick": (("humanoid3d_kick",), Segment("kick", {"foot": "right"})),
    "punch": (("humanoid3d_punch",), Segment("punch", {"hand": "right", "count": 1})),
}
GAIT_MEASURES = (
    "speed (m/s)",
    "step length / leg",
    "cadence (steps/min)",
    "pelvis bob (mm)",
    "pelvis sway (mm)",
    "arm swing (mm)",
    "knee flexion in stance (deg)",
    "knee flexion in swing (deg)",
    "foot clearance (mm)",
    "step time spread (% of a step)",
)


def _leg(joints: np.ndarray) -> float:
    first = joints[0]
    return float(np.linalg.norm(first[1] - first[4]) + np.linalg.norm(first[4] - first[7]))


def _knee_flexion(joints: np.ndarray) -> np.ndarray:
    """(T, 2) degrees each knee bends away from straight."""
    thigh = joints[:, HIPS] - joints[:, KNEES]
    shin = joints[:, ANKLES] - joints[:, KNEES]
    cosine = (
        np.sum(thigh * shin, -1) / np.linalg.norm(thigh, axis=-1) / np.linalg.norm(shin, axis=-1)
    )
    return 180.0 - np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def _steady(joints: np.ndarray) -> slice:
    """The frames of steady travel: horizontal pelvis speed above 70% of its median while
    moving (a whole real clip is one steady cycle)."""
    speed = np.linalg.norm(np.diff(joints[:, PELVIS, [0, 2]], axis=0), axis=-1) * FPS
    moving = speed > 0.2
    if moving.all():
        return slice(0, len(joints))
    fast = np.flatnonzero(speed > 0.7 * np.median(speed[moving]))
    return slice(int(fast[0]), int(fast[-1]) + 2)


def gait_measures(joints: np.ndarray) -> dict[str, float]:
    """The GAIT_MEASURES of one clip of straight walking or running."""
    joints = joints[_steady(joints)]
    seconds = (len(joints) - 1) / FPS
    forward = facing_directions(joints, SMPL_22)
    left = np.cross([0.0, 1.0, 0.0], forward)
    pelvis = joints[:, PELVIS]
    travel = pelvis[-1, [0, 2]] - pelvis[0, [0, 2]]
    speed = np.linalg.norm(travel) / seconds
    lead = np.einsum("tc,tc->t", joints[:, ANKLES[1]] - joints[:, ANKLES[0]], forward)
    crossings = np.flatnonzero(np.diff(np.sign(lead)) != 0)  # one per step
    steps_per_second = len(crossings) / seconds
    line = pelvis[0] + np.linspace(0.0, 1.0, len(pelvis))[:, None] * (pelvis[-1] - pelvis[0])
    sideways = np.einsum("tc,tc->t", pelvis - line, left)
    height = pelvis[:, 1] - (line[:, 1] - line[0, 1])
    wrists = np.einsum("tjc,tc->tj", joints[:, WRISTS] - pelvis[:, None], forward)
    ankles = joints[:, ANKLES, 1]
    planted = ankles < ankles.min(0) + PLANTED
    flexion = _knee_flexion(joints)
    intervals = np.diff(crossings) / FPS
    return {
        "speed (m/s)": speed,
        "step length / leg": speed / max(steps_per_second, 1e-9) / _leg(joints),
        "cadence (steps/min)": 60 * steps_per_second,
        "pelvis bob (mm)": 1000 * np.ptp(height),
        "pelvis sway (mm)": 1000 * np.ptp(sideways),
        "arm swing (mm)": 1000 * np.ptp(wrists, axis=0).mean(),
        "knee flexion in stance (deg)": float(np.median(flexion[planted])),
        "knee flexion in swing (deg)": float(flexion.max(0).mean()),
        "foot clearance (mm)": 1000 * np.ptp(ankles, axis=0).mean(),
        "step time spread (% of a step)": (
            100 * intervals.std() / intervals.mean() if len(intervals) > 2 else np.nan
        ),
    }


def jump_measures(joints: np.ndarray) -> dict[str, float]:
    feet = joints[:, FEET, 1].min(1)
    air = feet > feet.min() + AIRBORNE
    takeoff = int(np.argmax(air)) if air.any() else len(joints) - 1
    pelvis = joints[:, PELVIS, 1]
    stand = pelvis[0]
    return {
        "crouch before take-off (mm)": 1000 * (stand - pelvis[: takeoff + 1].min()),
        "time in the air (s)": air.sum() / FPS,
        "pelvis rise (mm)": 1000 * (pelvis.max() - stand),
        "distance (m)": float(
            np.linalg.norm(joints[-1, PELVIS, [0, 2]] - joints[0, PELVIS, [0, 2]])
        ),
    }


def kick_measures(joints: np.ndarray) -> dict[str, float]:
    ankles = joints[:, ANKLES, 1] - joints[:, ANKLES, 1].min(0)
    foot = int(np.argmax(ankles.max(0)))
    up = np.flatnonzero(ankles[:, foot] > AIRBORNE)
    peak = int(np.argmax(ankles[:, foot]))
    reach = np.einsum(
        "tc,tc->t", joints[:, ANKLES[foot]] - joints[:, PELVIS], facing_directions(joints, SMPL_22)
    )
    return {
        "kicking ankle's peak height (mm)": 1000 * ankles[peak, foot],
        "kicking ankle's reach in front (mm)": 1000 * reach.max(),
        "lift-off to peak (s)": (peak - up[0]) / FPS if len(up) else np.nan,
        "foot off the floor (s)": len(up) / FPS,
    }


def punch_measures(joints: np.ndarray) -> dict[str, float]:
    forward = facing_directions(joints, SMPL_22)
    reach = np.einsum("tjc,tc->tj", joints[:, WRISTS] - joints[:, (16, 17)], forward)
    speed = np.linalg.norm(np.diff(joints[:, WRISTS], axis=0), axis=-1).max(0) * FPS
    return {
        "fist's reach in front of the shoulder (mm)": 1000 * reach.max(),
        "fist's top speed (m/s)": float(speed.max()),
    }


MEASURE = {
    "walk": gait_measures,
    "run": gait_measures,
    "jump": jump_measures,
    "kick": kick_measures,
    "punch": punch_measures,
}


def _animated(segment: Segment, natural: bool, seed: int) -> np.ndarray:
    return animate([segment], np.random.default_rng(seed), natural).joints.astype(np.float64)


def measure_all(cache: Path, clips: int) -> tuple[list[tuple], dict[str, dict]]:
    """Table rows (move, measure, v1, v2, real) and each move's joints for the sheet."""
    real_files = {p.stem: p for p in deepmimic_clips(cache)}
    rows, shown = [], {}
    for move, (names, segment) in MOVES.items():
        real = [Motion.from_file(real_files[name]).joints.astype(np.float64) for name in names]
        sources = {
            "v1": [_animated(segment, False, s) for s in range(clips)],
            "v2": [_animated(segment, True, s) for s in range(clips)],
            "real": real,
        }
        values = {k: [MEASURE[move](j) for j in v] for k, v in sources.items()}
        for name in values["real"][0]:
            rows.append(
                (move, name)
                + tuple(
                    float(np.nanmean([m[name] for m in values[k]])) for k in ("v1", "v2", "real")
                )
            )
        shown[move] = {k: v[0] for k, v in sources.items()}
    return rows, shown


def table(rows: list[tuple], clips: int) -> str:
    lines = [
        f"| move | measure | corpus v1 (mean of {clips}) | corpus v2 (mean of {clips}) | "
        "real (DeepMimic) |",
        "| --- | --- | ---: | ---: | ---: |",
    ]
    for move, name, *values in rows:
        lines.append(
            f"| {move} | {name} | "
            + " | ".join(
                "n/a" if np.isnan(v) else f"{v:.2f}" if abs(v) < 10 else f"{v:.0f}" for v in values
            )
            + " |"
        )
    return "\n".join(lines)


def sheet(shown: dict[str, dict], path: Path, size: int = 72, columns: int = 8) -> None:
    """Per move three rows (real, v1, v2), `columns` frames spread over each clip's first
    2.5 s, `size` pixels each."""
    sheet = Image.new("RGB", (columns * size, 3 * size * len(shown)), "white")
    camera = Camera(size=192, focal=330, centre_y=110, distance=4.5, look_height=0.8)
    for m, (move, sources) in enumerate(shown.items()):
        for r, source in enumerate(("real", "v1", "v2")):
            joints = sources[source]
            times = np.linspace(0, min(len(joints), int(2.5 * FPS)) - 1, columns).astype(int)
            label = f"{move}: {'DeepMimic' if source == 'real' else 'corpus ' + source}"
            frames = render_frames(joints, label, camera=camera)
            for c, t in enumerate(times):
                sheet.paste(
                    frames[t].convert("RGB").resize((size, size)), (c * size, (3 * m + r) * size)
                )
    sheet.quantize(32).save(path, optimize=True)


def primitives_sheet(path: Path, size: int = 64, columns: int = 8, seed: int = 0) -> None:
    """A row per primitive corpus v2 adds to v1, `columns` frames over one random clip of it
    by a v2 performer."""
    new = [name for name in CORPORA["v2"] if name not in CORPORA["v1"]]
    sheet = Image.new("RGB", (columns * size, size * len(new)), "white")
    camera = Camera(size=192, focal=330, centre_y=110, distance=4.5, look_height=0.8)
    rng = np.random.default_rng(seed)
    for r, name in enumerate(new):
        segment = sample_segment(name, rng)
        joints = animate([segment], rng, natural=True).joints
        frames = render_frames(joints, name.replace("_", " "), camera=camera)
        for c, t in enumerate(np.linspace(0, len(joints) - 1, columns).astype(int)):
            sheet.paste(frames[t].convert("RGB").resize((size, size)), (c * size, r * size))
    sheet.quantize(32).save(path, optimize=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--cache",
        type=Path,
        default=Path.home() / ".cache" / "mogo",
        help="where pybullet's wheel is fetched to (as mogo bench real-motion)",
    )
    parser.add_argument("--out", type=Path, default=Path("realism"))
    parser.add_argument(
        "--clips", type=int, default=8, help="random performers per animator measure"
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows, shown = measure_all(args.cache, args.clips)
    text = table(rows, args.clips)
    (args.out / "realism.md").write_text(text + "\n")
    sheet(shown, args.out / "realism_sheet.png")
    primitives_sheet(args.out / "corpus_v2_sheet.png")
    print(text)
    print(f"wrote {args.out}/realism.md, realism_sheet.png and corpus_v2_sheet.png")


if __name__ == "__main__":
    main()
