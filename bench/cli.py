"""The `mogo` verbs of the measuring side: bench (latency; torch for the step tables), eval
(quality; runtime only) and real-motion (the VQ on real motion capture; runtime only).
mogo.cli adds them through the "mogo.commands" entry point."""
from __future__ import annotations

import argparse
from pathlib import Path

from mogo.cli import require_torch


def _cmd_bench(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.bench.speed.latency import main_from_args

    main_from_args(args)


def _cmd_eval(args: argparse.Namespace) -> None:
    import json

    from mogo.bench.quality.evaluate import EvalOptions, evaluate, format_table

    options = EvalOptions(args.bundle, Path(args.data), Path(args.evaluator), args.limit,
                          args.repeats, args.seed, args.mm_captions, args.mm_generations,
                          args.regenerate, args.threads)
    result = evaluate(options)
    print(format_table(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
        print(f"wrote {args.json}")


def _cmd_real_motion(args: argparse.Namespace) -> None:
    from mogo.bench.quality.real_motion import run

    run(args.bundle, Path(args.out), Path(args.cache))


def add_commands(commands) -> None:
    """Adds bench and eval to the `mogo` parser's subcommands."""
    bench = commands.add_parser(
        "bench", help="latency: the bundle through the runtime, and one step of the bundle-size "
                      "and paper-size models on onnxruntime fp32/int8 and torch eager")
    bench.add_argument("--bundle", help="bundle folder (default: the model shipped with mogo)")
    bench.add_argument("--out", default="bench_out",
                       help="folder for bench.json and the plots (default bench_out/)")
    bench.add_argument("--work", default=str(Path.home() / ".cache" / "mogo" / "bench"),
                       help="where the exported random-weight models are kept between runs")
    bench.add_argument("--threads", type=int, nargs="+", help="thread counts (default 1 2)")
    bench.add_argument("--lengths", type=int, nargs="+",
                       help="KV cache lengths of the step tables (default 1 10 50 100 200)")
    bench.add_argument("--long-steps", type=int, help="steps of the long stream (default 10000)")
    bench.add_argument("--no-paper", action="store_true",
                       help="skip the paper-size model (its first export takes minutes)")
    bench.add_argument("--quick", action="store_true",
                       help="a smoke run: tiny model, few lengths and rounds (for tests)")
    bench.set_defaults(run=_cmd_bench)

    evaluation = commands.add_parser(
        "eval", help="a bundle's quality on a test split: R-precision, FID, MM-Dist, Diversity, "
                     "MultiModality (no torch)")
    evaluation.add_argument("bundle", nargs="?", help="bundle folder (default: the shipped one)")
    evaluation.add_argument("--data", required=True, help="dataset folder with test.txt")
    evaluation.add_argument("--evaluator", required=True,
                            help="evaluator folder (RUN/evaluator of `mogo train evaluator`)")
    evaluation.add_argument("--limit", type=int,
                            help="a fixed random sample of this many test caption spans "
                                 "(default: all; at least 32)")
    evaluation.add_argument("--repeats", type=int, default=20)
    evaluation.add_argument("--seed", type=int, default=0)
    evaluation.add_argument("--mm-captions", type=int, default=10,
                            help="captions for MultiModality (protocol: 100; 0 = skip)")
    evaluation.add_argument("--mm-generations", type=int, default=30,
                            help="generations per MultiModality caption")
    evaluation.add_argument("--regenerate", action="store_true",
                            help="generate anew in every repeat (the full protocol; repeats x "
                                 "the generation time)")
    evaluation.add_argument("--threads", type=int, default=1,
                            help="clips generated in parallel")
    evaluation.add_argument("--json", help="also write the numbers to this file")
    evaluation.set_defaults(run=_cmd_eval)

    real = commands.add_parser(
        "real-motion", help="the bundle's VQ on real human motion: pybullet's 20 DeepMimic clips "
                            "(its wheel fetched by pip into a cache, never installed), MPJPE per "
                            "clip split into pose and trajectory, GIFs and a contact sheet")
    real.add_argument("bundle", nargs="?", help="bundle folder (default: the shipped one)")
    real.add_argument("--out", default="real_motion",
                      help="folder for the GIFs, contact sheet and table (default real_motion/)")
    real.add_argument("--cache", default=str(Path.home() / ".cache" / "mogo" / "pybullet"),
                      help="where the pybullet wheel is kept between runs")
    real.set_defaults(run=_cmd_real_motion)
