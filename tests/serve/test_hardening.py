"""The server against hostile clients (issue 39), real sockets on 127.0.0.1: foreign web pages
and Host names, the token, cross-site form posts and bad charsets, lone surrogates and deep
JSON, a prompt-switch flood, clip requests past the queue or abandoned, half-sent requests
and too many connections, a log flood. Every test is bounded in time."""

import asyncio
import json
import logging
import threading

import pytest

pytest.importorskip("aiohttp")
pytest.importorskip("onnx")

from aiohttp import ClientSession, WSMsgType, WSServerHandshakeError  # noqa: E402
from test_server import next_of, serving  # noqa: E402

from mogo.serve import server as server_module  # noqa: E402
from mogo.serve.server import SWITCH_BURST, Access, QuietLog  # noqa: E402
from mogo.token_generator import Stopped  # noqa: E402


def port_of(url: str) -> int:
    return int(url.rsplit(":", 1)[1])


async def status(session, url: str, **headers) -> int:
    async with session.get(url + "/v1/health", headers=headers) as answer:
        return answer.status


def test_web_pages_and_host_names_of_others_are_refused(generator, engine_parts):
    async def test(url, server):
        port = port_of(url)
        async with ClientSession() as session:
            for origin in (
                "http://evil.example",
                f"http://evil.example:{port}",
                "null",
                f"http://localhost:{port + 1}",
                f"http://127.0.0.1.evil:{port}",
            ):
                assert await status(session, url, Origin=origin) == 403, origin
                with pytest.raises(WSServerHandshakeError) as refused:
                    await session.ws_connect(url + "/v1/stream", headers={"Origin": origin})
                assert refused.value.status == 403
            async with session.post(
                url + "/v1/generate",
                json={"prompt": "a person jumps"},
                headers={"Origin": "http://evil.example"},
            ) as answer:
                assert answer.status == 403
                assert "--allow-origin http://evil.example" in (await answer.json())["error"]
            for host in (f"evil.example:{port}", "evil.example", f"127.0.0.1.nip.io:{port}"):
                assert await status(session, url, Host=host) == 403, host  # DNS rebinding
            for origin in (
                None,
                f"http://127.0.0.1:{port}",
                f"http://localhost:{port}",
                f"http://[::1]:{port}",
                "http://app.example:3000",
            ):
                assert (
                    await status(session, url, **({"Origin": origin} if origin else {})) == 200
                ), origin
            for host in (f"localhost:{port}", f"[::1]:{port}", "127.0.0.1"):
                assert await status(session, url, Host=host) == 200, host
            ws = await session.ws_connect(
                url + "/v1/stream", headers={"Origin": f"http://localhost:{port}"}
            )
            await ws.send_json({"prompt": "a person walks forward"})
            await next_of(ws, "started")
            await ws.close()

    serving(generator, engine_parts, test, access=Access(origins=("http://app.example:3000",)))


def test_a_token_is_asked_of_every_request_but_the_viewer_page(generator, engine_parts):
    async def test(url, server):
        async with ClientSession() as session:
            assert await status(session, url) == 401
            assert await status(session, url, Authorization="Bearer wrong") == 401
            assert await status(session, url, Authorization="Bearer s3cret") == 200
            async with session.get(url + "/v1/health?token=s3cret") as answer:
                assert answer.status == 200
            async with session.get(url + "/") as answer:
                assert answer.status == 200 and "<canvas" in await answer.text()
            with pytest.raises(WSServerHandshakeError):
                await session.ws_connect(url + "/v1/stream")
            ws = await session.ws_connect(url + "/v1/stream?token=s3cret")
            await ws.send_json({"prompt": "a person walks forward"})
            await next_of(ws, "started")
            await ws.close()

    serving(generator, engine_parts, test, access=Access(token="s3cret"))


def test_form_posts_bad_charsets_and_bad_bytes_are_one_line(generator, engine_parts):
    body = json.dumps({"prompt": "a person jumps", "seconds": 1}).encode()
    cases = [
        ("text/plain", body, 415, "application/json"),  # a web page's no-preflight post
        ("application/x-www-form-urlencoded", body, 415, "application/json"),
        ("application/json; charset=bogus", body, 400, "charset 'bogus'"),
        ("application/json; charset=latin-1", body, 400, "UTF-8"),
        ("application/json", b'{"prompt": "a person \xff jumps"}', 400, "not UTF-8"),
        ("application/json", b"[" * 3000, 400, "nested too deeply"),
        (
            "application/json",
            b'{"prompt": "a person \\ud800 jumps", "seconds": 1}',
            400,
            "lone surrogate",
        ),
    ]

    async def test(url, server):
        async with ClientSession() as session:
            for content_type, data, code, words in cases:
                async with session.post(
                    url + "/v1/generate", data=data, headers={"Content-Type": content_type}
                ) as answer:
                    error = (await answer.json())["error"]
                    assert answer.status == code and words in error, (content_type, error)
                    assert "\n" not in error
            async with session.post(
                url + "/v1/generate",
                data=body,
                headers={"Content-Type": "application/json; charset=UTF-8"},
            ) as answer:
                assert answer.status == 200

    serving(generator, engine_parts, test)


def test_lone_surrogates_and_deep_json_are_an_error_on_their_socket(generator, engine_parts):
    async def test(url, server):
        async with ClientSession() as session:
            ws = await session.ws_connect(url + "/v1/stream")
            await ws.send_str('{"prompt": "a person \\ud800 walks"}')
            error = (await next_of(ws, "error"))["error"]
            assert error == "prompt is not valid Unicode: a lone surrogate '\\ud800' at character 9"
            await ws.send_str("[" * 3000)
            assert "nested too deeply" in (await next_of(ws, "error"))["error"]
            await ws.send_json({"prompt": "a person walks forward"})
            await next_of(ws, "started")
            await ws.send_str('{"prompt": "\\udfff"}')
            assert "lone surrogate" in (await next_of(ws, "error"))["error"]
            await ws.close()

    serving(generator, engine_parts, test)


def test_a_flood_of_switches_is_refused_past_the_rate(generator, engine_parts):
    async def test(url, server):
        async with ClientSession() as session:
            ws = await session.ws_connect(url + "/v1/stream")
            await ws.send_json({"prompt": "a person walks forward", "seed": 1})
            await next_of(ws, "started")
            for k in range(40):
                await ws.send_json({"prompt": ["a person jumps", "a person waves"][k % 2]})
            answers = []
            while len(answers) < 40:
                message = await ws.receive()
                kind = json.loads(message.data)["type"]
                if kind in ("switched", "error"):
                    answers.append(json.loads(message.data))
            switched = sum(a["type"] == "switched" for a in answers)
            assert SWITCH_BURST <= switched <= 20  # 40 before
            assert all(
                a["error"].startswith("too many switches") for a in answers if a["type"] == "error"
            )
            await next_of(ws, "frames")  # the stream goes on
            await ws.close()

    serving(generator, engine_parts, test)


@pytest.fixture
def clip_calls(monkeypatch):
    """Each clip the server makes, told as "started", then "stopped" or "done"."""
    calls, real = [], server_module._clip_file

    def watched(*args):
        calls.append("started")
        try:
            data = real(*args)
        except Stopped:
            calls.append("stopped")
            raise
        calls.append("done")
        return data

    monkeypatch.setattr(server_module, "_clip_file", watched)
    return calls


async def until(condition, seconds: float = 30) -> None:
    for _ in range(int(seconds / 0.02)):
        if condition():
            return
        await asyncio.sleep(0.02)
    raise AssertionError("not within the bound")


def test_a_client_that_leaves_stops_its_clip_and_a_full_queue_says_503(
    generator, engine_parts, clip_calls, monkeypatch
):
    monkeypatch.setattr(server_module, "QUEUED_CLIPS", 0)
    long_clip = {"prompt": "a person walks forward", "seconds": 300, "seed": 1}

    async def test(url, server):
        async with ClientSession() as session:
            request = asyncio.create_task(session.post(url + "/v1/generate", json=long_clip))
            await until(lambda: clip_calls == ["started"])
            async with session.post(url + "/v1/generate", json=long_clip) as answer:
                assert answer.status == 503 and answer.headers["Retry-After"]
                assert (await answer.json())["error"].startswith("busy: 1 clips")
            request.cancel()  # the client leaves: its connection closes
        await until(lambda: clip_calls == ["started", "stopped"])
        await until(lambda: server.clip_jobs == 0)
        async with ClientSession() as session:
            async with session.post(
                url + "/v1/generate", json={"prompt": "a person jumps", "seconds": 1}
            ) as answer:
                assert answer.status == 200

    serving(generator, engine_parts, test)


def test_clips_are_made_side_by_side(generator, engine_parts, monkeypatch):
    together = threading.Barrier(2, timeout=30)  # broken unless two clips run at once
    real = server_module._clip_file

    def meeting(*args):
        together.wait()
        return real(*args)

    monkeypatch.setattr(server_module, "_clip_file", meeting)

    async def test(url, server):
        async with ClientSession() as session:

            async def clip(seed):
                async with session.post(
                    url + "/v1/generate",
                    json={"prompt": "a person jumps", "seconds": 1, "seed": seed},
                ) as answer:
                    return answer.status

            assert await asyncio.gather(clip(1), clip(2)) == [200, 200]

    serving(generator, engine_parts, test, threads=2)


def test_half_sent_requests_are_closed_and_connections_capped(generator, engine_parts, monkeypatch):
    monkeypatch.setattr(server_module, "REQUEST_SECONDS", 0.5)

    async def test(url, server):
        port = port_of(url)
        half = []
        for _ in range(3):  # slowloris: headers that never end
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-a: b\r\n")
            half.append((reader, writer))
        reader, writer = await asyncio.open_connection("127.0.0.1", port)  # past the cap
        assert await asyncio.wait_for(reader.read(), 10) == b""
        for reader, _ in half:  # closed once their headers are late
            assert await asyncio.wait_for(reader.read(), 10) == b""
        async with ClientSession() as session:
            assert await status(session, url) == 200

    serving(generator, engine_parts, test, max_connections=3)


def test_log_lines_of_one_kind_are_rate_limited():
    now = [0.0]
    quiet = QuietLog(clock=lambda: now[0])

    def record(message):
        return logging.LogRecord("aiohttp.server", logging.ERROR, __file__, 1, message, None, None)

    passed = [quiet.filter(record("Error handling request")) for _ in range(1000)]
    assert passed == [True] + [False] * 999
    assert quiet.filter(record("another kind"))
    now[0] = server_module.LOG_EVERY_SECONDS
    assert quiet.filter(record("Error handling request"))


def test_a_clip_body_that_does_not_come_is_408_and_holds_no_place(
    generator, engine_parts, monkeypatch
):
    monkeypatch.setattr(server_module, "REQUEST_SECONDS", 0.5)

    async def test(url, server):
        reader, writer = await asyncio.open_connection("127.0.0.1", port_of(url))
        writer.write(
            b"POST /v1/generate HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: "
            b'application/json\r\nContent-Length: 100\r\n\r\n{"prompt"'
        )
        await asyncio.sleep(0.2)  # the handler waits for the body: no place in the queue
        assert server.clip_jobs == 0
        answer = await asyncio.wait_for(reader.readuntil(b"}"), 10)  # the JSON's end
        assert answer.startswith(b"HTTP/1.1 408 ") and b"Connection: close" in answer
        assert b"the body did not come within 0.5 s" in answer
        writer.close()

    serving(generator, engine_parts, test)


def test_a_socket_that_starts_no_stream_is_closed(generator, engine_parts, monkeypatch):
    monkeypatch.setattr(server_module, "REQUEST_SECONDS", 0.5)

    async def test(url, server):
        async with ClientSession() as session:
            idle = await session.ws_connect(url + "/v1/stream")
            chatty = await session.ws_connect(url + "/v1/stream")
            for _ in range(10):  # bad messages do not extend the time to start
                await chatty.send_str("{")
                await asyncio.sleep(0.1)
            for ws in (idle, chatty):
                error = await next_of(ws, "error")
                while error["error"].startswith("not JSON"):
                    error = await next_of(ws, "error")
                assert error["error"] == "no stream started within 0.5 s"
                assert (await ws.receive()).type in (WSMsgType.CLOSE, WSMsgType.CLOSED)
            streaming = await session.ws_connect(url + "/v1/stream")
            await streaming.send_json({"prompt": "a person walks forward"})
            await next_of(streaming, "started")
            await asyncio.sleep(1.0)  # past the time to start: a stream is not cut
            await next_of(streaming, "frames")
            await streaming.close()

    serving(generator, engine_parts, test)
