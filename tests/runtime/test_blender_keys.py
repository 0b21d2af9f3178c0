"""The Blender add-on's numpy maths without Blender (the add-on package itself needs bpy, so
its motion_keys module is loaded from its file): keys and presets."""

import importlib.util
import sys

import numpy as np
import pytest

from mogo import DEFAULT_BUNDLE
from mogo.blender.addon_zip import SOURCE
from mogo.bundle import Bundle
from mogo.motion.quaternion import qnormalize, qto_matrix
from mogo.motion.skeleton import SMPL_22


@pytest.fixture(scope="module")
def keys():
    name = "mogo_blender_motion_keys"
    spec = importlib.util.spec_from_file_location(name, SOURCE / "motion_keys.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    yield module
    del sys.modules[name]


def rotations(rng, *shape):
    return qto_matrix(qnormalize(rng.normal(size=shape + (4,))))


def test_pose_keys_and_world_from_keys_are_inverse(keys):
    rng = np.random.default_rng(0)
    parents = [p if p >= 0 else None for p in SMPL_22.parents]
    world, rest = rotations(rng, 5, 22), rotations(rng, 22)
    quaternions = keys.pose_keys(world, rest, parents)
    assert np.allclose(keys.world_from_keys(quaternions, rest, parents), world, atol=1e-9)
    assert np.all(np.sum(quaternions[1:] * quaternions[:-1], axis=-1) >= 0)  # the short way


def test_presets_find_mixamo_and_smpl_bones_whatever_their_prefix_and_case(keys):
    mixamo = ["mixamorig:" + name for name in keys.BONE_NAMES] + ["mixamorig:HeadTop_End"]
    assert keys.auto_map("MIXAMO", mixamo) == mixamo[:22]
    smpl = ["pelvis", "L_Hip", "r_hip"]
    assert keys.auto_map("SMPL", smpl)[:3] == smpl and keys.auto_map("SMPL", smpl)[3] == ""


def test_our_rig_stands_on_the_floor_facing_minus_y(keys):
    ours = keys.OurRig.of(Bundle.load(DEFAULT_BUNDLE).manifest.skeleton())
    feet = [SMPL_22.joint_names.index(n) for n in ("left_foot", "right_foot")]
    assert np.allclose(ours.heads[feet, 2], 0.0, atol=1e-6)  # Z up, on the floor
    assert np.all(ours.tails[feet, 1] < ours.heads[feet, 1])  # toes point at -Y


LONG = "a person walks forward, then waves with the right hand, then turns around and claps"


def test_action_names_fit_blender_and_are_cut_after_a_whole_word(keys):
    """Blender keeps 63 bytes of a name and cut retargeted takes mid-word ("... hand.001 o"):
    a name keeps room for Blender's ".001", ends after a whole word of the prompt, and keeps
    the take's own number and its suffix."""
    room = keys.NAME_BYTES - len(".001")
    assert keys.action_name("a person walks forward.") == "a person walks forward."
    assert keys.action_name("a person jogs.", " (live)") == "a person jogs. (live)"
    for text, suffix in [
        (LONG, ""),
        (LONG, " (live)"),
        (LONG[:56] + ".001", " on Mannequin"),
        (LONG + ".012", " on mixamorig:Armature"),
    ]:
        name = keys.action_name(text, suffix)
        number = ".0" + text.rsplit(".0", 1)[1] if ".0" in text else ""
        assert len(name.encode()) <= room and name.endswith(number + suffix), name
        words = name[: len(name) - len(number + suffix)]
        assert LONG.startswith(words) and LONG[len(words)] in " ,", name  # a whole word
    assert (
        keys.action_name(LONG + ".001", " on Mannequin")
        == "a person walks forward, then waves with.001 on Mannequin"
    )
    for text in ("人" * 40, "x" * 100):  # no space to cut at: whole characters
        name = keys.action_name(text)
        assert len(name.encode()) <= room and text.startswith(name) and len(name) > 15
    long_target = keys.action_name(LONG, " on " + "B" * 80)  # the take keeps half the room
    assert len(long_target.encode()) <= room and long_target.startswith("a person walks")
    assert keys.action_name("") == "motion"
