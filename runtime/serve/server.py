"""`mogo serve`: the HTTP and WebSocket server (aiohttp) around the Engine.

One thread runs the Engine (every stream's steps, prompt checks, switches), so the event loop
only moves messages. Each client has a bounded queue of outgoing bursts: a client that reads
too slowly loses its oldest bursts (the frame indices then jump), the others are not held up.
"""
from __future__ import annotations

import asyncio
import tempfile
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path

from aiohttp import WSMsgType, web

from mogo.arguments import PromptWarning, UnknownPromptWarning
from mogo.generator import MotionGenerator, _seed
from mogo.serve import protocol
from mogo.serve.engine import Engine, ServedStream

QUEUED_BURSTS = 8  # per client: ~3 s of motion; beyond, the oldest burst is dropped
MAX_WIRE_MESSAGE = 1 << 20  # aiohttp closes the socket (1009) past this; smaller ones get
FORMATS = {"bvh": "text/plain", "npy": "application/octet-stream", "json": "application/json",
           "glb": "model/gltf-binary"}
GENERATE_FIELDS = {"prompt", "seconds", "seed", "format"}


class Server:
    """The app's state: the engine, its thread, the clients."""

    def __init__(self, generator: MotionGenerator, threads: int, max_streams: int,
                 tokens=None):
        self.generator, self.max_streams = generator, max_streams
        self.engine = Engine(generator, threads, tokens)
        self.thread = ThreadPoolExecutor(1, "mogo-engine")
        self.clips = ThreadPoolExecutor(1, "mogo-generate")
        self.wake = asyncio.Event()
        self.queues: dict[int, asyncio.Queue] = {}
        self.clock = time.monotonic

    async def run_engine(self) -> None:
        """Step the streams as their clock asks; hand each burst to its client's queue."""
        loop = asyncio.get_running_loop()
        while True:
            out = await loop.run_in_executor(self.thread, self._round)
            if out is None:  # nobody was due: sleep to the next tick, or a new stream
                tick = self.engine.tick(self.clock())
                delay = max(0.0, (tick + 1) / self.engine.fps - self.clock())
                self.wake.clear()
                try:
                    await asyncio.wait_for(self.wake.wait(), delay)
                except asyncio.TimeoutError:
                    pass
                continue
            for stream, first, joints in out:
                self.deliver(stream.id, first, joints)

    def deliver(self, stream_id: int, first: int, joints) -> None:
        """Queue a burst for its client; a full queue (a slow client) loses its oldest."""
        queue = self.queues.get(stream_id)
        if queue is not None:
            if queue.full():
                queue.get_nowait()
            queue.put_nowait((first, joints))

    def _round(self):
        due = self.engine.due(self.clock())
        return self.engine.round(due) if due else None

    async def call(self, function, *args):
        """Run on the engine's thread, between rounds."""
        return await asyncio.get_running_loop().run_in_executor(self.thread, function, *args)

    def checked_prompt(self, prompt: str) -> tuple[str, list[str]]:
        """A prompt the model can read, and notes for words it cannot and for the known
        caption it is played as; ProtocolError else."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", PromptWarning)
            warnings.simplefilter("error", UnknownPromptWarning)
            try:
                text = self.generator._prompt(prompt, "prompt")
            except (TypeError, ValueError, UnknownPromptWarning) as error:
                raise protocol.ProtocolError(str(error)) from None
        notes = [str(w.message) for w in caught if issubclass(w.category, PromptWarning)]
        if (known := self.generator.known(text)) is not None and known.played_note:
            notes.append(known.played_note)
        return text, notes

    def open(self, start: protocol.Start) -> tuple[ServedStream, list[str]]:
        if len(self.engine.streams) >= self.max_streams:
            raise protocol.ServerFull(f"the server is full: {self.max_streams} streams "
                                         "(mogo serve --max-streams); try again later")
        text, notes = self.checked_prompt(start.prompt)
        try:
            sampling = self.generator.sampling(None, **start.options)
        except (TypeError, ValueError) as error:
            raise protocol.ProtocolError(str(error)) from None
        seed = _seed(start.seed)
        return self.engine.open(text, seed, sampling, self.clock(), start.plant_feet), notes

    def switch(self, stream: ServedStream, prompt: str) -> list[str]:
        text, notes = self.checked_prompt(prompt)
        self.engine.switch(stream, text)
        return notes


async def stream_socket(request: web.Request) -> web.WebSocketResponse:
    server: Server = request.app[SERVER]
    ws = web.WebSocketResponse(max_msg_size=MAX_WIRE_MESSAGE, heartbeat=20)
    await ws.prepare(request)
    stream, sender = None, None
    try:
        async for message in ws:
            if message.type in (WSMsgType.ERROR, WSMsgType.CLOSE):
                break
            try:
                body = protocol.read(message.data if message.type == WSMsgType.TEXT else b"")
                if stream is None:
                    start = protocol.start(body)
                    stream, notes = await server.call(server.open, start)
                    queue = server.queues[stream.id] = asyncio.Queue(QUEUED_BURSTS)
                    skeleton = server.generator.skeleton
                    await ws.send_str(protocol.started(stream.id, stream.seed, server.engine.fps,
                                                       skeleton.joint_names, skeleton.parents))
                    sender = asyncio.create_task(_send(ws, queue, start.binary))
                    server.wake.set()
                else:
                    prompt = protocol.later(body)
                    if prompt is None:
                        break
                    notes = await server.call(server.switch, stream, prompt)
                    await ws.send_str(protocol.switched(prompt))
                for note in notes:
                    await ws.send_str(protocol.note(note))
            except protocol.ProtocolError as error:
                await ws.send_str(protocol.error(str(error)))
                if isinstance(error, protocol.ServerFull):
                    break
    finally:
        if stream is not None:
            server.queues.pop(stream.id, None)
            await server.call(server.engine.close, stream)
        if sender is not None:
            sender.cancel()
        await ws.close()
    return ws


async def _send(ws: web.WebSocketResponse, queue: asyncio.Queue, binary: bool) -> None:
    while True:
        first, joints = await queue.get()
        data = protocol.frames(first, joints, binary)
        await (ws.send_bytes(data) if binary else ws.send_str(data))


async def health(request: web.Request) -> web.Response:
    server: Server = request.app[SERVER]
    return web.json_response({"status": "ok", "streams": len(server.engine.streams),
                              "max_streams": server.max_streams,
                              "bundle": server.generator.bundle.root.name})


async def viewer(request: web.Request) -> web.Response:
    page = resources.files("mogo.serve").joinpath("viewer/index.html").read_text("utf-8")
    return web.Response(text=page, content_type="text/html")


async def generate(request: web.Request) -> web.Response:
    """POST {prompt, seconds, seed, format} -> the file."""
    server: Server = request.app[SERVER]
    try:
        body = protocol.read(await request.text())
        protocol.known(body, GENERATE_FIELDS)
        fmt = body.get("format", "bvh")
        if fmt not in FORMATS:
            raise protocol.ProtocolError(f'"format" must be one of {", ".join(FORMATS)}, '
                                         f"got {fmt!r}")
        prompt, _ = await server.call(server.checked_prompt, body.get("prompt"))
        data = await asyncio.get_running_loop().run_in_executor(
            server.clips, _clip_file, server.generator, prompt, body.get("seconds"),
            body.get("seed"), fmt)
    except (protocol.ProtocolError, TypeError, ValueError) as error:
        return web.json_response({"type": "error", "error": str(error)}, status=400)
    return web.Response(body=data, content_type=FORMATS[fmt])


def _clip_file(generator: MotionGenerator, prompt: str, seconds, seed, fmt: str) -> bytes:
    save = getattr(generator.generate(prompt, seconds=seconds, seed=seed), f"save_{fmt}")
    with tempfile.TemporaryDirectory() as folder:
        return Path(save(Path(folder) / f"motion.{fmt}")).read_bytes()


SERVER = web.AppKey("server", Server)


def make_app(generator: MotionGenerator, threads: int = 1, max_streams: int = 200,
             tokens=None) -> web.Application:
    """The server's app; `tokens`: level graphs already made row-wise (tests share them)."""
    app = web.Application(client_max_size=64 * 1024)
    app[SERVER] = server = Server(generator, threads, max_streams, tokens)
    app.router.add_get("/", viewer)
    app.router.add_get("/v1/health", health)
    app.router.add_post("/v1/generate", generate)
    app.router.add_get("/v1/stream", stream_socket)

    async def engine_task(app):
        task = asyncio.create_task(server.run_engine())
        yield
        task.cancel()
        server.thread.shutdown(wait=False, cancel_futures=True)
        server.engine.shutdown()
        server.clips.shutdown(wait=False, cancel_futures=True)

    app.cleanup_ctx.append(engine_task)
    return app
