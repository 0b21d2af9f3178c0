"""The foot measures of mogo.bench.quality.feet on clips whose answers are known."""

from types import SimpleNamespace

import numpy as np

from mogo.bench.quality import feet
from mogo.bench.quality.feet import contacts, foot_measures, format_feet
from mogo.motion.features import feature_layout
from mogo.motion.skeleton import SMPL_22

VELOCITY = dict((name, start) for name, start, _ in feature_layout(SMPL_22))["joint_velocities"]
FEET = [7, 10, 8, 11]  # left ankle, left toe, right ankle, right toe


def _clip(step: float, frames: int = 21) -> tuple[np.ndarray, np.ndarray]:
    """A body gliding along +X by `step` metres a frame, feet flagged in contact throughout,
    5 cm below the floor at frame 10."""
    joints = np.zeros((frames, 22, 3))
    for child, parent in enumerate(SMPL_22.parents):
        if parent >= 0:
            joints[:, child] = joints[:, parent] + SMPL_22.rest_offsets[child]
    joints[..., 1] += 0.96
    joints[..., 0] += step * np.arange(frames)[:, None]
    joints[10, FEET, 1] = -0.05
    features = np.zeros((frames, SMPL_22.feature_dim), np.float32)
    features[:, VELOCITY : VELOCITY + 66 : 3] = step  # every joint's x velocity
    features[:, -4:] = 1.0
    return joints, features


def test_sliding_floor_pop_bones_and_change_are_measured():
    joints, features = _clip(0.01)  # 20 cm/s, every foot joint in contact
    decoded = joints.copy()
    joints[:, 4] += [0.0, 0.0, 0.02]  # both knees 2 cm forward: thigh and shin change
    joints[:, 5] += [0.0, 0.0, 0.02]
    result = foot_measures([(joints, features, decoded)], SMPL_22)
    assert abs(result["speed"] - 20.0) < 1e-6 and result["sliding"] == 100.0
    assert abs(result["depth"] - 5.0) < 1e-6 and abs(result["below"] - 100 / 21) < 1e-6
    assert result["bone_error"] > 0 and result["change"] > 0
    assert abs(result["change_legs"] - 100 * 0.02 * 2 / 6) < 1e-6  # 2 of the 6 leg joints moved
    still_joints, still_features = _clip(0.0)
    still = foot_measures([(still_joints, still_features, None)], SMPL_22)
    assert still["speed"] == 0 and still["sliding"] == 0 and "change" not in still
    dip = still_joints[0, FEET, 1].max() + 0.05  # the highest foot joint's dip: down, back up
    assert abs(still["pop"] - 2 * dip) < 1e-9
    assert "| x | 0.0 | 0.0% |" in format_feet({"x": still})


def test_a_contact_the_decoded_velocity_contradicts_is_not_one():
    _, features = _clip(0.1)  # 10 cm a frame: over HumanML3D's contact threshold
    assert not contacts(features, SMPL_22).any()
    assert contacts(features, SMPL_22, confirmed=False).all()


def test_a_body_that_travels_less_changes_travel_not_the_pose():
    slow, features = _clip(0.005)
    fast, _ = _clip(0.01)
    result = foot_measures([(slow, features, fast)], SMPL_22)
    assert abs(result["travel"] + 50.0) < 1e-6 and abs(result["travel_most"] + 50.0) < 1e-6
    assert result["change"] < 1e-9 and result["change_legs"] < 1e-9
    assert "| -50.0% (-50%) |" in format_feet({"x": result})


def test_the_windows_table_plants_with_each_window(monkeypatch):
    """`--windows`: a row as decoded, then one per window, the default's and the low-latency
    streams' named; a foot gliding 1 cm a frame in contact is held by every window."""
    joints, features = _clip(0.01, frames=40)
    joints[10, FEET, 1] = joints[9, FEET, 1]  # no dip: the floor is not what this measures

    def clips(generator, first_seed=0, low_latency=False):
        return [(joints, features, joints)]

    monkeypatch.setattr(feet, "locomotion", clips)
    rows = feet.windows(SimpleNamespace(skeleton=SMPL_22)).splitlines()[2:]
    assert len(rows) == 1 + len(feet.WINDOWS)
    assert rows[0].startswith("| as decoded | - | 20.0 | 20.0 |")
    assert rows[1].startswith("| 3 + 6 (default) | 8 |")
    assert any(row.startswith("| 2 + 1 (low-latency streams) | 2 |") for row in rows)
    assert all(float(row.split("|")[3]) < 5.0 for row in rows[1:])  # held: 20 cm/s down to ~2
