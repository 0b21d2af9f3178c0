"""`mogo bench WHAT`, the measuring side: latency (torch for the step tables), quick, serve,
deploy, long-streams, eval and real-motion (runtime only). mogo.cli adds them through the
"mogo.commands" entry point; the verbs they were before still run for a release."""

from __future__ import annotations

import argparse
from pathlib import Path

from mogo.cli import CliError, require_torch
from mogo.cli_flags import (
    OldSpelling,
    add_bundle,
    add_bundle_argument,
    add_out,
    add_threads,
)


def _cmd_quick(args: argparse.Namespace) -> None:
    from mogo.bench.speed.quick import main  # the runtime alone: no torch

    main(args.bundle, args.threads)


def _cmd_latency(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.bench.speed.latency import main_from_args

    main_from_args(args)


def _cmd_bench_serve(args: argparse.Namespace) -> None:
    from mogo.serve.cli import require_serve_extra

    if min(args.clients + args.burst) < 1 or args.seconds <= 0 or args.spread < 0:
        raise CliError("--clients and --burst take numbers >= 1, --seconds > 0, --spread >= 0")
    if args.beside < 0:
        raise CliError(f"--beside must be >= 0 (0: bursts on the idle server), got {args.beside}")
    require_serve_extra()
    if args.both_weights:
        from mogo.serve.rowwise import signed_products_exact

        if not args.engine_only:
            raise CliError("--both-weights goes with --engine-only")
        if not signed_products_exact():
            raise CliError(
                "--both-weights: this CPU's uint8 by int8 products saturate, so the server "
                "keeps uint8 weights here; there is nothing to compare"
            )
    from mogo.bench.speed.serve import main_from_args

    main_from_args(args)


def _cmd_avx2(args: argparse.Namespace) -> None:
    from mogo.bench.speed.avx2_only import Unavailable, run
    from mogo.bench.speed.quick import cpu

    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        raise CliError("mogo bench avx2 needs a command, e.g. mogo bench avx2 mogo bench quick")
    try:
        status = run(command, cpu()[1])
    except Unavailable as why:
        raise CliError(str(why)) from None
    raise SystemExit(status)


def _cmd_deploy(args: argparse.Namespace) -> None:
    from mogo.serve.cli import require_serve_extra

    if min(args.clients + args.workers) < 1 or args.seconds <= 0:
        raise CliError("--clients and --workers take numbers >= 1, --seconds > 0")
    require_serve_extra()
    from mogo.bench.speed.deploy import main_from_args

    main_from_args(args)


def _cmd_eval(args: argparse.Namespace) -> None:
    import json

    from mogo.bench.quality.evaluate import EvalOptions, evaluate, format_table

    options = EvalOptions(
        args.bundle,
        Path(args.data),
        Path(args.evaluator),
        args.limit,
        args.repeats,
        args.seed,
        args.mm_captions,
        args.mm_generations,
        args.regenerate,
        args.threads,
    )
    result = evaluate(options)
    print(format_table(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
        print(f"wrote {args.json}")


def _cmd_real_motion(args: argparse.Namespace) -> None:
    from mogo.bench.quality.real_motion import run

    run(args.bundle, Path(args.out), Path(args.cache))


def _cmd_long_streams(args: argparse.Namespace) -> None:
    from mogo.bench.long_streams import MODES, PATHS, main
    from mogo.bench.quality.stream_checks import REPERTOIRE

    if not set(args.modes) <= set(MODES):
        raise CliError(f"--modes: choose from {', '.join(MODES)}, got {' '.join(args.modes)}")
    if not set(args.path) <= set(PATHS):
        raise CliError(f"--path: choose from {', '.join(PATHS)}, got {' '.join(args.path)}")
    names = [a.name for a in REPERTOIRE]
    if unknown := [a for a in args.actions or () if a not in names]:
        raise CliError(f"--actions: no action {unknown[0]!r}; choose from {', '.join(names)}")
    if args.switches < 0:
        raise CliError(f"--switches must be >= 0 (0: none), got {args.switches}")
    if args.one_offs < 0:
        raise CliError(f"--one-offs must be >= 0 (0: none), got {args.one_offs}")
    if "serve" in args.path and not args.tables_from:
        from mogo.serve.cli import require_serve_extra

        require_serve_extra()
    if args.low_latency and not args.tables_from:
        _require_low_latency(args)
    main(args)


def _require_low_latency(args: argparse.Namespace) -> None:
    """--low-latency runs MotionStream's and served tasks again with the bundle's low-latency
    decoder."""
    from mogo.bench.long_streams import LOW_LATENCY
    from mogo.bundle import read_manifest
    from mogo.generator import DEFAULT_BUNDLE

    if not set(args.path) & set(LOW_LATENCY):
        raise CliError(
            "--low-latency runs the stream and serve paths again: add --path stream or serve"
        )
    if read_manifest(Path(args.bundle or DEFAULT_BUNDLE)).vq.low_latency_decoder is None:
        raise CliError(
            "--low-latency: this bundle has no low-latency decoder (manifest "
            "vq.low_latency_decoder; `mogo export decoder` adds one)"
        )


OLD_SPELLINGS = [
    OldSpelling("bench", "bench quick", "--quick", drop=True),
    OldSpelling("bench", "bench latency", alone=True),
    OldSpelling("bench-serve", "bench serve"),
    OldSpelling("long-streams", "bench long-streams"),
    OldSpelling("eval", "bench eval"),
    OldSpelling("real-motion", "bench real-motion"),
]


def add_commands(commands) -> list[OldSpelling]:
    """Adds `mogo bench WHAT` to the `mogo` parser's subcommands; returns the old spellings."""
    bench = commands.add_parser(
        "bench", help="measurements: speed, serving, long streams, quality (docs/performance.md)"
    )
    whats = bench.add_subparsers(dest="bench_command", required=True, metavar="WHAT")
    for name, arguments, run, what in WHATS:
        command = whats.add_parser(name, help=what)
        arguments(command)
        command.set_defaults(run=run)
    return OLD_SPELLINGS


def _latency_arguments(bench: argparse.ArgumentParser) -> None:
    add_bundle(bench)
    add_out(bench, "folder for bench.json and the plots", default="bench_out")
    bench.add_argument(
        "--work",
        default=str(Path.home() / ".cache" / "mogo" / "bench"),
        help="where the exported random-weight models are kept between runs",
    )
    add_threads(bench, "thread counts (default 1 2)", nargs="+")
    bench.add_argument(
        "--lengths",
        type=int,
        nargs="+",
        help="KV cache lengths of the step tables (default 1 10 50 100 200)",
    )
    bench.add_argument("--long-steps", type=int, help="steps of the long stream (default 10000)")
    bench.add_argument(
        "--no-paper",
        action="store_true",
        help="skip the paper-size model (its first export takes minutes)",
    )
    bench.add_argument(
        "--smoke",
        action="store_true",
        help="a smoke run: tiny model, few lengths and rounds (for tests)",
    )


def _avx2_arguments(avx2: argparse.ArgumentParser) -> None:
    avx2.add_argument(
        "command",
        nargs=argparse.REMAINDER,
        help="the command and its arguments, e.g. mogo bench serve --engine-only",
    )


def _quick_arguments(quick: argparse.ArgumentParser) -> None:
    add_bundle(quick)
    add_threads(quick, "thread counts (default 1 2)", nargs="+")


def _serve_arguments(serve: argparse.ArgumentParser) -> None:
    serve.add_argument(
        "--clients",
        type=int,
        nargs="+",
        default=[1, 10, 25, 50, 75, 100],
        help="client counts to try (default 1 10 25 50 75 100)",
    )
    serve.add_argument(
        "--burst",
        type=int,
        nargs="+",
        default=[1, 10, 50],
        help="clients connecting at once to the idle server, for the first-frame "
        "latency of each burst size (default 1 10 50)",
    )
    serve.add_argument(
        "--beside",
        type=int,
        default=0,
        metavar="N",
        help="each burst while N clients stream (arrived over 2 s, settled 3 s), and their "
        "p99 lateness after it (default 0: the idle server)",
    )
    serve.add_argument(
        "--seconds", type=float, default=15.0, help="how long each count streams (default 15)"
    )
    serve.add_argument(
        "--spread",
        type=float,
        default=2.0,
        help="the clients of a count arrive evenly over this many seconds (default 2)",
    )
    add_threads(serve, "the server's --threads (default its own)")
    add_bundle(serve)
    add_out(serve, "folder for serve_bench.json and serve_bench.png", default="bench_out")
    _engine_arguments(serve)
    serve.add_argument(
        "--json",
        action="store_true",
        help="the clients take JSON frames instead of binary ones (the "
        'protocol\'s "binary": false)',
    )
    serve.add_argument(
        "--low-latency",
        action="store_true",
        help="also clients that ask for the bundle's low-latency decoder, each burst and "
        "count in turn with the centred one (with --engine-only: both; with --profile: "
        "low-latency streams)",
    )


def _engine_arguments(serve: argparse.ArgumentParser) -> None:
    """bench serve's runs with no server: the engine alone."""
    serve.add_argument(
        "--engine-only",
        action="store_true",
        help="no server: the engine's CPU per stream step and wall per tick for "
        "each --clients, and one stream's first frame (serve_engine.json)",
    )
    serve.add_argument(
        "--both-weights",
        action="store_true",
        help="with --engine-only: each count with the level graphs' int8 weights, then with "
        "uint8 ones (where this CPU multiplies uint8 by int8 exactly)",
    )
    serve.add_argument(
        "--profile",
        type=int,
        metavar="N",
        help="no server: where the CPU of a stream step goes, N streams past "
        "warm-up, one thread, cProfile (a table)",
    )


def _deploy_arguments(deploy: argparse.ArgumentParser) -> None:
    deploy.add_argument(
        "--workers", type=int, nargs="+", default=[1, 2], help="worker counts (default 1 2)"
    )
    deploy.add_argument(
        "--clients",
        type=int,
        nargs="+",
        default=[4, 8, 12, 16, 24],
        help="client counts for each worker count (default 4 8 12 16 24)",
    )
    deploy.add_argument(
        "--seconds", type=float, default=10.0, help="how long each count streams (default 10)"
    )
    add_out(deploy, "folder for deploy_bench.json", default="bench_out")


def _long_streams_arguments(streams: argparse.ArgumentParser) -> None:
    add_bundle(streams)
    add_out(streams, "folder for long_streams.md, .json and .png", default="bench_out")
    streams.add_argument("--minutes", type=float, default=10.0, help="length of each stream")
    streams.add_argument("--seeds", type=int, default=2, help="streams per action and mode")
    streams.add_argument(
        "--switches",
        type=int,
        default=30,
        help="prompt switches per seed and mode (one every 10 s; 0: none)",
    )
    streams.add_argument(
        "--modes",
        nargs="+",
        default=["off", "on"],
        help="re-anchoring off (before) and/or on (default both)",
    )
    streams.add_argument(
        "--path",
        nargs="+",
        default=["stream"],
        help="the ways of making motion to run: MotionStream (in each --modes), generate of "
        "the whole length, play schedules, continue_from a clip, mogo serve over WebSockets "
        "(default stream)",
    )
    streams.add_argument(
        "--one-offs",
        type=int,
        default=2,
        help="seeds per one-off action played after a 5-s walk (a switch, or continue_from "
        "a walk clip; 0: none)",
    )
    streams.add_argument(
        "--jobs", type=int, default=2, help="streams run in parallel (served ones: all at once)"
    )
    streams.add_argument(
        "--actions",
        nargs="+",
        metavar="NAME",
        help="only these actions of the repertoire (default all; e.g. 'jog forward' spin)",
    )
    streams.add_argument(
        "--tables-from",
        nargs="+",
        metavar="JSON",
        help="no streams: the tables and plot of saved runs (long_streams.json), merged",
    )
    streams.add_argument(
        "--quick",
        action="store_true",
        help="a smoke run: two actions, 20-s streams, one seed, one switch",
    )
    streams.add_argument(
        "--low-latency",
        action="store_true",
        help="the stream and serve paths again with the bundle's low-latency decoder: columns "
        "of their own, and the switch as received beside the centred decoder's",
    )


def _eval_arguments(evaluation: argparse.ArgumentParser) -> None:
    add_bundle_argument(evaluation)
    evaluation.add_argument("--data", required=True, help="dataset folder with test.txt")
    evaluation.add_argument(
        "--evaluator",
        required=True,
        help="evaluator folder (RUN/evaluator of `mogo train evaluator`)",
    )
    evaluation.add_argument(
        "--limit",
        type=int,
        help="a fixed random sample of this many test caption spans (default: all; at least 32)",
    )
    evaluation.add_argument("--repeats", type=int, default=20)
    evaluation.add_argument("--seed", type=int, default=0)
    evaluation.add_argument(
        "--mm-captions",
        type=int,
        default=10,
        help="captions for MultiModality (protocol: 100; 0 = skip)",
    )
    evaluation.add_argument(
        "--mm-generations", type=int, default=30, help="generations per MultiModality caption"
    )
    evaluation.add_argument(
        "--regenerate",
        action="store_true",
        help="generate anew in every repeat (the full protocol; repeats x the generation time)",
    )
    add_threads(evaluation, "clips generated in parallel", default=1)
    evaluation.add_argument("--json", help="also write the numbers to this file")


def _real_motion_arguments(real: argparse.ArgumentParser) -> None:
    add_bundle_argument(real)
    add_out(real, "folder for the GIFs, contact sheet and table", default="real_motion")
    real.add_argument(
        "--cache",
        default=str(Path.home() / ".cache" / "mogo" / "pybullet"),
        help="where the pybullet wheel is kept between runs",
    )


WHATS = (  # name, its arguments, what runs it, its help line
    (
        "latency",
        _latency_arguments,
        _cmd_latency,
        "the bundle through the runtime, and one step of the bundle-size and paper-size "
        "models on onnxruntime fp32/int8 and torch eager",
    ),
    (
        "quick",
        _quick_arguments,
        _cmd_quick,
        "under a minute, no torch: this machine's CPU features, first frame, 9.8-s clip "
        "and token step beside the README's",
    ),
    (
        "serve",
        _serve_arguments,
        _cmd_bench_serve,
        "how many characters `mogo serve` streams in real time: N WebSocket clients at "
        "once, frame rate, lateness, CPU",
    ),
    (
        "deploy",
        _deploy_arguments,
        _cmd_deploy,
        "the cost of resuming a stream (docs/deploy.md), and characters in real time "
        "against `mogo serve --workers`",
    ),
    (
        "avx2",
        _avx2_arguments,
        _cmd_avx2,
        "run a command as on a CPU with AVX2 but no AVX-512, AVX-VNNI or AMX (onnxruntime's "
        "and numpy's AVX2 kernels; Linux x86-64 with CPUID faulting, and a C compiler)",
    ),
    (
        "long-streams",
        _long_streams_arguments,
        _cmd_long_streams,
        "do long streams keep doing what they were asked? every action of the "
        "repertoire on each path (MotionStream with re-anchoring off and on, generate, "
        "play, continue_from, serve; no torch)",
    ),
    (
        "eval",
        _eval_arguments,
        _cmd_eval,
        "a bundle's quality on a test split: R-precision, FID, MM-Dist, Diversity, "
        "MultiModality (no torch)",
    ),
    (
        "real-motion",
        _real_motion_arguments,
        _cmd_real_motion,
        "the bundle's VQ on real human motion: pybullet's 20 DeepMimic clips (its wheel "
        "fetched by pip into a cache, never installed), MPJPE per clip split into pose "
        "and trajectory, GIFs and a contact sheet",
    ),
)
