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
    synthesize_corpus(Path(args.out), num_clips=args.clips, seed=args.seed, progress=True)


def _cmd_data_show(args: argparse.Namespace) -> None:
    from mogo.export.show import show_clip

    show_clip(Path(args.data), args.id, Path(args.gif))
    print(f"wrote {args.gif}")


def _cmd_data_convert(args: argparse.Namespace) -> None:
    from mogo.export.convert import convert_joint_folder

    convert_joint_folder(Path(args.joints), Path(args.out), skeleton_name=args.skeleton,
                         source_fps=args.fps, progress=True)


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
