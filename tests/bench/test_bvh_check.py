"""Blender reads our BVH as our rig says (a real client, headless); skipped without Blender,
and the glTF check where Blender's glTF importer cannot run (no numpy < 1.24 in its Python)."""

import functools
import shutil
import subprocess

import numpy as np
import pytest

from mogo import MotionGenerator
from mogo.bench.quality.bvh_check import Check, blender_check, rig_error, rig_positions, table
from mogo.motion import rig
from mogo.motion.bvh import NAMINGS, save_bvh

BLENDER = shutil.which("blender")


@functools.cache
def blender_reads_gltf() -> bool:
    """Blender 3.4's glTF importer needs numpy, and one older than 1.24 (it uses np.bool);
    Debian's blender depends on neither."""
    done = subprocess.run(
        [
            BLENDER,
            "-b",
            "--factory-startup",
            "--python-expr",
            "import sys, numpy; numpy.bool; sys.exit(7)",
        ],
        capture_output=True,
        timeout=120,
    )
    return done.returncode == 7


@pytest.mark.skipif(BLENDER is None, reason="Blender is not installed: apt-get install blender")
def test_blender_reads_our_bvh_as_our_rig_says(tmp_path):
    motion = MotionGenerator.load().generate("a person walks forward.", seconds=2.0, seed=0)
    joints = motion.joints.astype(np.float64)
    path = tmp_path / "walk.bvh"
    save_bvh(path, joints, motion.skeleton, motion.fps, scale=100.0, naming="smpl")
    png = tmp_path / "walk.png"
    result = blender_check(
        path,
        NAMINGS["smpl"],
        motion.fps,
        dict(joints=joints, rig=rig_positions(path, "smpl", 100.0)),
        scale=100.0,
        blender=BLENDER,
        png=png,
        size=(48, 48),
        samples=1,
        timeout=120,
    )
    assert result["fps"] == 20.0 and result["frames"] == len(joints)  # "Update Scene FPS"
    assert result["errors"]["rig"]["max"] < 1e-4  # Blender's importer = our rig
    rigid = rig_error(joints, path, "smpl", 100.0)
    assert result["errors"]["joints"]["mean"] == pytest.approx(rigid.mean(), abs=1e-4)
    assert png.is_file()
    assert "| **all** | 40 |" in table([Check("walk", len(joints), rigid, result)])


@pytest.mark.skipif(BLENDER is None, reason="Blender is not installed: apt-get install blender")
def test_blender_reads_our_glb_as_our_rig_says(tmp_path):
    """Blender's glTF importer: the skinned mannequin's bones follow our rig, frame by frame."""
    if not blender_reads_gltf():
        pytest.skip(
            "Blender 3.4's glTF importer needs numpy < 1.24 in Blender's Python "
            "(/usr/bin/python3 -m pip install --break-system-packages 'numpy<1.24')"
        )
    motion = MotionGenerator.load().generate("a person jumps.", seconds=2.0, seed=0)
    path = motion.save_glb(tmp_path / "jump.glb")
    joints = motion.joints.astype(np.float64)
    result = blender_check(
        path,
        NAMINGS["mixamo"],
        motion.fps,
        dict(rig=rig.posed_joints(joints, motion.skeleton)),
        blender=BLENDER,
        timeout=120,
    )
    assert result["frames"] == len(joints) and result["errors"]["rig"]["max"] < 1e-4
