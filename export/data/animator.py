"""Procedural motion on the 22-joint SMPL skeleton, for the synthetic text-motion corpus.

A clip is a program of segments, each a primitive with params ("walk" to the "left", "wave"
the "right" hand twice). `animate` plays them one after another from the relaxed stance, the
body's position and facing carrying over, and returns world joint positions at 20 fps (Y up,
feet on the floor, the first frame facing +Z). Every clip draws its own performer (size,
proportions, tempo, movement size, arm swing, stance) from the rng, so no two clips are alike
and the same rng state always gives the same clip.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mogo.export.data.animator_body import FPS, Body, Track, pose_joints
from mogo.export.data.animator_more import KEYED_V2
from mogo.export.data.animator_moves import (
    Place,
    bow,
    clap,
    idle,
    jump,
    jumping_jacks,
    kick,
    perform,
    punch,
    raise_arms,
    sit,
    squat,
    stretch,
    wave,
)
from mogo.export.data.animator_steps import locomotion, turning


@dataclass(frozen=True)
class Segment:
    primitive: str
    params: dict


@dataclass(frozen=True)
class Choice:
    """One of a few values, equally likely."""

    values: tuple

    def draw(self, rng: np.random.Generator):
        return self.values[int(rng.integers(len(self.values)))]


@dataclass(frozen=True)
class Count:
    """A whole number from low to high, equally likely."""

    low: int
    high: int

    def draw(self, rng: np.random.Generator) -> int:
        return int(rng.integers(self.low, self.high + 1))


@dataclass(frozen=True)
class Degrees:
    """A signed whole angle (+ = to the left): 0 with probability `straight`, else a magnitude
    from low to high, half the time snapped to a multiple of `snap`."""

    low: int
    high: int
    snap: int
    straight: float = 0.0

    def draw(self, rng: np.random.Generator) -> int:
        if rng.random() < self.straight:
            return 0
        magnitude = int(rng.integers(self.low, self.high + 1))
        if rng.random() < 0.5:
            magnitude = int(np.clip(round(magnitude / self.snap) * self.snap, self.low, self.high))
        return magnitude if rng.random() < 0.5 else -magnitude


@dataclass(frozen=True)
class Seconds:
    """A duration from low to high in multiples of `step`."""

    low: float
    high: float
    step: float

    def draw(self, rng: np.random.Generator) -> float:
        return float(
            self.low + self.step * int(rng.integers(round((self.high - self.low) / self.step) + 1))
        )


SIDE = Choice(("left", "right"))
HANDS = Choice(("left", "right", "both"))
_PATH = {
    "direction": Choice(("forward", "backward", "left", "right")),
    "speed": Choice(("slow", "normal", "fast")),
    "turn": Degrees(30, 180, 45, straight=0.5),
}
_AHEAD = {"speed": _PATH["speed"], "turn": _PATH["turn"]}  # forward only
PRIMITIVES: dict[str, dict] = {
    "walk": {**_PATH, "steps": Count(3, 6)},
    "jog": {**_PATH, "steps": Count(4, 8)},
    "run": {**_PATH, "steps": Count(4, 8)},
    "turn": {"angle": Degrees(45, 180, 45)},
    "jump": {"forward": Choice((True, False)), "count": Count(1, 4)},
    "squat": {"count": Count(1, 4)},
    "sit": {},
    "bow": {},
    "wave": {"hand": HANDS, "count": Count(1, 4)},
    "raise_arms": {"hand": HANDS},
    "clap": {"count": Count(1, 6)},
    "punch": {"hand": SIDE, "count": Count(1, 4)},
    "kick": {"foot": SIDE},
    "spin": {"direction": SIDE},
    "stretch": {},
    "jumping_jacks": {"count": Count(1, 5)},
    "idle": {"seconds": Seconds(1.0, 3.0, 0.5)},
    # corpus v2
    "crouch_walk": {**_PATH, "steps": Count(3, 6)},
    "tiptoe": {**_PATH, "steps": Count(3, 6)},
    "march": {**_AHEAD, "steps": Count(4, 8)},
    "limp": {
        "foot": SIDE,
        "speed": Choice(("slow", "normal")),
        "turn": _PATH["turn"],
        "steps": Count(4, 7),
    },
    "skip": {**_AHEAD, "steps": Count(4, 8)},
    "carry": {**_PATH, "direction": Choice(("forward", "backward")), "steps": Count(3, 6)},
    "stumble": {"steps": Count(4, 6)},
    "hop": {"foot": SIDE, "count": Count(1, 5)},
    "step_up": {"foot": SIDE},
    "crawl": {"count": Count(1, 3)},
    "lie_down": {},
    "pick_up": {"hand": HANDS},
    "push": {"count": Count(1, 3)},
    "pull": {"count": Count(1, 3)},
    "throw": {"hand": SIDE},
    "point": {"hand": SIDE, "at": Choice(("forward", "up", "sideways"))},
    "look_around": {},
    "shrug": {"count": Count(1, 2)},
    "salute": {"hand": SIDE},
    "dance": {"count": Count(1, 3)},
    "uppercut": {"hand": SIDE, "count": Count(1, 4)},
    "duck": {"count": Count(1, 3)},
}
V1 = (
    "walk",
    "jog",
    "run",
    "turn",
    "jump",
    "squat",
    "sit",
    "bow",
    "wave",
    "raise_arms",
    "clap",
    "punch",
    "kick",
    "spin",
    "stretch",
    "jumping_jacks",
    "idle",
)
CORPORA = {"v1": V1, "v2": tuple(PRIMITIVES)}  # each corpus version's primitives
DEFAULT_CORPUS = "v1"  # the shipped bundle's; v2 once a model trained on it ships
GAITS = ("walk", "jog", "run", "crouch_walk", "tiptoe", "march", "limp", "skip", "carry", "stumble")
KEYED = {
    "idle": idle,
    "squat": squat,
    "sit": sit,
    "bow": bow,
    "wave": wave,
    "raise_arms": raise_arms,
    "clap": clap,
    "punch": punch,
    "kick": kick,
    "stretch": stretch,
    "jump": jump,
    "jumping_jacks": jumping_jacks,
    **KEYED_V2,
}


@dataclass
class Animation:
    joints: np.ndarray  # (T, 22, 3) float32 world positions, metres
    spans: list[tuple[int, int]]  # each segment's [start, end) frames, back to back
    fps: int = FPS


def _known(primitive: str) -> dict:
    if primitive not in PRIMITIVES:
        raise ValueError(
            f"unknown primitive {primitive!r}; expected one of {', '.join(sorted(PRIMITIVES))}"
        )
    return PRIMITIVES[primitive]


def sample_segment(primitive: str, rng: np.random.Generator) -> Segment:
    """A segment of `primitive` with random params. Sideways steps go straight and come in
    pairs (leading foot out, trailing foot in)."""
    params = {name: spec.draw(rng) for name, spec in _known(primitive).items()}
    if primitive in GAITS and params.get("direction") in ("left", "right"):
        params.update(turn=0, steps=params["steps"] + params["steps"] % 2)
    return Segment(primitive, params)


def _play(
    segment: Segment, place: Place, body: Body, rng: np.random.Generator
) -> tuple[Track, Place]:
    _known(segment.primitive)
    params = segment.params
    if segment.primitive in GAITS:
        return locomotion(segment.primitive, params, place, body, rng)
    if segment.primitive == "turn":
        return turning("turn", np.radians(params["angle"]), place, body, rng)
    if segment.primitive == "spin":
        return turning(
            "spin", 2 * np.pi * (1 if params["direction"] == "left" else -1), place, body, rng
        )
    keys = KEYED[segment.primitive](params, body, rng)
    return perform(keys, place, body, rng, exact=segment.primitive == "idle")


def animate(
    segments: Sequence[Segment], rng: np.random.Generator, natural: bool = False
) -> Animation:
    """Joint positions of a program of segments, played back to back by one random performer
    (`natural`: corpus v2's, whose steps vary)."""
    if not segments:
        raise ValueError("a program needs at least one segment")
    body = Body.sample(rng, natural)
    place = Place(np.zeros(2), 0.0)
    tracks, spans, start = [], [], 0
    for segment in segments:
        track, place = _play(segment, place, body, rng)
        tracks.append(track)
        spans.append((start, start + len(track)))
        start += len(track)
    joints = pose_joints(Track.concat(tracks), body)
    return Animation(joints.astype(np.float32), spans)
