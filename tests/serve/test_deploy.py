"""Three `mogo serve` processes behind HAProxy on loopback, with the deployment's own config
(examples/deploy/haproxy.cfg, docs/deploy.md): clients stream with switches through the proxy,
one backend is killed (SIGKILL) mid-stream, then another drained (SIGTERM), and every client
reconnects through the proxy and resumes: no frame lost or twice, every frame that of an
uninterrupted stream of the same seed and switch, no seam (the joint speed across the resume
that of the uninterrupted stream there)."""

import asyncio
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("aiohttp")
pytest.importorskip("onnx")

from aiohttp import ClientError, ClientSession, WSMsgType  # noqa: E402

from mogo.serve.engine import Engine  # noqa: E402
from mogo.stream_state import _payload  # noqa: E402

HAPROXY = shutil.which("haproxy")
CONFIG = Path(__file__).resolve().parents[2] / "examples" / "deploy" / "haproxy.cfg"
TOKEN = "deploy-test-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}
STARTUP_SECONDS = 60  # for the servers (a model each) and HAProxy's first health checks
TIMEOUT = 90  # for the streaming part
CLIENTS = [
    ("a person walks forward.", 11, "a person jumps."),
    ("a person jogs in a circle.", 12, "a person waves."),
    ("a person spins to the left.", 13, "a person walks backward."),
    ("a person claps.", 14, "a person sits down."),
]
BEFORE, AFTER = 40, 60  # frames before the switch; frames each client reads past its resume

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(HAPROXY is None, reason="needs HAProxy: apt-get install haproxy"),
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_healthy(url: str, deadline: float) -> None:
    import urllib.error
    import urllib.request

    while True:
        try:
            request = urllib.request.Request(url + "/v1/health", headers=HEADERS)
            with urllib.request.urlopen(request, timeout=2) as response:
                if response.status == 200:
                    return
        except (OSError, urllib.error.URLError):
            pass
        if time.monotonic() > deadline:
            raise AssertionError(f"{url} did not become healthy")
        time.sleep(0.2)


@pytest.fixture
def deployment(tmp_path):
    """(proxy url, {backend url: process}): three servers and HAProxy, stopped after."""
    ports = [free_port() for _ in range(4)]
    processes, backends = [], {}
    env = {**os.environ, "MOGO_SERVE_TOKEN": TOKEN}
    try:
        for k, port in enumerate(ports[1:], 1):
            log = open(tmp_path / f"serve{k}.log", "w")  # noqa: SIM115 (closed with the process)
            process = subprocess.Popen(
                [sys.executable, "-m", "mogo", "serve", "--port", str(port), "--state-every", "1"],
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
            processes.append(process)
            backends[f"http://127.0.0.1:{port}"] = process
        proxy_env = env | {"MOGO_LISTEN": f"127.0.0.1:{ports[0]}"}
        proxy_env |= {f"MOGO_SERVER_{k}": f"127.0.0.1:{p}" for k, p in enumerate(ports[1:], 1)}
        processes.append(
            subprocess.Popen(
                [HAPROXY, "-db", "-f", str(CONFIG)],
                env=proxy_env,
                stdout=open(tmp_path / "haproxy.log", "w"),  # noqa: SIM115
                stderr=subprocess.STDOUT,
            )
        )
        deadline = time.monotonic() + STARTUP_SECONDS
        for url in backends:
            wait_healthy(url, deadline)
        proxy = f"http://127.0.0.1:{ports[0]}"
        wait_healthy(proxy, deadline)
        time.sleep(2.5)  # HAProxy: every server up (rise 2 checks, 1 s apart)
        yield proxy, backends
    finally:
        for process in processes:
            if process.poll() is None:
                process.send_signal(signal.SIGKILL)
            process.wait(10)


class Client:
    """One character through the proxy: it streams, switches once, and on a dropped socket
    reconnects with its latest usable state, as examples/websocket_client.py does."""

    def __init__(self, prompt: str, seed: int, switch: str):
        self.prompt, self.seed, self.switch = prompt, seed, switch
        self.frames: dict[int, np.ndarray] = {}
        self.states: list[dict] = []
        self.switched = False
        self.seams: list[int] = []  # the first frame of each resumed socket
        self.ready = asyncio.Event()  # holds a state that knows of the switch

    @property
    def next(self) -> int:
        return max(self.frames) + 1 if self.frames else 0

    def usable(self) -> dict | None:
        states = [s for s in self.states if s["frame"] <= self.next]
        return states[-1] if states else None

    async def run(self, session: ClientSession, url: str, done: asyncio.Event) -> None:
        while True:
            try:
                async with session.ws_connect(url + "/v1/stream", headers=HEADERS) as ws:
                    state = self.usable()
                    if state is None:
                        await ws.send_json(
                            {"prompt": self.prompt, "seed": self.seed, "binary": True}
                        )
                    else:
                        self.seams.append(self.next)
                        await ws.send_json(
                            {"resume": state["state"], "from": self.next, "binary": True}
                        )
                    if await self.read(ws, done):
                        return
            except ClientError:
                pass
            await asyncio.sleep(0.2)  # HAProxy retries a dead server's connection elsewhere

    async def read(self, ws, done: asyncio.Event) -> bool:
        """Frames and states until the socket drops (False) or the test is done (True)."""
        async for message in ws:
            if message.type == WSMsgType.BINARY:
                index, n = struct.unpack_from("<II", message.data)
                joints = np.frombuffer(message.data, "<f4", offset=8).reshape(n, 22, 3)
                assert index == self.next, f"frame {index} came when {self.next} was due"
                for k in range(n):
                    self.frames[index + k] = joints[k]
                if self.next >= BEFORE and not self.switched:
                    self.switched = True
                    await ws.send_json({"prompt": self.switch})
            else:
                body = json.loads(message.data)
                if body["type"] == "error" and "stopping" in body["error"]:
                    return False  # reached the drained server before HAProxy saw it go
                assert body["type"] != "error", body
                if body["type"] in ("state", "drain"):
                    self.states.append(body)
                    if self.switch in _prompts(body):
                        self.ready.set()
            if done.is_set():
                return True
        return False


def _prompts(state: dict) -> list[str]:
    return [text for _, text in _payload(state["state"])["prompts"]]


def reference(generator, engine_parts, client: Client, frames: int) -> np.ndarray:
    """The uninterrupted stream: the same prompt, seed and switch step, on the engine's code
    path alone (the server's tokens and decoding), `frames` frames."""
    engine = Engine(generator, 1, tokens=engine_parts)
    switch = next(
        frame
        for s in client.states
        for frame, text in _payload(s["state"])["prompts"]
        if text == client.switch
    )
    stream = engine.open(client.prompt, client.seed, generator.sampling(None), 0.0)
    made = []
    while sum(map(len, made)) < frames:
        if stream.steps == switch // generator.down_factor:
            engine.switch(stream, client.switch)
        made += [joints for _, _, joints in engine.round([stream])]
    return np.concatenate(made)[:frames]


def test_clients_resume_through_the_proxy_when_a_backend_is_killed(
    deployment, generator, engine_parts
):
    proxy, backends = deployment
    clients = [Client(*c) for c in CLIENTS]

    async def main():
        done, moved = asyncio.Event(), 0
        async with ClientSession() as session:
            tasks = [asyncio.create_task(c.run(session, proxy, done)) for c in clients]
            await asyncio.wait_for(asyncio.gather(*(c.ready.wait() for c in clients)), TIMEOUT)
            for stop in (signal.SIGKILL, signal.SIGTERM):
                counts = {}
                for url, process in backends.items():
                    if process.poll() is None:
                        async with session.get(url + "/v1/health", headers=HEADERS) as response:
                            counts[url] = (await response.json())["streams"]
                victim = max(counts, key=counts.get)
                assert counts[victim] >= 1, counts
                moved += counts[victim]
                marks = [c.next for c in clients]
                backends[victim].send_signal(stop)
                if stop == signal.SIGTERM:  # drained: states handed over, then it exits
                    exited = asyncio.to_thread(backends[victim].wait, 10)
                    assert await asyncio.wait_for(exited, TIMEOUT) == 0
                while any(c.next < mark + AFTER for c, mark in zip(clients, marks, strict=True)):
                    await asyncio.sleep(0.1)
            done.set()
            await asyncio.wait_for(asyncio.gather(*tasks), TIMEOUT)
        return moved

    moved = asyncio.run(asyncio.wait_for(main(), 3 * TIMEOUT))
    assert sum(len(c.seams) for c in clients) >= moved  # every stream of each victim resumed
    fps = generator.fps
    for client in clients:
        got = np.array([client.frames[k] for k in range(client.next)])
        assert sorted(client.frames) == list(range(client.next))  # none lost, none twice
        expected = reference(generator, engine_parts, client, len(got))
        np.testing.assert_allclose(got, expected, atol=1e-5)
        # no seam: the joint speed across each resume is the uninterrupted stream's there (a
        # bound by the stream's own range failed where a resume fell on its fastest frame)
        speed = np.linalg.norm(np.diff(got, axis=0), axis=-1).mean(-1) * fps  # m/s, (n - 1,)
        usual = np.linalg.norm(np.diff(expected, axis=0), axis=-1).mean(-1) * fps
        for seam in client.seams:
            assert abs(speed[seam - 1] - usual[seam - 1]) < 1e-3, (seam, speed[seam - 1])
