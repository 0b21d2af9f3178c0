"""Which joint of a motion-capture rig is which of our 22: built-in maps by joint name (SMPL,
Mixamo and CMU naming) and a user's mapping file.

A joint of ours is where the rig's joint of that place sits, not the bone it moves: our
left_shoulder (the shoulder joint) is Mixamo's and CMU's LeftArm, our left_foot (the ball of the
foot) is their LeftToeBase. Names are compared without case, separators or a namespace
("mixamorig:LeftArm" is "leftarm"). A joint the rig lacks may be a point on the segment between
two of its joints: [a, b, f] is a + f (b - a).
"""

from __future__ import annotations

import os
import re
import reprlib
from pathlib import Path

from mogo.motion.skeleton import SMPL_22
from mogo.motion.untrusted import read_json

Source = str | tuple[str, str, float]  # a joint's name, or a point between two joints

_SIDES = ("left", "right")


def key(name: str) -> str:
    """A joint name as maps compare it: after any namespace, lower case, letters and digits."""
    name = name.rsplit(":", 1)[-1].lower()
    return re.sub(r"[^a-z0-9]", "", name)


def _sided(table: dict[str, Source]) -> dict[str, Source]:
    """A map written for the left side, with the right side added ("Left" -> "Right")."""
    full = dict(table)
    for ours, theirs in table.items():
        if ours.startswith("left_"):
            full["right_" + ours[5:]] = _swap(theirs)
    return full


def _swap(source: Source) -> Source:
    if isinstance(source, tuple):
        return (_swap(source[0]), _swap(source[1]), source[2])
    return source.replace("Left", "Right")


_SMPL = {name: name for name in SMPL_22.joint_names}
_SMPL_SHORT = {name: name.replace("left_", "L_").replace("right_", "R_") for name in _SMPL}
_MIXAMO = _sided(
    {
        "pelvis": "Hips",
        "spine1": "Spine",
        "spine2": "Spine1",
        "spine3": "Spine2",
        "neck": "Neck",
        "head": "Head",
        "left_collar": "LeftShoulder",
        "left_shoulder": "LeftArm",
        "left_elbow": "LeftForeArm",
        "left_wrist": "LeftHand",
        "left_hip": "LeftUpLeg",
        "left_knee": "LeftLeg",
        "left_ankle": "LeftFoot",
        "left_foot": "LeftToeBase",
    }
)
# CMU's BVH conversions: LowerBack, Neck and the collars' LeftShoulder sit where their parent
# is (Neck1 is the neck's base, level with the shoulders' top), so the spine's third joint and
# the collars are points between joints
_CMU = _sided(
    {
        "pelvis": "Hips",
        "spine1": "Spine",
        "spine2": "Spine1",
        "spine3": ("Spine1", "Neck1", 0.25),
        "neck": "Neck1",
        "head": "Head",
        "left_collar": ("LeftShoulder", "LeftArm", 0.5),
        "left_shoulder": "LeftArm",
        "left_elbow": "LeftForeArm",
        "left_wrist": "LeftHand",
        "left_hip": "LeftUpLeg",
        "left_knee": "LeftLeg",
        "left_ankle": "LeftFoot",
        "left_foot": "LeftToeBase",
    }
)
RIGS: dict[str, dict[str, Source]] = {
    "SMPL": _SMPL,
    "SMPL (L_/R_)": _SMPL_SHORT,
    "Mixamo": _MIXAMO,
    "CMU": _CMU,
}


def resolve(
    names: tuple[str, ...], mapping: dict[str, Source] | None = None, what: str = "the file"
) -> tuple[str, list[tuple[int, int, float]]]:
    """(naming, [(joint a, joint b, f)] for each of our 22 joints) for a rig's joint names:
    the given mapping, else the first built-in map that finds all 22. ValueError, one line,
    naming what is missing from the closest map, otherwise."""
    index = {}
    for k, name in enumerate(names):
        index.setdefault(key(name), k)
    candidates = [("the mapping file", mapping)] if mapping is not None else list(RIGS.items())
    best = None
    for naming, table in candidates:
        found, missing = _lookup(table, index)
        if not missing:
            return naming, found
        if best is None or len(missing) < len(best[1]):
            best = (naming, missing)
    naming, missing = best
    shown = ", ".join(missing[:6]) + (f" and {len(missing) - 6} more" if len(missing) > 6 else "")
    hint = "" if mapping is not None else "; give a mapping file (--map) for other names"
    raise ValueError(
        f"{what}: cannot map its skeleton onto the 22 joints: {naming} naming lacks {shown}{hint}"
    )


def _lookup(
    table: dict[str, Source], index: dict[str, int]
) -> tuple[list[tuple[int, int, float]], list[str]]:
    found, missing = [], []
    for ours in SMPL_22.joint_names:
        source = table.get(ours) or ours  # a mapping file may leave out joints named as ours
        a, b, f = (source, source, 0.0) if isinstance(source, str) else source
        if key(a) in index and key(b) in index:
            found.append((index[key(a)], index[key(b)], float(f)))
        else:
            theirs = a if key(a) not in index else b
            missing.append(ours if key(theirs) == key(ours) else f"{ours} ({theirs})")
    return found, missing


def _fraction(value: object) -> bool:
    """Whether a mapping file's value is a fraction along a segment (a finite number)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and -1e6 <= value <= 1e6


def read_mapping(path: str | os.PathLike) -> dict[str, Source]:
    """A mapping file: a JSON object from each of our 22 joint names to the rig's joint name,
    or to [a, b, f] for a point between two of its joints. ValueError naming what is wrong."""
    path = Path(path)
    table = read_json(path, "mapping file")
    if not isinstance(table, dict):
        raise ValueError(f"{path}: the mapping file must be a JSON object, joint -> name")
    unknown = sorted(set(table) - set(SMPL_22.joint_names))
    if unknown:
        raise ValueError(
            f"{path}: unknown joint(s) {', '.join(map(str, unknown))}; ours are "
            f"{', '.join(SMPL_22.joint_names)}"
        )
    mapping: dict[str, Source] = {}
    for ours, source in table.items():
        if (
            isinstance(source, list)
            and len(source) == 3
            and all(isinstance(v, str) for v in source[:2])
            and _fraction(source[2])
        ):
            mapping[ours] = (source[0], source[1], float(source[2]))
        elif isinstance(source, str):
            mapping[ours] = source
        else:
            raise ValueError(
                f"{path}: {ours}: expected a joint name or [name, name, fraction], "
                f"got {reprlib.repr(source)}"
            )
    return mapping
