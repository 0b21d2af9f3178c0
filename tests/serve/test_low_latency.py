"""Low-latency served streams ({"low_latency": true}): decoded by the bundle's low-latency
decoder in the engine's shared calls, beside centred streams; the frames of a local
`MotionStream(low_latency=True)` for the same prompt, seed and switch; resumed on another
server; refused in one line where the bundle has no such decoder or the field is no bool."""

import json

import numpy as np
import pytest

pytest.importorskip("aiohttp")
pytest.importorskip("onnx")

from aiohttp import ClientSession  # noqa: E402
from test_resume import Client, kind, reseal, two_servers  # noqa: E402
from test_server import frames, next_of, serving  # noqa: E402

from mogo.serve.engine import Engine  # noqa: E402
from mogo.stream_decoder import StepDecoder  # noqa: E402

WALK, JUMP = "a person walks forward", "a person jumps on the spot"


def local_frames(generator, seed: int, count: int, switch: int | None, low_latency=True):
    """`count` frames of a local MotionStream, switched to JUMP after token step `switch`."""
    stream = generator.stream(WALK, seed=seed, low_latency=low_latency)
    got = []
    while sum(map(len, got)) < count:
        if stream.steps == switch:
            stream.set_prompt(JUMP)
        got.append(stream.step())
    return np.concatenate(got)[:count]


def test_low_latency_and_centred_streams_share_rounds_and_keep_their_frames(
    generator, engine_parts
):
    """One engine, both decoders in the same rounds (a switch on the low-latency stream): each
    stream's frames are its local MotionStream's, and the low-latency one's come after its
    own decoder's lookahead (and the feet's), the centred one's after the centred decoder's."""
    g = generator
    engine = Engine(g, 1, tokens=engine_parts)
    low = engine.open(WALK, 7, g.sampling(None), 0.0, low_latency=True)
    centred = engine.open(WALK, 7, g.sampling(None), 0.0)
    firsts, got = {}, {low.id: [], centred.id: []}
    while centred.frames_emitted < 100:
        if low.steps == 30:
            engine.switch(low, JUMP)
        for stream, _, joints in engine.round([low, centred]):
            firsts.setdefault(stream.id, stream.steps)
            got[stream.id].append(joints)
    lookahead = {s.id: s.lookahead_steps + 1 for s in (low, centred)}
    assert firsts == lookahead
    assert g.manifest.vq.low_latency_decoder.lookahead == low.decoder.lookahead
    assert low.decoder.lookahead < centred.decoder.lookahead
    # the shipped bundle's step graph: a token a call, on the engine's own session of it
    assert isinstance(low.decoder, StepDecoder) and g.manifest.vq.low_latency_step is not None
    assert low.decoder.session is not g.streaming_decoder(low_latency=True).session
    served = {k: np.concatenate(v) for k, v in got.items()}
    expected = {
        low.id: local_frames(g, 7, len(served[low.id]), 30),
        centred.id: local_frames(g, 7, len(served[centred.id]), None, low_latency=False),
    }
    for k in served:
        np.testing.assert_allclose(served[k], expected[k], atol=1e-5)
    engine.shutdown()


def test_a_low_latency_client_gets_the_local_streams_frames_and_switches(generator, engine_parts):
    """Through a socket (binary frames): the local stream's frames, the switch at the frame
    `switched` names."""
    g, got = generator, {}

    async def test(url, server):
        async with ClientSession() as session:
            client = Client(await session.ws_connect(url + "/v1/stream"))
            start = {"prompt": WALK, "seed": 4, "low_latency": True, "binary": True}
            await client.ws.send_json(start)
            await client.until(lambda body: client.received() >= 20)
            await client.ws.send_json({"prompt": JUMP})
            got["switch"] = (await client.until(kind("switched")))["index"]
            await client.until(lambda body: client.received() >= got["switch"] + 40)
            got["frames"] = np.array([client.frames[k] for k in range(client.received())])

    serving(g, engine_parts, test)
    assert got["switch"] >= 20 and got["switch"] % g.down_factor == 0
    expected = local_frames(g, 4, len(got["frames"]), got["switch"] // g.down_factor)
    np.testing.assert_allclose(got["frames"], expected, atol=1e-5)


def test_a_low_latency_stream_resumes_on_another_server(generator, engine_parts):
    async def test(a, b, _):
        async with ClientSession() as session:
            original = Client(await session.ws_connect(a + "/v1/stream"))
            await original.ws.send_json(
                {"prompt": WALK, "seed": 5, "low_latency": True, "binary": True}
            )
            await original.until(lambda body: original.received() >= 30)
            await original.ws.send_json({"state": True})
            state = await original.until(kind("state"))
            await original.until(lambda body: original.received() >= state["frame"] + 60)
            resumed = Client(await session.ws_connect(b + "/v1/stream"))
            await resumed.ws.send_json({"resume": state["state"], "binary": True})
            assert (await resumed.until(kind("started")))["frame"] == state["frame"]
            await resumed.until(lambda body: resumed.received() >= state["frame"] + 60)
            assert min(resumed.frames) == state["frame"]
            both = sorted(set(resumed.frames) & set(original.frames))
            assert len(both) >= 50
            for index in both:
                np.testing.assert_array_equal(resumed.frames[index], original.frames[index])

    two_servers(generator, engine_parts, test)


def test_low_latency_is_refused_in_one_line_without_its_decoder_or_as_no_bool(
    centred_generator, engine_parts
):
    """A server whose bundle has no low-latency decoder refuses a stream or a state that asks
    for one; any server refuses a "low_latency" that is not true or false; the socket stays
    usable."""
    centred = centred_generator.stream(WALK, seed=1)
    for _ in range(5):
        centred.step()
    forged = reseal(centred.state(), "low_latency", True)  # this bundle's, checksum made again

    async def test(url, server):
        async with ClientSession() as session, session.ws_connect(url + "/v1/stream") as ws:
            refusals = [
                ({"prompt": WALK, "low_latency": True}, "has no low-latency decoder"),
                ({"prompt": WALK, "low_latency": 1}, '"low_latency" must be true or false, got 1'),
                ({"prompt": WALK, "low_latency": "yes"}, "must be true or false, got 'yes'"),
                ({"resume": forged}, "this server's bundle has no low-latency decoder"),
            ]
            for message, expected in refusals:
                await ws.send_str(json.dumps(message))
                error = (await next_of(ws, "error"))["error"]
                assert expected in error and "\n" not in error, error
            await ws.send_json({"prompt": WALK, "seed": 1})
            await next_of(ws, "started")
            await frames(ws, 5)
            assert len(server.engine.streams) == 1

    serving(centred_generator, engine_parts, test)
