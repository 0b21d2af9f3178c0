"""Does a long stream keep doing what its prompt asks? The corpus's semantic checks
(mogo.bench.quality.semantic) applied to windows of a stream, and the drift figures.

A continuing action (walk, clap, spin, ...) must show in every window: its check, with what
is counted or travelled judged against the procedural animator's own performance of the
primitive over a window of the same length (at least half as many claps, jacks or degrees
of spin; between half and twice the distance, as semantic.py judges a walk). A one-off
action (sit down, bow, ...) must happen in the first window, by its clip check, and hold in
every later one (the idle check: in place, steady, facing one way, the hands still).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mogo.bench.quality import semantic as S
from mogo.export.data.animator import Segment, animate
from mogo.motion.skeleton import SMPL_22

FPS = round(SMPL_22.fps)  # frames a second, whole: windows are counted in frames
CONTACT_HEIGHT = 0.05  # metres: a foot joint lower than this is on the floor
FEET = S.FEET


@dataclass(frozen=True)
class Action:
    name: str
    prompt: str
    primitive: str
    params: dict = field(hash=False)
    continuing: bool = True


def _loco(gait: str, direction: str) -> Action:
    words = {"left": "to the left", "right": "to the right"}.get(direction, direction)
    verb = {"walk": "walks", "jog": "jogs", "run": "runs"}[gait]
    return Action(
        f"{gait} {direction}",
        f"a person {verb} {words}.",
        gait,
        dict(direction=direction, speed="normal", turn=0, steps=40),
    )


REPERTOIRE = (
    *[_loco("walk", d) for d in ("forward", "backward", "left", "right")],
    *[_loco(g, d) for g in ("jog", "run") for d in ("forward", "backward")],
    Action("wave", "a person waves with the right hand.", "wave", dict(hand="right", count=4)),
    Action("clap", "a person claps.", "clap", dict(count=6)),
    Action("jumping jacks", "a person does jumping jacks.", "jumping_jacks", dict(count=5)),
    Action("spin", "a person spins to the left.", "spin", dict(direction="left")),
    Action("idle", "a person stands still.", "idle", dict(seconds=3.0)),
    Action("sit down", "a person sits down.", "sit", {}, False),
    Action(
        "jump 3x",
        "a person jumps on the spot three times.",
        "jump",
        dict(forward=False, count=3),
        False,
    ),
    Action("bow", "a person bows.", "bow", {}, False),
    Action("turn left", "a person turns left.", "turn", dict(angle=90), False),
    Action("kick", "a person kicks with the right foot.", "kick", dict(foot="right"), False),
)
COUNTED = {"clap": "count", "jumping_jacks": "count"}  # measured value, at least half the ref


def reference(action: Action, frames: int, seed: int = 0) -> np.ndarray:
    """The animator performing `action` on and on: the middle `frames` of back-to-back
    segments (one performer), what a window of a stream is judged against."""
    rng = np.random.default_rng(seed)
    segments = [Segment(action.primitive, action.params)]
    clip = animate(segments, rng).joints
    repeats = math.ceil((frames + 2 * FPS) / len(clip)) + 1
    clip = animate(segments * repeats, np.random.default_rng(seed)).joints
    start = (len(clip) - frames) // 2
    return clip[start : start + frames]


class WindowCheck:
    """An action's check on windows of one length, its references made once."""

    def __init__(self, action: Action, frames: int):
        self.action, self.frames = action, frames
        self.ref = reference(action, frames) if action.continuing else None
        if action.continuing and action.primitive in COUNTED:
            self.need = self._measure(self.ref) / 2
        elif action.primitive == "spin":
            self.need = self._turned(self.ref) / 2

    def continuing(self, joints: np.ndarray) -> bool:
        """The action under way throughout `joints` (a window)."""
        a = self.action
        if a.primitive in COUNTED:
            return self._measure(joints) >= self.need
        if a.primitive == "spin":
            return self._turned(joints) >= self.need
        return S.CHECKS[a.primitive](joints, a.params, self.ref).passed

    def happened(self, joints: np.ndarray) -> bool:
        """A one-off action's clip check (its whole performance inside `joints`)."""
        return S.CHECKS[self.action.primitive](joints, self.action.params, None).passed

    def _measure(self, joints: np.ndarray) -> float:
        verdict = S.CHECKS[self.action.primitive](joints, {"count": -1}, None)
        return float(verdict.measured[COUNTED[self.action.primitive]])

    def _turned(self, joints: np.ndarray) -> float:
        sign = 1 if self.action.params["direction"] == "left" else -1
        return sign * S.heading_change(joints)


def window_passes(check: WindowCheck, joints: np.ndarray) -> list[bool]:
    """One verdict per whole window of the stream: a continuing action's check in each; a
    one-off's: whether it happened in the first, then the hold in each later one."""
    n = check.frames
    windows = [joints[k : k + n] for k in range(0, len(joints) - n + 1, n)]
    if check.action.continuing:
        return [check.continuing(w) for w in windows]
    return [check.happened(windows[0])] + [
        S.CHECKS["idle"](w, {}, None).passed for w in windows[1:]
    ]


def reaction_frames(check: WindowCheck, after: np.ndarray, hop: int = 5) -> int | None:
    """Frames from a switch until the new action is under way: the first start, in `hop`
    frames, of a window that passes its check (a one-off: that happens in it); None: never."""
    for start in range(0, len(after) - check.frames + 1, hop):
        window = after[start : start + check.frames]
        if check.continuing(window) if check.action.continuing else check.happened(window):
            return start
    return None


def joint_speed(joints: np.ndarray) -> np.ndarray:
    """Mean joint speed (m/frame) from each frame to the next, (T - 1,)."""
    return np.linalg.norm(np.diff(joints, axis=0), axis=2).mean(1)


def drift(joints: np.ndarray) -> dict:
    """Pelvis height band (1st, 99th percentile, m), the deepest foot under the floor (m),
    foot sliding while in contact (mean horizontal foot speed, m/s) and jitter (mean joint
    acceleration, m/s^2: what less lookahead, in the decoder or the feet, shows as)."""
    pelvis = joints[:, S.J["pelvis"], 1]
    feet = joints[:, FEET]
    speed = np.linalg.norm(np.diff(feet[:, :, [0, 2]], axis=0), axis=2) * FPS
    contact = feet[1:, :, 1] < CONTACT_HEIGHT
    return dict(
        pelvis_low=float(np.percentile(pelvis, 1)),
        pelvis_high=float(np.percentile(pelvis, 99)),
        under_floor=float(max(0.0, -feet[:, :, 1].min())),
        slide=float(speed[contact].mean()) if contact.any() else 0.0,
        acceleration=float(np.linalg.norm(np.diff(joints, 2, axis=0), axis=2).mean() * FPS**2),
    )
