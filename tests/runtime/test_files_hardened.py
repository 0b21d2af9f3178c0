"""Files written only as regular files, whole against SIGINT, SIGTERM and SIGHUP, and takes
of two writers at once never mixed (docs/security.md, "Files")."""
import os
import signal
import socket
import stat
import subprocess
import sys
import textwrap

import pytest

from mogo.addon_zip import write_addon
from mogo.cli import main

from test_output_files import TAKE, assert_one_take, contents, motion


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
    save = {".gif": clip.save_gif, ".json": clip.save_json, ".npy": clip.save_npy,
            ".bvh": clip.save_bvh}
    for name, kind in nodes.items():
        with pytest.raises(FileExistsError, match=f"{kind} is in the way of this file; only "
                                                  "regular files are replaced"):
            save[os.path.splitext(name)[1]](tmp_path / name)
    assert kinds(tmp_path) == before and (tmp_path / "target.json").read_text() == "kept"
    stem = "fifo"  # a take with a FIFO as its .gif: refused with overwrite, numbered without
    with pytest.raises(FileExistsError, match="a FIFO is in the way"):
        clip.save_take(tmp_path, stem, overwrite=True)
    assert kinds(tmp_path) == before
    assert clip.save_take(tmp_path, stem)[0].name == "fifo-2.bvh"


def test_the_commands_refuse_a_special_file_before_the_work(tmp_path, capsys, monkeypatch):
    special_nodes(tmp_path)
    monkeypatch.setattr("mogo.cli._load_generator", lambda args: pytest.fail("generated"))
    assert main(["generate", "a person walks.", "--out", str(tmp_path), "--name", "fifo",
                 "--overwrite"]) == 2
    assert capsys.readouterr().err == (
        f"mogo: error: {tmp_path / 'fifo.gif'}: a FIFO is in the way of this file; only "
        "regular files are replaced\n")
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
    return subprocess.Popen([sys.executable, str(script), str(pause), "generate",
                             "a person walks.", "--seconds", "1", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            **options)


@pytest.mark.parametrize("number", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_during_the_renames_waits_for_the_whole_take(tmp_path, number):
    """Sent as the first file of an --overwrite take is renamed into place: the take ends
    whole, nothing hidden is left, and the command ends by the signal (status 128 + it)."""
    out = tmp_path / "out"
    motion(7).save_take(out, "walk")
    process = run_slowly(tmp_path, 0.3, "--seed", "1", "--out", str(out), "--name", "walk",
                         "--overwrite")
    while process.stderr.readline().strip() != "rename":
        assert process.poll() is None, "ended before the renames"
    process.send_signal(number)
    _, error = process.communicate(timeout=60)
    assert process.returncode == 128 + number and "Traceback" not in error, error
    assert sorted(contents(out)) == sorted(f"walk{suffix}" for suffix in TAKE)
    assert_one_take(out, "walk", seed=1)


@pytest.mark.parametrize("number", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_while_writing_leave_no_temporary(tmp_path, number):
    from test_output_files import SLOW_WRITER  # prints each step's name as it starts

    script = tmp_path / "slow.py"
    script.write_text(SLOW_WRITER)
    out = tmp_path / "out"
    motion(7).save_take(out, "walk")
    before = contents(out)
    process = subprocess.Popen(
        [sys.executable, str(script), "generate", "a person walks.", "--seconds", "1", "--out",
         str(out), "--name", "walk", "--overwrite"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    while process.stderr.readline().strip() != "_write_gif":
        assert process.poll() is None, "ended before writing"
    process.send_signal(number)
    _, error = process.communicate(timeout=60)
    assert process.returncode == 128 + number and "Traceback" not in error, error
    assert contents(out) == before


def test_two_overwriting_writers_at_once_leave_one_whole_take(tmp_path):
    out = tmp_path / "out"
    motion(7).save_take(out, "walk")
    writers = [run_slowly(tmp_path, 0.2, "--seed", str(seed), "--out", str(out), "--name",
                          "walk", "--overwrite") for seed in (1, 2)]
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
