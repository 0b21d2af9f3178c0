"""The Blender add-on in a real Blender, headless (one Blender run each): the `blender` on PATH
(skipped without one) and the `bpy` module from PyPI under the Python that MOGO_BPY_PYTHON names
(Blender 4.x/5.x, which distributions do not package; skipped when unset)."""

import dataclasses
import os
import shutil

import pytest

from mogo.bench.quality.blender_addon import PythonMismatch, as_module, background, run, table
from mogo.sampling import Sampling

BLENDER = shutil.which("blender")
BPY_PYTHON = os.environ.get("MOGO_BPY_PYTHON")  # e.g. a venv with `pip install bpy==4.4.0`
LAUNCHERS = [
    pytest.param(
        lambda: background(BLENDER),
        id="blender",
        marks=pytest.mark.skipif(
            BLENDER is None, reason="Blender is not installed: apt-get install blender"
        ),
    ),
    pytest.param(
        lambda: as_module(BPY_PYTHON),
        id="bpy-module",
        marks=pytest.mark.skipif(
            not BPY_PYTHON, reason="MOGO_BPY_PYTHON names no Python with the bpy module"
        ),
    ),
]


@pytest.mark.parametrize("launcher", LAUNCHERS)
def test_the_addon_generates_retargets_and_streams_in_blender(tmp_path, launcher):
    png = tmp_path / "frame.png"
    try:
        figures = run(
            launcher(), seconds=2.0, png=png, frame=10, size=(64, 40), samples=1, timeout=300
        )
    except PythonMismatch as error:
        pytest.skip(str(error))
    scene = figures.scene
    missing = scene["without_runtime"].strip()  # an operator's ERROR report, one line
    assert missing.startswith("Error: MOGO: MOGO runtime not found") and "\n" not in missing
    assert "Preferences > Add-ons > MOGO" in missing
    # Install's default: the wheel the add-on ships, this project (PyPI's `mogo` is another),
    # into the empty folder; its dependencies are not there yet (pip was told not to fetch them)
    installed = scene["install"].strip()
    assert installed.startswith(
        "Error: MOGO: MOGO runtime not found (numpy, onnxruntime, tokenizers, PIL, mogo missing in "
    ), installed
    assert scene["runtime_file"].endswith("/installed/mogo/__init__.py")
    assert (
        scene["empty_prompt"].strip() == "Error: MOGO: type a prompt, e.g. 'a person walks forward'"
    )
    # one key per frame, the 24 fps scene set to the motion's 20 and its range
    assert figures.frames == scene["keys"] == 40 and scene["fps"] == 20.0
    assert (scene["frame_start"], scene["frame_end"]) == (1, 40)
    first, second = scene["actions"]  # a second take is a new action, named after the prompt
    assert first == "a person walks forward." and second.startswith(first) and second != first
    assert scene["second_take_plays"]  # each take animates the armature (4.4+: its slot bound)
    assert figures.rig_max < 1e-4  # our armature = the runtime's rig
    assert figures.joints_mean < 0.015  # the rigid-skeleton error (docs/bvh.md)
    for option in dataclasses.fields(Sampling):  # the panel's limits are Sampling's
        default, low, high = scene["sampling"][option.name]
        assert default == option.default and low == option.metadata["low"]
        assert high == option.metadata["high"] or option.metadata["high"] is None
    assert scene["mapped"] == 22  # the Mixamo preset through the "mixamorig:" prefix
    for label, error in figures.follow.items():  # feet, hands, hips: ours x its proportions
        assert error < 1e-3, label
    live = scene["live"]
    assert live["error"] == "" and not live["running"] and live["plays"]
    assert live["action"] == "a person walks forward. (live)"
    assert live["keys"] == [1.0 + i for i in range(live["written"])]  # kept after Stop
    (_, walk), (switched, jog) = live["prompts"]
    assert (walk, jog) == ("a person walks forward.", "a person jogs.")
    assert 20 <= switched < live["written"]
    assert png.stat().st_size > 0
    # a long name: cut after a whole word, room left for the number Blender gives a second one
    first, second = scene["long_names"]
    assert first == "a person walks forward, then waves with the on Mannequin"
    assert second == first + ".001" and len(second.encode()) <= 63
    assert "| frames / keys / scene fps | 40 / 40 / 20 |" in table(figures)
