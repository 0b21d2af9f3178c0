"""The `mogo` command line. Subcommands import their modules lazily, so commands that need
torch fail with an install hint only when torch is actually needed."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from mogo.export.recipes import EVALUATOR_RECIPE, T2M_RECIPE, VQ_RECIPE


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


def _cmd_bench(args: argparse.Namespace) -> None:
    _require_torch()
    from mogo.bench.latency import main_from_args

    main_from_args(args)


def _cmd_train_evaluator(args: argparse.Namespace) -> None:
    _require_torch()
    from mogo.export.train_evaluator import EvaluatorTrainOptions, train_evaluator

    train_evaluator(EvaluatorTrainOptions(**_training_options(args)))


def _cmd_export(args: argparse.Namespace) -> None:
    _require_torch()
    from mogo.export.bundle import export_bundle, replace_vq_decoder

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


def _cmd_eval(args: argparse.Namespace) -> None:
    import json

    from mogo.bench.evaluate import EvalOptions, evaluate, format_table

    options = EvalOptions(args.bundle, Path(args.data), Path(args.evaluator), args.limit,
                          args.repeats, args.seed, args.mm_captions, args.mm_generations,
                          args.regenerate, args.threads)
    result = evaluate(options)
    print(format_table(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
        print(f"wrote {args.json}")


def _load_generator(args: argparse.Namespace):
    from mogo.runtime.generator import MotionGenerator

    if args.threads is not None and args.threads < 1:
        raise CliError(f"--threads must be at least 1, got {args.threads}")
    threads = min(2, os.cpu_count() or 1) if args.threads is None else args.threads
    return MotionGenerator.load(args.bundle, threads=threads)


def _sampling_options(args: argparse.Namespace) -> dict:
    return dict(temperature=args.temperature, top_k=args.top_k, top_p=args.top_p,
                guidance=args.guidance)


def _read_schedule(path: Path) -> list[tuple[str, float]]:
    """Lines "SECONDS PROMPT" (blank lines and # comments skipped)."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as error:
        raise CliError(f"cannot read the prompts file {path}: {error.strerror}") from None
    schedule = []
    for number, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        seconds, _, prompt = line.strip().partition(" ")
        try:
            schedule.append((prompt.strip(), float(seconds)))
        except ValueError:
            raise CliError(f"{path}:{number}: expected 'SECONDS PROMPT', got {line.strip()!r}"
                           ) from None
    if not schedule:
        raise CliError(f"{path}: no 'SECONDS PROMPT' lines")
    return schedule


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
    from mogo.runtime.llm_align import LLMAligner

    return LLMAligner(args.llm_url, args.llm_model, timeout=args.llm_timeout, fallback=rules)


def _cmd_generate(args: argparse.Namespace) -> None:
    if args.prompts_file:
        if args.text is not None or args.seconds is not None:
            raise CliError("give either a prompt (with --seconds) or --prompts-file, not both")
        if args.align:
            raise CliError("--align rewrites one prompt; a --prompts-file is played as written")
        schedule = _read_schedule(Path(args.prompts_file))
    elif args.text is None:
        raise CliError("give a prompt, e.g. mogo generate \"a person walks forward\"")
    generator = _load_generator(args)
    options = _sampling_options(args)
    if args.prompts_file:
        motion = generator.play(schedule, seed=args.seed, **options)
    else:
        motion = generator.generate(args.text, seconds=args.seconds, seed=args.seed,
                                    align=_aligner(args, generator), **options)
    if motion.alignment is not None:
        print(motion.alignment.describe())
        if motion.alignment.note:
            print(f"note: {motion.alignment.note}")
    stem = Path(args.out) / (args.name or _file_stem(motion.caption))
    written = [motion.save_bvh(stem.with_suffix(".bvh"),
                               bone_translations=args.bvh_bone_translations),
               motion.save_gif(stem.with_suffix(".gif")),
               motion.save_npy(stem.with_suffix(".npy")),
               motion.save_json(stem.with_suffix(".json"))]
    print(f"{motion.seconds:.1f} s of motion ({len(motion.joints)} frames, seed {motion.seed}) "
          f"for: {motion.caption}")
    for path in written:
        print(f"wrote {path}")


def _cmd_stream(args: argparse.Namespace) -> None:
    import json

    if args.frames is not None and args.frames < 1:
        raise CliError(f"--frames must be at least 1, got {args.frames}")
    generator = _load_generator(args)
    stream = generator.stream(args.text, seed=args.seed, **_sampling_options(args))
    try:
        for index, frame in enumerate(stream.frames(args.frames)):
            record = dict(frame=index, seconds=round(index / generator.fps, 4),
                          joints=[[round(float(v), 5) for v in joint] for joint in frame])
            sys.stdout.write(json.dumps(record, separators=(",", ":")) + "\n")
            sys.stdout.flush()
    except BrokenPipeError:  # the reading program stopped: a normal way to end a stream
        sys.stdout = None


def _cmd_info(args: argparse.Namespace) -> None:
    from mogo.runtime.bundle import Bundle
    from mogo.runtime.generator import DEFAULT_BUNDLE

    bundle = Bundle.load(args.bundle or DEFAULT_BUNDLE)
    m = bundle.manifest
    t2m, vq, text = m["t2m"], m["vq"], m["text"]
    config = t2m["config"]
    decoder = vq["decoder"]
    lines = [
        f"bundle      {bundle.root}",
        f"format      {m['format']} version {m['format_version']}",
        f"motion      {m['skeleton']} skeleton, {m['feature_dim']}-dim features, {m['fps']:g} fps",
        f"text        {text['kind']}, {text['embedding_dim']}-d prompt embedding, "
        f"at most {text['max_length']} tokens",
        f"transformer {t2m['num_levels']} levels, width {config['dim']}, layers "
        f"{config['layers']}, heads {config['heads']}, {t2m['codebook_size']} codes + end token",
        f"vq          {vq['levels']} levels of {vq['codebook_size']} codes, {vq['down_factor']} "
        f"frame(s) per token, decoder context {decoder['left_context']} back / "
        f"{decoder['lookahead']} ahead (tokens)",
        "defaults    " + ", ".join(f"{k} {v}" for k, v in m.get("defaults", {}).items()),
    ]
    if "int8" in m:
        check = m["int8"]
        lines.append(f"int8        {'used' if check['used'] else 'not used'}: greedy token "
                     f"agreement {check['greedy_token_agreement']:.1%} (threshold "
                     f"{check['threshold']:.0%}), {check['scheme']}")
    for part, info in m.get("training", {}).items():
        recipe = info.get("recipe") or {}
        tuned = (f", {'the decoder' if recipe.get('tune') == 'decoder' else 'all weights'} "
                 f"fine-tuned from {recipe['init']}" if recipe.get("init") else "")
        lines.append(f"trained     {part}: {info.get('step')} steps, batch "
                     f"{recipe.get('batch_size')}, lr {recipe.get('lr')}, "
                     f"seed {recipe.get('seed')}{tuned}")
    total = sum(entry["bytes"] for entry in m["files"].values())
    lines.append(f"files       {len(m['files'])}, {total / 1e6:.1f} MB, sha256 verified")
    lines += [f"  {name:20s} {entry['bytes'] / 1e6:8.2f} MB" for name, entry in m["files"].items()]
    print("\n".join(lines))


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
    vq.set_defaults(run=_cmd_train_vq)

    t2m = train_commands.add_parser(
        "t2m", help="train the text encoder and RQHC-Transformer on a trained VQ's tokens")
    run_arguments(t2m, T2M_RECIPE, val=500, checkpoint=500, log=50)
    t2m.add_argument("--vq", required=True, help="the `mogo train vq` run folder")
    t2m.add_argument("--text-encoder", choices=["small"], help="(default small)")
    t2m.set_defaults(run=_cmd_train_t2m)

    evaluator = train_commands.add_parser(
        "evaluator", help="train the text-motion evaluator for `mogo eval` (contrastive text "
                          "and motion encoders), exported to RUN/evaluator")
    run_arguments(evaluator, EVALUATOR_RECIPE, val=500, checkpoint=500, log=50)
    evaluator.add_argument("--val-spans", type=int, default=1024,
                           help="validation spans embedded for R-precision (0: all)")
    evaluator.set_defaults(run=_cmd_train_evaluator)

    def sampling_arguments(command: argparse.ArgumentParser) -> None:
        command.add_argument("--bundle",
                             help="bundle folder (default: the model shipped with mogo)")
        command.add_argument("--seed", type=int, help="same seed, same motion (default: random, "
                                                      "printed)")
        command.add_argument("--temperature", type=float, help="0 = greedy (default: bundle's)")
        command.add_argument("--top-k", type=int, help="0 = off (default: bundle's)")
        command.add_argument("--top-p", type=float, help="1 = off (default: bundle's)")
        command.add_argument("--guidance", type=float,
                             help="classifier-free guidance scale, 1 = off (default: bundle's)")
        command.add_argument("--threads", type=int,
                             help="cores to use; the same motion for any count (default: 2 "
                                  "where there are 2 or more, the fastest measured)")

    generate = commands.add_parser(
        "generate", help="text -> motion files (.bvh, .gif, .npy joints, .json)")
    generate.add_argument("text", nargs="?", help="what the person does")
    generate.add_argument("--seconds", type=float,
                          help="length (default: the model ends the motion itself)")
    generate.add_argument("--prompts-file", help="a schedule instead of one prompt: lines "
                                                 "'SECONDS PROMPT', played as one motion")
    generate.add_argument("--out", default="out", help="output folder (default out/)")
    generate.add_argument("--name", help="file name without extension (default: from the prompt)")
    generate.add_argument("--bvh-bone-translations", action="store_true",
                          help="position channels on every BVH joint: the joints back exactly, "
                               "bone stretch included (default: a rigid skeleton, rotations only)")
    generate.add_argument("--align", choices=["rules", "llm"],
                          help="rewrite the prompt into caption-style steps played as one "
                               "motion: built-in rules, or an LLM server (falls back to the "
                               "rules; API key from MOGO_LLM_API_KEY)")
    generate.add_argument("--llm-url", help="OpenAI-compatible server base URL, e.g. "
                                            "http://localhost:8080/v1 (default: MOGO_LLM_URL)")
    generate.add_argument("--llm-model", help="model name on that server (default: "
                                              "MOGO_LLM_MODEL)")
    generate.add_argument("--llm-timeout", type=float, default=10.0,
                          help="seconds to wait for the LLM before using the rules (default 10)")
    sampling_arguments(generate)
    generate.set_defaults(run=_cmd_generate)

    stream = commands.add_parser(
        "stream", help="stream frames to stdout as JSON lines until stopped (Ctrl-C)")
    stream.add_argument("text", help="what the person does")
    stream.add_argument("--frames", type=int, help="stop after this many frames (default: never)")
    sampling_arguments(stream)
    stream.set_defaults(run=_cmd_stream)

    info = commands.add_parser("info", help="describe a bundle (default: the shipped one)")
    info.add_argument("bundle", nargs="?", help="bundle folder")
    info.set_defaults(run=_cmd_info)

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

    return parser


def main(argv: list[str] | None = None) -> int:
    status = _run(build_parser().parse_args(argv))
    if int(os.environ.get("WORLD_SIZE", "1")) > 1:
        _leave_torchrun_worker(status)
    return status


def _run(args: argparse.Namespace) -> int:
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


def _leave_torchrun_worker(status: int) -> None:
    """Exit without the interpreter's teardown. The run's files are written and its process
    group destroyed by now, but torch 2.13's gloo aborts now and then in that teardown
    ("terminate called without an active exception"; 1 in about 370 two-process test runs
    here), and torchrun then reports the whole run as failed."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


if __name__ == "__main__":
    sys.exit(main())
