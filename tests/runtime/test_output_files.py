"""Output files: a take is never overwritten silently, written whole (all four files or none,
never a mix of two takes, no temporary left, whatever signal ends it; only regular files
replaced), checked before generating, and every failure to write is one `mogo: error:` line."""

import errno
import json
import math
import os
import resource
import signal
import socket
import stat
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from PIL import Image

from helpers import travelling_clip
from mogo import Motion, files
from mogo.blender.addon_zip import write_addon
from mogo.cli import main
from mogo.motion.bvh import NAMINGS
from mogo.motion.mocap import read_bvh
from mogo.motion.skeleton import SMPL_22

TAKE = (".bvh", ".gif", ".npy", ".json")


def motion(seed: int = 0, frames: int = 20) -> Motion:
    joints = travelling_clip(np.random.default_rng(seed), SMPL_22, frames=frames)
    return Motion(
        features=np.zeros((frames, 263), np.float32),
        joints=joints.astype(np.float32),
        fps=20.0,
        tokens=np.zeros((frames // 4, 6), np.int64),
        skeleton=SMPL_22,
        prompts=[(0, "a person walks")],
        seed=seed,
    )


def contents(folder) -> dict:
    """Every entry of the folder (hidden ones too) -> its bytes (None for a folder)."""
    return {p.name: None if p.is_dir() else p.read_bytes() for p in sorted(folder.iterdir())}


def assert_one_take(folder, stem, seed=None):
    """The four files of one take, each whole, all of the same motion."""
    joints = np.load(folder / f"{stem}.npy")
    document = json.loads((folder / f"{stem}.json").read_text())
    np.testing.assert_allclose(document["frames"], joints, atol=1e-5)
    assert seed is None or document["seed"] == seed
    with Image.open(folder / f"{stem}.gif") as gif:
        assert gif.n_frames == len(joints)
    clip = read_bvh(folder / f"{stem}.bvh")
    recovered = np.empty_like(clip.positions)
    recovered[:, [NAMINGS["mixamo"].index(name) for name in clip.names]] = clip.positions
    assert np.linalg.norm(recovered - joints, axis=-1).mean() < 0.1  # rigid bones: near


def test_a_take_never_replaces_an_earlier_one_unless_asked(tmp_path):
    first = motion(0).save_take(tmp_path, "walk")
    assert [p.name for p in first] == [f"walk{s}" for s in TAKE]
    before = contents(tmp_path)
    second = motion(1).save_take(tmp_path, "walk")
    assert [p.name for p in second] == [f"walk-2{s}" for s in TAKE]
    assert {k: v for k, v in contents(tmp_path).items() if k in before} == before
    (tmp_path / "walk-3.gif").write_bytes(b"someone else's")  # one file takes the name
    assert motion(2).save_take(tmp_path, "walk")[0].name == "walk-4.bvh"
    assert motion(3).save_take(tmp_path, "walk", overwrite=True) == first
    assert_one_take(tmp_path, "walk", seed=3)
    assert_one_take(tmp_path, "walk-2", seed=1)
    assert motion(0).save_take(tmp_path, "v1.2")[0].name == "v1.2.bvh"  # a dot stays
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_take_with_a_glb_animation(tmp_path):
    """formats with "glb" (`mogo generate --format glb`): a .glb in the .bvh's place, numbered
    with the rest of the take; an unknown format is refused before anything is written."""
    motion(0).save_take(tmp_path, "walk")
    written = motion(1).save_take(tmp_path, "walk", formats=("glb", "gif", "npy", "json"))
    assert [p.name for p in written] == ["walk-2.glb", "walk-2.gif", "walk-2.npy", "walk-2.json"]
    assert written[0].read_bytes()[:4] == b"glTF"
    with pytest.raises(ValueError, match="no format 'fbx'; choose from bvh, glb, gif, npy"):
        motion(1).save_take(tmp_path, "other", formats=("fbx",))
    assert not list(tmp_path.glob("other*"))


def test_a_take_of_some_formats_writes_those_alone(tmp_path):
    """A long take need not write its GIF and JSON: formats names the files (in FORMATS'
    order, whatever order given); a repeated, empty or bare-string list is refused."""
    written = motion(0).save_take(tmp_path, "walk", formats=["npy", "bvh"])
    assert [p.name for p in written] == ["walk.bvh", "walk.npy"]
    assert sorted(contents(tmp_path)) == ["walk.bvh", "walk.npy"]
    assert motion(1).save_take(tmp_path, "walk", formats=["npy"])[0].name == "walk-2.npy"
    for bad in (["npy", "npy"], []):
        with pytest.raises(ValueError, match="name each format once, at least one"):
            motion(1).save_take(tmp_path, "other", formats=bad)
    with pytest.raises(TypeError, match="formats must be a list of names, got str"):
        motion(1).save_take(tmp_path, "other", formats="npy")
    assert not list(tmp_path.glob("other*"))


def test_a_folder_in_the_way_is_skipped_or_an_error_never_a_half_take(tmp_path):
    motion(0).save_take(tmp_path, "x")
    (tmp_path / "x.gif").unlink()
    (tmp_path / "x.gif").mkdir()
    before = contents(tmp_path)
    with pytest.raises(IsADirectoryError, match="a folder is in the way"):
        motion(1).save_take(tmp_path, "x", overwrite=True)
    assert contents(tmp_path) == before
    assert motion(1).save_take(tmp_path, "x")[0].name == "x-2.bvh"


def test_single_files_are_replaced_whole_and_named_as_written(tmp_path):
    clip = motion(0)
    assert clip.save_npy(tmp_path / "x") == tmp_path / "x.npy"  # numpy adds .npy: say so
    assert clip.save_npy(tmp_path / "walk.v2") == tmp_path / "walk.v2.npy"
    assert clip.save_features(tmp_path / "f.npy") == tmp_path / "f.npy"
    np.testing.assert_array_equal(np.load(tmp_path / "x.npy"), clip.joints)
    path = clip.save_bvh(tmp_path / "a.bvh")
    assert motion(1).save_bvh(path) == path and read_bvh(path).positions.shape == (20, 22, 3)
    (tmp_path / "d.gif").mkdir()
    with pytest.raises(IsADirectoryError):
        clip.save_gif(tmp_path / "d.gif")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "a.bvh",
        "d.gif",
        "f.npy",
        "walk.v2.npy",
        "x.npy",
    ]


def test_json_is_strict_and_nan_is_refused(tmp_path):
    clip = motion(0)
    clip.seed = None
    text = clip.save_json(tmp_path / "m.json").read_text()
    document = json.loads(text, parse_constant=lambda name: pytest.fail(f"{name} in the JSON"))
    assert document["seed"] is None and document["fps"] == 20.0
    clip.joints[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="NaN or infinite"):
        clip.save_json(tmp_path / "bad.json")
    clip.joints[3, 4, 1] = 0.0
    clip.fps = math.nan
    with pytest.raises(ValueError, match="fps must be a positive number"):
        clip.save_json(tmp_path / "bad.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


def test_a_failed_write_leaves_the_earlier_take_and_no_temporary(tmp_path, monkeypatch):
    motion(0).save_take(tmp_path, "walk")
    before = contents(tmp_path)

    def disk_full(self, path):
        path.write_bytes(b"GIF89a half")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Motion, "_write_gif", disk_full)
    for overwrite in (False, True):
        with pytest.raises(OSError) as error:
            motion(1).save_take(tmp_path, "walk", overwrite=overwrite)
        assert error.value.errno == errno.ENOSPC
        assert error.value.filename == str(tmp_path / ("walk.gif" if overwrite else "walk-2.gif"))
        assert contents(tmp_path) == before


def test_a_failed_rename_puts_the_old_take_back(tmp_path, monkeypatch):
    motion(0).save_take(tmp_path, "walk")
    before = contents(tmp_path)
    place, calls = files._place, []

    def third_fails(temporary, path):
        calls.append(path)
        if len(calls) == 3:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        place(temporary, path)

    monkeypatch.setattr(files, "_place", third_fails)
    with pytest.raises(PermissionError):
        motion(1).save_take(tmp_path, "walk", overwrite=True)
    assert contents(tmp_path) == before


@pytest.fixture
def ctrl_c():
    """Python's own SIGINT handler, also where the suite runs with SIGINT ignored (a shell's
    background job)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_during_the_renames_waits_until_they_are_done(tmp_path, monkeypatch, ctrl_c):
    place = files._place

    def interrupted(temporary, path):
        signal.raise_signal(signal.SIGINT)  # Ctrl-C, just as each rename begins
        place(temporary, path)

    monkeypatch.setattr(files, "_place", interrupted)
    with pytest.raises(KeyboardInterrupt):
        motion(0).save_take(tmp_path, "walk")
    assert_one_take(tmp_path, "walk", seed=0)
    assert sorted(contents(tmp_path)) == sorted(f"walk{suffix}" for suffix in TAKE)


@pytest.mark.parametrize(
    "name, message",
    [
        ("../../x", "--name must be a file name, without a folder"),
        (".", "--name must be a file name"),
        ("..", "--name must be a file name"),
        ("", "--name must be a file name"),
        ("a/b", "--name must be a file name"),
        ("x" * 300, "--name is too long: 300 bytes, at most"),
    ],
)
def test_bad_names_and_folders_are_refused_before_generating(
    tmp_path, monkeypatch, capsys, name, message
):
    monkeypatch.setattr("mogo.cli.load_generator", lambda args: pytest.fail("generated"))
    out = tmp_path / "deep" / "out"
    assert main(["generate", "a person walks.", "--out", str(out), "--name", name]) == 2
    error = capsys.readouterr().err
    assert error.startswith(f"mogo: error: {message}") and error.count("\n") == 1
    assert list(tmp_path.iterdir()) == []  # not even the folder


def test_an_output_folder_that_is_a_file_or_blocked_fails_before_generating(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr("mogo.cli.load_generator", lambda args: pytest.fail("generated"))
    (tmp_path / "file").write_text("x")
    assert main(["generate", "a person walks.", "--out", str(tmp_path / "file")]) == 2
    assert capsys.readouterr().err == f"mogo: error: {tmp_path / 'file'}: not a folder\n"
    (tmp_path / "x.gif").mkdir()
    assert (
        main(["generate", "a person walks.", "--out", str(tmp_path), "--name", "x", "--overwrite"])
        == 2
    )
    assert capsys.readouterr().err == (
        f"mogo: error: {tmp_path / 'x.gif'}: a folder is in the way of this file\n"
    )


def test_generating_twice_keeps_both_takes_and_says_so(tmp_path, capsys):
    args = ["generate", "a person walks", "--seconds", "1", "--out", str(tmp_path)]
    assert main(args) == 0
    before = contents(tmp_path)
    capsys.readouterr()
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert (
        f"note: {tmp_path / 'a_person_walks'}.* is an earlier take, kept; this one is "
        "a_person_walks-2 (--overwrite replaces)"
    ) in printed
    assert f"wrote {tmp_path / 'a_person_walks-2.gif'}" in printed
    assert {k: v for k, v in contents(tmp_path).items() if k in before} == before
    assert len(contents(tmp_path)) == 8


def test_an_os_error_while_writing_is_one_line_naming_the_file(tmp_path, monkeypatch, capsys):
    def denied(self, path):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(Motion, "_write_json", denied)
    assert (
        main(
            ["generate", "a person walks.", "--seconds", "1", "--out", str(tmp_path), "--name", "w"]
        )
        == 2
    )
    assert capsys.readouterr().err == f"mogo: error: {tmp_path / 'w.json'}: Permission denied\n"
    assert list(tmp_path.iterdir()) == []


def run_mogo(*args, stdout=subprocess.PIPE, close_stdout=False):
    process = subprocess.Popen(
        [sys.executable, "-m", "mogo", *args], stdout=stdout, stderr=subprocess.PIPE, text=True
    )
    if close_stdout:  # `mogo ... | true`: the reader is gone before anything is written
        process.stdout.close()
    _, error = process.communicate(timeout=120)
    return process.returncode, error


def test_a_closed_or_full_standard_output_is_one_line(tmp_path):
    """`mogo generate`'s product is its take: a standard output that fails once the take is
    written is a note naming the files, status 0 (it was exit 2 and an error after the work);
    `mogo stream`'s product is its standard output: an error, or a normal end for a reader
    that stopped."""
    written = ", ".join(
        str(tmp_path / f"a_person_walks{suffix}") for suffix in (".bvh", ".gif", ".npy", ".json")
    )
    code, error = run_mogo(
        "generate", "a person walks.", "--seconds", "1", "--out", str(tmp_path), close_stdout=True
    )
    assert (code, error) == (
        0,
        f"note: cannot write to standard output (Broken pipe); the take was written: {written}\n",
    )
    with open("/dev/full", "w") as full:
        code, error = run_mogo(
            "generate",
            "a person walks.",
            "--seconds",
            "1",
            "--out",
            str(tmp_path),
            "--name",
            "again",
            stdout=full,
        )
    assert code == 0 and error.startswith(
        "note: cannot write to standard output (No space left on device); the take was written: "
    )
    assert len(list(tmp_path.iterdir())) == 8
    with open("/dev/full", "w") as full:
        code, error = run_mogo(
            "stream", "a person walks.", "--frames", "500", "--seed", "0", stdout=full
        )
    assert (code, error) == (
        2,
        "mogo: error: cannot write to standard output: No space left on device\n",
    )
    code, error = run_mogo(
        "stream", "a person walks.", "--seed", "0", close_stdout=True
    )  # `mogo stream | head`
    assert (code, error) == (0, "")


def small_file_limit():
    """In the child: files past 40 kB fail to grow (EFBIG), as on a disk that is full."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (40_000, 40_000))


def test_a_real_write_failure_is_one_line_and_changes_nothing(tmp_path):
    motion(0).save_take(tmp_path, "walk")
    before = contents(tmp_path)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "mogo",
            "generate",
            "a person walks.",
            "--seconds",
            "2",
            "--out",
            str(tmp_path),
            "--name",
            "walk",
            "--overwrite",
        ],
        capture_output=True,
        text=True,
        preexec_fn=small_file_limit,
    )
    assert done.returncode == 2  # the .bvh fits, the .gif does not
    assert done.stderr == f"mogo: error: {tmp_path / 'walk.gif'}: File too large\n"
    assert contents(tmp_path) == before


SLOW_WRITER = textwrap.dedent("""
    import signal, sys, time
    from mogo import clip, generator
    from mogo.cli import main

    signal.signal(signal.SIGINT, signal.default_int_handler)  # even if started in the background

    def slowly(owner, name):
        method = getattr(owner, name)

        def slow(*args, **kwargs):
            print(name, file=sys.stderr, flush=True)
            done = method(*args, **kwargs)
            time.sleep(0.4)
            return done
        setattr(owner, name, slow)

    slowly(generator.MotionGenerator, "generate")
    for name in ("_write_bvh", "_write_gif", "_write_json"):
        slowly(clip.Motion, name)
    sys.exit(main(sys.argv[1:]))
""")


@pytest.mark.parametrize("overwrite", [False, True])
def test_ctrl_c_at_any_moment_leaves_a_whole_take_or_none(tmp_path, overwrite):
    """SIGINT while generating, while each file is written and just before the renames (the
    renames themselves hold it back): the folder holds whole takes only, no temporary."""
    script = tmp_path / "slow.py"
    script.write_text(SLOW_WRITER)
    out = tmp_path / "out"
    motion(7).save_take(out, "walk")
    before = contents(out)
    for moment in ("generate", "_write_bvh", "_write_gif", "_write_json"):
        process = subprocess.Popen(
            [
                sys.executable,
                str(script),
                "generate",
                "a person walks.",
                "--seconds",
                "1",
                "--seed",
                "1",
                "--out",
                str(out),
                "--name",
                "walk",
                *(["--overwrite"] if overwrite else []),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        while process.stderr.readline().strip() != moment:
            assert process.poll() is None, f"ended before {moment}"
        process.send_signal(signal.SIGINT)
        _, error = process.communicate(timeout=60)
        assert process.returncode == 130 and "Traceback" not in error, error
        after = contents(out)
        assert not [name for name in after if name.startswith(".")], list(after)
        changed = {name for name in after if before.get(name) != after[name]}
        if changed:  # only where SIGINT came as the renames began: then the whole new take
            stem = min(changed).rsplit(".", 1)[0]
            assert changed == {f"{stem}{suffix}" for suffix in TAKE}, changed
            assert_one_take(out, stem, seed=1)
        before = after


# -- issue 39: only regular files replaced; SIGTERM and SIGHUP; two writers at once ----------


def special_nodes(folder):
    """A FIFO, a symbolic link, a socket and (as root) a copy of /dev/null's device node, each
    with a name a file is to be written at; -> name: what it is."""
    os.mkfifo(folder / "fifo.gif")
    (folder / "target.json").write_text("kept")
    os.symlink(folder / "target.json", folder / "link.json")
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(folder / "socket.npy"))
    server.close()
    nodes = {"fifo.gif": "a FIFO", "link.json": "a symbolic link", "socket.npy": "a socket"}
    if os.geteuid() == 0:
        os.mknod(folder / "null.bvh", 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        nodes["null.bvh"] = "a device"
    return nodes


def kinds(folder):
    return {p.name: stat.S_IFMT(p.lstat().st_mode) for p in folder.iterdir()}


def test_a_device_fifo_socket_or_link_is_refused_never_replaced(tmp_path):
    nodes = special_nodes(tmp_path)
    before = kinds(tmp_path)
    clip = motion(0)
    save = {
        ".gif": clip.save_gif,
        ".json": clip.save_json,
        ".npy": clip.save_npy,
        ".bvh": clip.save_bvh,
    }
    for name, kind in nodes.items():
        with pytest.raises(
            FileExistsError,
            match=f"{kind} is in the way of this file; only regular files are replaced",
        ):
            save[os.path.splitext(name)[1]](tmp_path / name)
    assert kinds(tmp_path) == before and (tmp_path / "target.json").read_text() == "kept"
    stem = "fifo"  # a take with a FIFO as its .gif: refused with overwrite, numbered without
    with pytest.raises(FileExistsError, match="a FIFO is in the way"):
        clip.save_take(tmp_path, stem, overwrite=True)
    assert kinds(tmp_path) == before
    assert clip.save_take(tmp_path, stem)[0].name == "fifo-2.bvh"


def test_the_commands_refuse_a_special_file_before_the_work(tmp_path, capsys, monkeypatch):
    special_nodes(tmp_path)
    monkeypatch.setattr("mogo.cli.load_generator", lambda args: pytest.fail("generated"))
    assert (
        main(
            ["generate", "a person walks.", "--out", str(tmp_path), "--name", "fifo", "--overwrite"]
        )
        == 2
    )
    assert capsys.readouterr().err == (
        f"mogo: error: {tmp_path / 'fifo.gif'}: a FIFO is in the way of this file; only "
        "regular files are replaced\n"
    )
    os.symlink(tmp_path / "target.json", tmp_path / "addon.zip")
    assert main(["blender-addon", "--out", str(tmp_path / "addon.zip"), "--overwrite"]) == 2
    assert "a symbolic link is in the way" in capsys.readouterr().err
    assert (tmp_path / "addon.zip").is_symlink()
    with pytest.raises(FileExistsError):
        write_addon(tmp_path / "addon.zip", overwrite=True)
    assert (tmp_path / "target.json").read_text() == "kept"


SLOW_RENAMES = textwrap.dedent("""
    import os, signal, sys, time
    from mogo.cli import main

    signal.signal(signal.SIGINT, signal.default_int_handler)  # even if started in the background

    def slowly(rename):
        def slow(*args, **kwargs):
            print("rename", file=sys.stderr, flush=True)
            rename(*args, **kwargs)
            time.sleep(float(sys.argv[1]))
        return slow
    os.link, os.replace = slowly(os.link), slowly(os.replace)
    sys.exit(main(sys.argv[2:]))
""")


def run_slowly(tmp_path, pause, *args, **options):
    script = tmp_path / "slow_renames.py"
    script.write_text(SLOW_RENAMES)
    return subprocess.Popen(
        [
            sys.executable,
            str(script),
            str(pause),
            "generate",
            "a person walks.",
            "--seconds",
            "1",
            *args,
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        **options,
    )


@pytest.mark.parametrize("number", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_during_the_renames_waits_for_the_whole_take(tmp_path, number):
    """Sent as the first file of an --overwrite take is renamed into place: the take ends
    whole, nothing hidden is left, and the command ends by the signal (status 128 + it)."""
    out = tmp_path / "out"
    motion(7).save_take(out, "walk")
    process = run_slowly(
        tmp_path, 0.3, "--seed", "1", "--out", str(out), "--name", "walk", "--overwrite"
    )
    while process.stderr.readline().strip() != "rename":
        assert process.poll() is None, "ended before the renames"
    process.send_signal(number)
    _, error = process.communicate(timeout=60)
    assert process.returncode == 128 + number and "Traceback" not in error, error
    assert sorted(contents(out)) == sorted(f"walk{suffix}" for suffix in TAKE)
    assert_one_take(out, "walk", seed=1)


@pytest.mark.parametrize("number", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_while_writing_leave_no_temporary(tmp_path, number):
    script = tmp_path / "slow.py"
    script.write_text(SLOW_WRITER)
    out = tmp_path / "out"
    motion(7).save_take(out, "walk")
    before = contents(out)
    process = subprocess.Popen(
        [
            sys.executable,
            str(script),
            "generate",
            "a person walks.",
            "--seconds",
            "1",
            "--out",
            str(out),
            "--name",
            "walk",
            "--overwrite",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    while process.stderr.readline().strip() != "_write_gif":
        assert process.poll() is None, "ended before writing"
    process.send_signal(number)
    _, error = process.communicate(timeout=60)
    assert process.returncode == 128 + number and "Traceback" not in error, error
    assert contents(out) == before


def test_two_overwriting_writers_at_once_leave_one_whole_take(tmp_path):
    out = tmp_path / "out"
    motion(7).save_take(out, "walk")
    writers = [
        run_slowly(
            tmp_path, 0.2, "--seed", str(seed), "--out", str(out), "--name", "walk", "--overwrite"
        )
        for seed in (1, 2)
    ]
    for process in writers:
        _, error = process.communicate(timeout=120)
        assert process.returncode == 0, error
    assert sorted(contents(out)) == sorted(f"walk{suffix}" for suffix in TAKE)
    seeds = {seed for seed in (1, 2) if _is_take(out, seed)}
    assert len(seeds) == 1


def _is_take(folder, seed):
    try:
        assert_one_take(folder, "walk", seed=seed)
        return True
    except AssertionError:
        return False


def test_odd_output_folders_are_refused_before_generating(tmp_path, monkeypatch, capsys):
    """Old: a link loop, a link to nowhere and a folder name too long for the file system
    were found only when the take was written, after the work."""
    monkeypatch.setattr("mogo.cli.load_generator", lambda args: pytest.fail("generated"))
    os.symlink("loop", tmp_path / "loop")
    os.symlink(tmp_path / "missing" / "x", tmp_path / "nowhere")
    nowhere = "a symbolic link that leads nowhere (a loop or a missing target)"
    for out, message in (
        (tmp_path / "loop", f"{tmp_path / 'loop'}: {nowhere}"),
        (
            tmp_path / "loop" / "sub",
            f"{tmp_path / 'loop'}: {nowhere} (so {tmp_path / 'loop' / 'sub'} cannot be made in it)",
        ),
        (tmp_path / "nowhere", f"{tmp_path / 'nowhere'}: {nowhere}"),
        (
            tmp_path / "a" / ("y" * 300) / "b",
            f"{tmp_path / 'a' / ('y' * 300) / 'b'}: a folder name longer than 255 bytes",
        ),
    ):
        assert main(["generate", "a person walks.", "--out", str(out)]) == 2
        assert capsys.readouterr().err == f"mogo: error: {message}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loop", "nowhere"]


@pytest.mark.parametrize(
    "options, error, message",
    [
        (
            dict(naming=["mixamo"]),
            ValueError,
            r"naming must be one of mixamo, smpl, got \['mixamo'\]",
        ),
        (dict(scale=[1, 2]), TypeError, "scale must be a number, got list"),
        (dict(scale=np.array([1.0, 2.0])), TypeError, "scale must be a number, got ndarray"),
        (dict(scale=math.nan), ValueError, "scale must be a positive number up to 10000, got nan"),
        (dict(scale=1e308), ValueError, "scale must be a positive number up to 10000"),
        (dict(bone_translations=[1]), TypeError, "bone_translations must be True or False"),
        (dict(overwrite="no"), TypeError, "overwrite must be True or False, got str"),
    ],
)
def test_a_takes_options_are_checked_before_any_file(tmp_path, options, error, message):
    """Old: "unhashable type: 'list'", numpy's "truth value of an array ... is ambiguous", a
    BVH of NaN offsets, and overwrite="no" taken for True (replacing the earlier take)."""
    motion(0).save_take(tmp_path, "walk")
    before = contents(tmp_path)
    with pytest.raises(error, match=message):
        motion(1).save_take(tmp_path, "walk", **options)
    assert contents(tmp_path) == before
