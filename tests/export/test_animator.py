import json

import numpy as np
import pytest

from mogo.export.data.animator import CORPORA, PRIMITIVES, Segment, animate, sample_segment
from mogo.motion.features import (
    facing_directions,
    features_to_joints,
    foot_contacts,
    joints_to_features,
)
from mogo.motion.skeleton import SMPL_22

NAMES = (
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
)  # corpus v1
PELVIS, HEAD = 0, 15
LEFT_WRIST, RIGHT_WRIST, LEFT_SHOULDER, RIGHT_SHOULDER = 20, 21, 16, 17
FEET = {"left": (7, 10), "right": (8, 11)}  # ankle, ball of the foot
SKATE_LIMIT = 0.005  # m per frame: a planted foot joint's horizontal drift
REST_BAND = 0.005  # m: a foot joint this close to its lowest height counts as planted


def seg(primitive: str, **params) -> Segment:
    return Segment(primitive, params)


def clip(*segments: Segment, seed: int = 0) -> np.ndarray:
    return animate(list(segments), np.random.default_rng(seed)).joints.astype(np.float64)


def headings(joints: np.ndarray) -> np.ndarray:
    """Unsmoothed facing angle of every frame, unwrapped (radians, + = turned left)."""
    forward = facing_directions(joints, SMPL_22, facing_sigma=0)
    return np.unwrap(np.arctan2(forward[:, 0], forward[:, 2]))


def turned(joints: np.ndarray) -> float:
    """Degrees the facing turned from the first frames to the last."""
    h = headings(joints)
    return float(np.degrees(h[-3:].mean() - h[:3].mean()))


def random_clips(primitive: str, count: int, seed: int) -> list[tuple[Segment, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        segment = sample_segment(primitive, rng)
        out.append((segment, animate([segment], rng).joints.astype(np.float64)))
    return out


def test_primitives_and_their_params():
    assert CORPORA["v1"] == NAMES and set(CORPORA["v2"]) == set(PRIMITIVES) > set(NAMES)
    rng = np.random.default_rng(0)
    for name in PRIMITIVES:
        for _ in range(50):
            segment = sample_segment(name, rng)
            assert segment.primitive == name and set(segment.params) == set(PRIMITIVES[name])
            assert json.loads(json.dumps(segment.params)) == segment.params
            assert all(type(v) in (int, float, str, bool) for v in segment.params.values())
    with pytest.raises(ValueError, match="moonwalk"):
        sample_segment("moonwalk", rng)
    with pytest.raises(ValueError, match="moonwalk"):
        animate([seg("moonwalk")], rng)


def test_param_ranges_cover_what_captions_promise():
    rng = np.random.default_rng(1)
    angles = [sample_segment("turn", rng).params["angle"] for _ in range(400)]
    assert all(45 <= abs(a) <= 180 for a in angles)
    assert any(abs(abs(a) - 90) <= 5 for a in angles) and any(abs(a) >= 175 for a in angles)
    assert {a > 0 for a in angles} == {True, False}
    walks = [sample_segment("walk", rng).params for _ in range(400)]
    straight = np.mean([w["turn"] == 0 for w in walks if w["direction"] in ("forward", "backward")])
    assert 0.35 < straight < 0.65
    assert all(
        w["turn"] == 0 and w["steps"] % 2 == 0 for w in walks if w["direction"] in ("left", "right")
    )
    seconds = {sample_segment("idle", rng).params["seconds"] for _ in range(200)}
    assert seconds == {1.0, 1.5, 2.0, 2.5, 3.0}


@pytest.mark.parametrize("primitive", NAMES)
def test_every_primitive_animates_validly(primitive):
    rng = np.random.default_rng(2)
    for _ in range(3):
        segments = [sample_segment(primitive, rng), sample_segment(primitive, rng)]
        animation = animate(segments, rng)
        joints = animation.joints
        assert joints.dtype == np.float32 and joints.ndim == 3 and joints.shape[1:] == (22, 3)
        assert np.all(np.isfinite(joints)) and animation.fps == 20
        spans = animation.spans
        assert len(spans) == 2 and spans[0][0] == 0 and spans[-1][1] == len(joints)
        assert spans[0][1] == spans[1][0] and all(end > start for start, end in spans)
        joints = joints.astype(np.float64)
        parents = SMPL_22.parents
        bones = np.linalg.norm(joints[:, 1:] - joints[:, parents[1:]], axis=-1)
        assert np.ptp(bones, axis=0).max() < 1e-4
        feet = joints[:, [7, 8, 10, 11], 1]
        assert abs(feet.min()) < 0.03 and joints[..., 1].min() > -0.01


def test_same_rng_state_same_clip():
    segments = [
        seg("walk", direction="forward", speed="fast", steps=4, turn=45),
        seg("wave", hand="both", count=2),
    ]
    a = animate(segments, np.random.default_rng(5))
    b = animate(segments, np.random.default_rng(5))
    c = animate(segments, np.random.default_rng(6))
    assert np.array_equal(a.joints, b.joints) and a.spans == b.spans
    assert a.joints.shape != c.joints.shape or not np.allclose(a.joints, c.joints, atol=0.01)


@pytest.mark.parametrize(
    "primitive", ["walk", "jog", "run", "turn", "spin", "jump", "jumping_jacks", "kick"]
)
def test_planted_feet_do_not_skate(primitive):
    """Where `foot_contacts` flags contact and a foot joint stays at its resting height, it
    stays put (lifting heels and toes pushing off are allowed to move)."""
    for _, joints in random_clips(primitive, 6, seed=3):
        contact = foot_contacts(joints, SMPL_22) > 0  # (T-1, 4): left ankle, toe, right ...
        feet = joints[:, list(FEET["left"]) + list(FEET["right"])]
        resting = feet[..., 1] < feet[..., 1].min(axis=0) + REST_BAND
        planted = contact & resting[:-1] & resting[1:]
        drift = np.linalg.norm(np.diff(feet[..., [0, 2]], axis=0), axis=-1)
        assert planted.sum() > 10
        assert drift[planted].max() < SKATE_LIMIT


@pytest.mark.parametrize("gait", ["walk", "jog", "run"])
@pytest.mark.parametrize("direction", ["forward", "backward", "left", "right"])
def test_locomotion_goes_where_the_params_say(gait, direction):
    joints = clip(seg(gait, direction=direction, speed="normal", steps=4, turn=0))
    forward = facing_directions(joints, SMPL_22)[0]
    left = np.cross([0.0, 1.0, 0.0], forward)
    moved = joints[-1, PELVIS] - joints[0, PELVIS]
    along, across = moved @ forward, moved @ left
    expected = {"forward": (1, 0), "backward": (-1, 0), "left": (0, 1), "right": (0, -1)}
    sign_along, sign_across = expected[direction]
    main, other = (along * sign_along, across) if sign_along else (across * sign_across, along)
    assert main > 0.4 and abs(other) < 0.2 * main
    assert abs(turned(joints)) < 10


@pytest.mark.parametrize("gait", ["walk", "jog", "run"])
def test_gaits_look_like_gaits(gait):
    """Arms swing against the legs; jogging and running have flight phases and lean forward."""
    joints = clip(seg(gait, direction="forward", speed="normal", steps=8, turn=0), seed=4)
    forward = facing_directions(joints, SMPL_22)
    ahead = np.einsum("tjc,tc->tj", joints - joints[:, :1], forward)  # (T, J) along the facing
    assert np.corrcoef(ahead[:, LEFT_WRIST], ahead[:, FEET["right"][0]])[0, 1] > 0.7
    assert np.corrcoef(ahead[:, RIGHT_WRIST], ahead[:, FEET["left"][0]])[0, 1] > 0.7
    lowest = joints[:, [10, 11], 1].min(axis=1)  # the lower ball of the foot
    airborne = np.sum(lowest > 0.02)
    lean = np.degrees(np.arctan2(ahead[:, 12], joints[:, 12, 1] - joints[:, 0, 1])).max()
    if gait == "walk":
        assert airborne == 0 and lean < 8
    else:
        assert airborne >= 4 and lean > 8


@pytest.mark.parametrize("angle", [45, 90, -90, 135, 180, -180])
def test_turn_in_place_turns_by_the_angle(angle):
    joints = clip(seg("turn", angle=angle), seed=angle % 7)
    assert abs(turned(joints) - angle) < 15
    moved = joints[-1, PELVIS] - joints[0, PELVIS]
    assert np.hypot(moved[0], moved[2]) < 0.1


@pytest.mark.parametrize("turn", [90, -180])
def test_walking_path_turns_the_facing(turn):
    joints = clip(seg("walk", direction="forward", speed="normal", steps=6, turn=turn))
    assert abs(turned(joints) - turn) < 15


@pytest.mark.parametrize("direction,sign", [("left", 1), ("right", -1)])
def test_spin_goes_all_the_way_round(direction, sign):
    joints = clip(seg("spin", direction=direction))
    h = headings(joints)
    total = np.degrees(h[-1] - h[0])
    assert abs(total - sign * 360) < 20
    assert np.cos(h - h[0]).min() < -0.95  # faced the opposite way on the way round


@pytest.mark.parametrize("forward", [False, True])
def test_jump_leaves_the_floor(forward):
    count = 2
    joints = clip(seg("jump", forward=forward, count=count))
    pelvis = joints[:, PELVIS]
    assert pelvis[:, 1].max() > pelvis[0, 1] + 0.1
    feet = joints[:, [7, 8, 10, 11], 1].min(axis=1)
    airborne = feet > 0.05
    assert np.sum(np.diff(airborne.astype(int)) == 1) == count
    facing = facing_directions(joints, SMPL_22)[0]
    travelled = (pelvis[-1] - pelvis[0]) @ facing
    if forward:
        assert 0.4 * count < travelled < 1.1 * count
    else:
        assert abs(travelled) < 0.1


@pytest.mark.parametrize("hand,other", [("left", "right"), ("right", "left")])
def test_wave_raises_the_named_hand(hand, other):
    joints = clip(seg("wave", hand=hand, count=3))
    wrist = {"left": LEFT_WRIST, "right": RIGHT_WRIST}
    head_height = joints[0, HEAD, 1]
    assert joints[:, wrist[hand], 1].max() > head_height - 0.05
    assert joints[:, wrist[other], 1].max() < joints[0, PELVIS, 1] + 0.1
    # The raised forearm sweeps side to side once per wave.
    across = joints[:, wrist[hand], 0] - joints[:, HEAD, 0]
    raised = joints[:, wrist[hand], 1] > head_height - 0.1
    swings = np.diff(np.sign(np.diff(across[raised])))
    assert np.sum(swings != 0) >= 3


@pytest.mark.parametrize("foot", ["left", "right"])
def test_kick_raises_the_named_foot(foot):
    joints = clip(seg("kick", foot=foot))
    other = "right" if foot == "left" else "left"
    kicking, standing = joints[:, FEET[foot][0]], joints[:, FEET[other][0]]
    assert kicking[:, 1].max() > 0.4
    assert standing[:, 1].max() - standing[:, 1].min() < 0.01
    facing = facing_directions(joints, SMPL_22)[0]
    assert ((kicking - joints[:, PELVIS]) @ facing).max() > 0.4


@pytest.mark.parametrize("count", [1, 2, 4])
def test_squat_lowers_the_pelvis_count_times(count):
    joints = clip(seg("squat", count=count))
    height = joints[:, PELVIS, 1]
    low = height < height[0] - 0.15
    assert low[0] == low[-1] == False  # noqa: E712
    assert np.sum(np.diff(low.astype(int)) == 1) == count


@pytest.mark.parametrize("count", [1, 3, 6])
def test_clap_brings_the_hands_together_count_times(count):
    joints = clip(seg("clap", count=count))
    gap = np.linalg.norm(joints[:, LEFT_WRIST] - joints[:, RIGHT_WRIST], axis=-1)
    together = gap < 0.12
    assert np.sum(np.diff(together.astype(int)) == 1) == count
    chest = joints[:, 9]
    assert np.all(joints[together, LEFT_WRIST, 1] > chest[together, 1] - 0.3)


def test_punch_extends_the_named_fist_forward():
    joints = clip(seg("punch", hand="right", count=3))
    facing = facing_directions(joints, SMPL_22)[0]
    reach = {
        w: (joints[:, w] - joints[:, s]) @ facing
        for w, s in ((RIGHT_WRIST, RIGHT_SHOULDER), (LEFT_WRIST, LEFT_SHOULDER))
    }
    assert reach[RIGHT_WRIST].max() > 0.4 and reach[LEFT_WRIST].max() < 0.3
    out = reach[RIGHT_WRIST] > 0.35
    assert np.sum(np.diff(out.astype(int)) == 1) == 3


def test_sit_reaches_the_floor_and_stands_back_up():
    joints = clip(seg("sit"))
    height = joints[:, PELVIS, 1]
    assert height.min() < 0.3 and abs(height[-1] - height[0]) < 0.02


def test_segments_join_without_jumps():
    """Segments come to rest at their ends: the step into the next segment is no bigger than
    the step before it."""
    rng = np.random.default_rng(8)
    names = sorted(PRIMITIVES)
    for _ in range(20):
        segments = [sample_segment(names[int(rng.integers(len(names)))], rng) for _ in range(3)]
        animation = animate(segments, rng)
        step = np.linalg.norm(np.diff(animation.joints, axis=0), axis=-1).max(axis=1)
        for start, _ in animation.spans[1:]:
            assert step[start - 1] < max(0.01, step[start - 2] + 0.005), (segments, start)


@pytest.mark.parametrize(
    "segments",
    [
        [seg("turn", angle=180)],
        [seg("walk", direction="forward", speed="normal", steps=6, turn=180)],
        [seg("walk", direction="backward", speed="slow", steps=5, turn=0)],
        [
            seg("run", direction="backward", speed="fast", steps=6, turn=-90),
            seg("spin", direction="left"),
        ],
        [
            seg("jog", direction="left", speed="fast", steps=6, turn=0),
            seg("jump", forward=True, count=2),
            seg("sit"),
        ],
    ],
)
def test_features_round_trip_to_the_canonical_joints(segments):
    """Including clips that turn around and walk backwards (the facing crosses 180 degrees)."""
    joints = clip(*segments, seed=9)
    features, canonical = joints_to_features(joints)
    np.testing.assert_allclose(features_to_joints(features), canonical[:-1], atol=1e-4)


def test_random_programs_round_trip():
    rng = np.random.default_rng(10)
    names = sorted(PRIMITIVES)
    for _ in range(8):
        segments = [
            sample_segment(names[int(rng.integers(len(names)))], rng)
            for _ in range(int(rng.integers(1, 4)))
        ]
        features, canonical = joints_to_features(animate(segments, rng).joints)
        np.testing.assert_allclose(features_to_joints(features), canonical[:-1], atol=1e-4)
