"""`mogo bench long-streams --quick` end to end on the shipped bundle (two actions, both modes; every
path), a run of chosen actions, and the window checks it rests on, judged against the procedural animator's own performance."""

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
from PIL import Image

from mogo.bench.long_streams import KINDS
from mogo.bench.quality.stream_checks import (
    REPERTOIRE,
    WindowCheck,
    drift,
    reaction_frames,
    reference,
    window_passes,
)
from mogo.bundle import read_manifest, write_manifest
from mogo.cli import main
from mogo.generator import DEFAULT_BUNDLE


def test_the_quick_run_writes_its_tables_figures_and_plot(tmp_path, capsys):
    assert main(["bench", "long-streams", "--quick", "--jobs", "1", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "| walk forward | a person walks forward. |" in printed
    assert "| sit down (one-off: hold) |" in printed and "within 1.5 s" in printed
    result = json.loads((tmp_path / "long_streams.json").read_text())
    assert result["columns"] == ["stream, anchoring off", "stream, anchoring on"]
    kinds = {k: [r for r in result["rows"] if r["kind"] == k] for k in ("action", "switches")}
    assert {r["column"] for r in kinds["action"]} == set(result["columns"])
    assert all(len(r["passes"]) == 2 for r in kinds["action"])  # 20 s: two 10-s windows
    assert all(len(s["reactions"]) == 1 for s in kinds["switches"])
    assert all(len(s["visible"]) == 1 for s in kinds["switches"])  # as the caller received it
    assert "| switch visible in the received frames |" in printed
    assert Image.open(tmp_path / "long_streams.png").size[0] > 0


def test_every_path_plays_the_schedules_it_can_with_motionstreams_frames(tmp_path, capsys):
    """generate, play and served streams (real sockets, a real `mogo serve`) give the frames of
    the re-anchored MotionStream for the same prompt, seed and switch frames; continue_from and
    one-off actions after a switch are judged on every path that has them."""
    pytest.importorskip("aiohttp")
    paths = ["stream", "generate", "play", "continue", "serve"]
    argv = ["bench", "long-streams", "--quick", "--path", *paths, "--modes", "on"]
    argv += ["--out", str(tmp_path)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert (
        "| one-off action after a walk | stream, anchoring on | play | continue | serve |"
        in printed
    )
    result = json.loads((tmp_path / "long_streams.json").read_text())
    columns = {k: {r["column"] for r in result["rows"] if r["kind"] == k} for k in KINDS}
    assert columns == {
        "action": {"stream, anchoring on", "generate", "play", "serve"},
        "switches": {"stream, anchoring on", "play", "continue", "serve"},
        "one-off": {"stream, anchoring on", "play", "continue", "serve"},
    }
    assert all(r["reaction"] is not None for r in result["rows"] if r["kind"] == "one-off")
    assert Image.open(tmp_path / "long_streams_paths.png").size[0] > 0
    agreement = result["agreement"]  # every motion compared keeps MotionStream's frames
    assert {c: (a["motions"], a["agree"]) for c, a in agreement.items()} == {
        "generate": (2, 2),
        "play": (4, 4),  # the two actions, the one-off and the switch schedule
        "serve": (2, 2),  # the actions: a served switch lands where the client sends it
    }
    assert agreement["generate"]["largest"] == agreement["play"]["largest"] == 0.0
    assert agreement["serve"]["largest"] < 1e-4  # row-wise graphs round otherwise


def test_served_low_latency_switches_are_measured_as_the_client_received_them(tmp_path, capsys):
    """--low-latency runs the served streams again, asking for the low-latency decoder: their
    switches counted from the frames the client had when it sent the new prompt, beside the
    centred decoder's."""
    pytest.importorskip("aiohttp")
    argv = ["bench", "long-streams", "--quick", "--path", "serve", "--low-latency"]
    assert main([*argv, "--one-offs", "0", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    result = json.loads((tmp_path / "long_streams.json").read_text())
    switches = {r["column"]: r for r in result["rows"] if r["kind"] == "switches"}
    assert set(switches) == {"serve", "serve, low-latency decoder"}
    for row in switches.values():
        (visible,), (reaction,) = row["visible"], row["reactions"]
        # the server switches at or after the frames the client had when it asked
        assert reaction is None or visible >= reaction
    assert "| serve | 1 |" in printed and "| serve, low-latency decoder | 1 |" in printed


def test_a_run_of_chosen_actions_without_switches(tmp_path, capsys):
    assert (
        main(
            [
                "bench",
                "long-streams",
                "--modes",
                "on",
                "--minutes",
                str(1 / 6),
                "--seeds",
                "1",
                "--switches",
                "0",
                "--actions",
                "spin",
                "--jobs",
                "1",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "| spin | a person spins to the left. |" in printed and "walk" not in printed
    assert "switches:" not in printed and "fresh clips" in printed
    result = json.loads((tmp_path / "long_streams.json").read_text())
    assert [(r["kind"], r["action"]) for r in result["rows"]] == [("action", "spin")]


@pytest.mark.parametrize(
    "args,message",
    [
        (["--actions", "moonwalk"], "no action 'moonwalk'"),
        (["--switches", "-1"], "--switches must be >= 0"),
        (["--one-offs", "-1"], "--one-offs must be >= 0"),
        (["--path", "stream", "teleport"], "--path: choose from stream, generate"),
    ],
)
def test_bad_choices_are_one_line_errors(args, message, capsys):
    assert main(["bench", "long-streams", *args]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("action", [a for a in REPERTOIRE if a.continuing], ids=lambda a: a.name)
def test_the_animator_passes_the_window_checks_of_its_own_continuing_actions(action):
    check = WindowCheck(action, 200)
    other = reference(action, 400, seed=1)  # another performer
    assert all(window_passes(check, other))
    assert reaction_frames(WindowCheck(action, 60), other) is not None


def test_a_still_figure_holds_and_does_not_walk():
    sit, walk = (next(a for a in REPERTOIRE if a.name == n) for n in ("sit down", "walk forward"))
    still = np.repeat(reference(walk, 1, seed=0), 400, axis=0)  # one frame, held 20 s
    assert window_passes(WindowCheck(sit, 200), still) == [False, True]  # never sat, then holds
    assert window_passes(WindowCheck(walk, 200), still) == [False, False]
    figures = drift(still)
    assert figures["slide"] == 0 and figures["pelvis_low"] == figures["pelvis_high"]
    assert figures["acceleration"] == 0


def test_jitter_is_the_mean_joint_acceleration():
    t = np.arange(40, dtype=np.float32) / 20  # seconds at 20 fps
    joints = np.zeros((40, 22, 3), np.float32)
    joints[:, :, 1] = 1.0 + 0.5 * 3.0 * t[:, None] ** 2  # every joint rises at 3 m/s^2
    assert abs(drift(joints)["acceleration"] - 3.0) < 1e-3


def test_low_latency_needs_the_stream_or_serve_path_and_a_bundle_with_that_decoder(
    tmp_path, capsys
):
    argv = ["bench", "long-streams", "--quick", "--low-latency", "--out", str(tmp_path / "out")]
    assert main([*argv, "--path", "generate"]) == 2
    assert "--low-latency runs the stream and serve paths again" in capsys.readouterr().err
    bundle = tmp_path / "centred"  # the shipped bundle without its low-latency decoder
    shutil.copytree(DEFAULT_BUNDLE, bundle)
    vq = read_manifest(bundle).vq
    for graph in (vq.low_latency_decoder, vq.low_latency_step):
        (bundle / graph.file).unlink()
    vq = replace(vq, low_latency_decoder=None, low_latency_step=None)
    write_manifest(bundle, replace(read_manifest(bundle), vq=vq))
    assert main([*argv, "--bundle", str(bundle)]) == 2
    assert "this bundle has no low-latency decoder" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
