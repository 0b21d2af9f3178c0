"""The animator's stepping moves (walk, jog, run, turn, spin): footsteps planned in world
space, with the pelvis, facing, torso twist and arm swing derived from the feet. The keyed
moves are in animator_moves.py."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mogo.export.data.animator_body import (
    FPS,
    LEFT,
    RIGHT,
    SIDES,
    Body,
    Track,
    curve,
    ease,
    facing,
    leftward,
    smooth,
)
from mogo.export.data.animator_moves import DEG, LIMBS, MIN_SECONDS, Place


@dataclass(frozen=True)
class Gait:
    """How a body steps: timing, foot clearance, and what the pelvis, torso and arms do."""

    period: float  # seconds per step
    stride: float  # metres the path advances per forward step (walk, jog, run)
    swing: float  # time a foot is off the floor, per step period (> 1: flight phases)
    lift: float  # foot clearance at mid-swing (m)
    bob: float  # pelvis rise per lifted foot (m); negative: lowest at mid-stance, as in running
    dip: float  # pelvis lowering while moving (m)
    lean: float  # forward torso bend while moving (rad)
    arm_gain: float  # arm swing (rad) per metre that the opposite foot is ahead
    arm_forward: float  # arms' swing while moving: bent arms carry the wrists forward (rad)
    arm_reach: float  # reach of the arms while moving (elbow bend)
    toe_off: float  # heel-up pitch as a foot leaves the floor (rad)
    crouch: float = 0.0  # pelvis lowered while moving (m); negative: raised, as on tiptoe
    tiptoe: float = 0.0  # heel-up pitch held while moving (rad)
    arm_spread: float | None = None  # arms held at this spread while moving (carrying)


GAITS = {
    "walk": Gait(0.55, 0.65, 0.78, 0.09, 0.02, 0.02, 2 * DEG, 0.45, 5 * DEG, 0.97, 20 * DEG),
    "jog": Gait(0.38, 0.75, 1.2, 0.14, -0.03, 0.05, 8 * DEG, 0.5, 35 * DEG, 0.72, 25 * DEG),
    "run": Gait(0.33, 1.05, 1.35, 0.2, -0.04, 0.07, 14 * DEG, 0.45, 40 * DEG, 0.62, 30 * DEG),
    "turn": Gait(0.42, 0.0, 0.7, 0.06, 0.01, 0.01, 0.0, 0.0, 0.0, 0.98, 10 * DEG),
    "spin": Gait(0.25, 0.0, 0.9, 0.07, 0.0, 0.04, 5 * DEG, 0.0, 20 * DEG, 0.8, 15 * DEG),
    # corpus v2's gaits
    "crouch_walk": Gait(
        0.6, 0.45, 0.75, 0.08, 0.01, 0.0, 35 * DEG, 0.3, 30 * DEG, 0.8, 15 * DEG, crouch=0.24
    ),
    "tiptoe": Gait(
        0.42,
        0.35,
        0.7,
        0.05,
        0.01,
        0.0,
        5 * DEG,
        0.2,
        25 * DEG,
        0.75,
        10 * DEG,
        crouch=-0.04,
        tiptoe=32 * DEG,
    ),
    "march": Gait(0.5, 0.6, 0.72, 0.22, 0.015, 0.03, 0.0, 1.3, 10 * DEG, 0.99, 10 * DEG),
    "limp": Gait(0.6, 0.5, 0.75, 0.06, 0.01, 0.03, 6 * DEG, 0.35, 5 * DEG, 0.95, 10 * DEG),
    "skip": Gait(0.36, 0.6, 1.25, 0.17, -0.05, 0.02, 4 * DEG, 0.9, 30 * DEG, 0.8, 30 * DEG),
    "carry": Gait(
        0.58,
        0.55,
        0.78,
        0.08,
        0.02,
        0.03,
        -3 * DEG,
        0.0,
        60 * DEG,
        0.62,
        15 * DEG,
        arm_spread=-12 * DEG,
    ),
    "stumble": Gait(0.55, 0.65, 0.78, 0.09, 0.02, 0.02, 2 * DEG, 0.45, 5 * DEG, 0.97, 20 * DEG),
}
# Corpus v2's walk, jog and run, calibrated against pybullet's DeepMimic clips
# (bench/quality/realism.py, docs/model.md): shorter, quicker steps, feet lifted higher, toes
# pushing off harder, arms swinging more in running.
NATURAL_GAITS = {
    **GAITS,
    "walk": Gait(0.51, 0.52, 0.8, 0.16, 0.005, 0.0, 2 * DEG, 0.55, 5 * DEG, 0.98, 35 * DEG),
    "jog": Gait(0.37, 0.7, 1.25, 0.22, -0.08, 0.02, 8 * DEG, 1.0, 40 * DEG, 0.7, 40 * DEG),
    "run": Gait(0.34, 0.95, 1.35, 0.3, -0.12, 0.02, 12 * DEG, 1.3, 45 * DEG, 0.6, 50 * DEG),
}
NATURAL_SWAY = 0.25  # share of the shift of weight over each foot that the pelvis follows
SPEEDS = {"slow": 0.75, "normal": 1.0, "fast": 1.3}  # speed multiplier: cadence^0.4 stride^0.6
# Heading of travel relative to the facing, and the stride's share of a forward stride
# (sideways: per pair of steps, the leading foot out, the trailing foot closing in).
DIRECTIONS = {
    "forward": (0.0, 1.0),
    "backward": (np.pi, 0.65),
    "left": (np.pi / 2, 0.45),
    "right": (-np.pi / 2, 0.45),
}
TURN_PER_STEP = {"turn": 75 * DEG, "spin": 100 * DEG}  # most rotation per re-planting
REFERENCE_LEG = 0.81  # the rest skeleton's leg; strides scale with the body's
HEEL_SECONDS = 0.12  # heel rises this long before the foot leaves the floor
LIFT_FIRST, SET_DOWN = 0.2, 0.15  # swing shares a foot spends going straight up and down
TOE_UP = 10 * DEG  # toes raised just before a foot lands
SWING_WEIGHT = 0.2  # a lifted foot's share in where the pelvis goes, against 1 planted
TWIST_GAIN = 0.15  # torso twist (rad) per metre that the right foot is ahead
LIMP_DIP, LIMP_LEAN = 0.035, 6 * DEG  # pelvis drop and lean while a hurt foot bears weight
LIMP_BEATS = (0.65, 1.35)  # periods after the hurt foot's step and after the good foot's
STUMBLE_LUNGE, STUMBLE_HASTE = 0.3, 0.3  # the catching step: strides longer, periods early


@dataclass(frozen=True)
class FootPlan:
    """One foot's footsteps: it leaves spots[k] at lifts[k] and lands on spots[k + 1] at
    lands[k]. Spots are where the ankle of the flat foot is, on the floor."""

    spots: np.ndarray  # (n + 1, 2)
    yaws: np.ndarray  # (n + 1,)
    lifts: np.ndarray  # (n,)
    lands: np.ndarray  # (n,)


def _stance(body: Body, xz: np.ndarray, yaw: float, foot: int) -> tuple[np.ndarray, float]:
    """Floor spot and yaw of one foot of a body standing relaxed at xz facing yaw."""
    return xz + leftward(yaw) * SIDES[foot] * body.stance, yaw + SIDES[foot] * body.toe_out


def _plans(
    body: Body,
    start: Place,
    steps: list[tuple[int, np.ndarray, float]],
    begin: float,
    period: float,
    swing: float,
    beats: np.ndarray,
) -> list[FootPlan]:
    """Both feet's plans from steps (foot, spot, yaw) taken from `begin` at `beats` periods."""
    plans = []
    for foot in (LEFT, RIGHT):
        spot, yaw = _stance(body, start.xz, start.yaw, foot)
        mine = [(k, s, y) for k, (f, s, y) in enumerate(steps) if f == foot]
        lifts = begin + period * beats[[k for k, _, _ in mine]]
        plans.append(
            FootPlan(
                np.array([spot] + [s for _, s, _ in mine]),
                np.array([yaw] + [y for _, _, y in mine]),
                lifts,
                lifts + swing * period,
            )
        )
    return plans


def _foot_channels(t: np.ndarray, plan: FootPlan, gait: Gait):
    """Floor position (T, 2), lift, yaw, pitch and swing phase u (T,) of one foot: planted,
    or on its way from one spot to the next (arcing up, and eased along the floor once it is
    clear of it, so a foot near the floor never slides)."""
    begun = np.searchsorted(plan.lifts, t, side="right")
    k = np.maximum(begun - 1, 0)
    u = np.where(
        begun > 0, np.clip((t - plan.lifts[k]) / (plan.lands[k] - plan.lifts[k]), 0.0, 1.0), 0.0
    )
    along = ease(np.clip((u - LIFT_FIRST) / (1.0 - LIFT_FIRST - SET_DOWN), 0.0, 1.0))
    xz = plan.spots[k] + along[:, None] * (plan.spots[k + 1] - plan.spots[k])
    yaw = plan.yaws[k] + along * (plan.yaws[k + 1] - plan.yaws[k])
    planted = plan.lifts - np.concatenate([[0.0], plan.lands[:-1]])
    heel = np.minimum(HEEL_SECONDS, 0.5 * planted)
    times = np.stack(
        [plan.lifts - heel, plan.lifts, plan.lifts + 0.6 * (plan.lands - plan.lifts), plan.lands],
        -1,
    ).ravel()
    values = np.tile([0.0, gait.toe_off, -TOE_UP, 0.0], len(plan.lifts))
    return xz, gait.lift * np.sin(np.pi * u), yaw, curve(times, values, t), u


def _step_track(
    body: Body,
    start: Place,
    steps: list,
    gait: Gait,
    period: float,
    beats: np.ndarray | None = None,
    hurt: int | None = None,
) -> Track:
    """Footsteps (foot, spot, yaw), one per period (or at `beats` periods from the first),
    and a body carried by them: the pelvis follows the planted feet (swaying over each), the
    facing follows the feet's yaw, the arms swing against the legs. A `hurt` foot takes the
    weight briefly, the pelvis dipping over it. Padded so the stance is relaxed at both ends."""
    beats = np.arange(len(steps), dtype=np.float64) if beats is None else beats
    radius = max(1, int(round(0.6 * period * FPS)))  # frames of smoothing for the body
    active = (beats[-1] + gait.swing) * period
    pad = max((radius + 1) / FPS, 0.5 * (MIN_SECONDS - active))  # the body comes to rest
    plans = _plans(body, start, steps, pad, period, gait.swing, beats)
    t = np.arange(int(round((active + 2 * pad) * FPS))) / FPS
    xz, lift, yaw, pitch, u = (
        np.stack(c, 1)
        for c in zip(*(_foot_channels(t, plan, gait) for plan in plans), strict=False)
    )
    in_air = np.sin(np.pi * u)  # (T, 2)

    weight = 1.0 - (1.0 - SWING_WEIGHT) * in_air
    root = smooth(np.sum(weight[..., None] * xz, 1) / weight.sum(1)[:, None], radius)
    body_yaw = smooth(np.mean(yaw - SIDES * body.toe_out, 1), radius)
    if body.natural:  # sway less: a person's pelvis shifts only partly over each foot
        side = leftward(body_yaw)
        shift = np.sum((root - smooth(xz.mean(1), 2 * radius)) * side, -1)
        root -= (1 - NATURAL_SWAY) * shift[:, None] * side
    moving = smooth(((t >= pad) & (t <= pad + active)).astype(np.float64), radius)
    ahead = np.sum((xz[:, RIGHT] - xz[:, LEFT]) * facing(body_yaw), -1)  # right foot's lead

    height = body.stand_height - (gait.dip + gait.crouch) * moving + gait.bob * in_air.sum(1)
    lean = np.zeros_like(t)
    if hurt is not None:  # weight on the hurt foot while the other swings: dip, lean away
        height -= LIMP_DIP * in_air[:, 1 - hurt]
        lean -= SIDES[hurt] * LIMP_LEAN * in_air[:, 1 - hurt]
    pelvis = np.stack([root[:, 0], smooth(height, 1), root[:, 1]], -1)
    torso = np.stack([body.posture + gait.lean * moving, lean, -TWIST_GAIN * ahead], -1)
    feet = np.stack([xz[..., 0], lift, xz[..., 1]], -1)
    return Track(
        pelvis=pelvis,
        yaw=body_yaw,
        torso=torso,
        arms=_swinging_arms(body, gait, moving, ahead),
        feet=feet,
        foot_yaw=yaw,
        foot_pitch=pitch + gait.tiptoe * moving[:, None],
    )


def _swinging_arms(body: Body, gait: Gait, moving: np.ndarray, ahead: np.ndarray) -> np.ndarray:
    """Arm angles (T, 2, 4) of a stepping move: each arm swings against its leg (`ahead`: the
    right foot's lead), the gait's carriage blended in while `moving`."""
    arms = np.empty((len(moving), 2, 4))
    arms[:, :, 0] = (
        body.arm_rest[0]
        + gait.arm_forward * moving[:, None]
        + body.arm_swing * gait.arm_gain * np.stack([ahead, -ahead], 1)
    )
    arms[:, :, 1] = body.arm_rest[1]
    if gait.arm_spread is not None:
        arms[:, :, 1] += (gait.arm_spread - body.arm_rest[1]) * moving[:, None]
    arms[:, :, 2] = body.arm_rest[2] + (gait.arm_reach - body.arm_rest[2]) * moving[:, None]
    arms[:, :, 3] = body.arm_rest[3]
    return arms


def _alternating(lead: int, count: int) -> list[int]:
    """Which foot takes each of `count` steps, starting with `lead`."""
    return [lead if k % 2 == 0 else 1 - lead for k in range(count)]


def _arc(s: np.ndarray, heading: float, curvature: float) -> np.ndarray:
    """Floor offsets (..., 2) after distances s along a path that starts along `heading` and
    turns by `curvature` radians per metre."""
    if abs(curvature) < 1e-9:
        return s[..., None] * facing(heading)
    end = heading + curvature * s
    return np.stack([np.cos(heading) - np.cos(end), np.sin(end) - np.sin(heading)], -1) / curvature


def locomotion(
    gait_name: str, params: dict, place: Place, body: Body, rng: np.random.Generator
) -> tuple[Track, Place]:
    """`steps` footsteps along a path in `direction` relative to the facing, the facing turning
    evenly by `turn` degrees along the way. Forward and backward steps alternate feet, the
    first half a stride and the last closing the feet (so at least two); sideways steps come
    in pairs, the leading foot out and the trailing foot in (an odd count gets one more
    closing step). Params a gait lacks are forward, straight, at normal speed; a limp favours
    its hurt `foot`; a stumble trips halfway and catches itself with one long quick step."""
    gait = (NATURAL_GAITS if body.natural else GAITS)[gait_name]
    direction = params.get("direction", "forward")
    heading, share = DIRECTIONS[direction]
    speed = SPEEDS[params.get("speed", "normal")] * rng.uniform(0.93, 1.07)
    period = gait.period / speed**0.4 / body.tempo
    stride = gait.stride * speed**0.6 * share * np.sqrt(body.energy) * body.leg / REFERENCE_LEG
    count = max(2, params["steps"])
    if direction in ("left", "right"):
        count += count % 2
        lead = LEFT if direction == "left" else RIGHT
        advance = stride * np.ceil(np.arange(1, count + 1) / 2)
    else:
        lead = int(rng.integers(2))
        advance = stride * np.minimum(np.arange(1, count + 1), count - 1)
    feet = _alternating(lead, count)
    beats, hurt = None, None
    if gait_name == "limp":
        hurt = LIMBS[params["foot"]][0]
        beats = np.concatenate([[0.0], np.cumsum([LIMP_BEATS[f != hurt] for f in feet[:-1]])])
    if gait_name == "stumble":
        trip = count // 2
        advance = advance + STUMBLE_LUNGE * stride * (np.arange(count) >= trip)
        beats = np.arange(count) - STUMBLE_HASTE * (np.arange(count) >= trip)
    if body.variation:  # no two steps alike: each lands a little early or late, long or short
        jitter = rng.normal(0.0, body.variation, (2, count))
        beats = np.arange(count, dtype=np.float64) if beats is None else beats
        beats = beats + np.concatenate([[0.0], np.cumsum(jitter[0, 1:])])
        asymmetric = 1 + body.asymmetry * SIDES[np.array(feet)]
        advance = np.cumsum(np.diff(advance, prepend=0.0) * (asymmetric + jitter[1]))
    length = advance[-1]
    turn = np.radians(params.get("turn", 0))
    curvature = turn / length
    points = place.xz + _arc(advance, place.yaw + heading, curvature)
    yaws = place.yaw + curvature * advance
    steps = [(f,) + _stance(body, p, y, f) for f, p, y in zip(feet, points, yaws, strict=False)]
    track = _step_track(body, place, steps, gait, period, beats, hurt)
    if gait_name == "stumble":
        _stumble(track, body, period, beats[trip])
    return track, Place(points[-1], place.yaw + turn)


def _stumble(track: Track, body: Body, period: float, beat: float) -> None:
    """The trip: torso pitched forward, arms thrown out in front, pelvis dropping, around the
    catching step (at `beat` periods from the first step), then recovered."""
    t = np.arange(len(track)) / FPS
    first = np.flatnonzero(np.abs(np.diff(track.feet[:, :, 1], axis=0)).sum(1) > 0)
    start = (first[0] / FPS if len(first) else 0.0) + beat * period
    bump = np.clip(1 - np.abs(t - start - 0.1) / (1.6 * period), 0.0, 1.0) ** 2
    track.torso[:, 0] += 28 * DEG * body.energy * bump
    track.pelvis[:, 1] -= 0.06 * bump
    track.arms[:, :, 0] += (75 * DEG * bump)[:, None]
    track.arms[:, :, 1] += (25 * DEG * bump)[:, None]


def turning(
    kind: str, angle: float, place: Place, body: Body, rng: np.random.Generator
) -> tuple[Track, Place]:
    """Turn in place by `angle` radians with small steps, the foot on the turning side first,
    each step re-planting a foot at the next share of the rotation."""
    gait = GAITS[kind]
    count = 2 + int(np.ceil(abs(angle) / TURN_PER_STEP[kind]))
    lead = LEFT if angle > 0 else RIGHT
    yaws = place.yaw + angle * np.minimum(np.arange(1, count + 1), count - 1) / (count - 1)
    steps = [
        (f,) + _stance(body, place.xz, y, f)
        for f, y in zip(_alternating(lead, count), yaws, strict=False)
    ]
    period = gait.period * rng.uniform(0.93, 1.07) / body.tempo
    return _step_track(body, place, steps, gait, period), Place(place.xz, place.yaw + angle)
