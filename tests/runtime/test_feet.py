"""Foot planting (mogo.motion.feet): the two-bone IK, feet held during their contacts with
continuous blends, rigid legs on or above the floor, the body stepping back where a flagged
foot still swings, any chunking of a stream giving the offline result, and the generator's
plant_feet option (off: the joints as decoded)."""

import numpy as np
import pytest

from mogo.generator import STREAM_DECODE_EVERY, MotionGenerator
from mogo.motion.features import JointStream, feature_layout
from mogo.motion.feet import (
    BLEND_OUT,
    BODY_FRAMES,
    BODY_STEP,
    LOOKAHEAD,
    SHORT,
    WINDOW,
    FootPlanter,
    Window,
    leg_joints,
    planted,
    push_together,
    two_bone_ik,
)
from mogo.motion.rig import rest_offsets
from mogo.motion.skeleton import KIT_21, SMPL_22

LEGS = leg_joints(SMPL_22)  # (2, 4) hip, knee, ankle, toe
CONTACT_JOINTS = LEGS[:, 2:].reshape(-1)
VELOCITY = dict((name, start) for name, start, _ in feature_layout(SMPL_22))["joint_velocities"]


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


def test_ik_keeps_bone_lengths_reaches_reachable_targets_and_bends_towards_the_pole():
    rng = np.random.default_rng(0)
    hip = rng.normal(size=(500, 3))
    upper, lower = rng.uniform(0.3, 0.5, 500), rng.uniform(0.3, 0.5, 500)
    direction = rng.normal(size=(500, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    reach = rng.uniform(np.abs(upper - lower) + 0.01, 0.99 * (upper + lower))
    target = hip + reach[:, None] * direction
    pole = hip + rng.normal(size=(500, 3))
    knee, ankle = two_bone_ik(hip, target, pole, upper, lower)
    np.testing.assert_allclose(ankle, target, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(knee - hip, axis=-1), upper, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(ankle - knee, axis=-1), lower, rtol=1e-9)
    # the knee lies in the plane of hip, target and pole, on the pole's side
    normal = np.cross(target - hip, pole - hip)
    assert np.abs(np.sum((knee - hip) * normal, -1)).max() < 1e-9
    axis = direction

    def side(p):
        return np.sum(
            (p - hip) * (pole - hip - np.sum((pole - hip) * axis, -1, keepdims=True) * axis), -1
        )

    assert np.all(side(knee) > 0)
    far = hip + 2 * (upper + lower)[:, None] * direction  # out of reach: on the line, stretched
    knee, ankle = two_bone_ik(hip, far, pole, upper, lower)
    np.testing.assert_allclose(np.linalg.norm(ankle - hip, axis=-1), 0.9995 * (upper + lower))
    np.testing.assert_allclose(np.linalg.norm(knee - hip, axis=-1), upper, rtol=1e-9)


def _standing(frames: int) -> np.ndarray:
    """(T, 22, 3) the rest skeleton with bent knees (pelvis 4 cm lower, ankles kept)."""
    rest = np.zeros((22, 3))
    for child, parent in enumerate(SMPL_22.parents):
        if parent >= 0:
            rest[child] = rest[parent] + SMPL_22.rest_offsets[child]
    rest[:, 1] += 0.96
    legs = LEGS.reshape(-1)
    rest[[j for j in range(22) if j not in legs] + list(LEGS[:, 0])] -= [0.0, 0.04, 0.0]
    rest[LEGS[:, 1]] += [0.0, -0.02, 0.08]  # knees forward
    return np.repeat(rest[None], frames, 0)


def _features(joints: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """Features with only what the planter reads: joint velocities and the contact channels."""
    features = np.zeros((len(joints), SMPL_22.feature_dim), np.float32)
    step = np.diff(joints, axis=0, append=joints[-1:])
    features[:, VELOCITY : VELOCITY + 66] = step.reshape(len(joints), -1)
    features[:, -4:] = contacts
    return features


def _sliding_left_foot(frames=60, start=15, stop=35, speed=0.005):
    """A still body whose left ankle and toe slide forward all along (from 15 cm behind), the
    foot's contact on in [start, stop)."""
    joints = _standing(frames)
    joints[:, LEGS[0, 2:], 2] += speed * np.arange(frames)[:, None] - 0.15
    contacts = np.zeros((frames, 4))
    contacts[start:stop, :2] = 1.0
    return _features(joints, contacts), joints


def test_a_foot_is_held_still_through_its_contact_and_eased_in_and_out_without_a_jump():
    features, joints = _sliding_left_foot()
    out = planted(features, joints, SMPL_22)
    ankle, toe = out[:, LEGS[0, 2]], out[:, LEGS[0, 3]]
    held = slice(15, 36)  # the contact's frames and the one after (still from t to t+1)
    assert np.ptp(ankle[held], axis=0).max() < 1e-6 and np.ptp(toe[held], axis=0).max() < 1e-6
    steps = np.linalg.norm(np.diff(out[:, LEGS.reshape(-1)], axis=0), axis=-1)
    released = 0.005 * (35 - (15 + WINDOW.pin_frames / 2 - 0.5))  # offset from the decoded foot
    assert steps.max() < 0.005 + 1.5 * released / (BLEND_OUT + 1) + 1e-3  # smoothstep, no jump
    far = slice(0, 15 - 3)  # before the foot eases onto its pin: feet where they were decoded
    np.testing.assert_allclose(out[far, CONTACT_JOINTS], joints[far, CONTACT_JOINTS], atol=1e-6)
    untouched = [j for j in range(22) if j not in LEGS[:, 1:].reshape(-1)]
    assert np.array_equal(out[:, untouched], joints[:, untouched].astype(np.float32))


def test_legs_get_the_skeletons_canonical_bone_lengths_and_feet_stay_on_or_above_the_floor():
    rng = np.random.default_rng(1)
    features, joints = _sliding_left_foot()
    joints = joints + rng.normal(scale=0.01, size=joints.shape)  # stretchy bones
    joints[20:30, LEGS[1, 2:], 1] -= 0.05  # the right foot sinks into the floor
    out = planted(features, joints, SMPL_22)
    rest = np.linalg.norm(rest_offsets(SMPL_22), axis=1)  # the BVH rig's: left, right averaged
    for bone in range(3):  # thigh, shin, foot: both sides, from the first frame on
        a, b = LEGS[:, bone], LEGS[:, bone + 1]
        length = np.linalg.norm(out[:, b] - out[:, a], axis=-1)
        np.testing.assert_allclose(length, np.broadcast_to(rest[b], length.shape), rtol=1e-5)
    assert out[:, CONTACT_JOINTS, 1].min() >= -1e-6


def test_a_flagged_foot_stepping_fast_moves_the_body_back_by_the_excess_smoothly():
    features, joints = _sliding_left_foot(speed=0.1)  # flagged in [15, 35) at 10 cm a frame
    np.testing.assert_allclose(
        planted(features, joints, SMPL_22)[:, 0], joints[:, 0], atol=1e-6
    )  # by default the body is left as decoded
    out = planted(features, joints, SMPL_22, body_step=BODY_STEP)
    upper = [j for j in range(22) if j not in LEGS[:, 1:].reshape(-1)]  # hips and above
    shift = out[:, upper] - joints[:, upper]
    assert np.ptp(shift, axis=1).max() < 1e-6  # the whole body moves as one, horizontally
    shift = shift[:, 0]
    assert np.abs(shift[:, :2]).max() < 1e-6
    excess = 0.1 - BODY_STEP  # per flagged frame, spread over BODY_FRAMES frames
    np.testing.assert_allclose(shift[:16, 2], 0.0, atol=1e-6)
    np.testing.assert_allclose(shift[35 + BODY_FRAMES - 1 :, 2], -20 * excess, atol=1e-5)
    steps = np.diff(shift[:, 2])
    assert steps.max() < 1e-6 and steps.min() > -excess - 1e-6  # no jump back
    assert np.abs(np.diff(steps)).max() < excess / BODY_FRAMES + 1e-6  # eased in and out


@pytest.mark.parametrize(
    "seed,window",
    [
        (0, WINDOW),
        (1, WINDOW),
        (2, WINDOW),
        (0, SHORT),
        (1, SHORT),
        (2, Window(2, 4)),
        (3, Window(1, 2)),
    ],
)
def test_any_chunking_gives_the_offline_result(seed, window):
    rng = np.random.default_rng(seed)
    joints = _standing(90)  # feet stepping 0-16 cm a frame: some held, some moving the body
    joints[:, CONTACT_JOINTS, 2] += np.cumsum(rng.uniform(0, 0.16, (90, 1)), 0)
    features = _features(joints, rng.uniform(0, 1, (90, 4)) > 0.4)  # contacts on and off often
    offline = planted(features, joints, SMPL_22, body_step=BODY_STEP, window=window)
    planter, rows, pieces, at = FootPlanter(SMPL_22, body_step=BODY_STEP, window=window), [], [], 0
    while at < len(joints):
        size = int(rng.integers(0, 12))
        out = planter.push(features[at : at + size], joints[at : at + size])
        rows.append(out[0])
        pieces.append(out[1])
        at += size
        assert planter.pending == min(at, window.lookahead)  # held back for their lookahead
    rest = planter.flush()
    assert np.array_equal(np.concatenate(rows + [rest[0]]), features)  # rows kept in step
    assert np.array_equal(np.concatenate(pieces + [rest[1]]), offline)


def test_planters_pushed_together_give_what_each_gives_alone():
    """push_together (the server's round) solves the legs of many planters' frames in one pass:
    bit for bit each planter's own push, whatever each holds, pushes (nothing included) and
    looks ahead."""
    rng = np.random.default_rng(4)
    windows = [WINDOW, SHORT, WINDOW, Window(2, 4)]
    clips = []
    for _ in windows:
        joints = _standing(60)
        joints[:, CONTACT_JOINTS, 2] += np.cumsum(rng.uniform(0, 0.16, (60, 1)), 0)
        clips.append((_features(joints, rng.uniform(0, 1, (60, 4)) > 0.4), joints))
    alone = [FootPlanter(SMPL_22, body_step=BODY_STEP, window=w) for w in windows]
    together = [FootPlanter(SMPL_22, body_step=BODY_STEP, window=w) for w in windows]
    at = [0] * len(windows)
    for _ in range(12):
        sizes = [int(rng.integers(0, 8)) for _ in windows]
        pieces = [
            (f[a : a + n], j[a : a + n]) for (f, j), a, n in zip(clips, at, sizes, strict=True)
        ]
        made = push_together(together, [f for f, _ in pieces], [j for _, j in pieces])
        for planter, (f, j), (rows, legs) in zip(alone, pieces, made, strict=True):
            want_rows, want_legs = planter.push(f, j)
            assert np.array_equal(rows, want_rows) and np.array_equal(legs, want_legs)
            assert legs.dtype == want_legs.dtype
        at = [a + n for a, n in zip(at, sizes, strict=True)]
    assert any(len(legs) for _, legs in made)


def test_a_stream_emits_the_offline_result_of_its_own_frames(generator):
    stream = generator.stream("a person walks in a circle.", seed=3)
    streamed = np.concatenate([stream.step() for _ in range(100)])
    lookahead = generator.manifest.vq.decoder.lookahead
    assert 100 - lookahead - STREAM_DECODE_EVERY < len(streamed) + LOOKAHEAD <= 100 - lookahead
    recorded = generator.stream("a person walks in a circle.", seed=3)
    recorded.advance(100)
    motion = recorded.finish()
    raw = generator.stream("a person walks in a circle.", seed=3, plant_feet=False)
    raw.advance(100 + LOOKAHEAD)  # a cut's last frames are planted with the feet's lookahead
    raw = raw.finish()
    assert np.array_equal(raw.tokens[:100], motion.tokens)
    assert np.array_equal(raw.features[:100], motion.features)
    offline = planted(raw.features, raw.joints, generator.skeleton)[:100]
    assert np.array_equal(motion.joints, offline)
    assert np.array_equal(streamed, offline[: len(streamed)])


def test_a_low_latency_stream_plants_its_own_frames_two_frames_behind(generator):
    """The shipped low-latency decoder: its stream's frames are the one-pass planting (SHORT)
    of its own decoded frames, each out once SHORT's frames after it are decoded."""
    stream = generator.stream("a person walks in a circle.", seed=3, low_latency=True)
    counts = [len(stream.step()) for _ in range(60)]
    wait = generator.manifest.vq.low_latency_decoder.lookahead + SHORT.lookahead
    assert counts == [0] * wait + [1] * (60 - wait) and stream.lookahead_steps == wait
    raw = generator.stream(
        "a person walks in a circle.", seed=3, low_latency=True, plant_feet=False
    )
    raw.advance(60)
    raw = raw.finish()
    streamed = generator.stream("a person walks in a circle.", seed=3, low_latency=True)
    streamed.advance(60)
    offline = planted(raw.features, raw.joints, generator.skeleton, window=SHORT)
    assert np.array_equal(streamed.finish().joints, offline)


def test_planted_feet_add_their_lookahead_to_the_first_frame(generator):
    stream = generator.stream("a person walks forward.", seed=0)
    first = next(step for step in range(1, 100) if len(stream.step()))
    decoder = generator.manifest.vq.decoder.lookahead + 1  # the decoder's first frame
    bursts = -(-LOOKAHEAD // STREAM_DECODE_EVERY)  # then frame LOOKAHEAD comes in these
    assert first == decoder + bursts * STREAM_DECODE_EVERY


def test_generated_feet_slide_less_and_plant_feet_false_keeps_the_decoded_joints(generator):
    motion = generator.generate("a person walks forward.", seconds=4, seed=1)
    raw = generator.generate("a person walks forward.", seconds=4, seed=1, plant_feet=False)
    assert np.array_equal(motion.tokens, raw.tokens)
    assert np.array_equal(JointStream(SMPL_22).push(raw.features), raw.joints)
    contact = raw.features[:-1, -4:] > 0.5

    def sliding(joints):
        return np.linalg.norm(np.diff(joints[:, CONTACT_JOINTS], axis=0)[..., [0, 2]], axis=-1)[
            contact
        ].mean()

    assert sliding(motion.joints) < 0.5 * sliding(raw.joints)


def test_bad_plant_feet_and_skeletons_without_such_legs_are_refused(generator):
    with pytest.raises(TypeError, match="plant_feet must be True or False"):
        generator.generate("a person walks forward.", seconds=1, seed=0, plant_feet="no")
    with pytest.raises(TypeError, match="plant_feet"):
        generator.stream("a person walks forward.", plant_feet=1)
    with pytest.raises(ValueError, match="kit skeleton"):
        FootPlanter(KIT_21)


def test_the_cli_plants_feet_unless_told_not_to(generator, tmp_path):
    from mogo.cli import main

    for flag, plant in (("--plant-feet", True), ("--no-plant-feet", False)):
        assert (
            main(
                [
                    "generate",
                    "a person jogs forward.",
                    "--seconds",
                    "2",
                    "--seed",
                    "5",
                    "--out",
                    str(tmp_path),
                    "--name",
                    flag[2:],
                    flag,
                ]
            )
            == 0
        )
        motion = generator.generate("a person jogs forward.", seconds=2, seed=5, plant_feet=plant)
        assert np.array_equal(np.load(tmp_path / f"{flag[2:]}.npy"), motion.joints)
