"""bench/quality/realism: its measures read what they say, and corpus v2's animator is closer
than v1's to the real clips (their figures as `python -m mogo.bench.quality.realism` printed
them for pybullet 3.2.7's DeepMimic walk, run and jump; no download here)."""

import numpy as np
import pytest

from mogo.bench.quality.realism import MOVES, gait_measures, jump_measures
from mogo.export.data.animator import Segment, animate

REAL = {  # docs/model.md's realism table, real column
    "walk": {
        "step length / leg": 0.69,
        "cadence (steps/min)": 102,
        "pelvis bob (mm)": 34,
        "pelvis sway (mm)": 36,
        "foot clearance (mm)": 201,
    },
    "run": {"pelvis sway (mm)": 11, "arm swing (mm)": 715, "knee flexion in stance (deg)": 47},
    "jump": {"crouch before take-off (mm)": 297, "time in the air (s)": 0.40},
}


def _mean(move: str, natural: bool) -> dict[str, float]:
    measure = gait_measures if move in ("walk", "run") else jump_measures
    values = [
        measure(
            animate([MOVES[move][1]], np.random.default_rng(s), natural).joints.astype(np.float64)
        )
        for s in range(4)
    ]
    return {name: float(np.mean([v[name] for v in values])) for name in values[0]}


@pytest.mark.parametrize("move", sorted(REAL))
def test_v2_is_closer_to_the_real_clips_than_v1(move):
    v1, v2 = _mean(move, False), _mean(move, True)
    for name, real in REAL[move].items():
        assert abs(v2[name] - real) < abs(v1[name] - real), (name, v1[name], v2[name], real)


def test_gait_measures_of_a_clip_whose_answers_are_known():
    """A walk's speed is its travel over its time; it steps at the rate its feet cross."""
    walk = Segment("walk", {"direction": "forward", "speed": "normal", "steps": 10, "turn": 0})
    joints = animate([walk], np.random.default_rng(0)).joints.astype(np.float64)
    measures = gait_measures(joints)
    assert 0.8 < measures["speed (m/s)"] < 1.4 and 80 < measures["cadence (steps/min)"] < 130
    assert 0 < measures["pelvis bob (mm)"] < 100 and measures["knee flexion in swing (deg)"] > 30
    assert measures["foot clearance (mm)"] > 50
    still = np.repeat(joints[:1], 40, axis=0)
    assert jump_measures(still)["time in the air (s)"] == 0.0
