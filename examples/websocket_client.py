"""A WebSocket client of `mogo serve`: one character streamed, its prompt switched, stopped;
when its server goes away (a crash, a restart, a drain), it reconnects and resumes the same
motion from the first frame it lacks, on that server or any other with the same bundle.

    pip install ".[serve]"
    mogo serve                                   # in another terminal
    python examples/websocket_client.py [ws://127.0.0.1:8765/v1/stream]

The protocol is in docs/serve.md; frames come as they are made, each a list of 22 joints
[x, y, z]. It asks for low latency, as a game character would: a switch shows in the frames
after a few tenths of a second, not two seconds (the default bundle has that decoder; a bundle
without one refuses it, and centred streams come in bursts of 8).
"""

import asyncio
import json
import sys

import aiohttp

URL = sys.argv[1] if len(sys.argv) > 1 else "ws://127.0.0.1:8765/v1/stream"  # the default
RETRY_SECONDS = 1.0  # between reconnections
RETRIES = 30  # reconnections in a row that may fail before the client gives up


class Resumable:
    """The latest state this client can resume from: the server sends states (every few
    seconds, after a switch, before it stops) that may run ahead of the frames received;
    one is usable once every frame before its own has come."""

    def __init__(self):
        self.next_frame = 0  # the first frame not received
        self.states: list[dict] = []

    def frames(self, index: int, count: int) -> None:
        self.next_frame = index + count

    def offered(self, message: dict) -> None:
        self.states.append(message)

    def first_message(self, start: dict) -> dict:
        usable = [s for s in self.states if s["frame"] <= self.next_frame]
        if not usable:
            return start
        self.states = [usable[-1]] + [s for s in self.states if s["frame"] > self.next_frame]
        return {"resume": usable[-1]["state"], "from": self.next_frame}


async def main() -> None:
    resumable, switched, stopped, failures = Resumable(), False, False, 0
    async with aiohttp.ClientSession() as session:
        while not stopped:
            try:
                async with session.ws_connect(URL) as ws:
                    failures = 0
                    await ws.send_json(
                        resumable.first_message(
                            {"prompt": "a person walks forward", "seed": 1, "low_latency": True}
                        )
                    )
                    async for message in ws:  # ends when the server closes the socket
                        body = json.loads(message.data)
                        if body["type"] == "error":
                            sys.exit(f"server: {body['error']}")
                        if body["type"] in ("state", "drain"):
                            resumable.offered(body)
                            continue
                        if body["type"] != "frames":
                            print(body["type"])
                            continue
                        index, frames = body["index"], body["joints"]  # frames x 22 x [x, y, z]
                        resumable.frames(index, len(frames))
                        print(f"frames {index}-{index + len(frames) - 1}, head at {frames[-1][15]}")
                        if index >= 40 and not switched:
                            await ws.send_json({"prompt": "a person jumps"})
                            switched = True
                        if index >= 100 and not stopped:
                            await ws.send_json({"stop": True})
                            stopped = True
            except aiohttp.ClientError as error:
                failures += 1
                if failures > RETRIES:
                    sys.exit(f"cannot reach {URL}: {error}")
            if not stopped:
                print("reconnecting")
                await asyncio.sleep(RETRY_SECONDS)


asyncio.run(main())
