import numpy as np
import pytest

from helpers import rest_pose, travelling_clip
from mogo.motion.features import (
    JointStream,
    canonicalize,
    facing_directions,
    features_to_joints,
    joints_to_features,
    joints_together,
)
from mogo.motion.mirror import mirror_joints, mirror_text
from mogo.motion.skeleton import KIT_21, SMPL_22


@pytest.mark.parametrize(
    "turn,backwards", [(0.0, False), (180.0, False), (180.0, True), (-400.0, True), (720.0, False)]
)
def test_round_trip_recovers_canonical_joints(turn, backwards):
    rng = np.random.default_rng(int(turn) % 97 + backwards)
    clip = travelling_clip(rng, turn_degrees=turn, backwards=backwards)
    features, canonical = joints_to_features(clip)
    assert features.shape == (clip.shape[0] - 1, 263) and features.dtype == np.float32
    recovered = features_to_joints(features)
    assert np.abs(recovered - canonical[:-1]).max() < 1e-4


def test_canonical_clip_is_on_floor_at_origin_facing_z():
    clip = travelling_clip(np.random.default_rng(1), turn_degrees=90.0)
    canonical = canonicalize(clip, SMPL_22)
    assert abs(canonical[..., 1].min()) < 1e-9
    np.testing.assert_allclose(canonical[0, 0, [0, 2]], 0.0, atol=1e-9)
    np.testing.assert_allclose(facing_directions(canonical, SMPL_22)[0], [0, 0, 1], atol=1e-9)
    # Canonicalising preserves the shape of the motion (a rigid transform).
    np.testing.assert_allclose(
        np.linalg.norm(canonical[:, 7] - canonical[:, 0], axis=-1),
        np.linalg.norm(clip[:, 7] - clip[:, 0], axis=-1),
        atol=1e-9,
    )


def test_kit_skeleton_round_trip():
    clip = travelling_clip(np.random.default_rng(2), KIT_21, turn_degrees=200.0, backwards=True)
    features, canonical = joints_to_features(clip, KIT_21)
    assert features.shape[-1] == 251
    assert np.abs(features_to_joints(features) - canonical[:-1]).max() < 1e-4


def test_recovery_is_batched():
    rng = np.random.default_rng(3)
    batch = np.stack([joints_to_features(travelling_clip(rng, frames=40))[0] for _ in range(3)])
    np.testing.assert_allclose(
        features_to_joints(batch), np.stack([features_to_joints(f) for f in batch]), atol=1e-6
    )


def test_feature_blocks_mean_what_the_format_says():
    clip = np.repeat(rest_pose(SMPL_22)[None], 30, axis=0)
    clip += np.linspace(0, 1, 30)[:, None, None] * [0.0, 0.0, 1.2]  # glide forward 1.2 m
    features, _ = joints_to_features(clip)
    np.testing.assert_allclose(features[:, 0], 0.0, atol=1e-7)  # no turning
    np.testing.assert_allclose(features[:, 2], 1.2 / 29, atol=1e-6)  # forward speed per frame
    np.testing.assert_allclose(features[:, 3], rest_pose(SMPL_22)[0, 1], atol=1e-6)
    contacts = features[:, -4:]
    assert np.all(contacts == 1.0)  # 4 cm per frame is under the HumanML3D threshold
    fast = clip * [1, 1, 10]
    assert np.all(joints_to_features(fast)[0][:, -4:] == 0.0)


def test_turning_left_gives_positive_facing_change():
    clip = travelling_clip(np.random.default_rng(4), turn_degrees=90.0, jitter=0.0)
    features, canonical = joints_to_features(clip)
    assert features[:, 0].sum() < 0  # the half-angle of the world->facing rotation
    raw = facing_directions(canonical, SMPL_22, facing_sigma=0)
    turned = np.degrees(np.arctan2(raw[-1, 0], raw[-1, 2]) - np.arctan2(raw[0, 0], raw[0, 2]))
    assert abs(turned - 90.0) < 1e-3  # +90 degrees (left) turns +Z toward +X


@pytest.mark.parametrize(
    "bad,message",
    [
        (
            np.zeros((10, 21, 3)),
            r"^joints must be \(T, 22, 3\) for the humanml3d skeleton, got "
            r"shape \(10, 21, 3\)$",
        ),
        (np.zeros((10, 23, 3)), r"got shape \(10, 23, 3\)$"),
        (np.zeros((10, 22, 4)), r"got shape \(10, 22, 4\)$"),
        (np.zeros((1, 22, 3)), "^a clip needs at least 2 frames, got 1$"),
        (np.full((5, 22, 3), np.nan), "NaN"),
    ],
)
def test_bad_joints_are_rejected(bad, message):
    with pytest.raises(ValueError, match=message):
        joints_to_features(bad)


def test_unknown_feature_dim_is_rejected():
    with pytest.raises(ValueError, match="no skeleton has 100-dim"):
        features_to_joints(np.zeros((5, 100)))


@pytest.mark.parametrize("dims", [100, 300])
def test_features_of_another_skeleton_are_refused_with_both_sizes(dims):
    with pytest.raises(
        ValueError, match=f"^features have {dims} dims, the humanml3d skeleton needs 263$"
    ):
        features_to_joints(np.zeros((2, 5, dims)), SMPL_22)


def test_float64_features_give_float64_joints_and_others_float32():
    features, _ = joints_to_features(travelling_clip(np.random.default_rng(8)))
    assert features_to_joints(features).dtype == np.float32
    assert features_to_joints(features.astype(np.float64)).dtype == np.float64
    assert features_to_joints(features.astype(np.float16)).dtype == np.float16
    assert features_to_joints(features.astype(bool)).dtype == np.float32
    assert features_to_joints(features.astype(np.int32)).dtype == np.float32


def test_features_need_a_time_axis():
    with pytest.raises(
        ValueError,
        match=r"^features must be \(\.\.\., T, D\), got shape "
        r"\(263,\)$",
    ):
        features_to_joints(np.zeros(263))


def test_mirroring_twice_is_identity():
    clip = travelling_clip(np.random.default_rng(5))
    for skeleton, data in [
        (SMPL_22, clip),
        (KIT_21, travelling_clip(np.random.default_rng(6), KIT_21)),
    ]:
        np.testing.assert_array_equal(mirror_joints(mirror_joints(data, skeleton), skeleton), data)
    text = "A person waves the left hand, then turns right, spinning clockwise. LEFT!"
    assert mirror_text(mirror_text(text)) == text
    assert mirror_text(text) == (
        "A person waves the right hand, then turns left, spinning counterclockwise. RIGHT!"
    )


def test_mirrored_clip_turns_the_other_way():
    clip = travelling_clip(np.random.default_rng(7), turn_degrees=120.0)
    features, _ = joints_to_features(clip)
    mirrored, _ = joints_to_features(mirror_joints(clip, SMPL_22))
    np.testing.assert_allclose(mirrored[:, 0], -features[:, 0], atol=1e-5)
    left_wrist, right_wrist = SMPL_22.index("left_wrist"), SMPL_22.index("right_wrist")
    np.testing.assert_allclose(
        mirror_joints(clip, SMPL_22)[:, left_wrist, 0], -clip[:, right_wrist, 0]
    )


def test_joint_stream_equals_one_recovery_whatever_the_chunks():
    rng = np.random.default_rng(7)
    features, _ = joints_to_features(travelling_clip(rng, turn_degrees=400.0), SMPL_22)
    whole = features_to_joints(features)
    stream = JointStream(SMPL_22)
    cuts = np.sort(rng.choice(np.arange(1, len(features)), size=9, replace=False))
    pieces = [stream.push(chunk) for chunk in np.split(features, cuts)]
    assert stream.push(features[:0]).shape == (0, 22, 3)
    np.testing.assert_allclose(np.concatenate(pieces), whole, atol=1e-5)


@pytest.mark.parametrize("rows", [1, 8])
def test_joints_together_are_each_streams_own_pushes_bit_for_bit(rows):
    """Streams at other yaws and places, pushed together chunk after chunk (the server's
    rounds: a token's frame or a window's 8), give the joints and keep the state that each
    stream pushed alone does."""
    rng = np.random.default_rng(rows)
    clips = [
        joints_to_features(travelling_clip(rng, turn_degrees=90.0 * k), SMPL_22)[0][: 4 * rows]
        for k in range(5)
    ]
    alone, together = [JointStream(SMPL_22) for _ in clips], [JointStream(SMPL_22) for _ in clips]
    for start in range(0, 4 * rows, rows):
        chunk = np.stack([clip[start : start + rows] for clip in clips])
        made = joints_together(together, chunk)
        for stream, rows_in, joints in zip(alone, chunk, made, strict=True):
            assert np.array_equal(stream.push(rows_in), joints)
    for a, b in zip(alone, together, strict=True):
        assert a.half_angle == b.half_angle and np.array_equal(a.xz, b.xz)
    with pytest.raises(ValueError, match="one skeleton"):
        joints_together([JointStream(SMPL_22), JointStream(KIT_21)], chunk[:2])
