"""The `serve` verb (an entry point of "mogo.commands"): importable without the serve extra,
so that `mogo --help` lists it and `mogo serve` says how to install what it needs."""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import logging
import multiprocessing
import os
import signal
import socket
import sys
import time
from urllib.parse import urlsplit

from mogo.cli import CliError, load_generator, needs_extra
from mogo.cli_flags import add_bundle, add_threads
from mogo.serve.protocol import STATE_EVERY_SECONDS

TOKEN_VARIABLE = "MOGO_SERVE_TOKEN"
RESERVED_DESCRIPTORS = 64  # file descriptors kept for the process itself (graphs, logs)


def add_commands(commands) -> None:
    serve = commands.add_parser(
        "serve",
        help="a local server: many characters streaming at once over WebSocket, a "
        "viewer page, clips over HTTP (needs the serve extra)",
    )
    serve.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only)",
    )
    serve.add_argument("--port", type=int, default=8765, help="port (default 8765)")
    add_bundle(serve)
    add_threads(serve, "cores for the level graphs (default 2 where there are 2 or more)")
    serve.add_argument(
        "--max-streams",
        type=int,
        default=200,
        help="streams at once; more are refused (default 200)",
    )
    serve.add_argument(
        "--allow-origin",
        action="append",
        default=[],
        metavar="ORIGIN",
        help="a web page (scheme://host[:port]) that may use the server beside "
        "its own pages; repeatable; '*' allows every page",
    )
    serve.add_argument(
        "--token",
        help="a secret every request must carry ('Authorization: "
        f"Bearer TOKEN' or ?token=TOKEN); env {TOKEN_VARIABLE}",
    )
    serve.add_argument(
        "--workers",
        type=int,
        default=1,
        help="server processes on the one port (SO_REUSEPORT; Linux), each with its own "
        "model and --max-streams; default 1 (docs/deploy.md: what more gave on 2 cores)",
    )
    serve.add_argument(
        "--state-every",
        type=float,
        default=STATE_EVERY_SECONDS,
        metavar="SECONDS",
        help="send each client its stream's state this often, to resume it on any server "
        f"with the same bundle (default {STATE_EVERY_SECONDS:g}; 0: on request and after "
        "switches only)",
    )
    serve.set_defaults(run=_cmd_serve)


def require_serve_extra() -> None:
    """A clear line instead of an ImportError where the serve extra is missing."""
    if any(importlib.util.find_spec(name) is None for name in ("aiohttp", "onnx", "threadpoolctl")):
        raise CliError(needs_extra("serve", "serve"))


def _cmd_serve(args: argparse.Namespace) -> None:
    require_serve_extra()
    from mogo.serve import server

    if not 1 <= args.port <= 65535:
        raise CliError(f"--port must be between 1 and 65535, got {args.port}")
    if args.max_streams < 1:
        raise CliError(f"--max-streams must be at least 1, got {args.max_streams}")
    token = args.token if args.token is not None else os.environ.get(TOKEN_VARIABLE)
    if token is not None and not token.strip():
        raise CliError(f"--token ({TOKEN_VARIABLE}) must not be empty")
    access = server.Access(args.host, tuple(map(_origin, args.allow_origin)), token)
    if not _is_local(args.host):
        print(
            f"mogo: warning: listening on {args.host}: other machines can reach this server"
            + ("" if token else "; anyone who reaches it can use it (see --token)"),
            file=sys.stderr,
        )
    if not 0 <= args.state_every <= 3600:
        raise CliError(
            f"--state-every must be between 0 and 3600 seconds, got {args.state_every:g}"
        )
    if args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    if args.workers == 1:
        _serve_one(args, access)
        return
    if not hasattr(socket, "SO_REUSEPORT") or not hasattr(os, "fork"):
        raise CliError("--workers needs SO_REUSEPORT and fork (Linux, BSD, macOS)")
    if args.threads is None:  # the cores shared out, at least one each
        args.threads = max(1, min(2, (os.cpu_count() or 1) // args.workers))
    _workers(args, access)


def _serve_one(args: argparse.Namespace, access, ready=None) -> None:
    """One server process; `ready`: a worker's event, set once it listens (the port shared)."""
    from mogo.serve import server

    app = server.make_app(
        load_generator(args),
        args.threads or 2,
        args.max_streams,
        access=access,
        state_every=args.state_every,
    )
    asyncio.run(_serve(app, args.host, args.port, _connections(args.max_streams), ready))


def _workers(args: argparse.Namespace, access) -> None:
    """`--workers N`: N forked server processes on one port; this one waits, says when all
    listen, passes SIGINT, SIGTERM and SIGHUP on (each drains) and exits when they have."""
    context = multiprocessing.get_context("fork")  # before any model or thread exists here
    ready = [context.Event() for _ in range(args.workers)]
    workers = [
        context.Process(target=_worker, args=(args, access, event), name=f"mogo-serve-{k}")
        for k, event in enumerate(ready)
    ]
    for worker in workers:
        worker.start()
    stopping = []

    def stop(number, _frame) -> None:
        stopping.append(number)
        for worker in workers:
            if worker.exitcode is None:
                os.kill(worker.pid, number)

    for number in _STOP_SIGNALS:
        signal.signal(number, stop)
    told = False
    while any(worker.exitcode is None for worker in workers):
        if not told and all(event.is_set() for event in ready):
            told = True
            _banner(_address(args.host, args.port), f" ({args.workers} workers)")
        failed = [w.exitcode for w in workers if w.exitcode not in (None, 0)]
        if failed and not stopping:
            stop(signal.SIGTERM, None)
            for worker in workers:
                worker.join()
            raise CliError(f"a worker stopped (status {failed[0]}); the others were stopped")
        time.sleep(0.1)


def _worker(args: argparse.Namespace, access, ready) -> None:
    try:
        _serve_one(args, access, ready)
    except CliError as error:
        print(f"mogo: error: {error}", file=sys.stderr, flush=True)
        sys.exit(2)


_STOP_SIGNALS = [
    number
    for number in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None))
    if number is not None
]


def _address(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def _banner(address: str, more: str = "") -> None:
    print(
        f"mogo serve: http://{address}/ (viewer), ws://{address}/v1/stream{more}; Ctrl-C stops",
        file=sys.stderr,
        flush=True,
    )


async def _serve(app, host: str, port: int, connections: int, ready=None) -> None:
    """Listen, then say so (a worker: sets `ready`); serve until SIGINT, SIGTERM or SIGHUP,
    then drain: every client gets its stream's state to resume elsewhere (docs/deploy.md),
    every socket is closed."""
    from mogo.serve import server

    address = _address(host, port)
    try:
        runner, listener = await server.listen(app, host, port, connections, ready is not None)
    except OSError as error:
        raise CliError(f"cannot listen on {address}: {error.strerror or error}") from None
    _quiet_logs(server.QuietLog())
    stopping = asyncio.Event()
    for number in _STOP_SIGNALS:
        try:
            asyncio.get_running_loop().add_signal_handler(number, stopping.set)
        except NotImplementedError:  # Windows: Ctrl-C cancels
            pass
    if ready is None:
        _banner(address)
    else:
        ready.set()
    try:
        await stopping.wait()
        listener.close()  # new connections go elsewhere at once (a proxy retries them)
        await app[server.SERVER].drain()
    finally:
        await server.stop(runner, listener)


def _quiet_logs(quiet) -> None:
    """The server's log lines (aiohttp's, asyncio's, ours) on stderr, rate-limited."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("mogo serve: %(message)s"))
    handler.addFilter(quiet)
    logging.getLogger().addHandler(handler)


def _connections(max_streams: int) -> int:
    """How many connections the server keeps open at once: every stream and some spare,
    within the descriptors the system allows (the soft limit raised where it is lower)."""
    from mogo.serve.server import SPARE_CONNECTIONS

    wanted = max_streams + SPARE_CONNECTIONS
    try:
        import resource
    except ImportError:  # Windows: no such limit to raise
        return wanted
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    needed = wanted + RESERVED_DESCRIPTORS
    if soft != resource.RLIM_INFINITY and soft < needed:
        soft = needed if hard == resource.RLIM_INFINITY else min(hard, needed)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    if soft == resource.RLIM_INFINITY:
        return wanted
    return max(1, min(wanted, soft - RESERVED_DESCRIPTORS))


def _origin(text: str) -> str:
    """An --allow-origin: '*' or scheme://host[:port], as browsers send it."""
    try:
        url = urlsplit(text)
        url.port  # noqa: B018 (a bad port raises)
    except ValueError:
        url = None
    if text != "*" and (
        url is None
        or url.scheme not in ("http", "https")
        or not url.hostname
        or url.path not in ("", "/")
        or url.query
        or url.fragment
    ):
        raise CliError(
            f"--allow-origin takes '*' or scheme://host[:port] (as "
            f"http://localhost:3000), got {text!r}"
        )
    return text


def _is_local(host: str) -> bool:
    """Whether every address `host` names is this machine's loopback (127.1 and localhost
    are; 0.0.0.0 is every interface)."""
    from mogo.serve.server import local

    try:
        addresses = {info[4][0] for info in socket.getaddrinfo(host, None)}
    except (OSError, UnicodeError):
        return False
    return bool(addresses) and all(map(local, addresses))
