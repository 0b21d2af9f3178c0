"""A WebSocket client of `mogo serve`: one character streamed, its prompt switched, stopped.

    pip install ".[serve]"
    mogo serve                                   # in another terminal
    python examples/websocket_client.py [ws://127.0.0.1:8765/v1/stream]

The protocol is in docs/serve.md; frames come in bursts, each a list of 22 joints [x, y, z].
"""

import asyncio
import json
import sys

import aiohttp

URL = sys.argv[1] if len(sys.argv) > 1 else "ws://127.0.0.1:8765/v1/stream"  # the default


async def main() -> None:
    switched = stopped = False
    async with aiohttp.ClientSession() as session, session.ws_connect(URL) as ws:
        await ws.send_json({"prompt": "a person walks forward", "seed": 1})
        async for message in ws:  # ends when the server closes the socket after "stop"
            body = json.loads(message.data)
            if body["type"] == "error":
                sys.exit(f"server: {body['error']}")
            if body["type"] != "frames":
                print(body["type"])
                continue
            index, frames = body["index"], body["joints"]  # frames x 22 x [x, y, z], metres
            print(f"frames {index}-{index + len(frames) - 1}, head at {frames[-1][15]}")
            if index >= 40 and not switched:
                await ws.send_json({"prompt": "a person jumps"})
                switched = True
            if index >= 100 and not stopped:
                await ws.send_json({"stop": True})
                stopped = True


asyncio.run(main())
