"""The animator's primitives: each turns a segment's params into a `Track` that starts and ends
in the relaxed stance, and says where the body stands and faces at its end.

Two kinds: keyed moves (here: everything but stepping) are a list of key poses, relative to the
relaxed stance, joined by monotone cubic curves; stepping moves (walk, jog, run, turn, spin,
animator_steps.py) plan footsteps in world space and derive the pelvis, facing and arm swing
from the feet.
"""

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
    facing,
    leftward,
)

DEG = np.pi / 180
MIN_SECONDS = 2.0  # shorter segments are padded with standing, so one segment makes a clip
TIMING_JITTER = 0.1  # each key's duration varies by up to this share
# Corpus v2, calibrated against pybullet's DeepMimic jump and punch (bench/quality/realism.py):
# jumps crouch deeper, fly longer, higher and further; punches strike faster.
NATURAL_JUMP, NATURAL_STRIKE = 1.35, 0.55


@dataclass(frozen=True)
class Place:
    """Where a segment starts: the pelvis's floor position (x, z) and the facing yaw."""

    xz: np.ndarray
    yaw: float


# ---------------------------------------------------------------------------------------------
# Keyed moves

POSE = {
    "pelvis": slice(0, 3),
    "torso": slice(3, 6),
    "arms": slice(6, 14),
    "feet": slice(14, 20),
    "pitch": slice(20, 22),
}  # layout of a key pose vector


def pose(
    body: Body,
    pelvis=(0.0, 0.0, 0.0),
    torso=(0.0, 0.0, 0.0),
    arms=None,
    feet=None,
    pitch=(0.0, 0.0),
) -> np.ndarray:
    """A key pose (22,): offsets from the relaxed stance in the body frame (pelvis: left, up,
    forward; torso: bend, lean, twist added to the posture; feet (2, 3): outward, lift,
    forward), foot pitches, and the arms' absolute angles (2, 4) (see `arm`)."""
    arms = np.broadcast_to(body.arm_rest, (2, 4)) if arms is None else arms
    feet = np.zeros((2, 3)) if feet is None else feet
    return np.concatenate([pelvis, torso, np.ravel(arms), np.ravel(feet), pitch])


def arm(swing: float, spread: float, reach: float, flare: float = 0.0) -> np.ndarray:
    """One arm's channels (see Track.arms)."""
    return np.array([swing, spread, reach, flare])


LIMBS = {"left": [LEFT], "right": [RIGHT], "both": [LEFT, RIGHT]}


def limbs(which: str, value, other) -> np.ndarray:
    """(2, n): `value` on the named limb or limbs ("left", "right", "both"), `other` on the
    rest; for arms and foot offsets."""
    out = np.array([other, other], dtype=np.float64)
    out[LIMBS[which]] = value
    return out


def both(value) -> np.ndarray:
    """(2, n): the same arm or foot offset on both sides."""
    return np.array([value, value], dtype=np.float64)


def perform(
    keys: list[tuple[float, np.ndarray]],
    place: Place,
    body: Body,
    rng: np.random.Generator,
    exact: bool = False,
) -> tuple[Track, Place]:
    """Play key poses from the relaxed stance at `place`: each key is (seconds to reach it,
    pose). The last key must be a relaxed stance (its pelvis offset moves the body).
    Durations follow the body's tempo with some jitter unless `exact`; moves shorter than
    MIN_SECONDS get a still pad, split at random between their start and end."""
    rest = pose(body)
    durations = np.array([d for d, _ in keys])
    poses = [p for _, p in keys]
    if not exact:
        durations *= rng.uniform(1 - TIMING_JITTER, 1 + TIMING_JITTER, len(keys)) / body.tempo
        missing = MIN_SECONDS - durations.sum()
        if missing > 0:
            before = rng.uniform(0.2, 0.8)
            durations = np.concatenate([[before * missing], durations, [(1 - before) * missing]])
            poses = [rest] + poses + [poses[-1]]
    times = np.concatenate([[0.0], np.cumsum(durations)])
    t = np.arange(max(2, int(round(times[-1] * FPS)))) / FPS
    v = curve(times, np.stack([rest] + poses), t)  # (T, 22)

    frames = len(t)
    ahead, left = facing(place.yaw), leftward(place.yaw)

    def on_floor(sideways: np.ndarray, forward: np.ndarray) -> np.ndarray:
        """World floor (x, z) of body-frame offsets from `place`."""
        return place.xz + sideways[..., None] * left + forward[..., None] * ahead

    offset = v[:, POSE["pelvis"]]
    pelvis = np.empty((frames, 3))
    pelvis[:, [0, 2]] = on_floor(offset[:, 0], offset[:, 2])
    pelvis[:, 1] = body.stand_height + offset[:, 1]
    feet_offset = v[:, POSE["feet"]].reshape(frames, 2, 3)
    feet = np.empty((frames, 2, 3))
    feet[..., [0, 2]] = on_floor(SIDES * (body.stance + feet_offset[..., 0]), feet_offset[..., 2])
    feet[..., 1] = feet_offset[..., 1]
    track = Track(
        pelvis=pelvis,
        yaw=np.full(frames, place.yaw),
        torso=v[:, POSE["torso"]] + [body.posture, 0.0, 0.0],
        arms=v[:, POSE["arms"]].reshape(frames, 2, 4),
        feet=feet,
        foot_yaw=np.tile(place.yaw + SIDES * body.toe_out, (frames, 1)),
        foot_pitch=v[:, POSE["pitch"]],
    )
    end = poses[-1][POSE["pelvis"]]
    return track, Place(on_floor(end[0], end[2]), place.yaw)


def idle(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Standing, with the small sway of a person who stands still."""
    shifts = rng.integers(2, 4)
    sway = [
        pose(
            body,
            pelvis=(rng.uniform(-0.015, 0.015), 0.0, rng.uniform(-0.01, 0.01)),
            torso=(rng.uniform(-0.02, 0.02), rng.uniform(-0.02, 0.02), 0.0),
        )
        for _ in range(shifts)
    ]
    step = params["seconds"] / (shifts + 1)
    return [(step, p) for p in sway] + [(step, pose(body))]


def squat(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Hips down and back, torso forward, arms out in front for balance; `count` times."""
    depth = rng.uniform(0.28, 0.42) * body.energy
    forward = both(arm(80 * DEG, 10 * DEG, 0.97))
    down = pose(
        body, pelvis=(0.0, -depth, -0.3 * depth), torso=(1.2 * depth, 0.0, 0.0), arms=forward
    )
    keys = [(0.6, down)]
    for _ in range(params["count"] - 1):
        keys += [(0.55, pose(body, arms=forward)), (0.6, down)]
    return keys + [(0.7, pose(body))]


def sit(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Down through a squat to sit on the floor behind the feet, knees up, then back up."""
    seat = 0.09 - body.offsets[1, 1] - body.stand_height  # hips just above the floor
    crouch = pose(
        body,
        pelvis=(0.0, -0.35, -0.15),
        torso=(0.55, 0.0, 0.0),
        arms=both(arm(60 * DEG, 10 * DEG, 0.9)),
    )
    lowering = pose(
        body,
        pelvis=(0.0, 0.45 * seat, -0.32),
        torso=(0.35, 0.0, 0.0),
        arms=both(arm(-25 * DEG, 20 * DEG, 1.0)),
    )
    seated = pose(
        body,
        pelvis=(0.0, seat, -0.42),
        torso=(-0.15, 0.0, 0.0),
        arms=both(arm(45 * DEG, 15 * DEG, 0.85)),
    )
    return [
        (0.6, crouch),
        (0.5, lowering),
        (0.45, seated),
        (rng.uniform(0.5, 1.0), seated),
        (0.45, lowering),
        (0.5, crouch),
        (0.65, pose(body)),
    ]


def bow(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Bend forward from the hips, hold, come back up."""
    bent = pose(
        body, pelvis=(0.0, -0.01, -0.08), torso=(rng.uniform(40, 65) * DEG * body.energy, 0.0, 0.0)
    )
    return [(0.7, bent), (rng.uniform(0.3, 0.7), bent), (0.8, pose(body))]


def wave(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Hand up beside the head, swept out and in `count` times."""
    hand, swing, reach = params["hand"], rng.uniform(150, 160) * DEG, 0.72
    sweep = rng.uniform(15, 25) * DEG * body.energy
    lean = {"left": -0.05, "right": 0.05, "both": 0.0}[hand]

    def raised(spread: float) -> np.ndarray:
        return pose(
            body,
            torso=(0.0, lean, 0.0),
            arms=limbs(hand, arm(swing, spread, reach, 1.0), body.arm_rest),
        )

    keys = [(0.5, raised(40 * DEG))]
    for _ in range(params["count"]):
        keys += [(0.28, raised(40 * DEG + sweep)), (0.28, raised(40 * DEG - sweep))]
    return keys + [(0.22, raised(40 * DEG)), (0.55, pose(body))]


def raise_arms(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Arms straight up overhead, held, lowered."""
    hand = params["hand"]
    lean = {"left": -0.06, "right": 0.06, "both": 0.0}[hand]
    up = pose(
        body,
        torso=(0.0, lean, 0.0),
        arms=limbs(hand, arm(172 * DEG, 12 * DEG, 0.99), body.arm_rest),
    )
    return [(0.75, up), (rng.uniform(0.6, 1.0), up), (0.75, pose(body))]


CLAP_GAP = 0.035  # wrist joint to the chest's midline when the palms meet (m)


def clap(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Hands up in front of the chest, brought together `count` times."""
    swing, reach = rng.uniform(60, 80) * DEG, 0.75
    meet = np.arcsin(-(body.shoulder_width() - CLAP_GAP) / (reach * body.arm))
    apart = pose(body, arms=both(arm(swing, 25 * DEG, reach, 0.5)))
    together = pose(body, arms=both(arm(swing, meet, reach, 0.5)))
    keys = [(0.45, apart)]
    for _ in range(params["count"]):
        keys += [(0.15, together), (0.2, apart)]
    return keys + [(0.5, pose(body))]


def punch(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Fists up in guard; the named fist shoots forward from the shoulder and back `count`
    times, the shoulders turning into each punch."""
    hand = params["hand"]
    guard = arm(75 * DEG, -10 * DEG, 0.42, 0.1)
    strike = pose(
        body,
        torso=(0.0, 0.0, -SIDES[LIMBS[hand][0]] * 20 * DEG * body.energy),
        arms=limbs(hand, arm(88 * DEG, -14 * DEG, 0.99, 0.2), guard),
    )
    keys = [(0.35, pose(body, arms=both(guard)))]
    snap = NATURAL_STRIKE if body.natural else 1.0
    for _ in range(params["count"]):
        keys += [(0.14 * snap, strike), (0.28, pose(body, arms=both(guard)))]
    return keys + [(0.45, pose(body))]


def kick(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Weight onto the other foot, knee up, the named foot swings forward and up, and back."""
    foot = params["foot"]
    kicking = LIMBS[foot][0]
    balance = both(arm(15 * DEG, 35 * DEG, 0.95))
    shift = (-SIDES[kicking] * 0.06, -0.02, 0.0)
    height = rng.uniform(0.4, 0.55) * body.energy

    def lifted(lift: float, forward: float, toes: float, lean: float) -> np.ndarray:
        return pose(
            body,
            pelvis=shift,
            torso=(lean, 0.0, 0.0),
            arms=balance,
            feet=limbs(foot, (0.0, lift, forward), (0.0, 0.0, 0.0)),
            pitch=toes * (np.arange(2) == kicking),
        )

    chamber = lifted(0.28, 0.12, 20 * DEG, -0.08)
    return [
        (0.35, lifted(0.0, 0.0, 0.0, 0.0)),
        (0.3, chamber),
        (0.18, lifted(height, 1.5 * height, 45 * DEG, -0.25)),
        (0.25, chamber),
        (0.3, lifted(0.0, 0.0, 0.0, 0.0)),
        (0.4, pose(body)),
    ]


def stretch(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Arms overhead, then a lean to each side or a reach up onto the toes."""
    overhead = both(arm(172 * DEG, 8 * DEG, 0.99))
    up = pose(body, arms=overhead)
    if rng.random() < 0.5:
        side = rng.choice(SIDES)
        lean = rng.uniform(20, 30) * DEG

        def leaning(s: float) -> np.ndarray:
            return pose(
                body, pelvis=(-0.03 * s, 0.0, 0.0), torso=(0.0, s * lean, 0.0), arms=overhead
            )

        middle = [
            (0.6, leaning(side)),
            (0.3, leaning(side)),
            (0.9, leaning(-side)),
            (0.3, leaning(-side)),
        ]
    else:
        tiptoe = pose(
            body,
            pelvis=(0.0, 0.05, 0.0),
            torso=(-0.08, 0.0, 0.0),
            arms=both(arm(178 * DEG, 4 * DEG, 1.0)),
            pitch=(30 * DEG, 30 * DEG),
        )
        middle = [(0.6, tiptoe), (0.7, tiptoe)]
    return [(0.6, up)] + middle + [(0.6, up), (0.6, pose(body))]


def jump(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Crouch with the arms back, spring up (toes last off the floor), fly, land and absorb;
    `count` times, travelling forward if asked. Feet rise before they travel and stop
    travelling before they come down."""
    forward = params["forward"]
    big = NATURAL_JUMP if body.natural else 1.0
    distance = rng.uniform(0.5, 0.85) * body.energy * big if forward else 0.0
    height = (rng.uniform(0.15, 0.2) if forward else rng.uniform(0.2, 0.3)) * body.energy * big

    def crouch(at: float) -> np.ndarray:
        return pose(
            body,
            pelvis=(0.0, -0.2 * big, at - 0.04),
            torso=(0.5, 0.0, 0.0),
            arms=both(arm(-40 * DEG, 15 * DEG, 0.97)),
            feet=both((0.0, 0.0, at)),
        )

    def airborne(
        at: float, feet_at: float, lift: float, toes: float, swing: float, bend: float
    ) -> np.ndarray:
        return pose(
            body,
            pelvis=(0.0, 0.03 + lift, at),
            torso=(bend, 0.0, 0.0),
            arms=both(arm(swing, 20 * DEG, 0.97)),
            feet=both((0.0, lift, feet_at)),
            pitch=(toes, toes),
        )

    keys = [(0.4, crouch(0.0))]
    for k in range(params["count"]):
        start, end = k * distance, (k + 1) * distance
        keys += [
            (0.16, airborne(start + 0.1 * distance, start, 0.0, 50 * DEG, 50 * DEG, 0.2)),
            (
                0.08 * big,
                airborne(start + 0.25 * distance, start, 0.4 * height, 35 * DEG, 100 * DEG, 0.15),
            ),
            (
                0.12 * big,
                airborne(
                    start + 0.5 * distance, start + 0.5 * distance, height, 25 * DEG, 140 * DEG, 0.1
                ),
            ),
            (
                0.12 * big,
                airborne(start + 0.75 * distance, end, 0.4 * height, 25 * DEG, 110 * DEG, 0.1),
            ),
            (0.08 * big, airborne(end - 0.05 * distance, end, 0.0, 30 * DEG, 80 * DEG, 0.15)),
            (0.18, crouch(end)),
        ]
    end = params["count"] * distance
    return keys + [(0.5, pose(body, pelvis=(0.0, 0.0, end), feet=both((0.0, 0.0, end))))]


def jumping_jacks(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Small hops that spread the feet with the arms swung up overhead, then close both.
    Feet rise before they move apart or together and stop moving before they land."""
    wide, hop = rng.uniform(0.18, 0.26) * body.energy, rng.uniform(0.06, 0.09)

    def at(out: float, lift: float, spread: float, toes: float, rise: float) -> np.ndarray:
        return pose(
            body,
            pelvis=(0.0, rise + lift, 0.0),
            arms=both(arm(0.0, spread, 0.98)),
            feet=both((out, lift, 0.0)),
            pitch=(toes, toes),
        )

    def hop_to(start: float, end: float, arms_from: float, arms_to: float) -> list:
        def arms(share: float) -> float:
            return arms_from + share * (arms_to - arms_from)

        return [
            (0.1, at(start, 0.0, arms(0.1), 35 * DEG, 0.02)),
            (0.06, at(start, 0.6 * hop, arms(0.3), 25 * DEG, 0.02)),
            (0.08, at((start + end) / 2, hop, arms(0.55), 20 * DEG, 0.02)),
            (0.08, at(end, 0.6 * hop, arms(0.8), 20 * DEG, 0.02)),
            (0.06, at(end, 0.0, arms_to, 10 * DEG, -0.02)),
            (0.08, at(end, 0.0, arms_to, 0.0, -0.05)),
        ]

    closed, overhead = body.arm_rest[1], 160 * DEG
    keys = [(0.25, at(0.0, 0.0, closed, 0.0, -0.04))]
    for _ in range(params["count"]):
        keys += hop_to(0.0, wide, closed, overhead) + hop_to(wide, 0.0, overhead, closed)
    return keys + [(0.4, pose(body))]
