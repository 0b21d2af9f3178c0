"""The server on an ephemeral port, with real WebSocket and HTTP clients: the protocol, faults
on one socket that leave the others streaming, the stream cap, disconnects, slow readers, and
the same frames for a stream alone and among others. Every test is bounded in time."""

import asyncio
import io
import json
import threading

import numpy as np
import pytest

pytest.importorskip("aiohttp")
pytest.importorskip("onnx")

from aiohttp import ClientSession, WSMsgType  # noqa: E402

from mogo.serve import protocol  # noqa: E402
from mogo.serve.engine import Engine  # noqa: E402
from mogo.serve.server import QUEUED_BURSTS, SERVER, Access, Server, listen, make_app, stop  # noqa: E402

TIMEOUT = 60  # seconds for a whole test: far above what each needs, so a hang fails


def serving(
    generator, engine_parts, test, max_streams=8, access=None, threads=1, max_connections=64
):
    """Run `test(base_url, server)` against a server on an ephemeral port, as `mogo serve`
    runs it (mogo.serve.server.listen)."""

    async def main():
        app = make_app(
            generator, threads, max_streams, tokens=engine_parts, access=access or Access()
        )
        runner, listener = await listen(app, "127.0.0.1", 0, max_connections)
        port = listener.sockets[0].getsockname()[1]
        try:
            await asyncio.wait_for(test(f"http://127.0.0.1:{port}", app[SERVER]), TIMEOUT)
        finally:
            await stop(runner, listener)

    asyncio.run(main())


async def next_of(ws, kind: str) -> dict:
    """The next message of this type (frames may come between)."""
    while True:
        message = await ws.receive()
        assert message.type == WSMsgType.TEXT, message
        body = json.loads(message.data)
        if body["type"] == kind:
            return body


async def frames(ws, count: int) -> list[dict]:
    got = []
    while sum(len(b["joints"]) for b in got) < count:
        got.append(await next_of(ws, "frames"))
    return got


def test_a_stream_starts_switches_and_stops(generator, engine_parts):
    async def test(url, server):
        async with ClientSession() as session, session.ws_connect(url + "/v1/stream") as ws:
            await ws.send_json({"prompt": "a person walks forward", "seed": 4, "top_k": 50})
            started = await next_of(ws, "started")
            assert started["seed"] == 4 and started["fps"] == 20 and len(started["joints"]) == 22
            bursts = await frames(ws, 20)
            indices = [i for b in bursts for i in range(b["index"], b["index"] + len(b["joints"]))]
            assert indices == list(range(len(indices)))
            assert np.asarray(bursts[0]["joints"]).shape[1:] == (22, 3)
            await ws.send_json({"prompt": "a person jumps"})
            assert (await next_of(ws, "switched"))["prompt"] == "a person jumps"
            await frames(ws, 10)
            await ws.send_json({"stop": True})
            while (await ws.receive()).type not in (WSMsgType.CLOSE, WSMsgType.CLOSED):
                pass
        async with ClientSession() as session:
            health = await (await session.get(url + "/v1/health")).json()
        assert health["status"] == "ok" and health["streams"] == 0

    serving(generator, engine_parts, test)


def test_prompts_are_read_off_the_engines_thread(generator, engine_parts):
    """A new prompt's text graphs take milliseconds: read on the engine's thread, they would
    hold every stream meanwhile."""

    async def test(url, server):
        threads = []
        checked = server.checked_prompt

        def recorded(prompt):
            threads.append(threading.current_thread().name)
            return checked(prompt)

        server.checked_prompt = recorded
        async with ClientSession() as session, session.ws_connect(url + "/v1/stream") as ws:
            await ws.send_json({"prompt": "a person walks forward", "seed": 4})
            await frames(ws, 1)
            await ws.send_json({"prompt": "a person jumps"})
            await next_of(ws, "switched")
        assert len(threads) == 2 and all(n.startswith("mogo-prompt") for n in threads), threads

    serving(generator, engine_parts, test)


def test_a_switch_names_the_first_frame_of_its_prompt(generator, engine_parts):
    """`switched` carries the index from which frames follow the new prompt: a MotionStream
    switched at that frame gives the frames the socket got, before and after it."""

    async def test(url, server):
        async with ClientSession() as session, session.ws_connect(url + "/v1/stream") as ws:
            await ws.send_json({"prompt": "a person walks forward", "seed": 6})
            received = await frames(ws, 30)
            await ws.send_json({"prompt": "a person jumps"})
            switch = await next_of(ws, "switched")
            got = sum(len(b["joints"]) for b in received)
            assert switch["prompt"] == "a person jumps" and switch["index"] >= got
            received += await frames(ws, switch["index"] + 60 - got)
        served = np.concatenate([b["joints"] for b in received])
        local = generator.stream("a person walks forward", seed=6)
        assert switch["index"] % generator.down_factor == 0
        expected = [local.step() for _ in range(switch["index"] // generator.down_factor)]
        local.set_prompt("a person jumps")
        while sum(map(len, expected)) < len(served):
            expected.append(local.step())
        n = len(served)
        np.testing.assert_allclose(served, np.concatenate(expected)[:n], atol=2e-4)

    serving(generator, engine_parts, test)


def test_bad_messages_get_an_error_on_their_socket_and_the_others_go_on(generator, engine_parts):
    bad = [
        "{not json",
        json.dumps({"prompt": "a person jumps", "colour": "red"}),
        json.dumps({"prompt": "x" * (protocol.MAX_MESSAGE_CHARS + 1)}),
        json.dumps({"prompt": ""}),
        json.dumps({"prompt": "a person jumps", "seed": -1}),
        json.dumps({"prompt": "a person jumps", "top_p": 7}),
        json.dumps([1, 2]),
    ]

    async def test(url, server):
        async with ClientSession() as session:
            other = await session.ws_connect(url + "/v1/stream")
            await other.send_json({"prompt": "a person jogs", "seed": 1})
            await next_of(other, "started")
            ws = await session.ws_connect(url + "/v1/stream")
            for text in bad:  # before the start: refused, the socket stays usable
                await ws.send_str(text)
                assert (await next_of(ws, "error"))["error"]
            await ws.send_bytes(b"\x00\x01")
            assert "JSON text" in (await next_of(ws, "error"))["error"]
            await ws.send_json({"prompt": "a person waves", "seed": 2})
            await next_of(ws, "started")
            for text in bad[:3] + [json.dumps({"stop": False}), json.dumps({"seed": 3})]:
                await ws.send_str(text)  # during the stream: refused, the stream goes on
                assert (await next_of(ws, "error"))["error"]
            far = await session.ws_connect(url + "/v1/stream")  # read, with a note
            await far.send_json({"prompt": "qwxz zzyq"})
            await next_of(far, "started")
            assert "far from what this model knows" in (await next_of(far, "note"))["note"]
            await far.send_json({"prompt": "someone saunters forward"})  # other words
            assert (await next_of(far, "note"))["note"] == (
                "played as the known caption 'a person takes three steps forward straight'"
            )
            await frames(ws, 10)
            await frames(other, 30)
            for socket in (ws, other, far):
                await socket.close()

    serving(generator, engine_parts, test)


def test_past_the_cap_a_stream_is_refused_clearly(generator, engine_parts):
    async def test(url, server):
        async with ClientSession() as session:
            first = await session.ws_connect(url + "/v1/stream")
            await first.send_json({"prompt": "a person jogs"})
            await next_of(first, "started")
            second = await session.ws_connect(url + "/v1/stream")
            await second.send_json({"prompt": "a person jogs"})
            assert "full" in (await next_of(second, "error"))["error"]
            assert (await second.receive()).type in (WSMsgType.CLOSE, WSMsgType.CLOSED)
            await frames(first, 10)
            await first.close()

    serving(generator, engine_parts, test, max_streams=1)


def test_a_disconnect_mid_stream_frees_the_stream(generator, engine_parts):
    async def test(url, server):
        async with ClientSession() as session:
            ws = await session.ws_connect(url + "/v1/stream")
            await ws.send_json({"prompt": "a person runs forward"})
            await frames(ws, 1)
            assert len(server.engine.streams) == 1
        # the session is gone without a stop or a close handshake of ours
        while server.engine.streams or server.queues:
            await asyncio.sleep(0.05)

    serving(generator, engine_parts, test)


def test_a_client_that_does_not_read_holds_up_no_other(generator, engine_parts):
    async def test(url, server):
        async with ClientSession() as session:
            idle = await session.ws_connect(url + "/v1/stream")
            await idle.send_json({"prompt": "a person kicks"})  # and never reads again
            reader = await session.ws_connect(url + "/v1/stream")
            await reader.send_json({"prompt": "a person walks forward"})
            bursts = await frames(reader, 120)  # 6 s of motion while the idle one reads nothing
            assert bursts[-1]["index"] + len(bursts[-1]["joints"]) >= 120
            await idle.close()
            await reader.close()

    serving(generator, engine_parts, test)


def test_a_full_queue_drops_its_oldest_burst():
    server = Server.__new__(Server)
    server.queues = {1: asyncio.Queue(QUEUED_BURSTS)}
    for index in range(QUEUED_BURSTS + 3):
        server.deliver(1, index, None)
    kept = [server.queues[1].get_nowait()[0] for _ in range(QUEUED_BURSTS)]
    assert kept == list(range(3, QUEUED_BURSTS + 3))
    server.deliver(2, 0, None)  # a client gone meanwhile: nothing to do


def test_generate_returns_the_file(generator, engine_parts):
    async def test(url, server):
        async with ClientSession() as session:

            def post(**body):
                return session.post(url + "/v1/generate", json=body)

            async with post(prompt="a person jumps", seconds=2, seed=1, format="bvh") as answer:
                assert answer.status == 200 and (await answer.text()).startswith("HIERARCHY")
            async with post(prompt="a person jumps", seconds=2, seed=1, format="npy") as answer:
                joints = np.load(io.BytesIO(await answer.read()), allow_pickle=False)
            assert joints.shape == (40, 22, 3)
            expected = generator.generate("a person jumps", seconds=2, seed=1).joints
            assert np.allclose(joints, expected)
            async with post(prompt="a person jumps", seconds=2, format="json") as answer:
                assert answer.status == 200 and "fps" in json.dumps(await answer.json())
            async with post(prompt="a person jumps", seconds=2, format="glb") as answer:
                assert answer.status == 200 and (await answer.read())[:4] == b"glTF"
            for body in (
                dict(prompt="a person jumps", format="gif"),
                dict(prompt=""),
                dict(prompt="a person jumps", seconds=-1),
                dict(prompt="a", size=3),
            ):
                async with post(**body) as answer:
                    assert answer.status == 400 and (await answer.json())["error"]

    serving(generator, engine_parts, test)


def test_a_stream_gives_the_same_frames_alone_and_among_others(generator, engine_parts):
    """On the engine's own clock (no wall time): others start before, with and after it; the
    switch lands on a fixed step of the stream (where it lands is the one thing a client's
    timing decides). Every round runs a call's levels in two groups on two threads."""

    def play(others: list[float], seconds: float = 12.0) -> np.ndarray:
        engine = Engine(generator, 2, tokens=engine_parts)
        sampling = generator.sampling(None)
        stream = engine.open("a person walks forward", 5, sampling, 1.0)
        pending = sorted(others)
        got, now = [], 0.95
        while now < 1.0 + seconds:
            while pending and pending[0] <= now:
                engine.open("a person jumps", len(pending), sampling, pending.pop(0))
            if stream.steps == 100 and stream.prompt != "a person waves":
                engine.switch(stream, "a person waves")
            due = engine.due(now)
            out = engine.round(due) if due else []
            got += [joints for s, _, joints in out if s is stream]
            now = round(now + (0 if due else 0.05), 6)
        return np.concatenate(got)

    alone = play([])
    among = play([0.95, 1.0, 1.3, 4.0, 9.0])
    assert len(alone) > 150 and np.array_equal(alone, among[: len(alone)])


@pytest.mark.parametrize("binary", [False, True])
def test_the_benchmark_client_counts_every_frame_in_either_encoding(
    generator, engine_parts, binary
):
    """`mogo bench serve`'s client (mogo.bench.speed.serve.client): one arrival time per frame,
    from JSON bursts or binary ones, whatever their size."""
    from mogo.bench.speed.serve import client

    async def test(url, server):
        first, arrivals = await client(f"{url}/v1/stream", 0, 4.0, None, binary)
        assert len(arrivals) >= 9 and arrivals == sorted(arrivals)
        assert 0 < first < arrivals[-1] - arrivals[0] + first
        assert (len(arrivals) - 1) % 8 == 0  # a burst of the first frame, then bursts of 8

    serving(generator, engine_parts, test)
