"""The procedural animator's body: per-clip proportions and style, the motion channels every
primitive writes, curve helpers, and the kinematics that turn channels into joint positions.

Channels are world-space time series. The spine, neck and head are posed by angles and forward
kinematics; legs and arms reach their targets by two-bone inverse kinematics, so feet stay
exactly where the footstep planner puts them and no bone ever changes length.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from mogo.motion.quaternion import qfrom_axis_angle, qmul, qrot, qyaw
from mogo.motion.skeleton import SMPL_22

FPS = int(SMPL_22.fps)  # HumanML3D's frame rate, as an int for frame counts and files
LEFT, RIGHT = 0, 1
SIDES = np.array([1.0, -1.0])  # +X is the character's left
X_AXIS, Z_AXIS = np.eye(3)[0], np.eye(3)[2]

STAND_REACH = 0.996  # hip-to-ankle distance of a relaxed stance, as a share of the leg length
MAX_REACH = 0.999  # the pelvis is lowered wherever a foot target is further than this
# Share of the torso's bend / lean / twist taken by pelvis, spine1, spine2, spine3 and neck.
TORSO_SHARES = np.array(
    [
        [0.30, 0.00, 0.00],
        [0.25, 0.35, 0.30],
        [0.20, 0.35, 0.35],
        [0.15, 0.20, 0.25],
        [0.10, 0.10, 0.10],
    ]
)
ELBOW_POLE = np.array([0.1, -0.3, -1.0])  # chest frame, x mirrored per arm: back, down, out
FLARED_POLE = np.array([1.0, -0.3, 0.0])  # elbow out to the side
KNEE_POLE = np.array([0.15, 0.4, 1.0])  # foot frame, x mirrored per leg: forward, up, a bit out
LEG_BONES, ARM_BONES = [4, 5, 7, 8], [18, 19, 20, 21]


@dataclass(frozen=True)
class Body:
    """One performer: bone vectors (metres) and movement style, fixed for a whole clip."""

    offsets: np.ndarray  # (22, 3) bone vectors from each joint's parent, facing +Z
    tempo: float  # > 1 moves faster
    energy: float  # > 1 moves bigger
    arm_swing: float  # multiplies the arm swing of walking and running
    stance: float  # half the distance between the ankles when standing
    toe_out: float  # each foot's yaw away from the facing, radians
    posture: float  # forward bend of the relaxed torso, radians
    arm_rest: np.ndarray  # (4,) relaxed arms (see Track.arms)
    natural: bool = False  # corpus v2's: gaits calibrated against real clips (animator_steps)
    variation: float = 0.0  # spread of each step's timing and length (share of a step)
    asymmetry: float = 0.0  # the left steps' length over the right's, minus one, halved

    @classmethod
    def sample(cls, rng: np.random.Generator, natural: bool = False) -> Body:
        """A random performer; `natural` (corpus v2) also draws an uneven, varying gait,
        after every v1 draw so that v1 corpora stay what they were."""
        offsets = SMPL_22.rest_offsets * rng.uniform(0.96, 1.04)
        offsets[LEG_BONES] *= rng.uniform(0.98, 1.02)
        offsets[ARM_BONES] *= rng.uniform(0.98, 1.02)
        body = cls(
            offsets=offsets,
            tempo=rng.uniform(0.9, 1.1),
            energy=rng.uniform(0.85, 1.15),
            arm_swing=rng.uniform(0.7, 1.3),
            stance=rng.uniform(0.085, 0.115),
            toe_out=np.radians(rng.uniform(3.0, 12.0)),
            posture=np.radians(rng.uniform(-2.0, 6.0)),
            arm_rest=np.array(
                [rng.uniform(-0.05, 0.1), rng.uniform(0.06, 0.2), rng.uniform(0.975, 0.995), 0.0]
            ),
        )
        if not natural:
            return body
        return replace(
            body,
            natural=True,
            variation=rng.uniform(0.02, 0.05),
            asymmetry=rng.uniform(-0.04, 0.04),
        )

    def length(self, joint: int) -> float:
        return float(np.linalg.norm(self.offsets[joint]))

    @property
    def leg(self) -> float:
        return self.length(4) + self.length(7)

    @property
    def arm(self) -> float:
        return self.length(18) + self.length(20)

    @property
    def ankle_height(self) -> float:
        """Ankle height of a flat foot whose ball rests on the floor."""
        return -float(self.offsets[10, 1])

    @property
    def stand_height(self) -> float:
        """Pelvis height of the relaxed stance."""
        across = self.stance - self.offsets[1, 0]
        drop = np.sqrt((STAND_REACH * self.leg) ** 2 - across**2)
        return float(self.ankle_height + drop - self.offsets[1, 1])

    def shoulder_width(self) -> float:
        """Distance from the chest's midline to each shoulder joint."""
        return float(self.offsets[13, 0] + self.offsets[16, 0])


@dataclass
class Track:
    """Per-frame channels of a motion, world space, angles in radians; per-limb axes are
    ordered (left, right)."""

    pelvis: np.ndarray  # (T, 3) pelvis position
    yaw: np.ndarray  # (T,) facing: + turns left (counter-clockwise from above), 0 faces +Z
    torso: np.ndarray  # (T, 3) bend forward, lean left, twist left
    # (T, 2, 4) shoulder-to-wrist direction as swing (0 down, pi/2 forward, pi up) and
    # spread (+ outward), reach (that distance over the arm's length), and flare (0: elbow
    # back, 1: elbow out to the side)
    arms: np.ndarray
    feet: np.ndarray  # (T, 2, 3) x, lift above the floor, z of each ankle when its foot is flat
    foot_yaw: np.ndarray  # (T, 2)
    foot_pitch: np.ndarray  # (T, 2) toes down; positive pitch pivots about the ball (heel up)

    def __len__(self) -> int:
        return len(self.yaw)

    @classmethod
    def concat(cls, tracks: list[Track]) -> Track:
        return cls(*(np.concatenate([getattr(t, f.name) for t in tracks]) for f in fields(cls)))


def facing(yaw) -> np.ndarray:
    """Unit floor (x, z) vectors (..., 2) a body with this yaw faces."""
    return np.stack([np.sin(yaw), np.cos(yaw)], -1)


def leftward(yaw) -> np.ndarray:
    """Unit floor (x, z) vectors (..., 2) to the left of a body with this yaw."""
    return np.stack([np.cos(yaw), -np.sin(yaw)], -1)


def ease(u: np.ndarray) -> np.ndarray:
    """Smoothstep: 0 -> 1 with zero speed at both ends."""
    return u * u * (3.0 - 2.0 * u)


def curve(times, values, t: np.ndarray) -> np.ndarray:
    """Monotone cubic (PCHIP) through key `values` (K, ...) at increasing `times` (K,),
    sampled at `t` (T,) -> (T, ...). Slopes are zero at the first and last key and at every
    turning point, so repeated keys hold exactly still and nothing overshoots its keys."""
    times = np.asarray(times, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    v = values.reshape(len(times), -1)
    h = np.diff(times)
    delta = np.diff(v, axis=0) / h[:, None]  # (K-1, D)
    slope = np.zeros_like(v)
    if len(times) > 2:
        before, after = delta[:-1], delta[1:]
        w1, w2 = (2 * h[1:] + h[:-1])[:, None], (h[1:] + 2 * h[:-1])[:, None]
        same = before * after > 0
        safe_before, safe_after = np.where(same, before, 1.0), np.where(same, after, 1.0)
        slope[1:-1] = np.where(same, (w1 + w2) / (w1 / safe_before + w2 / safe_after), 0.0)
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    s = np.clip((t - times[k]) / h[k], 0.0, 1.0)[:, None]
    span = h[k][:, None]
    out = (
        (2 * s**3 - 3 * s**2 + 1) * v[k]
        + (s**3 - 2 * s**2 + s) * span * slope[k]
        + (3 * s**2 - 2 * s**3) * v[k + 1]
        + (s**3 - s**2) * span * slope[k + 1]
    )
    return out.reshape((len(t),) + values.shape[1:])


def _windows(x: np.ndarray, radius: int) -> np.ndarray:
    """(T, D, 2 radius + 1) sliding windows over x (T, D) with its edge values repeated."""
    padded = np.concatenate([np.repeat(x[:1], radius, 0), x, np.repeat(x[-1:], radius, 0)], 0)
    return np.lib.stride_tricks.sliding_window_view(padded, 2 * radius + 1, axis=0)


def smooth(x: np.ndarray, radius: int) -> np.ndarray:
    """Hann-window average over +-radius frames along axis 0, edge values held. The window
    is finite, so a signal that is constant for `radius` frames at an end keeps its value."""
    if radius < 1:
        return x
    kernel = np.hanning(2 * radius + 3)[1:-1]
    flat = x.reshape(len(x), -1)
    return (_windows(flat, radius) @ (kernel / kernel.sum())).reshape(x.shape)


def _smooth_min(x: np.ndarray, radius: int) -> np.ndarray:
    """A smooth signal nowhere above x (T,): a running minimum, then smoothing within the
    same radius."""
    return smooth(_windows(x[:, None], radius)[:, 0].min(axis=-1), radius)


def two_bone_ik(
    root: np.ndarray, target: np.ndarray, pole: np.ndarray, upper: float, lower: float
) -> tuple[np.ndarray, np.ndarray]:
    """Middle and end joints (..., 3) of a limb reaching from `root` toward `target`, bending
    toward `pole`. A target out of reach pulls the end in along the line: bones never stretch."""
    offset = target - root
    distance = np.linalg.norm(offset, axis=-1, keepdims=True)
    direction = offset / np.maximum(distance, 1e-9)
    distance = np.clip(distance, abs(upper - lower) + 1e-6, (upper + lower) * (1 - 1e-6))
    along = (upper**2 - lower**2 + distance**2) / (2 * distance)
    out = np.sqrt(np.maximum(upper**2 - along**2, 0.0))
    bend = pole - np.sum(pole * direction, axis=-1, keepdims=True) * direction
    bend /= np.linalg.norm(bend, axis=-1, keepdims=True)
    return root + along * direction + out * bend, root + distance * direction


def _mirrored(v: np.ndarray) -> np.ndarray:
    """(2, 3): a left-limb vector and its mirror for the right limb."""
    return np.stack([v, v * np.array([-1.0, 1.0, 1.0])])


def _torso_rotation(angles: np.ndarray) -> np.ndarray:
    """Local rotation (..., 4) of one spine joint from its share of (bend, lean, twist)."""
    bend = qfrom_axis_angle(X_AXIS, angles[..., 0])
    lean = qfrom_axis_angle(Z_AXIS, -angles[..., 1])
    return qmul(qyaw(angles[..., 2]), qmul(lean, bend))


def pose_joints(track: Track, body: Body) -> np.ndarray:
    """Joint positions (T, 22, 3) of a track, all frames at once."""
    o = body.offsets
    frames = len(track)
    joints = np.zeros((frames, 22, 3))
    rotations = [_torso_rotation(track.torso * share) for share in TORSO_SHARES]
    pelvis_frame = qmul(qyaw(track.yaw), rotations[0])

    # Feet: the toe-down pitch pivots about the ball of the foot, which stays put.
    foot_frame = qyaw(track.foot_yaw)  # (T, 2, 4)
    ball = o[10]
    heel_up = qfrom_axis_angle(X_AXIS, np.maximum(track.foot_pitch, 0.0))
    ankle = track.feet + np.array([0.0, body.ankle_height, 0.0])
    ankle += qrot(foot_frame, ball - qrot(heel_up, ball))

    # Lower the pelvis where a leg could not otherwise reach its foot.
    hips = qrot(pelvis_frame[:, None], o[[1, 2]])  # (T, 2, 3) relative to the pelvis
    across = np.linalg.norm((track.pelvis[:, None] + hips - ankle)[..., [0, 2]], axis=-1)
    room = np.sqrt(np.maximum((MAX_REACH * body.leg) ** 2 - across**2, 0.0))
    highest = np.min(ankle[..., 1] + room - hips[..., 1], axis=-1)
    pelvis = track.pelvis.copy()
    pelvis[:, 1] += _smooth_min(np.minimum(highest - pelvis[:, 1], 0.0), 3)
    joints[:, 0] = pelvis

    # Spine, neck and head by forward kinematics.
    frame = pelvis_frame
    for joint, rotation in zip((3, 6, 9), rotations[1:4], strict=False):
        joints[:, joint] = joints[:, SMPL_22.parents[joint]] + qrot(frame, o[joint])
        frame = qmul(frame, rotation)
    chest = frame
    joints[:, 12] = joints[:, 9] + qrot(chest, o[12])
    joints[:, 15] = joints[:, 12] + qrot(qmul(chest, rotations[4]), o[15])

    # Legs reach the feet; knees point along the feet.
    joints[:, [1, 2]] = pelvis[:, None] + hips
    knees, ankles = two_bone_ik(
        joints[:, [1, 2]],
        ankle,
        qrot(foot_frame, _mirrored(KNEE_POLE)),
        body.length(4),
        body.length(7),
    )
    joints[:, [4, 5]], joints[:, [7, 8]] = knees, ankles
    pitch = qfrom_axis_angle(X_AXIS, track.foot_pitch)
    joints[:, [10, 11]] = ankles + qrot(qmul(foot_frame, pitch), ball)

    _pose_arms(joints, track, body, chest)
    return joints


def _pose_arms(joints: np.ndarray, track: Track, body: Body, chest: np.ndarray) -> None:
    """Arms into `joints`: collar and shoulder ride on the chest; the wrist goes where the
    angles point, the elbow solved between."""
    o = body.offsets
    chest2 = chest[:, None]
    joints[:, [13, 14]] = joints[:, 9:10] + qrot(chest2, o[[13, 14]])
    shoulders = joints[:, [13, 14]] + qrot(chest2, o[[16, 17]])
    joints[:, [16, 17]] = shoulders
    swing, spread, reach, flare = np.moveaxis(track.arms, -1, 0)  # (T, 2) each
    direction = np.stack(
        [SIDES * np.sin(spread), -np.cos(spread) * np.cos(swing), np.cos(spread) * np.sin(swing)],
        -1,
    )
    wrist = shoulders + qrot(chest2, direction * (reach * body.arm)[..., None])
    flare = flare[..., None]
    elbow_pole = qrot(chest2, (1 - flare) * _mirrored(ELBOW_POLE) + flare * _mirrored(FLARED_POLE))
    joints[:, [18, 19]], joints[:, [20, 21]] = two_bone_ik(
        shoulders, wrist, elbow_pole, body.length(18), body.length(20)
    )
