"""The `mogo` verbs of the training side: data, train, export. mogo.cli adds them through the
"mogo.commands" entry point; each imports its modules (and torch) only when it runs, so a
missing training extra is one clear line."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from mogo.cli import CliError, require_torch
from mogo.export.train.recipes import EVALUATOR_RECIPE, T2M_RECIPE, VQ_RECIPE


def _cmd_data_synth(args: argparse.Namespace) -> None:
    from mogo.export.data.corpus import synthesize_corpus

    if args.clips < 1:
        raise CliError(f"--clips must be at least 1, got {args.clips}")
    if args.workers is not None and args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    synthesize_corpus(Path(args.out), num_clips=args.clips, seed=args.seed, progress=True,
                      workers=args.workers)


def _cmd_data_show(args: argparse.Namespace) -> None:
    from mogo.export.data.show import show_clip

    show_clip(Path(args.data), args.id, Path(args.gif))
    print(f"wrote {args.gif}")


def _cmd_data_convert(args: argparse.Namespace) -> None:
    from mogo.export.data.convert import convert_joint_folder

    convert_joint_folder(Path(args.joints), Path(args.out), skeleton_name=args.skeleton,
                         source_fps=args.fps, progress=True)


def _training_options(args: argparse.Namespace) -> dict:
    return {k: v for k, v in vars(args).items()
            if k not in ("command", "train_command", "run", "finish")}


def _cmd_train_vq(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.train.train_vq import VQTrainOptions, train_vq

    train_vq(VQTrainOptions(**_training_options(args)))


def _cmd_train_t2m(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.train.train_t2m import T2MTrainOptions, train_t2m

    train_t2m(T2MTrainOptions(**_training_options(args)))


def _cmd_train_evaluator(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.train.train_evaluator import EvaluatorTrainOptions, train_evaluator

    train_evaluator(EvaluatorTrainOptions(**_training_options(args)))


def _cmd_export(args: argparse.Namespace) -> None:
    require_torch()
    from mogo.export.onnx.bundle import export_bundle, replace_vq_decoder

    if args.bundle is not None:
        if args.int8:
            raise CliError("--int8 quantises new level graphs; with --bundle they are copied "
                           "as they are")
        manifest = replace_vq_decoder(Path(args.vq), Path(args.bundle), Path(args.out))
    else:
        manifest = export_bundle(Path(args.vq), Path(args.t2m), Path(args.out), int8=args.int8)
    size = sum(entry["bytes"] for entry in manifest["files"].values())
    note = ""
    if "int8" in manifest:
        check = manifest["int8"]
        note = (f"; int8 level graphs {'used' if check['used'] else 'NOT used'} (greedy token "
                f"agreement {check['greedy_token_agreement']:.1%}, threshold "
                f"{check['threshold']:.0%})")
    print(f"wrote {args.out}: {len(manifest['files'])} files, {size / 1e6:.1f} MB{note}")


def add_commands(commands) -> None:
    """Adds data, train and export to the `mogo` parser's subcommands."""
    data = commands.add_parser("data", help="make, inspect and convert motion data")
    data_commands = data.add_subparsers(dest="data_command", required=True, metavar="ACTION")

    synth = data_commands.add_parser("synth", help="make the procedural text-motion corpus")
    synth.add_argument("--out", required=True, help="output folder (HumanML3D layout)")
    synth.add_argument("--clips", type=int, default=20000, help="number of clips before mirroring")
    synth.add_argument("--seed", type=int, default=0)
    synth.add_argument("--workers", type=int, help="processes (default: one per CPU core; the "
                                                   "corpus is the same for any number)")
    synth.set_defaults(run=_cmd_data_synth)

    show = data_commands.add_parser("show", help="render one clip as a stick-figure GIF")
    show.add_argument("id", help="clip ID, e.g. 000042 or M000042")
    show.add_argument("--data", required=True, help="dataset folder (HumanML3D layout)")
    show.add_argument("--gif", required=True, help="output GIF path")
    show.set_defaults(run=_cmd_data_show)

    convert = data_commands.add_parser(
        "convert", help="turn a folder of joint-position .npy files (T x J x 3, metres, Y up) "
                        "into HumanML3D features")
    convert.add_argument("--joints", required=True, help="folder of .npy joint positions")
    convert.add_argument("--out", required=True, help="output folder (HumanML3D layout)")
    convert.add_argument("--skeleton", default="humanml3d", choices=["humanml3d", "kit"])
    convert.add_argument("--fps", type=float, default=None,
                         help="frame rate of the source clips; resampled to the skeleton's "
                              "(20 for humanml3d, 12.5 for kit) when given")
    convert.set_defaults(run=_cmd_data_convert)

    train = commands.add_parser("train", help="train the models (torch; torchrun for several "
                                              "processes)")
    train_commands = train.add_subparsers(dest="train_command", required=True, metavar="MODEL")

    def run_arguments(command: argparse.ArgumentParser, recipe: dict, val: int, checkpoint: int,
                      log: int) -> None:
        """What both trainers take: `recipe` holds the run's defaults; then the default number
        of steps between validations, checkpoint.pt writes and progress lines."""
        command.add_argument("--data", required=True, help="dataset folder (HumanML3D layout)")
        command.add_argument("--out", required=True, help="run folder (checkpoints, metrics)")
        command.add_argument("--config", dest="preset", choices=["tiny", "cpu_default", "paper"],
                             help="model size (default cpu_default)")
        command.add_argument("--steps", type=int, default=20000, help="total optimizer steps")
        command.add_argument("--batch-size", type=int,
                             help=f"per process (default {recipe['batch_size']})")
        command.add_argument("--lr", type=float, help=f"peak learning rate, cosine to lr/10 "
                                                      f"(default {recipe['lr']:g})")
        command.add_argument("--warmup", type=int,
                             help=f"linear warm-up steps (default {recipe['warmup']})")
        command.add_argument("--seed", type=int, help=f"(default {recipe['seed']})")
        command.add_argument("--device", default="auto", help="auto, cpu or cuda")
        for name, default, what in (("val", val, "validations"),
                                    ("checkpoint", checkpoint, "checkpoint.pt writes"),
                                    ("log", log, "progress lines")):
            command.add_argument(f"--{name}-every", type=int, default=default,
                                 help=f"steps between {what}")
        command.add_argument("--resume", action="store_true",
                             help="continue the run in --out from its checkpoint.pt (the "
                                  "settings without a default above are the run's)")

    vq = train_commands.add_parser(
        "vq", help="train the MoSA-VQ motion tokenizer on random crops")
    run_arguments(vq, VQ_RECIPE, val=1000, checkpoint=1000, log=100)
    vq.add_argument("--crop-frames", type=int, help="frames per training crop (default 64)")
    vq.add_argument("--whole-clips", action="store_true", default=None,
                    help="train on whole clips, batched by length, instead of crops: what "
                         "validation and the runtime decode (the root trajectory of a whole "
                         "clip included)")
    vq.add_argument("--weight-average", type=float, metavar="DECAY",
                    help="validate and keep (best.pt) an exponential moving average of the "
                         "weights with this decay, e.g. 0.999: it averages out the noise of the "
                         "steps, which the root trajectory, summed from per-frame velocities, "
                         "is sensitive to (default off)")
    vq.add_argument("--levels", type=int, help="residual levels (ablation; default the config's)")
    vq.add_argument("--down-factor", type=int, choices=[1, 2, 4],
                    help="frames per token (default 1: one token per frame, as the paper)")
    vq.add_argument("--causal", action="store_true", default=None,
                    help="causal convolutions: zero decoder lookahead when streaming")
    vq.add_argument("--no-scale-bias", dest="scale_bias", action="store_false", default=None,
                    help="plain residual VQ, without the per-level scale and bias (ablation)")
    vq.add_argument("--decorrelation", type=float,
                    help="weight of the cross-level decorrelation loss (0 turns it off)")
    vq.add_argument("--val-clips", type=int, default=256,
                    help="val clips decoded whole at each validation")
    vq.add_argument("--init", type=Path,
                    help="fine-tune: start from the weights of this `mogo train vq` run, or of "
                         "this bundle's VQ graphs (with --tune decoder); new optimizer, "
                         "schedule and training settings")
    vq.add_argument("--tune", choices=["all", "decoder"],
                    help="with --init: train all weights (default), or the decoder alone, "
                         "which keeps every token, so a T2M trained on the --init VQ still fits")
    vq.set_defaults(run=_cmd_train_vq, finish=_leave_torchrun_worker)

    t2m = train_commands.add_parser(
        "t2m", help="train the text encoder and RQHC-Transformer on a trained VQ's tokens")
    run_arguments(t2m, T2M_RECIPE, val=500, checkpoint=500, log=50)
    t2m.add_argument("--vq", required=True, help="the `mogo train vq` run folder")
    t2m.add_argument("--text-encoder", choices=["small"], help="(default small)")
    t2m.set_defaults(run=_cmd_train_t2m, finish=_leave_torchrun_worker)

    evaluator = train_commands.add_parser(
        "evaluator", help="train the text-motion evaluator for `mogo eval` (contrastive text "
                          "and motion encoders), exported to RUN/evaluator")
    run_arguments(evaluator, EVALUATOR_RECIPE, val=500, checkpoint=500, log=50)
    evaluator.add_argument("--val-spans", type=int, default=1024,
                           help="validation spans embedded for R-precision (0: all)")
    evaluator.set_defaults(run=_cmd_train_evaluator, finish=_leave_torchrun_worker)

    export = commands.add_parser("export", help="trained runs -> a bundle folder for the runtime")
    export.add_argument("--vq", required=True, help="the `mogo train vq` run folder")
    source = export.add_mutually_exclusive_group(required=True)
    source.add_argument("--t2m", help="the `mogo train t2m` run folder")
    source.add_argument("--bundle", help="instead of --t2m: a bundle whose VQ decoder --vq "
                                         "replaces (a decoder fine-tune of that bundle's VQ, "
                                         "`mogo train vq --init BUNDLE --tune decoder`); every "
                                         "other file is copied")
    export.add_argument("--out", required=True, help="new bundle folder")
    export.add_argument("--int8", action="store_true",
                        help="dynamic int8 level graphs, kept only if they pass the token "
                             "agreement check against fp32")
    export.set_defaults(run=_cmd_export)


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
