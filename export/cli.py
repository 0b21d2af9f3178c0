"""The `mogo` command line. Subcommands import their modules lazily, so commands that need
torch fail with an install hint only when torch is actually needed."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


class CliError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def _require_torch() -> None:
    try:
        import torch  # noqa: F401
    except ImportError:
        raise CliError("this command needs the training extra: pip install 'mogo[train]'") from None


def _cmd_data_synth(args: argparse.Namespace) -> None:
    from mogo.export.corpus import synthesize_corpus

    if args.clips < 1:
        raise CliError(f"--clips must be at least 1, got {args.clips}")
    if args.workers is not None and args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    synthesize_corpus(Path(args.out), num_clips=args.clips, seed=args.seed, progress=True,
                      workers=args.workers)


def _cmd_data_show(args: argparse.Namespace) -> None:
    from mogo.export.show import show_clip

    show_clip(Path(args.data), args.id, Path(args.gif))
    print(f"wrote {args.gif}")


def _cmd_data_convert(args: argparse.Namespace) -> None:
    from mogo.export.convert import convert_joint_folder

    convert_joint_folder(Path(args.joints), Path(args.out), skeleton_name=args.skeleton,
                         source_fps=args.fps, progress=True)


def _training_options(args: argparse.Namespace) -> dict:
    return {k: v for k, v in vars(args).items() if k not in ("command", "train_command", "run")}


def _cmd_train_vq(args: argparse.Namespace) -> None:
    _require_torch()
    from mogo.export.train_vq import VQTrainOptions, train_vq

    train_vq(VQTrainOptions(**_training_options(args)))


def _cmd_train_t2m(args: argparse.Namespace) -> None:
    _require_torch()
    from mogo.export.train_t2m import T2MTrainOptions, train_t2m

    train_t2m(T2MTrainOptions(**_training_options(args)))


def _cmd_export(args: argparse.Namespace) -> None:
    _require_torch()
    from mogo.export.bundle import export_bundle

    manifest = export_bundle(Path(args.vq), Path(args.t2m), Path(args.out), int8=args.int8)
    size = sum(entry["bytes"] for entry in manifest["files"].values())
    note = ""
    if "int8" in manifest:
        check = manifest["int8"]
        note = (f"; int8 level graphs {'used' if check['used'] else 'NOT used'} (greedy token "
                f"agreement {check['greedy_token_agreement']:.1%}, threshold "
                f"{check['threshold']:.0%})")
    print(f"wrote {args.out}: {len(manifest['files'])} files, {size / 1e6:.1f} MB{note}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mogo", description="MOGO: text to 3D human motion, token by token, on a CPU.")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

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

    vq = train_commands.add_parser(
        "vq", help="train the MoSA-VQ motion tokenizer on random crops")
    vq.add_argument("--data", required=True, help="dataset folder (HumanML3D layout)")
    vq.add_argument("--out", required=True, help="run folder (checkpoints, metrics)")
    vq.add_argument("--config", dest="preset", choices=["tiny", "cpu_default", "paper"],
                    help="model size (default cpu_default)")
    vq.add_argument("--steps", type=int, default=20000, help="total optimizer steps")
    vq.add_argument("--batch-size", type=int, help="crops per process (default 64)")
    vq.add_argument("--lr", type=float, help="peak learning rate, cosine to lr/10 (default 2e-4)")
    vq.add_argument("--warmup", type=int, help="linear warm-up steps (default 1000)")
    vq.add_argument("--seed", type=int, help="(default 0)")
    vq.add_argument("--crop-frames", type=int, help="frames per training crop (default 64)")
    vq.add_argument("--levels", type=int, help="residual levels (ablation; default the config's)")
    vq.add_argument("--down-factor", type=int, choices=[1, 2, 4],
                    help="frames per token (default 1: one token per frame, as the paper)")
    vq.add_argument("--causal", action="store_true", default=None,
                    help="causal convolutions: zero decoder lookahead when streaming")
    vq.add_argument("--no-scale-bias", dest="scale_bias", action="store_false", default=None,
                    help="plain residual VQ, without the per-level scale and bias (ablation)")
    vq.add_argument("--decorrelation", type=float,
                    help="weight of the cross-level decorrelation loss (0 turns it off)")
    vq.add_argument("--device", default="auto", help="auto, cpu or cuda")
    vq.add_argument("--val-every", type=int, default=1000, help="steps between validations")
    vq.add_argument("--val-clips", type=int, default=256,
                    help="val clips decoded whole at each validation")
    vq.add_argument("--checkpoint-every", type=int, default=1000,
                    help="steps between checkpoint.pt writes")
    vq.add_argument("--log-every", type=int, default=100, help="steps between progress lines")
    vq.add_argument("--resume", action="store_true",
                    help="continue the run in --out from its checkpoint.pt")
    vq.set_defaults(run=_cmd_train_vq)

    t2m = train_commands.add_parser(
        "t2m", help="train the text encoder and RQHC-Transformer on a trained VQ's tokens")
    t2m.add_argument("--data", required=True, help="dataset folder (HumanML3D layout)")
    t2m.add_argument("--vq", required=True, help="the `mogo train vq` run folder")
    t2m.add_argument("--out", required=True, help="run folder (checkpoints, metrics, tokens)")
    t2m.add_argument("--config", dest="preset", choices=["tiny", "cpu_default", "paper"],
                     help="model size (default cpu_default)")
    t2m.add_argument("--steps", type=int, default=20000, help="total optimizer steps")
    t2m.add_argument("--batch-size", type=int, help="per process (default 32)")
    t2m.add_argument("--lr", type=float, help="peak learning rate, cosine to lr/10 "
                                             "(default 2e-4)")
    t2m.add_argument("--warmup", type=int, help="linear warm-up steps (default 1000)")
    t2m.add_argument("--seed", type=int, help="(default 0)")
    t2m.add_argument("--text-encoder", choices=["small"], help="(default small)")
    t2m.add_argument("--device", default="auto", help="auto, cpu or cuda")
    t2m.add_argument("--val-every", type=int, default=500, help="steps between validations")
    t2m.add_argument("--checkpoint-every", type=int, default=500,
                     help="steps between checkpoint.pt writes")
    t2m.add_argument("--log-every", type=int, default=50, help="steps between progress lines")
    t2m.add_argument("--resume", action="store_true",
                     help="continue the run in --out from its checkpoint.pt (the settings "
                          "without a default above are the run's)")
    t2m.set_defaults(run=_cmd_train_t2m)

    export = commands.add_parser("export", help="trained runs -> a bundle folder for the runtime")
    export.add_argument("--vq", required=True, help="the `mogo train vq` run folder")
    export.add_argument("--t2m", required=True, help="the `mogo train t2m` run folder")
    export.add_argument("--out", required=True, help="new bundle folder")
    export.add_argument("--int8", action="store_true",
                        help="dynamic int8 level graphs, kept only if they pass the token "
                             "agreement check against fp32")
    export.set_defaults(run=_cmd_export)

    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.run(args)
    except CliError as error:
        print(f"mogo: error: {error}", file=sys.stderr)
        return 2
    except (ValueError, FileNotFoundError, NotADirectoryError, PermissionError) as error:
        print(f"mogo: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
