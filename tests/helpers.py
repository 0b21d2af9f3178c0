"""Plain helpers the tests share (fixtures are in conftest.py): tiny data, clips, training-run
records, the two-process runner and a prefill counter. Importable as `helpers` from any test
folder."""

import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator

import numpy as np

from mogo.motion.quaternion import qrot, qyaw
from mogo.motion.skeleton import SMPL_22


def mogo_on_two_gloo_processes(*args) -> None:
    """`mogo ARGS` under torchrun, two CPU processes on gloo. On failure the message holds what
    both printed, with every thread's Python stack should one of them abort."""
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node",
        "2",
        "-m",
        "mogo",
        *map(str, args),
        "--device",
        "cpu",
    ]
    done = subprocess.run(
        command,
        capture_output=True,
        text=True,
        timeout=180,
        env=dict(os.environ, OMP_NUM_THREADS="1", PYTHONFAULTHANDLER="1"),
    )
    assert done.returncode == 0, f"stdout:\n{done.stdout[-3000:]}\nstderr:\n{done.stderr[-8000:]}"


def records(run, kind=None) -> list[dict]:
    """A training run's metrics.jsonl records, without the timings."""
    lines = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    return [
        {k: v for k, v in r.items() if k not in ("seconds", "steps_per_s")}
        for r in lines
        if kind is None or r["kind"] == kind
    ]


def interrupt_after_step(monkeypatch, stop_step: int) -> None:
    """Make training stop like Ctrl-C right after logging `stop_step`, before any checkpoint
    of it: what a resumed run must recover from."""
    from mogo.export.train.training import MetricsLog

    write = MetricsLog.write

    def interrupted(self, kind, step, **values):
        write(self, kind, step, **values)
        if step == stop_step:
            raise KeyboardInterrupt

    monkeypatch.setattr(MetricsLog, "write", interrupted)


CLIP_FRAMES = [40 + 3 * k for k in range(12)]  # 40 .. 73 feature rows
SPLITS = {"train": range(0, 8), "val": range(8, 10), "test": range(10, 12)}


def caption_lines(k: int) -> list[str]:
    """Every clip: one whole-clip caption; even clips: a 0.5-2.5 s span (rows 10..50);
    every third clip: NaN times and no tokens (whole clip); clip 1: a 1 s span (20 rows)."""
    lines = ["a person walks forward.#a/DET person/NOUN walk/VERB forward/ADV#0.0#0.0"]
    if k % 2 == 0:
        lines.append("the person waves.#the/DET person/NOUN wave/VERB#0.5#2.5")
    if k % 3 == 0:
        lines.append("someone jumps.##nan#nan")
    if k == 1:
        lines.append("a short kick.#a/DET short/ADJ kick/NOUN#0.0#1.0")
    return lines


def make_tiny_humanml3d(root):
    """A 12-clip HumanML3D-layout folder of random 263-dim features (IDs 000000..000011)."""
    (root / "new_joint_vecs").mkdir(parents=True)
    (root / "texts").mkdir()
    rng = np.random.default_rng(0)
    clips = []
    for k, frames in enumerate(CLIP_FRAMES):
        features = rng.normal(scale=0.05, size=(frames, 263)).astype(np.float32)
        features[:, 3] += 0.9  # root height
        np.save(root / "new_joint_vecs" / f"{k:06d}.npy", features)
        (root / "texts" / f"{k:06d}.txt").write_text("\n".join(caption_lines(k)) + "\n")
        clips.append(features)
    stacked = np.concatenate(clips)
    np.save(root / "Mean.npy", stacked.mean(0))
    np.save(root / "Std.npy", stacked.std(0))
    for name, ks in SPLITS.items():
        (root / f"{name}.txt").write_text("".join(f"{k:06d}\n" for k in ks))
    return root


def rest_pose(skeleton):
    offsets = skeleton.rest_offsets
    if offsets is None:  # KIT: unit-ish bones along the raw directions
        offsets = skeleton.raw_offsets * 0.25
    pose = np.zeros((skeleton.num_joints, 3))
    for joint, parent in enumerate(skeleton.parents):
        if parent >= 0:
            pose[joint] = pose[parent] + offsets[joint]
    pose[:, 1] -= pose[:, 1].min()
    return pose


def travelling_clip(
    rng, skeleton=SMPL_22, frames=120, turn_degrees=180.0, backwards=False, jitter=0.02
):
    """A jittered rest pose travelling along a curve while turning by `turn_degrees`."""
    facing = np.radians(turn_degrees) * np.linspace(0, 1, frames) ** 2 + rng.uniform(-np.pi, np.pi)
    step = 0.06 * (-1 if backwards else 1)
    heading = np.stack([np.sin(facing), np.zeros(frames), np.cos(facing)], -1)
    root = np.cumsum(step * heading, axis=0) + rng.normal(size=3) * [3, 0, 3]
    root[:, 1] = 0.03 * np.sin(np.arange(frames) / 3)
    noise = rng.normal(scale=jitter, size=(frames, skeleton.num_joints, 3))
    body = rest_pose(skeleton)[None] + noise
    return qrot(qyaw(facing)[:, None], body) + root[:, None]


OLD_TEXT_SIDE = os.path.join(os.path.dirname(__file__), "runtime", "old_text_side")


def bundle_with_old_text_side(folder) -> str:
    """The shipped bundle as it was before its sentence encoder: the same level and VQ graphs
    with the text encoder trained with them (its 254-word tokenizer; the shipped bundle keeps
    both as trained_*) and that bundle's own manifest (tests/runtime/old_text_side), for the
    runtime's path of such bundles."""
    from mogo.generator import DEFAULT_BUNDLE
    from mogo.manifest import Manifest

    with open(os.path.join(OLD_TEXT_SIDE, "manifest.json")) as file:
        old = Manifest.from_json(json.load(file))
    os.makedirs(folder, exist_ok=True)
    for name in old.files:
        source = "trained_" + name if name in ("text_encoder.onnx", "tokenizer.json") else name
        shutil.copy2(os.path.join(DEFAULT_BUNDLE, source), os.path.join(folder, name))
    shutil.copy2(
        os.path.join(OLD_TEXT_SIDE, "manifest.json"), os.path.join(folder, "manifest.json")
    )
    return str(folder)


@contextlib.contextmanager
def served(timeout: float = 60.0) -> Iterator[int]:
    """A real `mogo serve` on 127.0.0.1 and a free port (yielded), ready once /v1/health
    answers; stopped (killed if it lingers) on the way out. Its stderr goes to a file, so a
    chatty server never blocks on a full pipe."""
    from mogo.bench.speed.serve import free_port

    port = free_port()
    with tempfile.TemporaryFile("w+") as log:
        server = subprocess.Popen(
            [sys.executable, "-m", "mogo", "serve", "--port", str(port), "--threads", "1"],
            stderr=log,
            text=True,
        )
        try:
            deadline = time.monotonic() + timeout
            while not _answers(f"http://127.0.0.1:{port}/v1/health"):
                if server.poll() is not None or time.monotonic() > deadline:
                    log.seek(0)
                    raise AssertionError(f"mogo serve is not answering: {log.read()}")
                time.sleep(0.2)
            yield port
        finally:
            server.terminate()
            try:
                server.wait(timeout=10)
            except subprocess.TimeoutExpired:
                server.kill()
                server.wait()


def _answers(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2):
            return True
    except OSError:
        return False


def counted_prefills(monkeypatch) -> list:
    """Each cache prefill computed from now on (mogo.token_generator): the streams of each
    call, appended."""
    from mogo import token_generator

    prefills, compute = [], token_generator._prefilled_together
    monkeypatch.setattr(
        token_generator,
        "_prefilled_together",
        lambda streams: prefills.append(streams) or compute(streams),
    )
    return prefills
