"""Do the feet stay planted? Foot measures of generated locomotion as decoded and with the
runtime's foot planting (mogo.motion.feet), beside the corpus's real clips, the semantic checks
both ways (with --data), and what planting costs a stream per frame against one token step:

    python -m mogo.bench.quality.feet [--data DIR] [--per-primitive 20]
    python -m mogo.bench.quality.feet --windows   # the lookahead a stream waits, against quality

A contact frame of a foot joint (ankle or toe, t -> t+1) is one where the clip's contact
channel is above 0.5 and its decoded velocity is under HumanML3D's contact threshold (what a
contact means in the format); the "channel alone" rows count every frame the channel flags
(issue 25's definition).
Measures, on joints in metres:
- slide: horizontal speed of foot joints in contact (cm/s), and the share over 10 cm/s;
- floor: the deepest foot joint below y = 0 (cm), and the share of frames below -1 cm;
- pop: the change of a foot joint's velocity from one frame to the next (m/frame per frame,
  all frames): its worst per clip, averaged over clips, and its 99th percentile; the same
  worst for the pelvis (the body's stutter where planting moves it);
- bones: thigh, shin and foot lengths against the skeleton's canonical ones (the rest offsets,
  left and right averaged, as mogo.motion.rig), mean error (%) and share of bone-frames off by
  more than 1%;
- change: mean distance of every joint, and of the leg joints, from the decoded ones, the
  body's horizontal shift aside (each relative to its pelvis's ground point; cm);
- travel: the pelvis's horizontal path length against the decoded one's, per clip (%): its
  mean and the clip changed most.
The planted rows are the default planter (legs only: the body as decoded), the same with the
body stepping back past 1.34 m/s (FootPlanter's body_step), and the default holding flagged
joints up to 2.4 m/s instead of HumanML3D's contact threshold (what issue 25's channel-alone
target takes).
Torch-free.
"""

from __future__ import annotations

import argparse
import functools
import platform
import time
import warnings

import numpy as np

from mogo.arguments import PromptWarning
from mogo.bench.quality.evaluate import low_latency_window
from mogo.generator import STREAM_DECODE_EVERY, MotionGenerator
from mogo.motion.features import FOOT_CONTACT_THRESHOLD, JointStream, feature_layout
from mogo.motion.feet import (
    BODY_STEP,
    LOOKAHEAD,
    SHORT,
    WINDOW,
    FootPlanter,
    Window,
    leg_joints,
    planted,
)
from mogo.motion.rig import rest_offsets

LOCOMOTION = (
    "a person walks forward.",
    "a person jogs forward.",
    "a person runs forward.",
    "a person walks backward.",
    "a person turns around.",
    "a person walks in a circle.",
)
SEEDS, SECONDS = 4, 5.0  # 24 clips of 5 s
SLIDING = 0.10  # m/s: a contact frame faster than this slides
VARIANTS = {  # row name: FootPlanter's steps (m a frame)
    "feet planted": {},
    "feet planted, body past 1.34 m/s": dict(body_step=BODY_STEP),
    "feet planted, held under 2.4 m/s": dict(hold_step=0.12),
}
FLOOR = 0.01  # m below the floor that counts as penetration
TRADE_OFF = (  # (hold_step, body_step), m a frame: the --trade-off table's planters
    (FOOT_CONTACT_THRESHOLD**0.5, np.inf),
    (0.07, np.inf),
    (0.10, np.inf),
    (0.12, np.inf),
    (np.inf, np.inf),
    (FOOT_CONTACT_THRESHOLD**0.5, 0.067),
    (FOOT_CONTACT_THRESHOLD**0.5, FOOT_CONTACT_THRESHOLD**0.5),
    (0.07, 0.067),
    (0.10, 0.067),
    (0.12, 0.067),
    (np.inf, 0.067),
    (0.10, FOOT_CONTACT_THRESHOLD**0.5),
    (FOOT_CONTACT_THRESHOLD**0.5, 0.0),
)

WINDOWS = (  # the --windows table's planters: (blend_in, pin_frames), lookahead 8 down to 2
    WINDOW,
    Window(2, 5),
    Window(3, 3),
    Window(2, 3),
    Window(1, 4),
    Window(3, 2),
    Window(2, 2),
    Window(1, 3),
    Window(1, 2),
    Window(2, 1),
)


def contacts(features: np.ndarray, skeleton, confirmed: bool = True) -> np.ndarray:
    """(n, 4) contact flags of the ankle and toe joints of feature rows (n, D) (see the
    module doc)."""
    flags = features[:, -4:] > 0.5
    if confirmed:
        start = dict((name, s) for name, s, _ in feature_layout(skeleton))["joint_velocities"]
        feet = leg_joints(skeleton)[:, 2:].reshape(-1)
        velocity = (
            features[:, start : start + 3 * skeleton.num_joints]
            .reshape(len(flags), -1, 3)[:, feet]
            .astype(np.float64)
        )
        flags &= np.sum(velocity**2, -1) < FOOT_CONTACT_THRESHOLD
    return flags


def foot_measures(
    clips: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]], skeleton, confirmed: bool = True
) -> dict[str, float]:
    """The measures over clips (joints, features, decoded joints or None), frames pooled."""
    legs = leg_joints(skeleton)
    feet = legs[:, 2:].reshape(-1)
    rest = np.linalg.norm(rest_offsets(skeleton), axis=1)
    speeds, depths, below, pops, pelvis, errors, moved, moved_legs, travel = ([] for _ in range(9))
    for joints, features, decoded in clips:
        step = np.diff(joints[:, feet], axis=0)[..., [0, 2]]
        flags = contacts(features[: len(step)], skeleton, confirmed)  # real clips: T-1 rows
        speeds.append(np.linalg.norm(step, axis=-1)[flags] * skeleton.fps)
        lowest = joints[:, feet, 1].min(-1)
        depths.append(max(0.0, -float(lowest.min())))
        below.append(lowest < -FLOOR)
        pops.append(np.linalg.norm(np.diff(joints[:, feet], 2, axis=0), axis=-1).ravel())
        pelvis.append(np.linalg.norm(np.diff(joints[:, 0], 2, axis=0), axis=-1).max())
        for bone in range(3):
            a, b = legs[:, bone], legs[:, bone + 1]
            length = np.linalg.norm(joints[:, b] - joints[:, a], axis=-1)
            errors.append(np.abs(length / rest[b] - 1).ravel())
        if decoded is not None:
            ground = np.array([1.0, 0.0, 1.0])  # the pelvis's ground point: the body's shift
            distance = np.linalg.norm(
                (joints - joints[:, :1] * ground) - (decoded - decoded[:, :1] * ground), axis=-1
            )
            moved.append(distance.ravel())
            moved_legs.append(distance[:, legs[:, 1:].ravel()].ravel())
            travel.append(100 * (_path(joints) / max(_path(decoded), 1e-9) - 1))
    speed, error = np.concatenate(speeds), np.concatenate(errors)
    result = dict(
        speed=100 * speed.mean(),
        sliding=100 * np.mean(speed > SLIDING),
        depth=100 * max(depths),
        below=100 * np.concatenate(below).mean(),
        pop=np.mean([p.max() for p in pops]),
        pop_p99=float(np.percentile(np.concatenate(pops), 99)),
        pelvis_pop=float(np.mean(pelvis)),
        bone_error=100 * error.mean(),
        bone_off=100 * np.mean(error > 0.01),
    )
    if moved:
        result.update(
            change=100 * np.concatenate(moved).mean(),
            change_legs=100 * np.concatenate(moved_legs).mean(),
            travel=float(np.mean(travel)),
            travel_most=max(travel, key=abs),
        )
    return result


def _path(joints: np.ndarray) -> float:
    """Horizontal path length of the pelvis (m)."""
    return float(np.linalg.norm(np.diff(joints[:, 0, [0, 2]], axis=0), axis=-1).sum())


@functools.lru_cache(maxsize=4)
def locomotion(
    generator: MotionGenerator, first_seed: int = 0, low_latency: bool = False
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The 24 clips as decoded: (joints, features, joints) each (made once per generator);
    `low_latency`: their tokens decoded by the bundle's low-latency decoder, as its streams'."""
    clips, window = [], low_latency_window(generator) if low_latency else None
    for prompt in LOCOMOTION:
        for seed in range(first_seed, first_seed + SEEDS):
            motion = generator.generate(prompt, seconds=SECONDS, seed=seed, plant_feet=False)
            features, joints = motion.features, motion.joints
            if low_latency:
                features = generator.denormalised(window.decode_offline(motion.tokens))
                joints = JointStream(generator.skeleton).push(features)
            clips.append((joints, features, joints))
    return clips


def real_clips(data, limit: int = 500) -> list[tuple[np.ndarray, np.ndarray, None]]:
    from mogo.export.data.humanml3d import HumanML3DFolder

    folder = HumanML3DFolder(data, splits=("test",))
    return [(folder.joints(i), folder.features(i), None) for i in folder.ids("test")[:limit]]


def format_feet(rows: dict[str, dict[str, float]]) -> str:
    def cell(row, key, digits=1):
        return f"{row[key]:.{digits}f}" if key in row else "-"

    lines = [
        "| clips | slide in contact (cm/s) | sliding > 10 cm/s | deepest below floor (cm) "
        "| frames > 1 cm below | foot pop, worst per clip | foot pop, p99 "
        "| pelvis pop, worst per clip | leg bone error "
        "| bone-frames > 1% off | joint change (cm) | leg joint change (cm) "
        "| body travel vs decoded (most changed clip) |",
        "|---" * 13 + "|",
    ]
    for name, row in rows.items():
        lines.append(
            f"| {name} | {cell(row, 'speed')} | {cell(row, 'sliding')}% | "
            f"{cell(row, 'depth')} | {cell(row, 'below')}% | "
            f"{cell(row, 'pop', 3)} | {cell(row, 'pop_p99', 3)} | "
            f"{cell(row, 'pelvis_pop', 3)} | "
            f"{cell(row, 'bone_error', 2)}% | {cell(row, 'bone_off')}% | "
            f"{cell(row, 'change', 2)} | {cell(row, 'change_legs', 2)} | "
            + (
                f"{row['travel']:+.1f}% ({row['travel_most']:+.0f}%) |"
                if "travel" in row
                else "- |"
            )
        )
    return "\n".join(lines)


def feet_rows(generator: MotionGenerator, data=None) -> dict[str, dict[str, float]]:
    """The table's rows: the locomotion clips as decoded and planted by each of VARIANTS
    (contact confirmed by the decoded velocity, and the channel alone), and the corpus's real
    test clips."""
    decoded = locomotion(generator)
    variants = {
        name: [(planted(f, j, generator.skeleton, **steps), f, j) for j, f, _ in decoded]
        for name, steps in VARIANTS.items()
    }
    rows = {}
    for confirmed, label in ((True, ""), (False, ", channel alone")):
        rows[f"generated, as decoded{label}"] = foot_measures(
            decoded, generator.skeleton, confirmed
        )
        for name, clips in variants.items():
            rows[f"generated, {name}{label}"] = foot_measures(clips, generator.skeleton, confirmed)
    if data is not None:
        rows["real (corpus test split)"] = foot_measures(real_clips(data), generator.skeleton)
    return rows


def by_prompt(generator: MotionGenerator) -> str:
    """Per prompt (its seeds' clips): the body's travel with the body step against the
    decoded, and the worst foot pop per clip as decoded, planted, and with the body step."""
    clips, skeleton = locomotion(generator), generator.skeleton
    body = VARIANTS["feet planted, body past 1.34 m/s"]
    lines = [
        "| prompt | body travel vs decoded, body step | foot pop, worst per clip: as "
        "decoded / planted / body step |",
        "|---|---|---|",
    ]
    for k, prompt in enumerate(LOCOMOTION):
        mine = clips[k * SEEDS : (k + 1) * SEEDS]
        pops = [
            foot_measures(
                [
                    (j if steps is None else planted(f, j, skeleton, **steps), f, j)
                    for j, f, _ in mine
                ],
                skeleton,
                False,
            )
            for steps in (None, {}, body)
        ]
        lines.append(
            f"| {prompt} | {pops[2]['travel']:+.1f}% | "
            + " / ".join(f"{p['pop']:.3f}" for p in pops)
            + " |"
        )
    return "\n".join(lines)


def trade_off(generator: MotionGenerator) -> str:
    """The channel-alone slide against the pop and the body's travel, planter by planter
    (TRADE_OFF), on the 24 clips and, for the slide, on 24 others (the next SEEDS seeds)."""
    skeleton = generator.skeleton
    lines = [
        "| planter | slide, channel alone (cm/s) | > 10 cm/s | foot pop, worst per clip | "
        'p99 | worst, "walks forward" | pelvis pop, worst per clip | body travel vs '
        f"decoded (most changed clip) | slide, seeds {SEEDS}-{2 * SEEDS - 1} |",
        "|---" * 9 + "|",
    ]
    for hold, body in TRADE_OFF:
        main, other = (
            [(planted(f, j, skeleton, hold_step=hold, body_step=body), f, j) for j, f, _ in clips]
            for clips in (locomotion(generator), locomotion(generator, SEEDS))
        )
        row, walks = (foot_measures(clips, skeleton, False) for clips in (main, main[:SEEDS]))
        lines.append(
            f"| {_planter(hold, body, skeleton.fps)} | {row['speed']:.1f} | "
            f"{row['sliding']:.1f}% | "
            f"{row['pop']:.3f} | {row['pop_p99']:.3f} | {walks['pop']:.3f} | "
            f"{row['pelvis_pop']:.3f} | {row['travel']:+.1f}% "
            f"({row['travel_most']:+.0f}%) | "
            f"{foot_measures(other, skeleton, False)['speed']:.1f} |"
        )
    return "\n".join(lines)


def windows(generator: MotionGenerator, low_latency: bool = False) -> str:
    """The default planter with each of WINDOWS (what a stream waits for its feet) against
    the slide and the pops, on the 24 clips (the slide on 24 others too); `low_latency`: the
    clips decoded by the bundle's low-latency decoder."""
    skeleton = generator.skeleton
    lines = [
        "| blend-in + pin frames | lookahead (frames) | slide in contact (cm/s) | channel alone "
        "| > 10 cm/s, channel alone | foot pop, worst per clip | p99 | leg bone error | "
        f"leg joint change (cm) | slide, channel alone, seeds {SEEDS}-{2 * SEEDS - 1} |",
        "|---" * 10 + "|",
    ]
    for window in (None, *WINDOWS):
        main, other = (
            [
                (j if window is None else planted(f, j, skeleton, window=window), f, j)
                for j, f, _ in clips
            ]
            for clips in (
                locomotion(generator, 0, low_latency),
                locomotion(generator, SEEDS, low_latency),
            )
        )
        confirmed, alone = (foot_measures(main, skeleton, c) for c in (True, False))
        name = (
            "as decoded"
            if window is None
            else f"{window.blend_in} + {window.pin_frames}"
            + " (default)" * (window == WINDOW)
            + " (low-latency streams)" * (window == SHORT)
        )
        lines.append(
            f"| {name} | {'-' if window is None else window.lookahead} | "
            f"{confirmed['speed']:.1f} | {alone['speed']:.1f} | {alone['sliding']:.1f}% | "
            f"{alone['pop']:.3f} | {alone['pop_p99']:.3f} | {alone['bone_error']:.2f}% | "
            f"{alone['change_legs']:.2f} | {foot_measures(other, skeleton, False)['speed']:.1f} |"
        )
    return "\n".join(lines)


def _planter(hold: float, body: float, fps: float) -> str:
    """A planter's row name, its steps in m/s."""
    body = (
        "legs only"
        if body == np.inf
        else "body takes every flagged step"
        if body == 0
        else f"body past {body * fps:.2f} m/s"
    )
    hold = "every flagged frame held" if hold == np.inf else f"held under {hold * fps:.1f} m/s"
    return f"{body}, {hold}"


def semantic_both_ways(
    generator: MotionGenerator, data, per_primitive: int = 20, seed: int = 0
) -> dict[str, tuple[tuple[int, int], tuple[int, int]]]:
    """Semantic pass rates per primitive (mogo.bench.quality.semantic's sample and checks) of
    the same generated clips as decoded and with planted feet -> {primitive: (decoded,
    planted)}, each (passed, total), "all" last."""
    from mogo.bench.quality.semantic import check, pass_rates, program_items, stratified
    from mogo.export.data.humanml3d import HumanML3DFolder

    folder = HumanML3DFolder(data, splits=("test",))
    items = stratified(program_items(data, folder.ids("test")), per_primitive, seed)
    verdicts: tuple[list, list] = ([], [])
    for k, item in enumerate(items):
        with warnings.catch_warnings():  # held-out caption words: the sample is what it is
            warnings.simplefilter("ignore", PromptWarning)
            motion = generator.generate(
                item.caption, seconds=item.frames / generator.fps, seed=seed + k, plant_feet=False
            )
        real = folder.joints(item.clip_id)[item.start : item.end]
        for joints, kept in zip(
            (motion.joints, planted(motion.features, motion.joints, generator.skeleton)),
            verdicts,
            strict=False,
        ):
            kept.append(check(item, joints, real))
    decoded, planted_rates = (pass_rates(items, kept) for kept in verdicts)
    rows = {name: (decoded[name], planted_rates[name]) for name in decoded}
    rows["all"] = tuple(
        tuple(map(sum, zip(*column, strict=False))) for column in zip(*rows.values(), strict=False)
    )
    return rows


def format_semantic_both_ways(rows) -> str:
    lines = ["| primitive | as decoded | feet planted |", "|---|---|---|"]
    lines += [f"| {name} | {a[0]}/{a[1]} | {b[0]}/{b[1]} |" for name, (a, b) in rows.items()]
    return "\n".join(lines)


def cost(generator: MotionGenerator, threads: tuple[int, ...] = (1, 2), rounds: int = 7) -> str:
    """Per-frame cost of planting (pushed in the stream's bursts) against one token step, timed
    in turn (median of `rounds`), and a stream's first frame with and without planting (median
    of `rounds` streams)."""
    clips = locomotion(generator)
    frames = sum(len(joints) for joints, _, _ in clips)
    lines = [
        "| threads | token step (ms) | planting per frame (ms) | share of a step | first "
        "frame as decoded (ms) | first frame, feet planted (ms) |",
        "|---" * 6 + "|",
    ]
    for count in threads:
        sized = MotionGenerator(generator.bundle, count)
        stream = sized.stream(LOCOMOTION[0], seed=0, plant_feet=False)
        for _ in range(50):  # past the decoder's first frame, the cache warm
            stream.step()
        steps, planting = [], []
        for _ in range(rounds):
            steps.append(
                _seconds(lambda s=stream: [s.step() for _ in range(frames // 24)])
                / (frames // 24)
                / generator.down_factor
            )
            planting.append(
                _seconds(lambda: [_plant_in_bursts(generator.skeleton, clip) for clip in clips])
                / frames
            )
        step, per_frame = float(np.median(steps)), float(np.median(planting))
        first = [
            np.median(
                [
                    _seconds(
                        lambda g=sized, p=plant: next(
                            g.stream(LOCOMOTION[0], seed=0, plant_feet=p).frames()
                        )
                    )
                    for _ in range(rounds)
                ]
            )
            for plant in (False, True)
        ]
        lines.append(
            f"| {count} | {1e3 * step:.2f} | {1e3 * per_frame:.3f} | "
            f"{per_frame / step:.1%} | {1e3 * first[0]:.0f} | {1e3 * first[1]:.0f} |"
        )
    return "\n".join(lines)


def _plant_in_bursts(skeleton, clip) -> None:
    joints, features, _ = clip
    planter = FootPlanter(skeleton)
    for at in range(0, len(joints), STREAM_DECODE_EVERY):
        burst = slice(at, at + STREAM_DECODE_EVERY)
        planter.push(features[burst], joints[burst])
    planter.flush()


def _seconds(call) -> float:
    start = time.perf_counter()
    call()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", help="the procedural corpus: adds its real clips' row")
    parser.add_argument("--bundle", help="bundle folder (default: the shipped one)")
    parser.add_argument(
        "--per-primitive",
        type=int,
        default=20,
        help="generated captions per primitive for the semantic checks",
    )
    parser.add_argument(
        "--trade-off",
        action="store_true",
        help="only the table of planters: slide against pop and travel",
    )
    parser.add_argument(
        "--windows",
        action="store_true",
        help="only the table of planting windows: the lookahead a stream waits against "
        "slide and pop",
    )
    args = parser.parse_args()
    generator = MotionGenerator.load(args.bundle)
    if args.trade_off:
        print(trade_off(generator))
        return
    if args.windows:
        print(f"Decoded by the centred decoder:\n\n{windows(generator)}\n")
        if generator.manifest.vq.low_latency_decoder is not None:
            print(f"Decoded by the low-latency decoder:\n\n{windows(generator, True)}\n")
        return
    print(
        f"{len(LOCOMOTION) * SEEDS} generated clips of {SECONDS:g} s ({', '.join(LOCOMOTION)}; "
        f"seeds 0-{SEEDS - 1}); planting reads {LOOKAHEAD} frames ahead\n"
    )
    print(format_feet(feet_rows(generator, args.data)))
    print(f"\nPer prompt ({SEEDS} clips each):\n\n{by_prompt(generator)}")
    if args.data:
        print(
            f"\nSemantic checks (mogo.bench.quality.semantic, {args.per_primitive} test captions "
            f"per primitive, the same clips both ways):\n"
        )
        print(
            format_semantic_both_ways(semantic_both_ways(generator, args.data, args.per_primitive))
        )
    print(
        f"\nPlanting's cost ({platform.processor() or platform.machine()}, "
        f"{STREAM_DECODE_EVERY}-frame pushes as a stream makes them):\n"
    )
    print(cost(generator))


if __name__ == "__main__":
    main()
