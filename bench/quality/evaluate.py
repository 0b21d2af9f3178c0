"""`mogo bench eval BUNDLE --data DIR --evaluator DIR`: a bundle's text-to-motion quality on a test
split, by the protocol every paper reports (docs/evaluation.md), without torch.

Items are the test split's caption spans of 40..196 feature rows (cut to the first 196), the
standard loaders' rule; `--limit N` takes a fixed random sample of N of them. For each item the
bundle generates a motion from the caption with the ground-truth length (seed: `--seed` + the
item's index); the evaluator embeds captions and motions; the metrics come from
mogo.export.data.metrics. Rows: the ground truth (real motions against themselves, so its FID is 0
and its other columns are the references), the bundle's VQ reconstruction of the real motions
(encode then decode), and the bundle's generations.

Repeats: each of `--repeats` draws new R-precision batches and Diversity pairs; with
`--regenerate` each also generates the motions anew (new seeds), Guo et al.'s full protocol,
which multiplies the generation time by the repeats. Without it FID and MM-Dist do not vary, so
their interval is 0. MultiModality (`--mm-captions` captions x `--mm-generations`
generations, 10 pairs each) is on captions spread evenly over the sample; the protocol's 100 x 30
take about 13 minutes on this project's 2-core CPU, so the default is 10 x 30.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mogo.bench.quality.evaluator import OnnxEvaluator, TextMotionEvaluator
from mogo.clip import Motion
from mogo.export.data import metrics
from mogo.export.data.humanml3d import DatasetError, HumanML3DFolder
from mogo.generator import MotionGenerator
from mogo.motion.skeleton import MAX_FRAMES, MIN_FRAMES
from mogo.progress import Progress
from mogo.stream_decoder import StreamingDecoder

COLUMNS = ("R-Precision Top-1", "Top-2", "Top-3", "FID", "MM-Dist", "Diversity", "MultiModality")


@dataclass(frozen=True)
class TestItem:
    clip_id: str
    caption: str
    start: int  # feature rows [start, end) of the clip
    end: int

    @property
    def frames(self) -> int:
        return self.end - self.start


def caption_items(
    folder: HumanML3DFolder, split: str = "test", limit: int | None = None, seed: int = 0
) -> list[TestItem]:
    """Every caption span of MIN..MAX_FRAMES rows of a split (longer spans: their first
    MAX_FRAMES), or a fixed random sample of `limit` of them, in split order."""
    items = []
    for clip_id in folder.ids(split):
        if not folder.has_captions(clip_id):
            continue
        rows = len(folder.features(clip_id))
        for caption in folder.captions(clip_id):
            start, end = caption.span(rows)
            if end - start >= MIN_FRAMES:
                items.append(TestItem(clip_id, caption.text, start, min(end, start + MAX_FRAMES)))
    if not items:
        raise DatasetError(
            f"{folder.root / f'{split}.txt'}: no caption span of at least {MIN_FRAMES} frames"
        )
    if limit is not None and limit < len(items):
        keep = np.sort(np.random.default_rng(seed).permutation(len(items))[:limit])
        items = [items[k] for k in keep]
    return items


def parallel_map(fn: Callable, values: Sequence, threads: int, label: str, unit: str) -> list:
    """fn over values in `threads` threads (onnxruntime releases the GIL), in order, with a
    progress line."""
    progress = Progress(len(values), label, unit=unit)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        results = []
        for result in pool.map(fn, values):
            results.append(result)
            progress.update()
    progress.close()
    return results


def generate_items(
    generator: MotionGenerator,
    items: Sequence[TestItem],
    seed: int,
    threads: int = 1,
    label: str = "generating",
) -> list[Motion]:
    """One motion per item, from its caption, with its ground-truth length; item k's seed is
    seed + k, so any item can be reproduced alone."""

    def one(k: int) -> Motion:
        item = items[k]
        return generator.generate(item.caption, seconds=item.frames / generator.fps, seed=seed + k)

    return parallel_map(one, range(len(items)), threads, label, "clips")


def reconstruct(
    generator: MotionGenerator,
    clips: Sequence[np.ndarray],
    threads: int = 1,
    low_latency: bool = False,
) -> list[np.ndarray]:
    """Each clip's features through the bundle's VQ: encode, then decode to its length
    (`low_latency`: by the bundle's low-latency decoder, the frames a low-latency stream of
    those tokens gets)."""
    skeleton = generator.skeleton

    def one(features: np.ndarray) -> np.ndarray:
        real = Motion(
            features,
            np.zeros((len(features), skeleton.num_joints, 3), np.float32),
            generator.fps,
            np.zeros((0, 1), np.int64),
            skeleton,
        )
        tokens = generator.encode_motion(real)
        if not low_latency:
            return generator.decode(tokens, [], len(features)).features
        return generator.denormalised(window.decode_offline(tokens)[: len(features)])

    window = low_latency_window(generator) if low_latency else None
    return parallel_map(one, clips, threads, "VQ reconstruction", "clips")


def low_latency_window(generator: MotionGenerator) -> StreamingDecoder:
    """The bundle's low-latency decoder as its window graph, which decodes whole clips (its
    streams step the same decoder a token a call, mogo.stream_decoder.StepDecoder, which has
    no end padding): the frames of a low-latency stream of the same tokens, to float rounding,
    but at the clip's end."""
    graph = generator.manifest.vq.low_latency_decoder
    if graph is None:
        raise ValueError("this bundle has no low-latency decoder (manifest vq.low_latency_decoder)")
    path = generator.bundle.path(graph.file)
    return StreamingDecoder(path, graph.left_context, graph.lookahead, generator.codebook_size)


@dataclass
class EvalOptions:
    bundle: str | None  # None: the default bundle
    data: Path
    evaluator: Path | None  # an evaluator folder; None when `evaluate` is given an evaluator
    limit: int | None = None
    repeats: int = metrics.REPEATS
    seed: int = 0
    mm_captions: int = 10
    mm_generations: int = 30
    regenerate: bool = False
    threads: int = 1

    def check(self) -> None:
        if self.limit is not None and self.limit < metrics.R_PRECISION_BATCH:
            raise ValueError(
                f"--limit must be at least {metrics.R_PRECISION_BATCH} (one "
                f"R-precision batch), got {self.limit}"
            )
        if self.repeats < 1 or self.threads < 1 or self.seed < 0:
            raise ValueError(
                f"--repeats and --threads must be at least 1 and --seed "
                f"non-negative, got {self.repeats}, {self.threads}, {self.seed}"
            )
        if self.mm_captions < 0 or (
            self.mm_captions and self.mm_generations < metrics.MULTIMODALITY_PAIRS
        ):
            raise ValueError(
                f"--mm-captions must be >= 0 and --mm-generations >= "
                f"{metrics.MULTIMODALITY_PAIRS}, got {self.mm_captions}, "
                f"{self.mm_generations}"
            )
        if self.evaluator is not None and not Path(self.evaluator).is_dir():
            raise FileNotFoundError(f"{self.evaluator}: no such evaluator folder")


def score(
    text: np.ndarray,
    real: np.ndarray,
    motions: Callable[[int], np.ndarray],
    repeats: int,
    seed: int,
    per_caption: np.ndarray | None = None,
) -> dict:
    """The protocol's numbers for one row: motions(repeat) -> the row's motion embeddings
    (N, D) aligned with `text`; per_caption (captions, generations, D) for MultiModality.
    -> {column: (mean, interval)}."""
    pairs = min(metrics.DIVERSITY_PAIRS, len(real))

    def once(k: int) -> np.ndarray:
        rng = np.random.default_rng([seed, k])
        motion = motions(k)
        values = [
            *metrics.r_precision(text, motion, rng),
            metrics.fid(real, motion),
            metrics.matching_score(text, motion),
            metrics.diversity(motion, rng, pairs),
        ]
        if per_caption is not None:
            values.append(metrics.multimodality(per_caption, rng))
        return np.array(values)

    mean, interval = metrics.repeat_with_interval(once, repeats)
    return {
        column: (float(m), float(i)) for column, m, i in zip(COLUMNS, mean, interval, strict=False)
    }


def evaluate(options: EvalOptions, evaluator: TextMotionEvaluator | None = None) -> dict:
    """-> dict(rows={name: {column: (mean, interval)}}, items=N, notes=[...]); `evaluator`
    (another model behind the same seam) replaces the folder options.evaluator."""
    options.check()
    if evaluator is None and options.evaluator is None:
        raise ValueError("give an evaluator folder or an evaluator")
    folder = HumanML3DFolder(options.data, splits=("test",))
    evaluator = evaluator or OnnxEvaluator(options.evaluator, options.threads)
    generator = MotionGenerator.load(options.bundle)
    items = caption_items(folder, "test", options.limit, options.seed)
    real_features = [folder.features(item.clip_id)[item.start : item.end] for item in items]
    text = evaluator.embed_text([item.caption for item in items])
    real = evaluator.embed_motion(real_features)
    vq = evaluator.embed_motion(reconstruct(generator, real_features, options.threads))

    generated: dict[int, np.ndarray] = {}

    def bundle_motions(repeat: int) -> np.ndarray:
        key = repeat if options.regenerate else 0
        if key not in generated:
            label = (
                f"generating (repeat {repeat + 1}/{options.repeats})"
                if options.regenerate
                else "generating"
            )
            motions = generate_items(
                generator, items, options.seed + key * len(items), options.threads, label
            )
            generated[key] = evaluator.embed_motion([m.features for m in motions])
        return generated[key]

    per_caption = _multimodality(options, generator, evaluator, items)
    rows = {
        "Ground truth": score(text, real, lambda k: real, options.repeats, options.seed),
        "VQ reconstruction": score(text, real, lambda k: vq, options.repeats, options.seed),
        "Bundle": score(text, real, bundle_motions, options.repeats, options.seed, per_caption),
    }
    return dict(
        rows=rows,
        items=len(items),
        notes=_notes(options, len(items), per_caption),
        evaluator=str(getattr(evaluator, "folder", type(evaluator).__name__)),
    )


def _multimodality(options: EvalOptions, generator, evaluator, items) -> np.ndarray | None:
    """Motion embeddings (captions, generations, D) of mm_captions spread over the items,
    each generated mm_generations times (None where mm_captions is 0)."""
    if not options.mm_captions:
        return None
    chosen = items[:: max(1, len(items) // options.mm_captions)][: options.mm_captions]
    repeated = [item for item in chosen for _ in range(options.mm_generations)]
    motions = generate_items(
        generator, repeated, options.seed + 10**6, options.threads, "multimodality"
    )
    return evaluator.embed_motion([m.features for m in motions]).reshape(
        len(chosen), options.mm_generations, -1
    )


def _notes(options: EvalOptions, items: int, per_caption: np.ndarray | None) -> list[str]:
    """How the table was made: spans, repeats, pairs."""
    notes = [
        f"{items} test caption spans, ground-truth lengths, {options.repeats} repeats "
        f"(mean ± 95% interval)"
        + (
            "; motions regenerated every repeat"
            if options.regenerate
            else "; motions generated once, batches and pairs redrawn every repeat"
        ),
        f"Diversity over {min(metrics.DIVERSITY_PAIRS, items)} pairs",
    ]
    if per_caption is not None:
        notes.append(
            f"MultiModality: {len(per_caption)} captions x {options.mm_generations} "
            f"generations, {metrics.MULTIMODALITY_PAIRS} pairs each"
        )
    return notes


def format_table(result: dict) -> str:
    """The paper's table: `mean±interval` per column, 3 decimals."""
    lines = ["| Methods | " + " | ".join(COLUMNS) + " |", "|---|" + "---|" * len(COLUMNS)]
    for name, row in result["rows"].items():
        cells = [f"{row[c][0]:.3f}±{row[c][1]:.3f}" if c in row else "-" for c in COLUMNS]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines + [""] + [f"- {note}" for note in result["notes"]])
