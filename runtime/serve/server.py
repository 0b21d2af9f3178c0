"""`mogo serve`: the HTTP and WebSocket server (aiohttp) around the Engine.

One thread runs the Engine (every stream's steps, prompt checks, switches), so the event loop
only moves messages. Each client has a bounded queue of outgoing bursts: a client that reads
too slowly loses its oldest bursts (the frame indices then jump), the others are not held up.
Whole clips run on a pool of their own, a bounded queue in front of it. What the server
trusts and refuses (Host, Origin, token, limits): docs/security.md.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import logging
import tempfile
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from urllib.parse import urlsplit

from aiohttp import WSCloseCode, WSMsgType, web

from mogo.arguments import PromptWarning, UnknownPromptWarning
from mogo.generator import MotionGenerator, checked_seed
from mogo.sampling import Sampling
from mogo.serve import protocol
from mogo.serve.engine import Engine, ServedStream
from mogo.stream_state import StateError
from mogo.stream_state import read as read_state

QUEUED_BURSTS = 8  # per client: ~3 s of motion; beyond, the oldest burst is dropped
MAX_WIRE_MESSAGE = 1 << 20  # aiohttp closes the socket (1009) past this; smaller ones get
SWITCHES_PER_SECOND, SWITCH_BURST = 2, 4  # per socket; more get an error, not a switch
QUEUED_CLIPS = 8  # clip requests waiting beyond the running ones; more get 503
REQUEST_SECONDS = 10.0  # for a request's headers, a clip's body, a socket's first stream
KEEPALIVE_SECONDS = 15.0  # an idle keep-alive connection is closed after this
SHUTDOWN_SECONDS = 2.0  # on SIGINT/SIGTERM, what a request in flight gets to finish
SPARE_CONNECTIONS = 64  # connections beyond --max-streams (clips, health, the viewer)
LOG_EVERY_SECONDS = 10.0  # one log line of a kind per this, at most (no log floods)
LOCAL_NAMES = {"localhost"}  # with every loopback address
RESUME_AHEAD_SECONDS = 30.0  # a resume's "from" at most this far past its state
DRAIN_SECONDS = 5.0  # on SIGTERM: what the clients get to read their states and go


@dataclass(frozen=True)
class Opening:
    """A start message's stream, read: its prompt as the model reads it, sampling, seed."""

    text: str
    sampling: Sampling
    seed: int


@dataclass(frozen=True)
class Access:
    """Who may use the server. `host`: the address it listens on; `origins`: web pages
    allowed beside its own (--allow-origin; "*" for any); `token`: asked of every request
    but the viewer page when given (--token)."""

    host: str = "127.0.0.1"
    origins: tuple[str, ...] = ()
    token: str | None = None

    def refusal(self, request: web.Request) -> tuple[int, str] | None:
        """(HTTP status, why) for a request it refuses, None for one it serves."""
        if not (wildcard(self.host) or self._our_host(request.host)):
            return 403, (
                f"Host {request.host!r} is not this server (a web page's DNS "
                "rebinding?); use http://127.0.0.1 or http://localhost"
            )
        origin = request.headers.get("Origin")
        if origin is not None and not self._allowed(origin, request):
            return 403, (
                f"web pages from {origin!r} may not use this server; start it with "
                f"--allow-origin {origin} to allow them"
            )
        if self.token is not None and request.path != "/" and not self._has_token(request):
            return 401, (
                "this server needs its token: send the header 'Authorization: "
                "Bearer TOKEN' or add ?token=TOKEN to the URL"
            )
        return None

    def _our_host(self, host: str) -> bool:
        try:
            name = urlsplit(f"http://{host}").hostname or ""
        except ValueError:
            return False
        return name == self.host.lower().strip("[]") or local(name)

    def _allowed(self, origin: str, request: web.Request) -> bool:
        origin = origin.rstrip("/").lower()
        if "*" in self.origins or origin in (o.rstrip("/").lower() for o in self.origins):
            return True
        try:
            url = urlsplit(origin)
            port = url.port or {"http": 80, "https": 443}.get(url.scheme)
        except ValueError:
            return False
        sockname = request.transport.get_extra_info("sockname") if request.transport else None
        bound_port = sockname[1] if sockname else None
        same = url.netloc == request.host.lower()  # the page is one the server gave
        return url.scheme in ("http", "https") and (
            same or (local(url.hostname or "") and port == bound_port)
        )

    def _has_token(self, request: web.Request) -> bool:
        header = request.headers.get("Authorization", "")
        given = header[7:] if header[:7].lower() == "bearer " else request.query.get("token", "")
        return hmac.compare_digest(given.encode(), self.token.encode())


def local(host: str) -> bool:
    """localhost or a loopback address, written as a URL or an address (127.1, [::1])."""
    host = host.strip("[]").lower()
    if host in LOCAL_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def wildcard(host: str) -> bool:
    """An address that listens on every interface (0.0.0.0, ::): any Host may be asked for."""
    try:
        return ipaddress.ip_address(host.strip("[]")).is_unspecified
    except ValueError:
        return host == ""


class Rate:
    """At most `per_second` events a second, `burst` at once (a token bucket)."""

    def __init__(self, per_second: float, burst: float, clock=time.monotonic):
        self.per_second, self.burst, self.clock = per_second, burst, clock
        self.tokens, self.last = burst, clock()

    def take(self) -> bool:
        now = self.clock()
        self.tokens = min(self.burst, self.tokens + (now - self.last) * self.per_second)
        self.last = now
        if self.tokens < 1:
            return False
        self.tokens -= 1
        return True


class Server:
    """The app's state: the engine, its thread, the clients, the clip pool."""

    def __init__(
        self,
        generator: MotionGenerator,
        threads: int,
        max_streams: int,
        tokens=None,
        access: Access = Access(),
        state_every: float = protocol.STATE_EVERY_SECONDS,
    ):
        self.generator, self.max_streams, self.access = generator, max_streams, access
        self.state_every = state_every  # 0: states only on request and after switches
        self.draining = False
        self.engine = Engine(generator, threads, tokens)
        self.thread = ThreadPoolExecutor(1, "mogo-engine")
        self.clip_workers = threads
        self.clips = ThreadPoolExecutor(threads, "mogo-generate")
        self.restores = ThreadPoolExecutor(1, "mogo-resume")  # resumed streams' caches
        # prompts read (a new one's text graphs: ~10 ms) off the engine's thread, which would
        # hold every stream meanwhile; one at a time, since catch_warnings is process-wide
        self.prompts = ThreadPoolExecutor(1, "mogo-prompt")
        self.clip_jobs = 0  # running and waiting
        self.wake = asyncio.Event()
        self.queues: dict[int, asyncio.Queue] = {}
        self.sockets: set[web.WebSocketResponse] = set()
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
                skip = stream.send_from - first  # a resume's client has these already
                if skip < len(joints):
                    self.deliver(stream.id, first + max(0, skip), joints[max(0, skip) :])

    def deliver(self, stream_id: int, first: int | None, joints) -> None:
        """Queue a burst for its client; a full queue (a slow client) loses its oldest.
        first=None: `joints` is a message's text (a state), or None: close the socket."""
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

    async def reading(self, function, *args):
        """Run on the prompts' thread: what reads a client's prompt."""
        return await asyncio.get_running_loop().run_in_executor(self.prompts, function, *args)

    def checked_prompt(self, prompt: str) -> tuple[str, list[str]]:
        """A prompt the model can read, and notes for words it cannot and for the known
        caption it is played as; ProtocolError else."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", PromptWarning)
            warnings.simplefilter("error", UnknownPromptWarning)
            try:
                text = self.generator.read_prompt(prompt, "prompt")
            except (TypeError, ValueError, UnknownPromptWarning) as error:
                raise protocol.ProtocolError(str(error)) from None
        notes = [str(w.message) for w in caught if issubclass(w.category, PromptWarning)]
        if (known := self.generator.known(text)) is not None and known.played_note:
            notes.append(known.played_note)
        return text, notes

    def admit(self) -> None:
        """ServerFull for a stream this server does not take now."""
        if self.draining:
            raise protocol.ServerFull("the server is stopping: connect again (to another)")
        if len(self.engine.streams) >= self.max_streams:
            raise protocol.ServerFull(
                f"the server is full: {self.max_streams} streams "
                "(mogo serve --max-streams); try again later"
            )

    def read_start(self, start: protocol.Start) -> tuple[Opening, list[str]]:
        """A start message's prompt, sampling and seed checked (ProtocolError else), and the
        prompt's notes: on the prompts' thread."""
        self.admit()
        text, notes = self.checked_prompt(start.prompt)
        try:
            sampling = self.generator.sampling(None, **start.options)
        except (TypeError, ValueError) as error:
            raise protocol.ProtocolError(str(error)) from None
        return Opening(text, sampling, checked_seed(start.seed)), notes

    def open(self, start: protocol.Start, opening: Opening) -> ServedStream:
        """The stream of a start message read by `read_start`: on the engine's thread."""
        self.admit()  # again: other streams may have come while its prompt was read
        try:
            return self.engine.open(
                opening.text,
                opening.seed,
                opening.sampling,
                self.clock(),
                start.plant_feet,
                start.low_latency,
            )
        except ValueError as error:  # no low-latency decoder
            raise protocol.ProtocolError(str(error)) from None

    async def resume(self, resume: protocol.Resume) -> tuple[ServedStream, list[str]]:
        """A stream going on from a client's state (mogo.stream_state), refused with one
        error where the state is not one this server goes on from. Its cache is made again
        on a thread of its own: the engine goes on stepping the others meanwhile."""
        state, first, notes = await self.reading(self._resumable, resume)
        try:
            stream = await asyncio.get_running_loop().run_in_executor(
                self.restores, self.engine.restore, state
            )
        except StateError as error:
            raise protocol.ProtocolError(str(error)) from None
        await self.call(self._resume, stream, first)
        return stream, notes

    def _resumable(self, resume: protocol.Resume):
        """The state read and checked, the first frame to send, the prompt's notes."""
        self.admit()
        try:
            state = read_state(resume.state, self.generator)
            if state.low_latency and not self.engine.low_latency:
                raise StateError(
                    "the state is of a low-latency stream; this server's bundle has no "
                    "low-latency decoder"
                )
            window = self.generator.defaults.window  # what a resume may replay: bounded
            if state.window is None or state.window > window:
                raise StateError(f"the state's window is larger than this server's ({window})")
            _, notes = self.checked_prompt(state.prompt)
            frame = state.payload["frames"]  # checked by restore, in Engine.restore
            first = frame if resume.first is None else resume.first
            if not isinstance(frame, int) or first > frame + RESUME_AHEAD_SECONDS * self.engine.fps:
                raise StateError(f'"from" is more than {RESUME_AHEAD_SECONDS:g} s past the state')
        except StateError as error:
            raise protocol.ProtocolError(str(error)) from None
        return state, max(first, frame), notes

    def _resume(self, stream: ServedStream, first: int) -> None:
        self.admit()  # again: other streams may have come while its cache was made
        self.engine.resume(stream, self.clock(), first)

    def switch(self, stream: ServedStream, text: str) -> int:
        """The switch to a prompt read by `checked_prompt` played: the first frame that
        follows it."""
        self.engine.switch(stream, text)
        return stream.prompts[-1][0]

    def state(self, stream: ServedStream, drain: bool = False) -> str:
        """The stream's state message (on the engine's thread, between rounds)."""
        return protocol.state(stream.frames_emitted, stream.state(), drain)

    async def offer_state(self, stream: ServedStream) -> None:
        """Queue the stream's state for its client, behind the frames made before it."""
        self.deliver(stream.id, None, await self.call(self.state, stream))

    async def drain(self, seconds: float = DRAIN_SECONDS) -> None:
        """Stop taking streams (health says draining, so a load balancer takes this server
        out), give every client its stream's state and "go elsewhere", close its socket, within
        `seconds`. Every stream then goes on where its client resumes it."""
        self.draining = True
        streams = await self.call(self._stop_all)
        for stream, message in streams:
            self.deliver(stream.id, None, message)
            self.deliver(stream.id, None, None)  # then close
        deadline = time.monotonic() + seconds
        while self.sockets and time.monotonic() < deadline:
            await asyncio.sleep(0.02)

    def _stop_all(self) -> list[tuple[ServedStream, str]]:
        """Every stream's drain message, the streams closed: no round steps them after."""
        out = [(stream, self.state(stream, drain=True)) for stream in self.engine.streams.values()]
        for stream, _ in out:
            self.engine.close(stream)
        return out


async def stream_socket(request: web.Request) -> web.WebSocketResponse:
    server: Server = request.app[SERVER]
    ws = web.WebSocketResponse(max_msg_size=MAX_WIRE_MESSAGE, heartbeat=20)
    await ws.prepare(request)
    server.sockets.add(ws)
    stream, sender = None, None
    switches = Rate(SWITCHES_PER_SECOND, SWITCH_BURST)  # each: a prefill, engine's thread
    loop = asyncio.get_running_loop()
    deadline = loop.time() + REQUEST_SECONDS  # to start a stream
    try:
        while True:
            try:  # a socket that starts nothing would hold a connection for ever
                left = None if stream else max(deadline - loop.time(), 1e-3)  # 0: no timeout
                message = await ws.receive(timeout=left)
            except asyncio.TimeoutError:
                await ws.send_str(protocol.error(f"no stream started within {REQUEST_SECONDS:g} s"))
                break
            if message.type not in (WSMsgType.TEXT, WSMsgType.BINARY):  # closing, an error
                break
            try:
                text = message.data if message.type == WSMsgType.TEXT else b""
                body = protocol.read(text, first=stream is None)
                if stream is None:  # set first: the finally below closes it whatever follows
                    stream, notes, start = await _opened(server, body)
                    sender = await _started(ws, server, stream, start)
                else:
                    prompt = protocol.later(body)
                    if prompt is None:
                        break
                    if prompt == protocol.STATE:
                        await server.offer_state(stream)
                        continue
                    if not switches.take():
                        raise protocol.ProtocolError(
                            f"too many switches: at most {SWITCHES_PER_SECOND} a second "
                            f"({SWITCH_BURST} at once); this one was not played"
                        )
                    text, notes = await server.reading(server.checked_prompt, prompt)
                    index = await server.call(server.switch, stream, text)
                    await ws.send_str(protocol.switched(prompt, index))
                    await server.offer_state(stream)  # a resume then knows of the switch
                for note in notes:
                    await ws.send_str(protocol.note(note))
            except protocol.ProtocolError as error:
                await ws.send_str(protocol.error(str(error)))
                if isinstance(error, protocol.ServerFull):
                    break
    finally:
        server.sockets.discard(ws)
        if stream is not None:
            server.queues.pop(stream.id, None)
            await asyncio.shield(server.call(server.engine.close, stream))
        if sender is not None:
            sender.cancel()
        await ws.close()
    return ws


async def _opened(server: Server, body: dict):
    """A socket's first message: its stream started or resumed; -> the stream, its notes and
    the message read."""
    if "resume" in body:
        start = protocol.resume(body)
        stream, notes = await server.resume(start)
    else:
        start = protocol.start(body)
        opening, notes = await server.reading(server.read_start, start)
        stream = await server.call(server.open, start, opening)
    return stream, notes, start


async def _started(ws: web.WebSocketResponse, server: Server, stream, start) -> asyncio.Task:
    """`started` sent and the stream's frames on their way; -> the task sending them."""
    queue = server.queues[stream.id] = asyncio.Queue(QUEUED_BURSTS)
    skeleton = server.generator.skeleton
    await ws.send_str(
        protocol.started(
            stream.id,
            stream.seed,
            server.engine.fps,
            skeleton.joint_names,
            skeleton.parents,
            stream.send_from,
        )
    )
    sender = asyncio.create_task(_send(ws, queue, start.binary, server, stream))
    server.wake.set()
    return sender


async def _send(
    ws: web.WebSocketResponse,
    queue: asyncio.Queue,
    binary: bool,
    server: Server,
    stream: ServedStream,
) -> None:
    """The client's bursts and messages in order, its stream's state every
    `server.state_every` seconds; after a drain message, the socket closed (1001)."""
    loop = asyncio.get_running_loop()
    offered = loop.time()
    try:
        while True:
            if server.state_every and loop.time() - offered >= server.state_every:
                offered = loop.time()
                if not server.draining:
                    await server.offer_state(stream)
            try:
                wait = server.state_every or None
                first, joints = await asyncio.wait_for(queue.get(), wait)
            except asyncio.TimeoutError:
                continue
            if first is None and joints is None:  # after a drain message
                await ws.close(code=WSCloseCode.GOING_AWAY, message=b"resume elsewhere")
                return
            if first is None:
                await ws.send_str(joints)
                continue
            data = protocol.frames(first, joints, binary)
            await (ws.send_bytes(data) if binary else ws.send_str(data))
    except ConnectionError:  # the client left: its handler closes the stream
        pass


async def health(request: web.Request) -> web.Response:
    server: Server = request.app[SERVER]
    return web.json_response(
        {
            "status": "draining" if server.draining else "ok",
            "streams": len(server.engine.streams),
            "max_streams": server.max_streams,
            "bundle": server.generator.bundle.root.name,
        },
        status=503 if server.draining else 200,  # a load balancer's check takes it out
    )


async def viewer(request: web.Request) -> web.Response:
    page = resources.files("mogo.serve").joinpath("viewer/index.html").read_text("utf-8")
    return web.Response(text=page, content_type="text/html")


async def generate(request: web.Request) -> web.Response:
    """POST {prompt, seconds, seed, format} -> the file. A client that leaves stops its clip."""
    server: Server = request.app[SERVER]
    if request.content_type != "application/json":  # a web page's form post cannot send it
        return _refused(
            415,
            f"POST /v1/generate takes Content-Type: application/json, got {request.content_type!r}",
        )
    try:  # read before it takes a place in the queue: a body dripped slowly holds none
        body = await asyncio.wait_for(request.read(), REQUEST_SECONDS)
        clip = protocol.clip(protocol.body(body, request.charset))
    except asyncio.TimeoutError:
        late = _refused(408, f"the body did not come within {REQUEST_SECONDS:g} s")
        late.force_close()  # what is left of it would be read as the next request
        return late
    except protocol.ProtocolError as error:
        return _refused(400, str(error))
    if server.clip_jobs >= server.clip_workers + QUEUED_CLIPS:
        return _refused(
            503,
            f"busy: {server.clip_jobs} clips are being made or wait; try again later",
            {"Retry-After": "5"},
        )
    server.clip_jobs += 1
    stop = threading.Event()
    try:
        prompt, _ = await server.reading(server.checked_prompt, clip.prompt)
        data = await asyncio.get_running_loop().run_in_executor(
            server.clips, _clip_file, server.generator, prompt, clip, stop
        )
    except (protocol.ProtocolError, TypeError, ValueError) as error:
        return _refused(400, str(error))
    finally:  # on a disconnect too (aiohttp cancels this handler): the clip stops at its next step
        stop.set()
        server.clip_jobs -= 1
    return web.Response(body=data, content_type=protocol.CLIP_FORMATS[clip.format])


def _clip_file(
    generator: MotionGenerator, prompt: str, clip: protocol.Clip, stop: threading.Event
) -> bytes:
    motion = generator.generate(prompt, seconds=clip.seconds, seed=clip.seed, stop=stop)
    with tempfile.TemporaryDirectory() as folder:
        save = getattr(motion, f"save_{clip.format}")
        return Path(save(Path(folder) / f"motion.{clip.format}")).read_bytes()


def _refused(status: int, why: str, headers=None) -> web.Response:
    return web.json_response({"type": "error", "error": why}, status=status, headers=headers)


@web.middleware
async def guard(request: web.Request, handler):
    """Host, Origin and token before any route (docs/security.md)."""
    refusal = request.app[SERVER].access.refusal(request)
    return _refused(*refusal) if refusal else await handler(request)


SERVER = web.AppKey("server", Server)


def make_app(
    generator: MotionGenerator,
    threads: int = 1,
    max_streams: int = 200,
    tokens=None,
    access: Access = Access(),
    state_every: float = protocol.STATE_EVERY_SECONDS,
) -> web.Application:
    """The server's app; `tokens`: level graphs already made row-wise (tests share them)."""
    app = web.Application(client_max_size=64 * 1024, middlewares=[guard])
    app[SERVER] = server = Server(generator, threads, max_streams, tokens, access, state_every)
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
        server.restores.shutdown(wait=False, cancel_futures=True)
        server.prompts.shutdown(wait=False, cancel_futures=True)

    async def close_sockets(app):
        """On SIGINT/SIGTERM: every client gets a close frame (1001, going away), not a 1006."""
        await asyncio.gather(
            *(
                ws.close(code=WSCloseCode.GOING_AWAY, message=b"server stopping")
                for ws in list(server.sockets)
            )
        )

    app.cleanup_ctx.append(engine_task)
    app.on_shutdown.append(close_sockets)
    return app


async def listen(
    app: web.Application, host: str, port: int, max_connections: int, reuse_port: bool = False
) -> tuple[web.AppRunner, asyncio.Server]:
    """Serve `app` on host:port (OSError where it cannot listen): a client's disconnect
    cancels its request, idle and half-sent connections are closed, at most
    `max_connections` are open at once. `reuse_port`: other processes listen on the port
    too (SO_REUSEPORT: the kernel spreads the connections; `mogo serve --workers`)."""
    runner = web.AppRunner(
        app,
        handle_signals=False,
        handler_cancellation=True,
        shutdown_timeout=SHUTDOWN_SECONDS,
        access_log=None,
        keepalive_timeout=KEEPALIVE_SECONDS,
    )
    await runner.setup()
    open_ = set()
    try:
        listener = await asyncio.get_running_loop().create_server(
            lambda: _Guarded(runner.server(), open_, max_connections),
            host,
            port,
            reuse_port=reuse_port or None,
        )
    except BaseException:
        await runner.cleanup()
        raise
    return runner, listener


async def stop(runner: web.AppRunner, listener: asyncio.Server) -> None:
    """Stop listening, close every socket properly, stop the engine and the clips."""
    listener.close()
    await runner.cleanup()


_log = logging.getLogger("mogo.serve")


class _Guarded(asyncio.Protocol):
    """aiohttp's protocol for one connection, behind two checks of its own (slowloris): past
    the cap a new connection is closed at once, and one whose request headers are not
    complete within REQUEST_SECONDS is closed. Everything else passes through."""

    def __init__(self, inner: asyncio.Protocol, open_: set, cap: int):
        self.inner, self.open, self.cap = inner, open_, cap
        self.transport, self.head, self.timer = None, b"", None

    def connection_made(self, transport) -> None:
        if len(self.open) >= self.cap:
            _log.warning(
                "refused a connection: %d are open, the most this server keeps "
                "(--max-streams + %d)",
                len(self.open),
                SPARE_CONNECTIONS,
            )
            transport.abort()
            return
        self.transport = transport
        self.open.add(self)
        self.timer = asyncio.get_running_loop().call_later(REQUEST_SECONDS, transport.abort)
        self.inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        if self.timer is not None:
            self.head = (self.head + data)[-(len(data) + 3) :]  # enough to see b"\r\n\r\n"
            if b"\r\n\r\n" in self.head:
                self.timer.cancel()
                self.timer, self.head = None, b""
        self.inner.data_received(data)

    def eof_received(self):
        return self.inner.eof_received()

    def connection_lost(self, exc) -> None:
        if self.transport is None:  # refused: aiohttp never saw it
            return
        self.open.discard(self)
        if self.timer is not None:
            self.timer.cancel()
        self.inner.connection_lost(exc)

    def pause_writing(self) -> None:
        self.inner.pause_writing()

    def resume_writing(self) -> None:
        self.inner.resume_writing()


class QuietLog(logging.Filter):
    """One record of a kind (logger and message) per LOG_EVERY_SECONDS: a flood of bad
    connections writes a few lines, not megabytes of tracebacks."""

    def __init__(self, clock=time.monotonic):
        super().__init__()
        self.clock, self.rates = clock, {}

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, record.msg)
        rate = self.rates.setdefault(key, Rate(1 / LOG_EVERY_SECONDS, 1, self.clock))
        return rate.take()
