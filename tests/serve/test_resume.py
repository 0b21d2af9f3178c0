"""Streams that resume on another server (docs/serve.md, docs/deploy.md), with real sockets on
two servers in one process: a client resumed on the second server gets, from the first frame
it lacks, the very frames the first server goes on making; bad states get one error on their
own socket while the others stream on; a drained server hands every client its state."""

import asyncio
import base64
import json
import signal
import socket
import struct
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("aiohttp")
pytest.importorskip("onnx")

from aiohttp import ClientSession, WSMsgType  # noqa: E402

from mogo.serve.server import SERVER, listen, make_app, stop  # noqa: E402

TIMEOUT = 90  # seconds for a whole test: far above what each needs, so a hang fails


def two_servers(generator, engine_parts, test, state_every=0.0):
    """Run `test(url_a, url_b, server_a)` against two servers of one bundle on loopback."""

    async def main():
        running = []
        try:
            for _ in range(2):
                app = make_app(generator, 1, 8, tokens=engine_parts, state_every=state_every)
                runner, listener = await listen(app, "127.0.0.1", 0, 64)
                running.append((runner, listener, app))
            a, b = (f"http://127.0.0.1:{r[1].sockets[0].getsockname()[1]}" for r in running)
            await asyncio.wait_for(test(a, b, running[0][2][SERVER]), TIMEOUT)
        finally:
            for runner, listener, _ in running:
                await stop(runner, listener)

    asyncio.run(main())


class Client:
    """One binary stream's frames by index, and the messages between them."""

    def __init__(self, ws):
        self.ws, self.frames, self.messages = ws, {}, []

    async def until(self, done) -> dict | None:
        """Read until `done(message or None)` holds; returns that message (None: frames)."""
        while True:
            message = await self.ws.receive()
            if message.type == WSMsgType.BINARY:
                index, n = struct.unpack_from("<II", message.data)
                joints = np.frombuffer(message.data, "<f4", offset=8).reshape(n, 22, 3)
                for k in range(n):
                    assert index + k not in self.frames, "a frame came twice"
                    self.frames[index + k] = joints[k]
                if done(None):
                    return None
            elif message.type == WSMsgType.TEXT:
                body = json.loads(message.data)
                self.messages.append(body)
                if done(body):
                    return body
            else:
                return {"type": "closed", "code": self.ws.close_code}

    def received(self) -> int:
        """The first frame index it has not received (frames come in order)."""
        return max(self.frames) + 1 if self.frames else 0


def kind(name):
    return lambda body: body is not None and body["type"] == name


def test_a_resumed_stream_goes_on_with_the_same_frames_on_another_server(generator, engine_parts):
    async def test(a, b, _):
        async with ClientSession() as session:
            original = Client(await session.ws_connect(a + "/v1/stream"))
            await original.ws.send_json(
                {"prompt": "a person walks forward", "seed": 6, "binary": True}
            )
            await original.until(lambda body: len(original.frames) >= 40)
            await original.ws.send_json({"prompt": "a person jumps"})
            state = await original.until(kind("state"))  # offered after the switch
            assert state["frame"] >= 40
            await original.until(lambda body: original.received() >= state["frame"] + 120)
            first = state["frame"] + 25  # the client had frames up to here when its server died
            resumed = Client(await session.ws_connect(b + "/v1/stream"))
            await resumed.ws.send_json({"resume": state["state"], "from": first, "binary": True})
            started = await resumed.until(kind("started"))
            assert started["frame"] == first
            await resumed.until(lambda body: resumed.received() >= state["frame"] + 120)
            assert min(resumed.frames) == first  # nothing it had, nothing missing
            assert sorted(resumed.frames) == list(range(first, resumed.received()))
            both = sorted(set(resumed.frames) & set(original.frames))
            assert len(both) >= 90
            for index in both:
                np.testing.assert_array_equal(resumed.frames[index], original.frames[index])
            # and it takes states and switches as any stream does
            await resumed.ws.send_json({"state": True})
            again = await resumed.until(kind("state"))
            assert again["frame"] >= first
            await resumed.ws.send_json({"prompt": "a person waves"})
            assert (await resumed.until(kind("switched")))["prompt"] == "a person waves"

    two_servers(generator, engine_parts, test)


def reseal(state: str, key: str, value) -> str:
    """The state with one payload field replaced, its checksum made again (no signature)."""
    import hashlib
    import zlib

    from mogo.stream_state import HEADER, MAGIC, VERSION, _payload

    payload = _payload(state)
    payload[key] = value
    body = zlib.compress(json.dumps(payload).encode())
    head = HEADER.pack(MAGIC, VERSION, len(body), hashlib.sha256(body).digest())
    return base64.urlsafe_b64encode(head + body).decode().rstrip("=")


def test_bad_resume_states_get_one_error_each_and_the_others_stream_on(generator, engine_parts):
    good = generator.stream("a person walks", seed=1)
    for _ in range(30):
        good.step()
    state = good.state()  # the API's stream: the server reads the same states
    bad = {
        "truncated": state[: len(state) // 12 * 4],  # whole base64 quads: it decodes
        "corrupted": state[:60] + ("B" if state[60] == "A" else "A") + state[61:],
        "another bundle": reseal(state, "bundle", "f" * 64),
        "must be an integer": reseal(state, "steps", 2**200),
        "at most": "A" * 40_000,
        '"resume" must be a state': 12,
        "not a stream state": "bm90IGEgc3RhdGU",
        "window is larger": reseal(state, "window", 4000),  # a resume would replay 4000 steps
    }

    async def test(a, b, _):
        async with ClientSession() as session:
            watched = Client(await session.ws_connect(a + "/v1/stream"))
            await watched.ws.send_json({"prompt": "a person jogs", "seed": 2, "binary": True})
            await watched.until(lambda body: len(watched.frames) >= 20)
            for expected, text in bad.items():
                ws = await session.ws_connect(a + "/v1/stream")
                await ws.send_json({"resume": text})
                reply = json.loads((await ws.receive()).data)
                assert reply["type"] == "error" and expected in reply["error"], reply
                assert "\n" not in reply["error"]
                await ws.close()
            seen = watched.received()
            await watched.until(lambda body: watched.received() >= seen + 20)
            health = await (await session.get(a + "/v1/health")).json()
            assert health == {**health, "status": "ok", "streams": 1}

    two_servers(generator, engine_parts, test)


def test_a_drained_server_hands_every_stream_over(generator, engine_parts):
    async def test(a, b, server):
        async with ClientSession() as session:
            clients = []
            for seed, prompt in enumerate(["a person walks", "a person spins", "a person waves"]):
                client = Client(await session.ws_connect(a + "/v1/stream"))
                await client.ws.send_json({"prompt": prompt, "seed": seed, "binary": True})
                clients.append(client)
            for client in clients:
                await client.until(lambda body, c=client: len(c.frames) >= 30)
            drained = asyncio.create_task(server.drain())
            drains = [await client.until(kind("drain")) for client in clients]
            for client in clients:
                assert (await client.until(kind("closed")))["code"] == 1001
            await drained
            health = await session.get(a + "/v1/health")
            assert health.status == 503 and (await health.json())["status"] == "draining"
            late = await session.ws_connect(a + "/v1/stream")
            await late.send_json({"prompt": "a person walks"})
            assert "stopping" in json.loads((await late.receive()).data)["error"]
            for client, drain in zip(clients, drains, strict=True):
                assert client.received() == drain["frame"]  # every frame made was sent
                resumed = Client(await session.ws_connect(b + "/v1/stream"))
                await resumed.ws.send_json({"resume": drain["state"], "binary": True})
                await resumed.until(lambda body, r=resumed: len(r.frames) >= 10)
                assert min(resumed.frames) == drain["frame"]  # none lost, none twice

    two_servers(generator, engine_parts, test)


def test_states_come_every_few_seconds(generator, engine_parts):
    async def test(a, b, _):
        async with ClientSession() as session:
            client = Client(await session.ws_connect(a + "/v1/stream"))
            await client.ws.send_json({"prompt": "a person walks", "seed": 0, "binary": True})
            first = await client.until(kind("state"))
            second = await client.until(kind("state"))
            assert second["frame"] > first["frame"]

    two_servers(generator, engine_parts, test, state_every=0.5)


def serve_on(port: int, log) -> subprocess.Popen:
    """A real `mogo serve` on `port`, once its health check answers."""
    process = subprocess.Popen(
        [sys.executable, "-m", "mogo", "serve", "--port", str(port), "--threads", "1"],
        stderr=log,
    )
    deadline = time.monotonic() + 60
    while True:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/v1/health", timeout=2):
                return process
        except OSError:
            assert process.poll() is None and time.monotonic() < deadline, "no mogo serve"
            time.sleep(0.2)


def test_the_example_client_resumes_by_itself_when_its_server_drains(tmp_path):
    """examples/websocket_client.py against a real `mogo serve` that is drained (SIGTERM)
    mid-stream and replaced by another on the same port: the client reconnects, resumes, and
    its frames run on with no gap and nothing twice."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    example = Path(__file__).resolve().parents[2] / "examples" / "websocket_client.py"
    log = open(tmp_path / "serve.log", "w")  # noqa: SIM115 (closed below)
    servers = [serve_on(port, log)]
    client = subprocess.Popen(
        [sys.executable, str(example), f"ws://127.0.0.1:{port}/v1/stream"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        lines = []
        while not any(line.startswith("frames") for line in lines):
            lines.append(client.stdout.readline())
            assert lines[-1], client.stderr.read()
        servers[0].send_signal(signal.SIGTERM)
        assert servers[0].wait(15) == 0
        servers.append(serve_on(port, log))
        out, err = client.communicate(timeout=120)
        assert client.returncode == 0, err
    finally:
        for process in [client, *servers]:
            if process.poll() is None:
                process.kill()
                process.wait(10)
        log.close()
    lines += out.splitlines()
    assert "reconnecting" in lines
    ranges = [
        tuple(int(n) for n in line.split()[1].rstrip(",").split("-"))
        for line in lines
        if line.startswith("frames")
    ]
    assert ranges[0][0] == 0 and ranges[-1][1] >= 100
    for (_, end), (start, _) in zip(ranges, ranges[1:], strict=False):
        assert start == end + 1, ranges
