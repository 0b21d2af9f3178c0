"""The animator's stepping moves (walk, jog, run, turn, spin): footsteps planned in world
space, with the pelvis, facing, torso twist and arm swing derived from the feet. The keyed
moves are in animator_moves.py."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mogo.export.data.animator_body import (FPS, LEFT, RIGHT, SIDES, Body, Track, curve, ease,
                                            facing, leftward, smooth)
from mogo.export.data.animator_moves import DEG, MIN_SECONDS, Place


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


GAITS = {
    "walk": Gait(0.55, 0.65, 0.78, 0.09, 0.02, 0.02, 2 * DEG, 0.45, 5 * DEG, 0.97, 20 * DEG),
    "jog": Gait(0.38, 0.75, 1.2, 0.14, -0.03, 0.05, 8 * DEG, 0.5, 35 * DEG, 0.72, 25 * DEG),
    "run": Gait(0.33, 1.05, 1.35, 0.2, -0.04, 0.07, 14 * DEG, 0.45, 40 * DEG, 0.62, 30 * DEG),
    "turn": Gait(0.42, 0.0, 0.7, 0.06, 0.01, 0.01, 0.0, 0.0, 0.0, 0.98, 10 * DEG),
    "spin": Gait(0.25, 0.0, 0.9, 0.07, 0.0, 0.04, 5 * DEG, 0.0, 20 * DEG, 0.8, 15 * DEG),
}
SPEEDS = {"slow": 0.75, "normal": 1.0, "fast": 1.3}  # speed multiplier: cadence^0.4 stride^0.6
# Heading of travel relative to the facing, and the stride's share of a forward stride
# (sideways: per pair of steps, the leading foot out, the trailing foot closing in).
DIRECTIONS = {"forward": (0.0, 1.0), "backward": (np.pi, 0.65), "left": (np.pi / 2, 0.45),
              "right": (-np.pi / 2, 0.45)}
TURN_PER_STEP = {"turn": 75 * DEG, "spin": 100 * DEG}  # most rotation per re-planting
REFERENCE_LEG = 0.81  # the rest skeleton's leg; strides scale with the body's
HEEL_SECONDS = 0.12  # heel rises this long before the foot leaves the floor
LIFT_FIRST, SET_DOWN = 0.2, 0.15  # swing shares a foot spends going straight up and down
TOE_UP = 10 * DEG  # toes raised just before a foot lands
SWING_WEIGHT = 0.2  # a lifted foot's share in where the pelvis goes, against 1 planted
TWIST_GAIN = 0.15  # torso twist (rad) per metre that the right foot is ahead


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


def _plans(body: Body, start: Place, steps: list[tuple[int, np.ndarray, float]], begin: float,
           period: float, swing: float) -> list[FootPlan]:
    """Both feet's plans from steps (foot, spot, yaw) taken one per period from `begin`."""
    plans = []
    for foot in (LEFT, RIGHT):
        spot, yaw = _stance(body, start.xz, start.yaw, foot)
        mine = [(k, s, y) for k, (f, s, y) in enumerate(steps) if f == foot]
        lifts = begin + period * np.array([k for k, _, _ in mine], dtype=np.float64)
        plans.append(FootPlan(np.array([spot] + [s for _, s, _ in mine]),
                              np.array([yaw] + [y for _, _, y in mine]), lifts,
                              lifts + swing * period))
    return plans


def _foot_channels(t: np.ndarray, plan: FootPlan, gait: Gait):
    """Floor position (T, 2), lift, yaw, pitch and swing phase u (T,) of one foot: planted,
    or on its way from one spot to the next (arcing up, and eased along the floor once it is
    clear of it, so a foot near the floor never slides)."""
    begun = np.searchsorted(plan.lifts, t, side="right")
    k = np.maximum(begun - 1, 0)
    u = np.where(begun > 0, np.clip((t - plan.lifts[k]) / (plan.lands[k] - plan.lifts[k]),
                                    0.0, 1.0), 0.0)
    along = ease(np.clip((u - LIFT_FIRST) / (1.0 - LIFT_FIRST - SET_DOWN), 0.0, 1.0))
    xz = plan.spots[k] + along[:, None] * (plan.spots[k + 1] - plan.spots[k])
    yaw = plan.yaws[k] + along * (plan.yaws[k + 1] - plan.yaws[k])
    planted = plan.lifts - np.concatenate([[0.0], plan.lands[:-1]])
    heel = np.minimum(HEEL_SECONDS, 0.5 * planted)
    times = np.stack([plan.lifts - heel, plan.lifts, plan.lifts + 0.6 * (plan.lands - plan.lifts),
                      plan.lands], -1).ravel()
    values = np.tile([0.0, gait.toe_off, -TOE_UP, 0.0], len(plan.lifts))
    return xz, gait.lift * np.sin(np.pi * u), yaw, curve(times, values, t), u


def _step_track(body: Body, start: Place, steps: list, gait: Gait,
                period: float) -> Track:
    """Footsteps (foot, spot, yaw), one per period, and a body carried by them: the pelvis
    follows the planted feet (swaying over each), the facing follows the feet's yaw, the arms
    swing against the legs. Padded so the stance is relaxed at both ends."""
    radius = max(1, int(round(0.6 * period * FPS)))  # frames of smoothing for the body
    active = (len(steps) - 1 + gait.swing) * period
    pad = max((radius + 1) / FPS, 0.5 * (MIN_SECONDS - active))  # the body comes to rest
    plans = _plans(body, start, steps, pad, period, gait.swing)
    t = np.arange(int(round((active + 2 * pad) * FPS))) / FPS
    xz, lift, yaw, pitch, u = (np.stack(c, 1) for c in
                               zip(*(_foot_channels(t, plan, gait) for plan in plans)))
    in_air = np.sin(np.pi * u)  # (T, 2)

    weight = 1.0 - (1.0 - SWING_WEIGHT) * in_air
    root = smooth(np.sum(weight[..., None] * xz, 1) / weight.sum(1)[:, None], radius)
    body_yaw = smooth(np.mean(yaw - SIDES * body.toe_out, 1), radius)
    moving = smooth(((t >= pad) & (t <= pad + active)).astype(np.float64), radius)
    ahead = np.sum((xz[:, RIGHT] - xz[:, LEFT]) * facing(body_yaw), -1)  # right foot's lead

    height = body.stand_height - gait.dip * moving + gait.bob * in_air.sum(1)
    pelvis = np.stack([root[:, 0], smooth(height, 1), root[:, 1]], -1)
    torso = np.stack([body.posture + gait.lean * moving, np.zeros_like(t), -TWIST_GAIN * ahead], -1)
    arms = np.empty((len(t), 2, 4))
    arms[:, :, 0] = (body.arm_rest[0] + gait.arm_forward * moving[:, None]
                     + body.arm_swing * gait.arm_gain * np.stack([ahead, -ahead], 1))
    arms[:, :, 1] = body.arm_rest[1]
    arms[:, :, 2] = body.arm_rest[2] + (gait.arm_reach - body.arm_rest[2]) * moving[:, None]
    arms[:, :, 3] = body.arm_rest[3]
    feet = np.stack([xz[..., 0], lift, xz[..., 1]], -1)
    return Track(pelvis=pelvis, yaw=body_yaw, torso=torso, arms=arms, feet=feet, foot_yaw=yaw,
                 foot_pitch=pitch)


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


def locomotion(gait_name: str, params: dict, place: Place, body: Body,
               rng: np.random.Generator) -> tuple[Track, Place]:
    """`steps` footsteps along a path in `direction` relative to the facing, the facing turning
    evenly by `turn` degrees along the way. Forward and backward steps alternate feet, the
    first half a stride and the last closing the feet (so at least two); sideways steps come
    in pairs, the leading foot out and the trailing foot in (an odd count gets one more
    closing step)."""
    gait = GAITS[gait_name]
    heading, share = DIRECTIONS[params["direction"]]
    speed = SPEEDS[params["speed"]] * rng.uniform(0.93, 1.07)
    period = gait.period / speed ** 0.4 / body.tempo
    stride = gait.stride * speed ** 0.6 * share * np.sqrt(body.energy) * body.leg / REFERENCE_LEG
    count = max(2, params["steps"])
    if params["direction"] in ("left", "right"):
        count += count % 2
        lead = LEFT if params["direction"] == "left" else RIGHT
        advance = stride * np.ceil(np.arange(1, count + 1) / 2)
    else:
        lead = int(rng.integers(2))
        advance = stride * np.minimum(np.arange(1, count + 1), count - 1)
    length = advance[-1]
    turn = np.radians(params["turn"])
    curvature = turn / length
    points = place.xz + _arc(advance, place.yaw + heading, curvature)
    yaws = place.yaw + curvature * advance
    steps = [(f,) + _stance(body, p, y, f)
             for f, p, y in zip(_alternating(lead, count), points, yaws)]
    track = _step_track(body, place, steps, gait, period)
    return track, Place(points[-1], place.yaw + turn)


def turning(kind: str, angle: float, place: Place, body: Body,
            rng: np.random.Generator) -> tuple[Track, Place]:
    """Turn in place by `angle` radians with small steps, the foot on the turning side first,
    each step re-planting a foot at the next share of the rotation."""
    gait = GAITS[kind]
    count = 2 + int(np.ceil(abs(angle) / TURN_PER_STEP[kind]))
    lead = LEFT if angle > 0 else RIGHT
    yaws = place.yaw + angle * np.minimum(np.arange(1, count + 1), count - 1) / (count - 1)
    steps = [(f,) + _stance(body, place.xz, y, f) for f, y in zip(_alternating(lead, count), yaws)]
    period = gait.period * rng.uniform(0.93, 1.07) / body.tempo
    return _step_track(body, place, steps, gait, period), Place(place.xz, place.yaw + angle)
