"""`mogo serve` on the command line: listed in the help, one line when the extra is missing,
one line for a bad flag, a warning before listening beyond this machine; as a process: the
banner only once it listens, SIGTERM closes every socket properly and stops."""

import asyncio
import importlib.util
import signal
import socket
import subprocess
import sys
import tempfile

import pytest

from mogo.cli import main
from mogo.serve import cli as serve_cli


def test_serve_is_a_verb_of_mogo(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "serve" in capsys.readouterr().out


def test_without_the_extra_it_says_how_to_install_it(monkeypatch, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "aiohttp" else real(name, *a)
    )
    assert main(["serve"]) == 2
    assert capsys.readouterr().err == (
        "mogo: error: this command needs the serve extra: pip install 'mogo-edge[serve]'\n"
    )


@pytest.mark.parametrize("flags", [["--port", "70000"], ["--max-streams", "0"], ["--threads", "0"]])
def test_bad_flags_are_one_line(flags, capsys):
    pytest.importorskip("aiohttp")  # without the extra, the one line says to install it
    assert main(["serve", *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mogo: error: ") and err.count("\n") == 1


def test_only_loopback_addresses_count_as_local():
    pytest.importorskip("aiohttp")
    assert all(serve_cli._is_local(h) for h in ("127.0.0.1", "::1", "localhost", "127.0.0.2"))
    assert not any(serve_cli._is_local(h) for h in ("0.0.0.0", "192.168.1.5", "example.org"))


def test_loopback_names_count_as_local_however_written():
    pytest.importorskip("aiohttp")
    assert all(serve_cli._is_local(h) for h in ("127.1", "0:0:0:0:0:0:0:1", "127.0.0.1"))
    assert not serve_cli._is_local("::")


@pytest.mark.parametrize("origin", ["evil.example", "http://a.example/path", "ftp://a", ""])
def test_a_bad_allowed_origin_is_one_line(origin, capsys):
    pytest.importorskip("aiohttp")
    assert main(["serve", "--allow-origin", origin]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mogo: error: --allow-origin takes") and err.count("\n") == 1


# -- `mogo serve` as a process: what it prints, how it stops -----------------------------------


def free_port(host: str = "127.0.0.1") -> int:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family) as probe:
        probe.bind((host, 0))
        return probe.getsockname()[1]


def start_serve(*flags: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "mogo", "serve", *flags],
        stderr=subprocess.PIPE,
        text=True,
        cwd=tempfile.gettempdir(),
    )


def banner(process: subprocess.Popen) -> str:
    """stderr up to the line that says the server listens (or to its exit)."""
    lines = []
    for line in process.stderr:
        lines.append(line)
        if line.startswith("mogo serve: http"):
            break
    return "".join(lines)


def test_a_port_in_use_is_one_line_and_no_banner():
    pytest.importorskip("aiohttp")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        process = start_serve("--port", str(port))
        _, err = process.communicate(timeout=120)
    assert process.returncode == 2
    assert err.startswith(f"mogo: error: cannot listen on 127.0.0.1:{port}: ")
    assert err.count("\n") == 1 and "mogo serve: http" not in err


def test_sigterm_closes_every_socket_with_a_close_frame_and_stops():
    aiohttp = pytest.importorskip("aiohttp")
    port = free_port()
    process = start_serve("--port", str(port))
    try:
        banner(process)

        async def client():
            async with (
                aiohttp.ClientSession() as session,
                session.ws_connect(f"http://127.0.0.1:{port}/v1/stream") as ws,
            ):
                await ws.send_json({"prompt": "a person walks forward", "seed": 1})
                assert (await ws.receive()).type == aiohttp.WSMsgType.TEXT  # "started"
                process.send_signal(signal.SIGTERM)
                while (message := await ws.receive()).type == aiohttp.WSMsgType.TEXT:
                    pass
                return message, ws.close_code

        message, code = asyncio.run(asyncio.wait_for(client(), 60))
        assert message.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED)
        assert code == aiohttp.WSCloseCode.GOING_AWAY  # a close frame, not 1006
        assert process.wait(timeout=15) == 0  # a bound, not a speed: it took ~28 s
        assert "Traceback" not in process.stderr.read()
    finally:
        process.kill()
        process.wait()


def test_an_ipv6_address_is_printed_in_brackets():
    pytest.importorskip("aiohttp")
    try:
        port = free_port("::1")
    except OSError:
        pytest.skip("no IPv6 loopback on this machine")
    process = start_serve("--host", "::1", "--port", str(port))
    try:
        assert banner(process).endswith(
            f"mogo serve: http://[::1]:{port}/ (viewer), "
            f"ws://[::1]:{port}/v1/stream; Ctrl-C stops\n"
        )
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=15) == 0
    finally:
        process.kill()
        process.wait()
