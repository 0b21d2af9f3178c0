"""The `mogo` command. The runtime's verbs (generate, stream, info) are here and import no
torch; the verbs of mogo.export and mogo.bench (data, train, export, bench, eval) add
themselves through the "mogo.commands" entry points, so this module never imports them."""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib.util
import json
import math
import os
import re
import signal
import sys
import threading
import warnings
from collections.abc import Callable
from dataclasses import fields
from importlib.metadata import PackageNotFoundError, entry_points, version
from pathlib import Path

from mogo.arguments import (
    MAX_SCHEDULE_ENTRIES,
    PromptWarning,
    ScheduleError,
    UnfamiliarPromptWarning,
    UnknownPromptWarning,
    plural,
    shown,
)
from mogo.cli_flags import (
    OldSpelling,
    add_bundle,
    add_bundle_argument,
    add_out,
    add_overwrite,
    add_threads,
    current_spelling,
)
from mogo.sampling import Sampling, SamplingError

PLUGIN_GROUP = "mogo.commands"
PROMPTS_FILE_BYTES = 2**20  # a --prompts-file read past this is refused
LONG_TAKE_SECONDS = 30.0  # from this length on, generate shows its progress on stderr
# On PyPI, `mogo` is an unrelated PyMongo wrapper: the import name and the command stay `mogo`.
DISTRIBUTION = "mogo-edge"


class CliError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def needs_extra(label: str, extra: str) -> str:
    """The one line for a verb whose extra is missing, with the command that installs it."""
    return f"this command needs the {label} extra: pip install '{DISTRIBUTION}[{extra}]'"


def require_torch() -> None:
    """For verbs that need the training extra: a clear line instead of an ImportError."""
    if importlib.util.find_spec("torch") is None:
        raise CliError(needs_extra("training", "train"))


def load_generator(args: argparse.Namespace):
    from mogo.generator import MotionGenerator

    if args.threads is not None and args.threads < 1:
        raise CliError(f"--threads must be at least 1, got {args.threads}")
    threads = min(2, os.cpu_count() or 1) if args.threads is None else args.threads
    return MotionGenerator.load(args.bundle, threads=threads)


def _sampling(args: argparse.Namespace, generator):
    """The --temperature, --top-k, ... given, over the bundle's defaults; a bad value is
    named by its flag."""
    given = {option.name: getattr(args, option.name) for option in fields(Sampling)}
    defaults = generator.sampling()
    try:
        return defaults.updated(given)
    except SamplingError as error:
        raise CliError(f"--{error.option.replace('_', '-')} {error.problem}") from None


def _read_schedule(path: Path) -> tuple[list[tuple[str, float]], list[int]]:
    """Lines "SECONDS PROMPT", any whitespace between (blank lines and # comments skipped),
    and the line number of each; what is wrong in the file is named by file:line. At most
    PROMPTS_FILE_BYTES are read (/dev/zero is no prompts file)."""
    try:
        with open(path, "rb") as handle:
            data = handle.read(PROMPTS_FILE_BYTES + 1)
    except OSError as error:
        raise CliError(f"cannot read the prompts file {path}: {error.strerror}") from None
    if len(data) > PROMPTS_FILE_BYTES:
        raise CliError(
            f"{path}: larger than {PROMPTS_FILE_BYTES // 1024} KiB; a prompts file "
            f"holds at most {MAX_SCHEDULE_ENTRIES} lines 'SECONDS PROMPT'"
        )
    try:
        lines = data.decode("utf-8-sig").splitlines()
    except UnicodeDecodeError as error:
        line = data[: error.start].count(b"\n") + 1
        raise CliError(
            f"{path}:{line}: not UTF-8 text (byte 0x{data[error.start]:02x}); save "
            "the prompts file as UTF-8"
        ) from None
    schedule, numbers = [], []
    for number, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        seconds, prompt = (line.split(None, 1) + [""])[:2]
        try:
            length = float(seconds)
        except ValueError:
            raise CliError(
                f"{path}:{number}: expected 'SECONDS PROMPT', got {line.strip()!r}"
            ) from None
        if not math.isfinite(length) or length <= 0:
            raise CliError(
                f"{path}:{number}: the seconds must be a positive number, got {seconds!r}"
            )
        if not prompt.strip():
            raise CliError(f"{path}:{number}: no prompt after the seconds")
        schedule.append((prompt.strip(), length))
        numbers.append(number)
    if not schedule:
        raise CliError(f"{path}: no 'SECONDS PROMPT' lines")
    return schedule, numbers


def _file_stem(text: str) -> str:
    words = "".join(c if c.isalnum() else " " for c in text.lower()).split()
    return "_".join(words)[:48].rstrip("_") or "motion"


def _aligner(args: argparse.Namespace, generator):
    """--align rules|llm -> the aligner (the LLM falls back to the bundle's rules)."""
    if args.align is None:
        return False
    rules = generator.aligner(True)
    if args.align == "rules":
        return rules
    from mogo.llm_align import LLMAligner

    return LLMAligner(args.llm_url, args.llm_model, timeout=args.llm_timeout, fallback=rules)


def _formats(args: argparse.Namespace) -> tuple[str, ...]:
    """--formats bvh,npy; else the default take, its animation file --format's."""
    from mogo.clip import TAKE, take_suffixes

    if args.formats is None:
        return (args.format or TAKE[0],) + TAKE[1:]
    if args.format is not None:
        raise CliError("give --formats (it names the animation file too) or --format, not both")
    formats = tuple(name.strip() for name in args.formats.split(","))
    try:
        take_suffixes(formats)
    except ValueError as error:
        raise CliError(f"--formats: {error}") from None
    return formats


def _cmd_generate(args: argparse.Namespace) -> None:
    from mogo.clip import check_take
    from mogo.motion import bvh, rig

    schedule = lines = None
    if args.prompts_file:
        if args.text is not None or args.seconds is not None:
            raise CliError("give either a prompt (with --seconds) or --prompts-file, not both")
        if args.align:
            raise CliError("--align rewrites one prompt; a --prompts-file is played as written")
        schedule, lines = _read_schedule(Path(args.prompts_file))
    elif args.text is None:
        raise CliError('give a prompt, e.g. mogo generate "a person walks forward"')
    formats = _formats(args)
    folder = check_take(
        args.out, args.name, args.overwrite, what="--name", formats=formats
    )  # before the work
    seconds = sum(s for _, s in schedule) if schedule else args.seconds
    long = seconds is not None and seconds >= LONG_TAKE_SECONDS
    generator = load_generator(args)
    rig.check(generator.skeleton)  # the BVH and GLB files pose its rig: refused before the work
    motion = _generated(args, generator, schedule, lines, long)
    if motion.alignment is not None:
        print(shown(motion.alignment.describe(), keep="\n"))
        if motion.alignment.note:
            print(f"note: {shown(motion.alignment.note)}")
    elif args.text is not None:
        _note_played(generator, args)
    name = args.name or _file_stem(motion.caption)
    if long:
        print(
            f"writing: {', '.join(formats)} ({plural(len(motion.joints), 'frame')})",
            file=sys.stderr,
            flush=True,
        )
    written = motion.save_take(
        folder,
        name,
        overwrite=args.overwrite,
        bone_translations=args.bvh_bone_translations,
        scale=bvh.UNITS[args.bvh_units],
        naming=args.bvh_names,
        formats=formats,
    )
    _report_take(motion, folder / name, written)


def _generated(args: argparse.Namespace, generator, schedule, lines, long: bool):
    """The motion of the prompt (with --seconds, --align) or of the prompts file, whose
    problems are named by its line."""
    sampling = _sampling(args, generator)
    if schedule is None:
        return generator.generate(
            args.text,
            seconds=args.seconds,
            seed=args.seed,
            sampling=sampling,
            align=_aligner(args, generator),
            plant_feet=args.plant_feet,
            progress=long,
        )
    try:
        return generator.play(
            schedule, seed=args.seed, sampling=sampling, plant_feet=args.plant_feet, progress=long
        )
    except ScheduleError as error:
        where = "" if error.index is None else f":{lines[error.index]}"
        raise CliError(f"{args.prompts_file}{where}: {error.problem}") from None


def _report_take(motion, asked: Path, written: list[Path]) -> None:
    """What was made and where it went. The take is written: a stdout that fails (a closed
    pipe, a full disk) is no error, only a note on stderr."""
    frames = plural(len(motion.joints), "frame")
    try:
        print(
            f"{motion.seconds:.1f} s of motion ({frames}, seed {motion.seed}) "
            f"for: {shown(motion.caption)}"
        )
        taken = written[0].name.removesuffix(written[0].suffix)
        if taken != asked.name:
            print(
                f"note: {shown(asked)}.* is an earlier take, kept; this one is "
                f"{taken} (--overwrite replaces)"
            )
        for path in written:
            print(f"wrote {shown(path)}")
        sys.stdout.flush()
    except OSError as error:
        if error.filename != _Stdout.NAME:
            raise
        _silence_stdout()
        print(
            f"note: cannot write to standard output ({error.strerror}); the take was "
            f"written: {', '.join(shown(path) for path in written)}",
            file=sys.stderr,
        )


def _note_played(generator, args: argparse.Namespace) -> None:
    """A `note:` line on stderr naming the known caption a prompt in other words is played as
    (mogo.repertoire.Familiarity.played_note)."""
    if (known := generator.known(args.text)) is not None and known.played_note:
        print(f"note: {shown(known.played_note)}{_align_hint(args, far=False)}", file=sys.stderr)


def _align_hint(args: argparse.Namespace, far: bool) -> str:
    """What `--align rules` would do for a prompt `mogo generate` plays as written, where the
    model plays it as something else: its steps one by one, other words mapped to known ones
    ('' where --align is not at hand: given already, a prompts file, `mogo stream`)."""
    if not hasattr(args, "align") or args.align or args.text is None:
        return ""
    from mogo.repertoire import what_it_says

    if (steps := max(what_it_says(args.text)["steps"])) > 1:
        return f" (it reads as {steps} steps: --align rules plays them one after another)"
    return " (--align rules maps some other words onto the ones it knows)" if far else ""


def _cmd_stream(args: argparse.Namespace) -> None:
    if args.frames is not None and args.frames < 1:
        raise CliError(f"--frames must be at least 1, got {args.frames}")
    generator = load_generator(args)
    stream = generator.stream(
        args.text,
        seed=args.seed,
        sampling=_sampling(args, generator),
        plant_feet=args.plant_feet,
        low_latency=args.low_latency,
    )
    if args.seed is None:  # drawn at random: said, so that the stream can be had again
        print(
            f"note: seed {stream.seed} (random; --seed {stream.seed} streams this motion again)",
            file=sys.stderr,
        )
    _note_played(generator, args)
    try:
        for index, frame in enumerate(stream.frames(args.frames)):
            record = dict(
                frame=index,
                seconds=round(index / generator.fps, 4),
                joints=[[round(float(v), 5) for v in joint] for joint in frame],
            )
            sys.stdout.write(json.dumps(record, separators=(",", ":")) + "\n")
            sys.stdout.flush()
    except BrokenPipeError:  # the reading program stopped: a normal way to end a stream
        _silence_stdout()


def _cmd_blender_addon(args: argparse.Namespace) -> None:
    from mogo.blender.addon_zip import write_addon

    print(
        f"wrote {shown(write_addon(args.out, overwrite=args.overwrite))} (Blender: Edit > "
        "Preferences > Add-ons > Install, then enable 'MOGO motion'; docs/blender.md)"
    )


def _cmd_info(args: argparse.Namespace) -> None:
    from mogo.bundle import Bundle
    from mogo.generator import DEFAULT_BUNDLE
    from mogo.text_side import check_text_files

    bundle = Bundle.load(args.bundle or DEFAULT_BUNDLE)
    check_text_files(bundle)  # all that generate reads, not only the checksums
    m = bundle.manifest
    lines = [f"bundle      {bundle.root}", *_model_lines(m), *_text_lines(m.text)]
    if m.int8 is not None:
        lines.append(f"int8        {m.int8.describe()}, {m.int8.scheme}")
    lines += _training_lines(m)
    lines.append(
        f"files       {len(m.files)}, {m.total_bytes / 1e6:.1f} MB, sha256 verified; "
        f"{bundle.open_graphs()} graphs open with the manifest's names and types; "
        "tokenizers and repertoire read"
    )
    width = max(map(len, m.files))
    lines += [f"  {name:{width}s} {entry.bytes / 1e6:8.2f} MB" for name, entry in m.files.items()]
    print(shown("\n".join(lines), keep="\n"))  # a bundle's own text may hold escapes


def _model_lines(m) -> list[str]:
    """`mogo info`: the format, motion, transformer, VQ and defaults of manifest `m`."""
    t2m, vq, text, decoder = m.t2m.config, m.vq, m.text, m.vq.decoder
    return [
        f"format      {m.format} version {m.format_version}",
        f"motion      {m.motion.skeleton.name} skeleton, {m.feature_dim}-dim features, "
        f"{m.fps:g} fps, {len(m.motion.skeleton.joint_names)} joints",
        f"text        {text.kind}, {t2m.get('text_dim')}-d prompt embedding, at most "
        f"{text.max_length} tokens",
        f"transformer {m.t2m.num_levels} levels, width {t2m.get('dim')}, layers "
        f"{t2m.get('layers')}, heads {t2m.get('heads')}, {vq.codebook_size} codes + end token",
        f"vq          {vq.levels} levels of {vq.codebook_size} codes, "
        f"{plural(vq.down_factor, 'frame')} per token, decoder context "
        f"{decoder.left_context} back / {decoder.lookahead} ahead (tokens)",
        *(
            []
            if vq.low_latency_decoder is None
            else [
                f"            low-latency decoder: context {vq.low_latency_decoder.left_context} "
                f"back / {vq.low_latency_decoder.lookahead} ahead (tokens)"
                + (
                    ""
                    if vq.low_latency_step is None
                    else f", stepped a token a call (state {vq.low_latency_step.state_size} floats)"
                )
            ]
        ),
        "defaults    " + ", ".join(f"{k} {v}" for k, v in vars(m.defaults).items()),
    ]


def _text_lines(text) -> list[str]:
    """`mogo info`: the pretrained encoder and the repertoire of a bundle's text side."""
    lines = []
    if text.pretrained is not None:
        lines.append(
            f"encoder     {text.pretrained.name} ({text.pretrained.license}), int8 "
            f"graph vs fp32 reference: cosine >= {text.pretrained.reference_min_cosine}"
            + (
                "; prompts in the training words: the encoder trained with the model"
                if text.trained
                else ""
            )
        )
    if text.repertoire is not None:
        r = text.repertoire
        lines.append(
            f"repertoire  similarity threshold {r.threshold:.2f}: accepts "
            f"{r.held_out_accepted:.0%} of held-out captions, refuses "
            f"{r.outside_refused:.0%} of outside prompts"
            + (
                "; prompts in other words are played as the caption nearest their "
                "adapted embedding that says the same steps, sides and counts"
                if r.prompts
                else ""
            )
        )
    return lines


def _training_lines(m) -> list[str]:
    """`mogo info`: how each model of the bundle was trained, as its trainer recorded it."""
    lines = []
    for part, run in m.training.items():
        recipe = run.recipe or {}  # the trainer's own record: read as it is, where present
        tuned = (
            f", {'the decoder' if recipe.get('tune') == 'decoder' else 'all weights'} "
            f"fine-tuned from {_built_path(recipe['init'])}"
            if recipe.get("init")
            else ""
        )
        lines.append(
            f"trained     {part}: {run.step} steps, batch "
            f"{recipe.get('batch_size')}, lr {recipe.get('lr')}, "
            f"seed {recipe.get('seed')}{tuned}"
        )
    return lines


def _built_path(path: object) -> str:
    """A path the bundle's trainer recorded: its last part alone, the rest names folders of the
    machine that built the bundle, not this one."""
    name = re.split(r"[\\/]", str(path).rstrip("/\\"))[-1]
    return f"{name} (a path on the build machine)" if name else "a path on the build machine"


def _noting_prompts(command: Callable[[argparse.Namespace], None]):
    """`command` with a PromptWarning (words the model does not know, a prompt cut at the text
    encoder's length, far from the model's repertoire) as a `note:` line on stderr, stdout
    staying the output; a prompt with no known word refused, since its motion would be a
    generic one, and with --strict one far from the repertoire too."""

    @functools.wraps(command)
    def run(args: argparse.Namespace) -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("default", PromptWarning)  # each note once, whatever is set
            show = warnings.showwarning

            def note(message, category, *where, **options):
                if issubclass(category, UnknownPromptWarning) or (
                    args.strict and issubclass(category, UnfamiliarPromptWarning)
                ):
                    raise CliError(str(message))
                if issubclass(category, UnfamiliarPromptWarning):
                    print(f"note: {shown(message)}{_align_hint(args, far=True)}", file=sys.stderr)
                elif issubclass(category, PromptWarning):
                    print(f"note: {shown(message)}", file=sys.stderr)
                else:
                    show(message, category, *where, **options)

            warnings.showwarning = note
            command(args)

    return run


def _generation_arguments(command: argparse.ArgumentParser) -> None:
    """--bundle, --seed, a flag per field of Sampling (--top-k for top_k), --threads and
    --no-plant-feet."""
    add_bundle(command)
    command.add_argument(
        "--seed", type=int, help="same seed, same motion (default: random, printed)"
    )
    for option in fields(Sampling):
        command.add_argument(
            "--" + option.name.replace("_", "-"),
            type=type(option.default),
            help=f"{option.metadata['help']} (default: the bundle's)",
        )
    command.add_argument(
        "--strict",
        action="store_true",
        help="refuse a prompt far from what the model was trained on (bundles "
        "with a repertoire; `mogo info` shows its threshold)",
    )
    add_threads(
        command,
        "cores to use; the same motion for any count (default: 2 where "
        "there are 2 or more, the fastest measured)",
    )
    command.add_argument(
        "--plant-feet",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="hold each foot still while the motion's contacts say it is "
        "planted, the legs re-solved by IK (default: on; --no-plant-feet "
        "keeps the joints as decoded)",
    )


def _add_runtime_commands(commands) -> None:
    generate = commands.add_parser(
        "generate", help="text -> motion files (.bvh, .gif, .npy joints, .json)"
    )
    generate.add_argument("text", nargs="?", help="what the person does")
    generate.add_argument(
        "--seconds", type=float, help="length (default: the model ends the motion itself)"
    )
    generate.add_argument(
        "--prompts-file",
        help="a schedule instead of one prompt: lines 'SECONDS PROMPT', played as one motion",
    )
    _take_arguments(generate)
    _align_arguments(generate)
    _generation_arguments(generate)
    generate.set_defaults(run=_noting_prompts(_cmd_generate))

    stream = commands.add_parser(
        "stream", help="stream frames to stdout as JSON lines until stopped (Ctrl-C)"
    )
    stream.add_argument("text", help="what the person does")
    stream.add_argument("--frames", type=int, help="stop after this many frames (default: never)")
    stream.add_argument(
        "--low-latency",
        action="store_true",
        help="the bundle's low-latency decoder: frames a few tokens after theirs, "
        "not 31 (the default bundle's waits 2; a bundle without one refuses)",
    )
    _generation_arguments(stream)
    stream.set_defaults(run=_noting_prompts(_cmd_stream))

    addon = commands.add_parser(
        "blender-addon", help="write the Blender add-on as the zip Blender installs"
    )
    add_out(addon, "the zip to write", default="mogo_blender.zip")
    add_overwrite(addon)
    addon.set_defaults(run=_cmd_blender_addon)

    info = commands.add_parser("info", help="describe a bundle (default: the shipped one)")
    add_bundle_argument(info)
    info.set_defaults(run=_cmd_info)


def _take_arguments(generate: argparse.ArgumentParser) -> None:
    """Where `mogo generate` writes its take, and in which files."""
    from mogo.clip import ANIMATIONS, FORMATS, TAKE
    from mogo.motion import bvh  # their option lists

    add_out(generate, "output folder", default="out")
    generate.add_argument("--name", help="file name without extension (default: from the prompt)")
    add_overwrite(
        generate,
        "replace an earlier take of the same name (default: keep it, and "
        "name this one NAME-2, NAME-3, ...: the first free)",
    )
    generate.add_argument(
        "--bvh-bone-translations",
        action="store_true",
        help="position channels on every BVH joint: the joints back exactly, "
        "bone stretch included (default: a rigid skeleton, rotations only)",
    )
    generate.add_argument(
        "--format",
        choices=list(ANIMATIONS),
        help="the animation file: a .bvh skeleton, or a .glb skinned mannequin "
        "(three.js, Blender, engines play it as it is) (default bvh)",
    )
    generate.add_argument(
        "--formats",
        metavar="LIST",
        help=f"the files to write, comma-separated, of {', '.join(FORMATS)} "
        f"(default {','.join(TAKE)}; e.g. bvh,npy: a long take without "
        "its large GIF and JSON)",
    )
    generate.add_argument(
        "--bvh-names",
        choices=list(bvh.NAMINGS),
        default="mixamo",
        help="BVH (and GLB) joint names: each named for the bone it moves, "
        "Mixamo/Unity style (Hips, LeftUpLeg, LeftArm, ...), or the SMPL "
        "joint names (default mixamo)",
    )
    generate.add_argument(
        "--bvh-units", choices=list(bvh.UNITS), default="m", help="BVH length unit (default m)"
    )


def _align_arguments(generate: argparse.ArgumentParser) -> None:
    """`mogo generate --align`: the prompt rewritten by rules or an LLM server."""
    generate.add_argument(
        "--align",
        choices=["rules", "llm"],
        help="rewrite the prompt into caption-style steps played as one "
        "motion: built-in rules, or an LLM server (falls back to the "
        "rules; API key from MOGO_LLM_API_KEY)",
    )
    generate.add_argument(
        "--llm-url",
        help="OpenAI-compatible server base URL, e.g. "
        "http://localhost:8080/v1 (default: MOGO_LLM_URL)",
    )
    generate.add_argument("--llm-model", help="model name on that server (default: MOGO_LLM_MODEL)")
    generate.add_argument(
        "--llm-timeout",
        type=float,
        default=10.0,
        help="seconds to wait for the LLM before using the rules (default 10)",
    )


class _Parser(argparse.ArgumentParser):
    """argparse with its errors (unknown flag, 'x' for a number) as the one `mogo: error:`
    line every bad input gets, instead of a usage block; --help still shows the usage. The
    top parser keeps the old spellings its verbs still take (mogo.cli_flags.OldSpelling)."""

    old_spellings: tuple[OldSpelling, ...] = ()

    def error(self, message: str):
        self.exit(2, f"mogo: error: {message} (see {self.prog} --help)\n")


def _version() -> str:
    try:
        return version(DISTRIBUTION)
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="mogo", description="MOGO: text to 3D human motion, token by token, on a CPU."
    )
    parser.add_argument("--version", action="version", version=f"mogo {_version()}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_runtime_commands(commands)
    # by name: an environment that still has the old `mogo` distribution beside `mogo-edge`
    # lists each verb twice
    plugins = {plugin.name: plugin for plugin in entry_points(group=PLUGIN_GROUP)}
    parser.old_spellings = tuple(
        old for name in sorted(plugins) for old in plugins[name].load()(commands) or ()
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    for stream in (sys.stdout, sys.stderr):  # a terminal that cannot show a character: escaped
        with contextlib.suppress(AttributeError, ValueError):
            stream.reconfigure(errors="backslashreplace")
    try:
        parser = build_parser()
        args = parser.parse_args(
            current_spelling(sys.argv[1:] if argv is None else argv, parser.old_spellings)
        )
    except KeyboardInterrupt:  # Ctrl-C while the verbs load: a quiet stop, as during a run
        return 130
    status = _run(args)
    if hasattr(args, "finish"):  # a verb that must end its process its own way
        args.finish(status)
    return status


def _run(args: argparse.Namespace) -> int:
    stdout, sys.stdout = sys.stdout, _Stdout(sys.stdout)
    try:
        with _exit_on_termination():
            args.run(args)
        sys.stdout.flush()  # a closed pipe or a full disk shows here, not at Python's exit
    except CliError as error:
        print(f"mogo: error: {shown(error)}", file=sys.stderr)
        return 2
    except (ValueError, OSError) as error:
        print(f"mogo: error: {shown(_describe(error))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    finally:
        sys.stdout = stdout if isinstance(sys.stdout, _Stdout) else sys.stdout
    return 0


@contextlib.contextmanager
def _exit_on_termination():
    """SIGTERM and SIGHUP as an exit (status 128 + the signal) that runs every cleanup on the
    way out, as Ctrl-C does: temporaries and half-built folders removed (mogo.files holds all
    three signals while a set of files is renamed into place)."""

    def leave(number: int, _frame) -> None:
        raise SystemExit(128 + number)

    previous = {}
    if threading.current_thread() is threading.main_thread():
        for name in ("SIGTERM", "SIGHUP"):
            number = getattr(signal, name, None)
            if number is not None and signal.getsignal(number) is signal.SIG_DFL:
                previous[number] = signal.signal(number, leave)
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


class _Stdout:
    """sys.stdout while a verb runs: its write errors name it, as Python's do not."""

    NAME = "<stdout>"

    def __init__(self, stream):
        self._stream = stream

    def __getattr__(self, name: str):
        return getattr(self._stream, name)

    def write(self, text: str) -> int:
        return self._named(self._stream.write, text)

    def flush(self) -> None:
        self._named(self._stream.flush)

    def _named(self, method, *args):
        try:
            return method(*args)
        except OSError as error:  # OSError(EPIPE, ...) is a BrokenPipeError again
            raise OSError(error.errno, error.strerror, self.NAME) from None


def _describe(error: Exception) -> str:
    """One line for an error: an OSError as "FILE: what happened" (Python's own str() is
    "[Errno 28] No space left on device", without the file, when writing fails)."""
    if not isinstance(error, OSError):
        return str(error)
    if error.filename == _Stdout.NAME:
        _silence_stdout()
        return f"cannot write to standard output: {error.strerror}"
    if error.strerror and error.filename is not None:
        return f"{error.filename}: {error.strerror}"
    return error.strerror or str(error)


def _silence_stdout() -> None:
    """Standard output pointed at os.devnull: what it could not take is dropped, without
    Python's "Exception ignored ... BrokenPipeError" at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no file descriptor behind sys.stdout
        sys.stdout = None


if __name__ == "__main__":
    sys.exit(main())
