"""`mogo serve --workers N`: N processes on one port (SO_REUSEPORT), one banner once all listen,
streams served by each, SIGTERM drains them all and the command exits 0."""

import asyncio
import json
import signal
import socket
import subprocess
import sys

import pytest

pytest.importorskip("aiohttp")
pytest.importorskip("onnx")

from aiohttp import ClientSession  # noqa: E402

from mogo.cli import main  # noqa: E402

SOCKETS = 16  # all on one worker by chance: 2 ** -15


def test_bad_worker_counts_and_state_periods_are_one_line(capsys):
    assert main(["serve", "--workers", "0"]) == 2
    assert capsys.readouterr().err == "mogo: error: --workers must be at least 1, got 0\n"
    assert main(["serve", "--state-every", "-1"]) == 2
    assert capsys.readouterr().err == (
        "mogo: error: --state-every must be between 0 and 3600 seconds, got -1\n"
    )


@pytest.mark.skipif(not hasattr(socket, "SO_REUSEPORT"), reason="needs SO_REUSEPORT (Linux)")
def test_workers_share_the_port_and_drain_on_sigterm():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    process = subprocess.Popen(
        [sys.executable, "-m", "mogo", "serve", "--port", str(port), "--workers", "2"],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        banner = process.stderr.readline()
        assert banner.startswith("mogo serve: http") and "(2 workers)" in banner, banner

        async def streams():
            async with ClientSession() as session:
                sockets = [
                    await session.ws_connect(f"http://127.0.0.1:{port}/v1/stream")
                    for _ in range(SOCKETS)
                ]
                ids = []
                for ws in sockets:
                    await ws.send_json({"prompt": "a person walks", "seed": 1})
                    ids.append(json.loads((await ws.receive()).data)["stream"])
                process.send_signal(signal.SIGTERM)
                drains = 0
                for ws in sockets:
                    async for message in ws:
                        drains += json.loads(message.data)["type"] == "drain"
                return ids, drains

        ids, drains = asyncio.run(asyncio.wait_for(streams(), 60))
        assert len(set(ids)) < len(ids)  # each worker numbers its own streams from 1
        assert drains == SOCKETS  # every stream handed over
        assert process.wait(30) == 0
        assert process.stderr.read() == ""
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(10)
