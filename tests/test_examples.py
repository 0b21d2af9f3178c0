"""examples/ run as a user runs them: each script in a fresh interpreter, in an empty folder,
on the default bundle; what it says it writes is there and reads back. The WebSocket client
talks to a real `mogo serve` on 127.0.0.1."""

import re
import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

from helpers import served
from mogo import Motion

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run_example(name: str, folder: Path, *args: str) -> str:
    """The script's stdout; a failure shows its stderr."""
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args],
        cwd=folder,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert done.returncode == 0, f"{name} failed:\n{done.stderr[-3000:]}"
    return done.stdout


def test_every_example_is_tested():
    tested = {
        "text_to_bvh.py",
        "stream_switch.py",
        "batch.py",
        "websocket_client.py",
        "continue_bvh.py",
        "retarget_names.py",
    }
    assert {path.name for path in EXAMPLES.glob("*.py")} == tested


def test_text_to_bvh(tmp_path):
    run_example("text_to_bvh.py", tmp_path)
    assert abs(len(Motion.from_file(tmp_path / "walk_and_wave.bvh").joints) - 120) <= 1  # 6 s
    assert Image.open(tmp_path / "walk_and_wave.gif").n_frames > 100


def test_stream_switch_prints_a_pelvis_position_a_second(tmp_path):
    lines = run_example("stream_switch.py", tmp_path).splitlines()
    assert [line.split()[0] for line in lines] == [f"{s:.1f}" for s in range(10)]
    assert all(
        re.fullmatch(
            r" *\d\.\d s  pelvis x [+-]\d\.\d\d m, height \d\.\d\d m, "
            r"z [+-]\d+\.\d\d m",
            line,
        )
        for line in lines
    ), lines


def test_batch_writes_a_take_per_prompt(tmp_path):
    lines = run_example("batch.py", tmp_path).splitlines()
    assert [line.split()[1] for line in lines] == ["10", "11", "12", "13"]  # seed + k
    takes = sorted(path.name for path in (tmp_path / "takes").iterdir())
    assert takes == sorted(
        f"take_{k}{suffix}" for k in range(4) for suffix in (".bvh", ".gif", ".npy", ".json")
    )


def test_continue_bvh_makes_its_input_then_goes_on_from_it(tmp_path):
    run_example("continue_bvh.py", tmp_path)
    assert abs(len(Motion.from_file(tmp_path / "walk.bvh").joints) - 80) <= 1
    continued = Motion.from_file(tmp_path / "continued.bvh")
    assert abs(len(continued.joints) - 100) <= 1


def test_retarget_names_writes_the_namings_and_units(tmp_path):
    out = run_example("retarget_names.py", tmp_path)
    assert "run_mixamo.bvh: Hips," in out and "run_smpl_cm.bvh: pelvis," in out

    def first_offset(name):
        text = (tmp_path / name).read_text()
        return [float(v) for v in re.search(r"JOINT.*?OFFSET ([^\n]*)", text, re.S)[1].split()]

    assert first_offset("run_smpl_cm.bvh") == pytest.approx(
        [100 * v for v in first_offset("run_mixamo.bvh")], abs=1e-3
    )
    exact = Motion.from_file(tmp_path / "run_exact.bvh").joints
    assert len(exact) == len(Motion.from_file(tmp_path / "run_mixamo.bvh").joints)


def test_websocket_client_against_a_real_server(tmp_path):
    pytest.importorskip("aiohttp", reason='needs the serve extra: pip install -e ".[serve]"')
    with served() as port:
        out = run_example("websocket_client.py", tmp_path, f"ws://127.0.0.1:{port}/v1/stream")
    bursts = [int(m) for m in re.findall(r"^frames (\d+)-", out, re.M)]
    assert out.startswith("started\n") and bursts == sorted(bursts) and bursts[-1] >= 100, out
