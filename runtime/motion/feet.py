"""Feet that stay planted: contact-aware foot cleanup of decoded motion, offline and on streams.

Decoded feet skate: they drift while the motion's own contact channels (the last four feature
dims: left ankle, left toe, right ankle, right toe; "moved less than ~4.5 cm in this frame")
say they are planted, and the channels often call a foot planted a frame or two before it
lands and after it lifts, while it still swings. `FootPlanter` fixes the legs (and, only if
asked, moves the body):
- the body, with `body_step` (off by default): where a flagged joint steps further than
  body_step to the next frame, the whole body steps back horizontally by the excess (the mean
  over such joints), spread over BODY_FRAMES frames; the shift accumulates, so the body
  travels less and the foot keeps its decoded motion relative to the body. At BODY_STEP it
  lowers the slide a little but walks travel ~10% less and fail more of the long-stream
  checks (docs/feet.md), so the default leaves root motion as decoded;
- each contact joint is held while its channel is above CONTACT and its decoded step is under
  HOLD_STEP, HumanML3D's contact threshold (a foot swinging faster is not believed planted:
  holding it squeezes its stride into the frames left, a pop), the frame after too (a contact
  is "still from t to t+1"), at its mean position over the contact's first frames (its
  Window's pin_frames); its height is never below that pin (a heel may rise, a foot never
  sinks);
- it eases onto the pin over the Window's blend_in frames before the contact and back onto
  its path over BLEND_OUT frames after it, by blending offsets with a smoothstep: neither
  position nor speed jumps;
- the foot stays rigid (ankle to toe at the foot's length, the more planted end held) and on or
  above the floor (y >= 0);
- each leg is solved by analytic two-bone IK: hip as the (shifted) body's, knee in the plane of
  the decoded knee, ankle on its target; thigh, shin and foot at the bundle skeleton's
  canonical lengths (its rest offsets, left and right averaged, as the BVH rig's), so they
  stop stretching. A target out of the leg's reach is pulled towards the hip (the foot slides
  rather than the pelvis dropping).

It reads blend_in + pin_frames - 1 frames ahead (Window.lookahead), so a stream emits a frame
that many frames after it is decoded: 8 with the default WINDOW (one burst of the centred
decoder), 2 with SHORT, the low-latency streams' (docs/feet.md). Any chunking of `push` (then
`flush`) gives the output of one push of the whole clip.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .features import FOOT_CONTACT_THRESHOLD, feature_layout
from .rig import rest_offsets
from .skeleton import Skeleton

CONTACT = 0.5  # a contact channel above this holds its joint
# m a frame (0.9 m/s, HumanML3D's contact threshold): a flagged joint stepping further is not
# held (0.12, 2.4 m/s, would meet issue 25's 3 cm/s at a cost in pops: docs/feet.md)
HOLD_STEP = FOOT_CONTACT_THRESHOLD**0.5
BODY_STEP = 0.067  # m a frame (1.34 m/s): the body step measured best, when one is asked for
BODY_FRAMES = 3  # frames each such step back is spread over (the body slows, it does not jerk)
BLEND_OUT = 8  # frames to ease back onto the decoded path after a contact (no lookahead)


@dataclass(frozen=True)
class Window:
    """What the planter reads ahead: it eases onto a pin over `blend_in` frames before its
    contact starts, the pin being the mean position over the contact's first `pin_frames`."""

    blend_in: int
    pin_frames: int

    @property
    def lookahead(self) -> int:
        """Frames read ahead: a frame is final once this many frames after it are decoded."""
        return self.blend_in + self.pin_frames - 1


WINDOW = Window(blend_in=3, pin_frames=6)  # 8 frames ahead, one burst of the centred decoder
SHORT = Window(blend_in=2, pin_frames=1)  # 2 frames ahead: low-latency streams (docs/feet.md)
LOOKAHEAD = WINDOW.lookahead  # the default planter's: generate, centred streams, the serve engine
MAX_REACH = 0.9995  # share of thigh + shin the IK may stretch a leg to
KNEE_FORWARD = 0.1  # metres the knee's bend plane leans forward: a straight leg bends forward


def leg_joints(skeleton: Skeleton) -> np.ndarray:
    """(2, 4) hip, knee, ankle, toe of the left and right leg, from the contact joints; a
    ValueError for a skeleton whose feet are not root -> hip -> knee -> ankle -> toe."""
    parents = skeleton.parents
    legs = []
    for ankle, toe in (skeleton.left_foot, skeleton.right_foot):
        knee = parents[ankle]
        hip = parents[knee] if knee >= 0 else -1
        if parents[toe] != ankle or hip <= 0 or parents[hip] != 0:
            raise ValueError(
                f"foot planting needs legs hip -> knee -> ankle -> toe with contacts "
                f"on ankle and toe; the {skeleton.name} skeleton has other feet"
            )
        legs.append((hip, knee, ankle, toe))
    return np.array(legs)


def two_bone_ik(
    hip: np.ndarray, target: np.ndarray, pole: np.ndarray, upper: np.ndarray, lower: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Knee and ankle (..., 3) of a leg from the hip to `target`, bones of lengths upper and
    lower (...), the knee on the side of `pole` (a point, e.g. the decoded knee). A target out
    of reach is moved along the hip->target line to the nearest reachable distance."""
    reach = target - hip
    distance = _norm(reach)
    axis = reach / np.maximum(distance, 1e-9)
    upper, lower = upper[..., None], lower[..., None]
    distance = np.clip(distance, np.abs(upper - lower) + 1e-6, MAX_REACH * (upper + lower))
    side = pole - hip
    side = side - np.sum(side * axis, -1, keepdims=True) * axis
    side_norm = _norm(side)
    # a straight decoded leg along the pole: bend in any plane, here the one across x
    fallback = np.stack([np.zeros_like(axis[..., 0]), axis[..., 2], -axis[..., 1]], -1)
    side = np.where(
        side_norm > 1e-6,
        side / np.maximum(side_norm, 1e-9),
        fallback / np.maximum(_norm(fallback), 1e-9),
    )
    cos = (upper**2 + distance**2 - lower**2) / (2 * upper * distance)
    sin = np.sqrt(np.clip(1 - cos**2, 0.0, 1.0))
    knee = hip + upper * (cos * axis + sin * side)
    return knee, hip + distance * axis


def _norm(v: np.ndarray) -> np.ndarray:
    """Lengths (..., 1) of vectors (..., 3) (np.linalg.norm costs more on small arrays)."""
    return np.sqrt(np.sum(v * v, -1, keepdims=True))


class FootPlanter:
    """Cleans feet frame by frame: `push` decoded rows (features (n, D), joints (n, J, 3)),
    get back the rows whose frames are final, with planted feet; `flush` at the end."""

    def __init__(
        self,
        skeleton: Skeleton,
        hold_step: float = HOLD_STEP,
        body_step: float = np.inf,
        window: Window = WINDOW,
    ):
        self.hold_step, self.body_step = hold_step, body_step  # the bench compares others
        self.window = window
        self.legs = leg_joints(skeleton)  # (2, 4)
        self.contacts = self.legs[:, 2:].reshape(-1)  # left ankle, left toe, right ...
        start = dict((name, start) for name, start, _ in feature_layout(skeleton))
        self._velocity = start["joint_velocities"] + 3 * self.contacts[:, None] + np.arange(3)
        self._hips = skeleton.face_joints[:2]  # right hip, left hip: the facing
        joints = len(self.contacts)  # the state of each contact joint after the last frame out:
        self._flag = np.zeros(joints, bool)  # its contact flag
        self._held = np.zeros(joints, bool)  # held
        self._pin = np.zeros((joints, 3))  # the pin of its contact, while held
        self._released = np.zeros((joints, 3))  # its offset at the last held frame
        self._since = np.full(joints, 1 << 30)  # frames since then
        self._shift = np.zeros(3)  # the body's horizontal shift at the next frame out
        self._backs = np.zeros((BODY_FRAMES - 1, 3))  # its steps back at the frames before
        self._features = np.zeros((0, skeleton.feature_dim), np.float32)
        self._joints = np.zeros((0, skeleton.num_joints, 3))
        rest = np.linalg.norm(rest_offsets(skeleton), axis=1)  # the bundle's canonical bones
        self._lengths = rest[self.legs[0, 1:]]  # thigh, shin, foot (left and right averaged)

    @property
    def lookahead(self) -> int:
        """Frames held back: a pushed frame comes out once this many more are pushed."""
        return self.window.lookahead

    @property
    def pending(self) -> int:
        """Frames pushed but not yet returned."""
        return len(self._joints)

    def push(self, features: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows in, the rows now final out: (features, joints float32) with the feet planted."""
        return push_together([self], [features], [joints])[0]

    def flush(self) -> tuple[np.ndarray, np.ndarray]:
        """The remaining rows (the clip ends: no lookahead past them)."""
        features, joints, targets, weights = _take_together([self], len(self._joints))[0]
        return features, self._solve(joints, targets, weights)

    def _buffer(self, features: np.ndarray, joints: np.ndarray) -> None:
        self._features = np.concatenate([self._features, features])
        self._joints = np.concatenate([self._joints, np.asarray(joints, np.float64)])

    def _shifts(self, ready: int) -> np.ndarray:
        """(n, 3) the body's horizontal shift at each buffered frame. Where the channel flags a
        foot joint whose decoded step (to the next frame) is longer than BODY_STEP, the body
        steps back by the excess (the mean over such joints), spread over BODY_FRAMES frames:
        the foot's step shrinks towards BODY_STEP, it keeps its motion relative to the body,
        and the body travels less. The shift accumulates over the stream."""
        n = len(self._joints)
        steps = np.diff(self._joints[:, self.contacts], axis=0)  # (n - 1, 4, 3)
        steps[..., 1] = 0.0
        length = _norm(steps)[..., 0]
        fast = (self._features[:-1, -4:] > CONTACT) & (length > self.body_step)
        excess = np.where(fast, 1.0 - self.body_step / np.maximum(length, 1e-9), 0.0)
        back = -np.sum(excess[..., None] * steps, 1) / np.maximum(fast.sum(1), 1)[:, None]
        backs = np.concatenate([self._backs, back, np.zeros((1, 3))])  # (n + BODY_FRAMES - 1, 3)
        spread = sum(backs[k : k + n] for k in range(BODY_FRAMES)) / BODY_FRAMES  # (n, 3)
        shifts = self._shift + np.concatenate([np.zeros((1, 3)), np.cumsum(spread, 0)])
        self._shift, self._backs = shifts[ready], backs[ready : ready + BODY_FRAMES - 1]
        return shifts[:n]

    def _solve(self, joints: np.ndarray, targets: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Rigid feet on or above the floor, then two-bone IK, both legs at once: each frame on
        its own (so frames of many planters of one skeleton can be solved together); the
        joints out float32, as a stream hands them on."""
        lengths = np.broadcast_to(self._lengths, (len(joints), 3))
        out = joints.copy()
        hip, knee, ankle, toe = self.legs.T  # each (2,): left, right
        right, left = self._hips
        across = joints[:, right] - joints[:, left]
        forward = np.stack([across[:, 2], np.zeros(len(across)), -across[:, 0]], -1)  # up x across
        forward *= KNEE_FORWARD / np.maximum(_norm(forward), 1e-9)
        targets, weights = targets.reshape(-1, 2, 2, 3), weights.reshape(-1, 2, 2)
        a, t = targets[:, :, 0], targets[:, :, 1]  # (n, 2, 3) ankle and toe targets
        foot = lengths[:, None, 2:3]
        along = t - a
        span = _norm(along)
        along = along / np.maximum(span, 1e-9)
        total = weights.sum(-1)
        toe_share = np.where(total > 0, weights[..., 1] / np.maximum(total, 1e-9), 0.5)
        a = a + toe_share[..., None] * (span - foot) * along  # the more planted end stays
        a[..., 1] += np.maximum(0.0, -np.minimum(a[..., 1], (a + foot * along)[..., 1]))
        thigh, shin = (np.repeat(lengths[:, k : k + 1], 2, 1) for k in (0, 1))
        out[:, knee], out[:, ankle] = two_bone_ik(
            joints[:, hip], a, joints[:, knee] + forward[:, None], thigh, shin
        )
        out[:, toe] = out[:, ankle] + foot * along
        return out.astype(np.float32)


def push_together(
    planters: Sequence[FootPlanter], features: Sequence[np.ndarray], joints: Sequence[np.ndarray]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """FootPlanter.push of many planters of one skeleton (the server's round): the contacts
    and targets of those with as many frames buffered in one pass, then the legs of all their
    final frames in one pass (the same numbers as one push each: frames never mix)."""
    out: list = [None] * len(planters)
    alike: dict[tuple, list[int]] = {}  # planters by frames buffered and taken, and settings
    for k, (planter, rows, positions) in enumerate(zip(planters, features, joints, strict=True)):
        if not len(rows):  # no row in, none out (the last push kept just the lookahead): a
            # stream pushes nothing on 7 of every 8 token steps
            shape = (0, *planter._joints.shape[1:])
            out[k] = planter._features[:0], np.zeros(shape, np.float32)
            continue
        planter._buffer(rows, positions)
        n = len(planter._joints)
        ready = max(0, n - planter.lookahead)
        key = (n, ready, planter.window, planter.hold_step, planter.body_step)
        alike.setdefault(key, []).append(k)
    taken, ks = [], []
    for (_, ready, *_), members in alike.items():
        taken += _take_together([planters[k] for k in members], ready)
        ks += members
    if ks:
        cuts = np.cumsum([len(t[1]) for t in taken])[:-1]
        legs = (np.concatenate([t[i] for t in taken]) for i in (1, 2, 3))
        solved = np.split(planters[ks[0]]._solve(*legs), cuts)
        for k, t, solved_joints in zip(ks, taken, solved, strict=True):
            out[k] = t[0], solved_joints
    return out


def _take_together(planters: Sequence[FootPlanter], ready: int) -> list[tuple[np.ndarray, ...]]:
    """The first `ready` buffered frames of each planter (all with as many buffered, and one
    window, hold step and body step) out of its buffer, its state moved past them: their
    features, joints, and their contact joints' targets and planted weights."""
    first = planters[0]
    joints = np.stack([p._joints for p in planters])  # (B, n, J, 3): the body as decoded,
    if first.body_step != np.inf:  # unless a body step is asked for
        joints = joints + np.stack([p._shifts(ready) for p in planters])[:, :, None]
    buffered = np.stack([p._features for p in planters])  # (B, n, D)
    targets, weights = _targets_together(
        planters, _flags(first, buffered), joints[:, :, first.contacts], ready
    )
    taken = []
    for b, planter in enumerate(planters):
        taken.append((planter._features[:ready], joints[b, :ready], targets[b], weights[b]))
        planter._features, planter._joints = planter._features[ready:], planter._joints[ready:]
    return taken


def _flags(planter: FootPlanter, features: np.ndarray) -> np.ndarray:
    """(B, n, 4) contacts of buffered frames (B, n, D): the channel says so and the decoded
    joint steps less than the hold step (a swinging foot the channel calls planted is not held:
    holding it squeezes its stride into the frames before the next contact, docs/feet.md)."""
    speed = np.sum(features[..., planter._velocity].astype(np.float64) ** 2, -1)
    return (features[..., -4:] > CONTACT) & (speed < planter.hold_step**2)


def _targets_together(
    planters: Sequence[FootPlanter], flags: np.ndarray, paths: np.ndarray, ready: int
) -> tuple[np.ndarray, np.ndarray]:
    """Targets (B, ready, 4, 3) and planted weights (B, ready, 4) of the contact joints in the
    first `ready` buffered frames of each planter, from their flags (B, n, 4) and paths
    (B, n, 4, 3); each planter's state moved past them. Elementwise per planter: the numbers
    of one planter at a time."""
    B, n = flags.shape[:2]
    if not ready:
        return np.zeros((B, 0, 4, 3)), np.zeros((B, 0, 4))
    frames, bs, ks = np.arange(n)[:, None], np.arange(B)[:, None, None], np.arange(4)
    blend_in = planters[0].window.blend_in
    last_flag, last_held, last_since = (
        np.stack([getattr(p, a) for p in planters]) for a in ("_flag", "_held", "_since")
    )
    held = flags | np.concatenate([last_flag[:, None], flags[:, :-1]], 1)
    starts = held & ~np.concatenate([last_held[:, None], held[:, :-1]], 1)
    pins = _pins(planters, held, starts[:, : ready + blend_in], paths)
    run = np.maximum.accumulate(np.where(starts, frames, -1), axis=1)  # its start
    pins = np.where((run >= 0)[..., None], pins[bs, np.maximum(run, 0), ks], pins)
    held_offset = _offset(pins, paths)  # meaningful where held
    last = np.maximum.accumulate(np.where(held, frames, -1), axis=1)  # last held frame
    last = np.concatenate([np.full((B, 1, 4), -1), last[:, :-1]], 1)  # ... before this one
    since = np.where(last >= 0, frames - last, last_since[:, None] + frames + 1)
    released = np.where(
        (last >= 0)[..., None],
        held_offset[bs, np.maximum(last, 0), ks],
        np.stack([p._released for p in planters])[:, None],
    )
    out = _ease(1.0 - since / (BLEND_OUT + 1))
    upcoming = np.minimum.accumulate(np.where(flags, frames, n)[:, ::-1], axis=1)[:, ::-1]
    following = np.concatenate([upcoming[:, 1:], np.full((B, 1, 4), n)], 1)  # first flag after
    into = np.where(following < n, _ease(1.0 - (following - frames) / (blend_in + 1)), 0.0)
    start_offset = held_offset[bs, np.minimum(following, n - 1), ks]
    offset = out[..., None] * released + into[..., None] * start_offset
    weight = out + into
    offset /= np.maximum(weight, 1.0)[..., None]  # contacts close together share frames
    offset = np.where(held[..., None], held_offset, offset)
    weight = np.where(held, 1.0, np.minimum(weight, 1.0))
    end = ready - 1  # the state after the last frame out
    for b, p in enumerate(planters):
        p._flag, p._held, p._pin = flags[b, end], held[b, end], pins[b, end]
        p._released = np.where(held[b, end, :, None], held_offset[b, end], released[b, end])
        p._since = np.where(held[b, end], 0, since[b, end])
    return (paths + offset)[:, :ready], weight[:, :ready]


def _pins(
    planters: Sequence[FootPlanter], held: np.ndarray, starts: np.ndarray, paths: np.ndarray
) -> np.ndarray:
    """(B, n, 4, 3) each planter's pin before its frames, and at each contact's start frame
    (`starts`, the first frames of `held`) the mean position over the contact's first frames
    (at most the window's pin_frames), summed in frame order as numpy's mean does."""
    n = held.shape[1]
    pins = np.repeat(np.stack([p._pin for p in planters])[:, None], n, 1)
    b, i, k = np.nonzero(starts)
    idx = i[:, None] + np.arange(planters[0].window.pin_frames)  # (S, P)
    inside = idx < n
    idx = np.minimum(idx, n - 1)
    run = np.logical_and.accumulate(held[b[:, None], idx, k[:, None]] & inside, axis=1)
    window = paths[b[:, None], idx, k[:, None]]  # (S, P, 3)
    total = window[:, 0]
    for j in range(1, window.shape[1]):
        total = np.where(run[:, j, None], total + window[:, j], total)
    pins[b, i, k] = total / run.sum(1)[:, None]
    return pins


def _ease(x: np.ndarray) -> np.ndarray:
    """0 below 0, 1 above 1, smoothstep between: blends with no jump in speed either."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _offset(pin: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Pin minus position, its height part never pulling down (a foot may rise off its pin)."""
    offset = pin - position
    offset[..., 1] = np.maximum(offset[..., 1], 0.0)
    return offset


def planted(features: np.ndarray, joints: np.ndarray, skeleton: Skeleton, **options) -> np.ndarray:
    """The joints (T, J, 3) float32 of a whole clip with planted feet (one push and a flush);
    `options`: FootPlanter's hold_step, body_step and window."""
    planter = FootPlanter(skeleton, **options)
    first = planter.push(features, joints)[1]
    return np.concatenate([first, planter.flush()[1]])
