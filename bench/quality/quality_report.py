"""The quality report of a bundle (default: the shipped one), as markdown, in one command:

    python -m mogo.bench.quality.quality_report --data DIR --evaluator RUN/evaluator \
        --out docs/quality.md

the metric table of `mogo bench eval`, the per-primitive semantic pass rates (mogo.bench.quality.semantic)
for the real and the generated clips, the foot measures (mogo.bench.quality.feet), and the
MoSA-VQ ablation table that
`python -m mogo.bench.training.vq_ablation --runs RUNS` writes to RUNS/ablation.md
(`--ablation RUNS`; the report says when there is none). Torch-free.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from mogo.bench.quality.evaluate import EvalOptions, evaluate, format_table
from mogo.bench.quality.feet import LOCOMOTION, SECONDS, SEEDS, feet_rows, format_feet
from mogo.bench.quality.semantic import format_semantic, semantic_report
from mogo.generator import DEFAULT_BUNDLE, MotionGenerator


def ablation_section(ablation: Path | None) -> str:
    path = (
        None if ablation is None else (ablation / "ablation.md" if ablation.is_dir() else ablation)
    )
    if path is None or not path.is_file():
        where = f" ({path} does not exist)" if path is not None else ""
        return (
            f"Missing{where}: run `python -m mogo.bench.training.vq_ablation --data DIR "
            f"--runs RUNS` and pass `--ablation RUNS`."
        )
    return path.read_text().strip()


def report(args: argparse.Namespace) -> str:
    start = time.perf_counter()
    options = EvalOptions(
        args.bundle,
        args.data,
        args.evaluator,
        args.limit,
        args.repeats,
        args.seed,
        args.mm_captions,
        args.mm_generations,
        threads=args.threads,
    )
    metrics = evaluate(options)
    metrics_seconds = time.perf_counter() - start
    generator = MotionGenerator.load(args.bundle)
    semantic = semantic_report(generator, args.data, args.per_primitive, args.seed, args.threads)
    feet = format_feet(feet_rows(generator, args.data))
    seconds = time.perf_counter() - start
    evaluator_line = _evaluator_line(Path(args.evaluator))
    command = "python -m mogo.bench.quality.quality_report " + " ".join(
        map(shlex.quote, sys.argv[1:])
    )
    return "\n".join(
        [
            f"# Quality report: {args.bundle or 'the default bundle'}",
            "",
            f"Regenerate with `{command}` (torch-free; {seconds / 60:.0f} min on this project's "
            f"2-core CPU with {args.threads} thread(s), of which {metrics_seconds / 60:.0f} min for "
            f"the metrics).",
            "",
            f"Bundle `{args.bundle or DEFAULT_BUNDLE.name}`; test split of `{args.data}`; evaluator "
            f"{evaluator_line}.",
            "",
            "## Text-motion metrics",
            "",
            "The protocol of Guo et al. (docs/evaluation.md) with this project's own "
            "evaluator (mogo.export.models.evaluator: unit-length embeddings, so distances are on a "
            "different scale from papers using the HumanML3D evaluator; compare rows, not "
            "papers).",
            "",
            format_table(metrics),
            "",
            *_check_sections(args, semantic, feet),
            "## MoSA-VQ ablation",
            "",
            ablation_section(args.ablation),
            "",
        ]
    )


def _check_sections(args: argparse.Namespace, semantic, feet: str) -> list[str]:
    """The report's checks on joint positions: does the motion do what the caption says, and
    the feet."""
    return [
        "## Does the motion do what the caption says?",
        "",
        f"Captions that describe one program segment, checked on joint positions "
        f"(mogo.bench.quality.semantic). Real clips: every such caption of the test split. "
        f"Generated: {args.per_primitive} captions per primitive, generated with the real "
        f"length. The "
        f"last column runs the same checks on the real clip of another primitive: how often a "
        f"check passes what it should not.",
        "",
        format_semantic(semantic),
        "",
        "## Feet",
        "",
        f"Foot sliding, floor and leg bones of {len(LOCOMOTION) * SEEDS} generated locomotion "
        f"clips of {SECONDS:g} s, as decoded and with the runtime's foot planting (the default), "
        f"and of the real test clips (mogo.bench.quality.feet; docs/feet.md).",
        "",
        feet,
        "",
    ]


def _evaluator_line(folder: Path) -> str:
    """The evaluator folder, with its step and validation R-precision where it records them."""
    manifest = json.loads((folder / "evaluator.json").read_text())
    trained = manifest.get("training", {})
    val = trained.get("val", {})
    if not val:
        return f"`{folder}`"
    return (
        f"`{folder}`: step {trained.get('step')}, validation R-precision "
        f"top-1/2/3 {val.get('r1', float('nan')):.3f} / "
        f"{val.get('r2', float('nan')):.3f} / {val.get('r3', float('nan')):.3f} "
        f"(batches of 32)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="the procedural corpus")
    parser.add_argument("--evaluator", type=Path, required=True, help="evaluator folder")
    parser.add_argument("--bundle", help="bundle folder (default: the shipped one)")
    parser.add_argument("--out", type=Path, required=True, help="markdown file to write")
    parser.add_argument("--limit", type=int, default=300, help="test caption spans for the metrics")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--mm-captions", type=int, default=10)
    parser.add_argument("--mm-generations", type=int, default=30)
    parser.add_argument(
        "--per-primitive",
        type=int,
        default=20,
        help="generated captions per primitive for the semantic check",
    )
    parser.add_argument("--ablation", type=Path, help="the vq_ablation --runs folder")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    text = report(args)
    args.out.write_text(text)
    print(text)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
