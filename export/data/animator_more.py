"""Corpus v2's keyed moves: what game and animation users ask for beyond v1's set (hopping,
climbing a step, crawling, lying down, handling things, gestures, dance and boxing). Same
contract as animator_moves: key poses from the relaxed stance back to it."""

from __future__ import annotations

import numpy as np

from mogo.export.data.animator_body import SIDES, Body
from mogo.export.data.animator_moves import DEG, LIMBS, arm, both, limbs, pose

GUARD = arm(75 * DEG, -10 * DEG, 0.42, 0.1)  # a boxer's fist up in front of the chin
STEP_HEIGHT = 0.2  # the step (a box, a stair) climbed onto (m)


def _other(side: str) -> str:
    return "right" if side == "left" else "left"


def hop(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Weight onto the named foot, the other tucked up behind; `count` hops on the named
    foot, arms out for balance."""
    foot = _other(params["foot"])  # the lifted one
    lifted = LIMBS[foot][0]
    shift = -SIDES[lifted] * 0.07
    height = rng.uniform(0.07, 0.11) * body.energy
    balance = both(arm(25 * DEG, 35 * DEG, 0.9, 0.3))

    def at(drop: float, up: float, toes: float) -> np.ndarray:
        return pose(
            body,
            pelvis=(shift, drop + up, 0.0),
            arms=balance,
            feet=limbs(foot, (0.0, 0.24 + up, -0.16), (0.0, up, 0.0)),
            pitch=limbs(foot, 40 * DEG, toes),
        )

    keys = [(0.45, at(-0.02, 0.0, 0.0))]
    for _ in range(params["count"]):
        keys += [
            (0.14, at(-0.07, 0.0, 0.0)),
            (0.1, at(0.0, 0.4 * height, 30 * DEG)),
            (0.1, at(0.02, height, 15 * DEG)),
            (0.12, at(-0.06, 0.0, 0.0)),
        ]
    down = pose(body, pelvis=(shift, -0.02, 0.0), arms=balance)
    return keys + [(0.35, down), (0.4, pose(body))]


def step_up(params: dict, body: Body, rng: np.random.Generator) -> list:
    """The named foot up onto a step in front, the body up after it, the other foot beside;
    a moment on top, then back down, the other foot first."""
    lead = params["foot"]
    ahead = rng.uniform(0.32, 0.4)

    def feet(lead_at, trail_at) -> np.ndarray:
        return limbs(lead, lead_at, trail_at)

    floor, top = (0.0, 0.0, 0.0), (0.0, STEP_HEIGHT, ahead)
    keys = [
        (0.35, pose(body, pelvis=(0.0, -0.02, 0.0), torso=(0.1, 0.0, 0.0))),
        (
            0.3,
            pose(
                body,
                pelvis=(0.0, -0.03, 0.05),
                torso=(0.2, 0.0, 0.0),
                feet=feet((0.0, STEP_HEIGHT + 0.12, 0.6 * ahead), floor),
            ),
        ),
        (0.25, pose(body, pelvis=(0.0, -0.06, 0.15), torso=(0.3, 0.0, 0.0), feet=feet(top, floor))),
        (
            0.45,
            pose(
                body,
                pelvis=(0.0, STEP_HEIGHT - 0.02, ahead - 0.02),
                torso=(0.15, 0.0, 0.0),
                feet=feet(top, (0.0, STEP_HEIGHT + 0.1, 0.6 * ahead)),
            ),
        ),
        (0.3, pose(body, pelvis=(0.0, STEP_HEIGHT, ahead), feet=feet(top, top))),
        (rng.uniform(0.3, 0.7), pose(body, pelvis=(0.0, STEP_HEIGHT, ahead), feet=feet(top, top))),
        (
            0.35,
            pose(
                body,
                pelvis=(0.0, STEP_HEIGHT - 0.08, ahead - 0.1),
                torso=(0.1, 0.0, 0.0),
                feet=feet(top, (0.0, STEP_HEIGHT + 0.04, 0.5 * ahead)),
            ),
        ),
        (0.35, pose(body, pelvis=(0.0, 0.0, 0.1), torso=(0.05, 0.0, 0.0), feet=feet(top, floor))),
        (
            0.3,
            pose(
                body,
                pelvis=(0.0, -0.02, 0.02),
                feet=feet((0.0, STEP_HEIGHT + 0.05, 0.4 * ahead), floor),
            ),
        ),
        (0.35, pose(body)),
    ]
    return keys


def crawl(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Down onto hands and knees (the feet stay, the knees go down in front of them), `count`
    crawling cycles forward (each knee in turn, the opposite hand reaching), back up over the
    feet where the crawl ended."""
    reach = rng.uniform(0.2, 0.28) * body.energy  # metres per crawling cycle

    def on_all_fours(at, knees, lifts=(0.0, 0.0), hands=(0.0, 0.0)) -> np.ndarray:
        return _on_all_fours(body, at, knees, lifts, hands)

    def kneeling(at: float) -> np.ndarray:
        return _kneeling(body, at)

    keys = [
        (
            0.5,
            pose(
                body,
                pelvis=(0.0, -0.3, 0.1),
                torso=(0.5, 0.0, 0.0),
                arms=both(arm(40 * DEG, 15 * DEG, 0.9)),
            ),
        ),
        (0.45, kneeling(0.0)),
        (0.5, on_all_fours(0.0, (0.0, 0.0))),
    ]
    knees = [0.0, 0.0]
    for k in range(2 * params["count"]):
        side = k % 2
        start = k * reach / 2
        knees[side] = start + 0.75 * reach  # a quarter cycle ahead of the hips
        lifts = (0.04 * (side == 0), 0.04 * (side == 1))
        hand = (25 * DEG * (side == 1), 25 * DEG * (side == 0))  # the opposite hand reaches
        keys += [
            (0.22, on_all_fours(start + reach / 4, tuple(knees), lifts, hand)),
            (0.22, on_all_fours(start + reach / 2, tuple(knees))),
        ]
    end = params["count"] * reach
    return keys + [
        (0.5, kneeling(end)),
        (
            0.5,
            pose(
                body,
                pelvis=(0.0, -0.3, end + 0.1),
                torso=(0.5, 0.0, 0.0),
                feet=both((0.0, 0.0, end)),
            ),
        ),
        (0.55, pose(body, pelvis=(0.0, 0.0, end), feet=both((0.0, 0.0, end)))),
    ]


_CRAWL_LOW = -0.42  # the pelvis on hands and knees, from standing height


def _on_all_fours(
    body: Body, at: float, knees: tuple[float, float], lifts=(0.0, 0.0), hands=(0.0, 0.0)
) -> np.ndarray:
    """A crawl's pose: the hips `at` metres forward, the knees where given, ankles behind."""
    shin = body.length(7) + 0.02
    feet = np.array([[0.0, lifts[s], knees[s]] for s in range(2)])  # ankles behind knees
    arms = np.array([arm(80 * DEG + hands[s], 12 * DEG, 0.95, 0.2) for s in range(2)])
    return pose(
        body,
        pelvis=(0.0, _CRAWL_LOW, at + shin),
        torso=(84 * DEG, 0.0, 0.0),
        arms=arms,
        feet=feet,
    )


def _kneeling(body: Body, at: float) -> np.ndarray:
    """Kneeling upright over feet `at` metres forward: into and out of a crawl."""
    return pose(
        body,
        pelvis=(0.0, _CRAWL_LOW + 0.02, at + (body.length(7) + 0.02)),
        torso=(0.35, 0.0, 0.0),
        arms=both(arm(50 * DEG, 15 * DEG, 0.9)),
        feet=both((0.0, 0.0, at)),
    )


def lie_down(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Sit down on the floor, lie back flat, stay a moment, sit up and stand."""
    seat = 0.09 - body.offsets[1, 1] - body.stand_height
    crouch = pose(
        body,
        pelvis=(0.0, -0.35, -0.15),
        torso=(0.55, 0.0, 0.0),
        arms=both(arm(60 * DEG, 10 * DEG, 0.9)),
    )
    seated = pose(
        body,
        pelvis=(0.0, seat, -0.42),
        torso=(-0.15, 0.0, 0.0),
        arms=both(arm(-30 * DEG, 20 * DEG, 1.0)),
    )
    legs_out = both((0.0, 0.0, 0.3))
    lying = pose(
        body,
        pelvis=(0.0, seat - 0.02, -0.5),
        torso=(-85 * DEG, 0.0, 0.0),
        arms=both(arm(5 * DEG, 15 * DEG, 0.98)),
        feet=legs_out,
    )
    propped = pose(
        body,
        pelvis=(0.0, seat, -0.45),
        torso=(-40 * DEG, 0.0, 0.0),
        arms=both(arm(-40 * DEG, 20 * DEG, 1.0)),
        feet=legs_out,
    )
    return [
        (0.6, crouch),
        (0.55, seated),
        (0.5, propped),
        (0.6, lying),
        (rng.uniform(0.6, 1.2), lying),
        (0.6, propped),
        (0.5, seated),
        (0.6, crouch),
        (0.65, pose(body)),
    ]


def pick_up(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Bend the knees and reach to the floor in front with the named hand (or both), close
    on the thing, stand up holding it in front, then lower it."""
    hand = params["hand"]
    lean = {"left": 0.06, "right": -0.06, "both": 0.0}[hand]
    down = pose(
        body,
        pelvis=(0.0, -0.33, -0.15),
        torso=(0.75, lean, 0.0),
        arms=limbs(hand, arm(55 * DEG, 5 * DEG, 1.0), arm(30 * DEG, 15 * DEG, 0.9)),
    )
    holding = pose(body, arms=limbs(hand, arm(45 * DEG, -8 * DEG, 0.6, 0.3), body.arm_rest))
    return [
        (0.7, down),
        (rng.uniform(0.2, 0.4), down),
        (0.7, holding),
        (rng.uniform(0.4, 0.8), holding),
        (0.5, pose(body)),
    ]


def _staggered(body: Body, rng: np.random.Generator) -> np.ndarray:
    """Feet apart front and back, a random foot forward, for pushing and pulling."""
    return limbs(["left", "right"][int(rng.integers(2))], (0.0, 0.0, 0.2), (0.0, 0.0, -0.08))


def push(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Stagger the feet, hands up at the chest, push forward with both arms `count` times,
    leaning into it."""
    feet = _staggered(body, rng)
    set_ = pose(
        body,
        pelvis=(0.0, -0.03, 0.0),
        torso=(0.15, 0.0, 0.0),
        arms=both(arm(75 * DEG, -5 * DEG, 0.45, 0.5)),
        feet=feet,
    )
    pushed = pose(
        body,
        pelvis=(0.0, -0.05, 0.08),
        torso=(0.3, 0.0, 0.0),
        arms=both(arm(85 * DEG, -6 * DEG, 0.97, 0.2)),
        feet=feet,
    )
    keys = [(0.2, pose(body, pelvis=(0.0, -0.02, 0.0), feet=feet)), (0.35, set_)]
    for _ in range(params["count"]):
        keys += [(0.35, pushed), (0.4, set_)]
    return keys + [(0.3, pose(body, feet=feet)), (0.35, pose(body))]


def pull(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Stagger the feet, reach forward with both hands, pull them in to the chest `count`
    times, leaning back."""
    feet = _staggered(body, rng)
    reach = pose(
        body,
        pelvis=(0.0, -0.04, 0.05),
        torso=(0.25, 0.0, 0.0),
        arms=both(arm(88 * DEG, -5 * DEG, 0.97, 0.2)),
        feet=feet,
    )
    pulled = pose(
        body,
        pelvis=(0.0, -0.06, -0.08),
        torso=(-0.12, 0.0, 0.0),
        arms=both(arm(60 * DEG, 0.0, 0.4, 0.3)),
        feet=feet,
    )
    keys = [(0.2, pose(body, pelvis=(0.0, -0.02, 0.0), feet=feet)), (0.4, reach)]
    for _ in range(params["count"]):
        keys += [(0.4, pulled), (0.4, reach)]
    return keys + [(0.35, pose(body, feet=feet)), (0.35, pose(body))]


def throw(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Overarm throw: the other foot steps forward, the named arm winds up behind the head,
    the shoulders turn into the throw and the arm follows through across the body."""
    hand, side = params["hand"], SIDES[LIMBS[params["hand"]][0]]
    step = limbs(_other(hand), (0.0, 0.0, 0.3), (0.0, 0.0, 0.0))
    lifted = limbs(_other(hand), (0.0, 0.06, 0.15), (0.0, 0.0, 0.0))
    other = arm(60 * DEG, 20 * DEG, 0.85, 0.3)
    windup = pose(
        body,
        pelvis=(0.0, -0.02, -0.03),
        torso=(-0.1, 0.0, side * 35 * DEG),
        arms=limbs(hand, arm(200 * DEG, 25 * DEG, 0.8, 1.0), other),
        feet=lifted,
    )
    release = pose(
        body,
        pelvis=(0.0, -0.05, 0.12),
        torso=(0.25, 0.0, -side * 30 * DEG),
        arms=limbs(hand, arm(110 * DEG, 5 * DEG, 0.99, 0.5), arm(10 * DEG, 25 * DEG, 0.9)),
        feet=step,
    )
    through = pose(
        body,
        pelvis=(0.0, -0.07, 0.15),
        torso=(0.45, 0.0, -side * 35 * DEG),
        arms=limbs(hand, arm(35 * DEG, -25 * DEG, 0.95, 0.2), arm(0.0, 20 * DEG, 0.95)),
        feet=step,
    )
    return [
        (0.55, windup),
        (rng.uniform(0.1, 0.3), windup),
        (0.18, release),
        (0.25, through),
        (0.5, pose(body, pelvis=(0.0, 0.0, 0.15), feet=step)),
        (
            0.3,
            pose(
                body,
                pelvis=(0.0, -0.01, 0.22),
                feet=limbs(hand, (0.0, 0.07, 0.15), (0.0, 0.0, 0.3)),
            ),
        ),
        (0.3, pose(body, pelvis=(0.0, 0.0, 0.3), feet=both((0.0, 0.0, 0.3)))),
    ]


def point(params: dict, body: Body, rng: np.random.Generator) -> list:
    """The named arm straight out, pointing forward, up or out to its own side; held, then
    lowered."""
    hand, direction = params["hand"], params["at"]
    swing, spread = {
        "forward": (88 * DEG, -5 * DEG),
        "up": (150 * DEG, 10 * DEG),
        "sideways": (88 * DEG, 80 * DEG),
    }[direction]
    turn = {"forward": 0.0, "up": 0.0, "sideways": 12 * DEG}[direction]
    pointing = pose(
        body,
        torso=(0.0, 0.0, SIDES[LIMBS[hand][0]] * turn),
        arms=limbs(hand, arm(swing, spread, 1.0), body.arm_rest),
    )
    return [(0.45, pointing), (rng.uniform(0.6, 1.1), pointing), (0.5, pose(body))]


def look_around(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Turn the head and shoulders to one side, then the other, looking about, and back."""
    first = rng.choice(SIDES)
    twist = rng.uniform(45, 60) * DEG

    def looking(side: float, bend: float) -> np.ndarray:
        return pose(body, torso=(bend, 0.0, side * twist))

    return [
        (0.6, looking(first, 0.0)),
        (rng.uniform(0.4, 0.7), looking(first, -0.05)),
        (0.9, looking(-first, 0.0)),
        (rng.uniform(0.4, 0.7), looking(-first, 0.05)),
        (0.6, pose(body)),
    ]


def shrug(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Forearms out to the sides, palms up, the head tipped, `count` times."""
    up = pose(
        body,
        pelvis=(0.0, 0.01, 0.0),
        torso=(-0.06, rng.uniform(-0.06, 0.06), 0.0),
        arms=both(arm(25 * DEG, 40 * DEG, 0.68, 0.6)),
    )
    keys = []
    for _ in range(params["count"]):
        keys += [(0.35, up), (0.25, up), (0.35, pose(body))]
    return keys


def salute(params: dict, body: Body, rng: np.random.Generator) -> list:
    """The right hand up to the brow, elbow out, held, snapped down."""
    hand = params["hand"]
    saluting = pose(
        body,
        torso=(-0.03, 0.0, 0.0),
        arms=limbs(hand, arm(128 * DEG, 48 * DEG, 0.38, 1.0), body.arm_rest),
    )
    return [(0.4, saluting), (rng.uniform(0.7, 1.2), saluting), (0.35, pose(body))]


def dance(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Step-touch: a step out to one side, the other foot taps in beside it and goes back,
    then the same to the other side, arms swinging with bent elbows and the hips swaying;
    `count` times."""
    width = rng.uniform(0.22, 0.3)
    first = int(rng.integers(2))

    def at(side: int, out: float, tap: float, lift: float, tap_lift: float) -> np.ndarray:
        s = SIDES[side]
        feet = np.zeros((2, 3))
        feet[side] = (out, lift, 0.0)
        feet[1 - side] = (-tap, tap_lift, 0.0)
        shift = (out + tap) / 2
        swing = np.array(
            [arm(50 * DEG, (35 if k == side else -10) * DEG, 0.6, 0.5) for k in range(2)]
        )
        bounce = -0.03 - 0.03 * (tap > 0.5 * width)
        return pose(
            body,
            pelvis=(s * shift, bounce, 0.0),
            arms=swing,
            feet=feet,
            torso=(0.05, -s * 6 * DEG * shift / width, s * 10 * DEG * shift / width),
        )

    keys = []
    for _ in range(params["count"]):
        for side in (first, 1 - first):
            keys += [
                (0.12, at(side, width / 2, 0.0, 0.05, 0.0)),
                (0.12, at(side, width, 0.0, 0.0, 0.0)),
                (0.12, at(side, width, width / 2, 0.0, 0.05)),
                (0.12, at(side, width, width, 0.0, 0.01)),
                (0.12, at(side, width, width / 2, 0.0, 0.05)),
                (0.12, at(side, width, 0.0, 0.0, 0.0)),
                (0.12, at(side, width / 2, 0.0, 0.05, 0.0)),
            ]
    return keys + [(0.2, pose(body))]


def uppercut(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Guard up; dip and drive the named fist up from the hip to chin height, the hips and
    shoulders turning into it, `count` times."""
    hand, side = params["hand"], SIDES[LIMBS[params["hand"]][0]]
    guard = pose(body, pelvis=(0.0, -0.03, 0.0), arms=both(GUARD))
    load = pose(
        body,
        pelvis=(0.0, -0.1, 0.0),
        torso=(0.12, side * 0.1, side * 15 * DEG),
        arms=limbs(hand, arm(20 * DEG, 5 * DEG, 0.55, 0.0), GUARD),
    )
    strike = pose(
        body,
        pelvis=(0.0, 0.0, 0.02),
        torso=(-0.08, 0.0, -side * 20 * DEG),
        arms=limbs(hand, arm(125 * DEG, -15 * DEG, 0.62, 0.1), GUARD),
    )
    keys = [(0.35, guard)]
    for _ in range(params["count"]):
        keys += [(0.2, load), (0.14, strike), (0.28, guard)]
    return keys + [(0.4, pose(body))]


def duck(params: dict, body: Body, rng: np.random.Generator) -> list:
    """Guard up; bob and weave: dip under a punch bending the knees and slipping to one side,
    rising on the other, `count` times."""
    side = rng.choice(SIDES)
    guard = pose(body, pelvis=(0.0, -0.03, 0.0), torso=(0.1, 0.0, 0.0), arms=both(GUARD))
    keys = [(0.35, guard)]
    for _ in range(params["count"]):
        keys += [
            (
                0.3,
                pose(
                    body,
                    pelvis=(side * 0.08, -0.25, -0.03),
                    torso=(0.45, side * 0.2, 0.0),
                    arms=both(GUARD),
                ),
            ),
            (
                0.3,
                pose(
                    body,
                    pelvis=(-side * 0.06, -0.06, 0.0),
                    torso=(0.15, -side * 0.1, 0.0),
                    arms=both(GUARD),
                ),
            ),
        ]
        side = -side
    return keys + [(0.3, guard), (0.4, pose(body))]


KEYED_V2 = {
    "hop": hop,
    "step_up": step_up,
    "crawl": crawl,
    "lie_down": lie_down,
    "pick_up": pick_up,
    "push": push,
    "pull": pull,
    "throw": throw,
    "point": point,
    "look_around": look_around,
    "shrug": shrug,
    "salute": salute,
    "dance": dance,
    "uppercut": uppercut,
    "duck": duck,
}
