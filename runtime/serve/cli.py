"""The `serve` verb (an entry point of "mogo.commands"): importable without the serve extra,
so that `mogo --help` lists it and `mogo serve` says how to install what it needs."""
from __future__ import annotations

import argparse
import importlib.util
import ipaddress
import sys

from mogo.cli import CliError, _load_generator, needs_extra

LOCAL_HOSTS = {"localhost"}


def add_commands(commands) -> None:
    serve = commands.add_parser(
        "serve", help="a local server: many characters streaming at once over WebSocket, a "
                      "viewer page, clips over HTTP (needs the serve extra)")
    serve.add_argument("--host", default="127.0.0.1",
                       help="address to listen on (default 127.0.0.1: this machine only)")
    serve.add_argument("--port", type=int, default=8765, help="port (default 8765)")
    serve.add_argument("--bundle", help="bundle folder (default: the model shipped with mogo)")
    serve.add_argument("--threads", type=int,
                       help="cores for the level graphs (default 2 where there are 2 or more)")
    serve.add_argument("--max-streams", type=int, default=200,
                       help="streams at once; more are refused (default 200)")
    serve.set_defaults(run=_cmd_serve)


def require_serve_extra() -> None:
    """A clear line instead of an ImportError where the serve extra is missing."""
    if any(importlib.util.find_spec(name) is None for name in ("aiohttp", "onnx")):
        raise CliError(needs_extra("serve", "serve"))


def _cmd_serve(args: argparse.Namespace) -> None:
    require_serve_extra()
    if not 1 <= args.port <= 65535:
        raise CliError(f"--port must be between 1 and 65535, got {args.port}")
    if args.max_streams < 1:
        raise CliError(f"--max-streams must be at least 1, got {args.max_streams}")
    if not _is_local(args.host):
        print(f"mogo: warning: listening on {args.host}: other machines can reach this server; "
              "it has no authentication", file=sys.stderr)
    from aiohttp import web

    from mogo.serve.server import make_app

    app = make_app(_load_generator(args), args.threads or 2, args.max_streams)
    print(f"mogo serve: http://{args.host}:{args.port}/ (viewer), ws://{args.host}:{args.port}"
          "/v1/stream; Ctrl-C stops", file=sys.stderr, flush=True)
    web.run_app(app, host=args.host, port=args.port, print=None, handle_signals=True)


def _is_local(host: str) -> bool:
    if host in LOCAL_HOSTS:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
