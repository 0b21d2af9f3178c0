"""The `serve` verb (an entry point of "mogo.commands"): importable without the serve extra,
so that `mogo --help` lists it and `mogo serve` says how to install what it needs."""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import logging
import os
import signal
import socket
import sys
from urllib.parse import urlsplit

from mogo.cli import CliError, load_generator, needs_extra
from mogo.cli_flags import add_bundle, add_threads

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
    serve.set_defaults(run=_cmd_serve)


def require_serve_extra() -> None:
    """A clear line instead of an ImportError where the serve extra is missing."""
    if any(importlib.util.find_spec(name) is None for name in ("aiohttp", "onnx")):
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
    app = server.make_app(load_generator(args), args.threads or 2, args.max_streams, access=access)
    asyncio.run(_serve(app, args.host, args.port, _connections(args.max_streams)))


async def _serve(app, host: str, port: int, connections: int) -> None:
    """Listen, then say so; serve until SIGINT, SIGTERM or SIGHUP, then close every socket."""
    from mogo.serve import server

    address = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    try:
        runner, listener = await server.listen(app, host, port, connections)
    except OSError as error:
        raise CliError(f"cannot listen on {address}: {error.strerror or error}") from None
    _quiet_logs(server.QuietLog())
    stopping = asyncio.Event()
    for number in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        try:
            asyncio.get_running_loop().add_signal_handler(number, stopping.set)
        except (NotImplementedError, TypeError):  # Windows, or no SIGHUP: Ctrl-C cancels
            pass
    print(
        f"mogo serve: http://{address}/ (viewer), ws://{address}/v1/stream; Ctrl-C stops",
        file=sys.stderr,
        flush=True,
    )
    try:
        await stopping.wait()
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
