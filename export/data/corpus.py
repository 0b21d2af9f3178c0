"""`mogo data synth`: a procedural text-motion corpus in the HumanML3D layout.

Each clip is a program of 1-3 animator segments, captioned from templates. Every clip is made
from its own seed, SeedSequence(seed, spawn_key=(0, index)), so the corpus is the same
whatever the number of worker processes. The test split measures generalisation twice over:
a seed-chosen set of ordered primitive pairs ("walk then wave") appears only in test, and part
of the test clips are captioned only with held-out templates. Mirrored copies (M-prefixed IDs)
go in the same split as their originals, as in HumanML3D.

Two corpus versions: v1 (17 primitives, the shipped bundle's corpus, byte for byte what it
was) and v2 (39 primitives, performers whose steps vary, animator.CORPORA).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from functools import partial
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from mogo.export.data.animator import CORPORA, DEFAULT_CORPUS, Segment, animate, sample_segment
from mogo.export.data.animator_body import FPS
from mogo.export.data.caption_templates import JOINERS, TEMPLATES
from mogo.export.data.captions import caption_program, caption_segment
from mogo.export.data.humanml3d import format_caption_line
from mogo.export.data.normalization import STD_FLOOR, feature_statistics
from mogo.motion.features import joints_to_features
from mogo.motion.mirror import mirror_joints, mirror_text
from mogo.motion.skeleton import MAX_FRAMES, MIN_FRAMES, SMPL_22
from mogo.progress import Progress

GENERATOR_VERSION = 1
MAX_SEGMENTS = 3
MAX_ATTEMPTS = 100  # program draws per clip before giving up on the length limits
SPLIT_FRACTIONS = (("train", 0.80), ("val", 0.05), ("test", 0.15))
HELDOUT_PAIR_SHARE = 0.05  # of the ordered pairs of distinct non-idle primitives (v1: 12)
FORCED_PAIR_SHARE = 1 / 3  # test clips built around a held-out pair (more occur by chance)
HELDOUT_CAPTION_SHARE = 0.5  # test clips captioned from the held-out template pool
WHOLE_CAPTIONS = 3  # caption lines per clip; multi-segment clips give one to each segment
PARAPHRASE_TRIES = 10  # draws to find a caption not already on the clip


@dataclass(frozen=True)
class Plan:
    """What every clip needs to know about the corpus."""

    out: Path
    seed: int
    corpus: str
    heldout_pairs: frozenset[tuple[str, str]]


@dataclass(frozen=True)
class ClipResult:
    id: str
    split: str
    attempts: int


def heldout_pairs(seed: int, corpus: str = DEFAULT_CORPUS) -> list[tuple[str, str]]:
    """The ordered primitive pairs kept out of train and val, fixed by the seed."""
    names = sorted(p for p in CORPORA[corpus] if p != "idle")
    pairs = [(a, b) for a in names for b in names if a != b]
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
    chosen = rng.choice(len(pairs), size=round(HELDOUT_PAIR_SHARE * len(pairs)), replace=False)
    return sorted(pairs[k] for k in chosen)


def mirror_segment(segment: Segment) -> Segment:
    """The left-right mirror of a segment: sides swapped, turns reversed."""
    swap = {"left": "right", "right": "left"}
    params = {
        name: -value
        if name in ("turn", "angle")
        else swap.get(value, value)
        if isinstance(value, str)
        else value
        for name, value in segment.params.items()
    }
    return Segment(segment.primitive, params)


def _pairs(segments: list[Segment]) -> set[tuple[str, str]]:
    return {(a.primitive, b.primitive) for a, b in zip(segments[:-1], segments[1:], strict=False)}


def _draw_program(rng: np.random.Generator, plan: Plan, force_pair: bool) -> list[Segment]:
    """1-3 random segments; with `force_pair`, 2-3 segments around a held-out pair."""
    names = sorted(CORPORA[plan.corpus])
    if not force_pair:
        count = int(rng.integers(1, MAX_SEGMENTS + 1))
        return [sample_segment(names[int(rng.integers(len(names)))], rng) for _ in range(count)]
    pairs = sorted(plan.heldout_pairs)
    pair = list(pairs[int(rng.integers(len(pairs)))])
    if rng.random() < 0.5:
        extra = names[int(rng.integers(len(names)))]
        pair = [extra] + pair if rng.random() < 0.5 else pair + [extra]
    return [sample_segment(name, rng) for name in pair]


def _draw_clip(rng: np.random.Generator, plan: Plan, split: str):
    """A program and its animation within the length limits: out-of-range programs (and,
    outside test, programs with a held-out pair) are redrawn, never trimmed, so every
    caption describes the whole of its segment."""
    force_pair = split == "test" and rng.random() < FORCED_PAIR_SHARE
    for attempt in range(1, MAX_ATTEMPTS + 1):
        segments = _draw_program(rng, plan, force_pair)
        if split != "test" and _pairs(segments) & plan.heldout_pairs:
            continue
        animation = animate(segments, rng, natural=plan.corpus != "v1")
        if MIN_FRAMES <= animation.joints.shape[0] <= MAX_FRAMES:
            return segments, animation, attempt
    raise RuntimeError(
        f"no program within {MIN_FRAMES}-{MAX_FRAMES} frames in {MAX_ATTEMPTS} draws"
    )


def _captions(segments: list[Segment], spans, rng: np.random.Generator, pool: str) -> list[dict]:
    """WHOLE_CAPTIONS lines: whole-program paraphrases, and for multi-segment programs one
    line per segment with its time span; texts on one clip are distinct where possible."""
    whole = WHOLE_CAPTIONS if len(segments) == 1 else WHOLE_CAPTIONS - 1
    captions: list[dict] = []
    seen: set[str] = set()
    for _ in range(whole):
        for _ in range(PARAPHRASE_TRIES):
            sentence = caption_program(segments, rng, pool)
            if sentence.text not in seen:
                break
        seen.add(sentence.text)
        captions.append(
            {"text": sentence.text, "template_ids": list(sentence.template_ids), "span": None}
        )
    if len(segments) > 1:
        for segment, (start, end) in zip(segments, spans, strict=False):
            sentence = caption_segment(segment, rng, pool)
            captions.append(
                {
                    "text": sentence.text,
                    "template_ids": list(sentence.template_ids),
                    "span": [int(start), int(end)],
                }
            )
    return captions


def _write_clip(plan: Plan, clip_id: str, joints: np.ndarray, program: dict) -> None:
    features, canonical = joints_to_features(joints, SMPL_22)
    np.save(plan.out / "new_joint_vecs" / f"{clip_id}.npy", features)
    np.save(plan.out / "new_joints" / f"{clip_id}.npy", canonical)
    lines = [
        format_caption_line(
            c["text"], *((c["span"][0] / FPS, c["span"][1] / FPS) if c["span"] else (0.0, 0.0))
        )
        for c in program["captions"]
    ]
    (plan.out / "texts" / f"{clip_id}.txt").write_text("\n".join(lines) + "\n")
    (plan.out / "programs" / f"{clip_id}.json").write_text(json.dumps(program, indent=1) + "\n")


def make_clip(index: int, plan: Plan) -> ClipResult:
    """Draw, animate, caption and write clip `index` and its mirror."""
    rng = np.random.default_rng(np.random.SeedSequence(plan.seed, spawn_key=(0, index)))
    split = SPLIT_FRACTIONS[-1][0]
    draw, edge = rng.random(), 0.0
    for name, fraction in SPLIT_FRACTIONS:
        edge += fraction
        if draw < edge:
            split = name
            break
    segments, animation, attempts = _draw_clip(rng, plan, split)
    pool = "heldout" if split == "test" and rng.random() < HELDOUT_CAPTION_SHARE else "train"
    spans = [(int(s), int(e)) for s, e in animation.spans]
    captions = _captions(segments, spans, rng, pool)
    clip_id = f"{index:06d}"
    program = {
        "id": clip_id,
        "mirror_of": None,
        "seed": [plan.seed, index],
        "split": split,
        "frames": int(animation.joints.shape[0]),
        "fps": FPS,
        "caption_pool": pool,
        "heldout_pairs": sorted(map(list, _pairs(segments) & plan.heldout_pairs)),
        "segments": [
            {"primitive": s.primitive, "params": s.params, "span": list(span)}
            for s, span in zip(segments, spans, strict=False)
        ],
        "captions": captions,
    }
    _write_clip(plan, clip_id, animation.joints, program)
    mirrored = dict(program, id="M" + clip_id, mirror_of=clip_id)
    mirrored["segments"] = [
        dict(s, params=mirror_segment(seg).params)
        for s, seg in zip(program["segments"], segments, strict=False)
    ]
    mirrored["captions"] = [dict(c, text=mirror_text(c["text"])) for c in captions]
    _write_clip(plan, "M" + clip_id, mirror_joints(animation.joints, SMPL_22), mirrored)
    return ClipResult(clip_id, split, attempts)


def synthesize_corpus(
    out: Path,
    num_clips: int,
    seed: int,
    progress: bool = True,
    workers: int | None = None,
    corpus: str = DEFAULT_CORPUS,
) -> dict:
    """Write `num_clips` clips of corpus version `corpus` and their mirrors to `out` (which
    must be new or empty); returns the corpus summary also written as corpus.json."""
    out = Path(out)
    if corpus not in CORPORA:
        raise ValueError(f"unknown corpus {corpus!r}; expected one of {', '.join(CORPORA)}")
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out} is not empty; choose a new folder")
    if num_clips < 1:
        raise ValueError(f"num_clips must be at least 1, got {num_clips}")
    workers = workers or os.cpu_count() or 1
    for sub in ("new_joint_vecs", "new_joints", "texts", "programs"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    plan = Plan(out, seed, corpus, frozenset(heldout_pairs(seed, corpus)))

    splits: dict[str, list[str]] = {name: [] for name, _ in SPLIT_FRACTIONS}
    attempts = 0
    bar = Progress(num_clips, "synthesizing", enabled=progress)
    make = partial(make_clip, plan=plan)
    with Pool(workers) if workers > 1 else _InProcess() as pool:
        for result in pool.imap(make, range(num_clips), chunksize=4):
            splits[result.split] += [result.id, "M" + result.id]
            attempts += result.attempts
            bar.update()
    elapsed = bar.close()

    mean, std = feature_statistics(
        np.load(out / "new_joint_vecs" / f"{clip_id}.npy")
        for clip_id in splits["train"] or splits["test"]
    )
    np.save(out / "Mean.npy", mean)
    np.save(out / "Std.npy", std)
    for name, ids in splits.items():
        (out / f"{name}.txt").write_text("".join(f"{i}\n" for i in ids))
    summary = _summary(plan, num_clips, splits, attempts)
    (out / "corpus.json").write_text(json.dumps(summary, indent=1) + "\n")
    if progress:
        counts = ", ".join(f"{len(ids)} {name}" for name, ids in splits.items())
        print(
            f"wrote {num_clips} clips and their mirrors to {out} ({counts} IDs) in {elapsed:.0f}s"
        )
    return summary


def _summary(plan: Plan, num_clips: int, splits: dict[str, list[str]], attempts: int) -> dict:
    """corpus.json: how the corpus was made, its splits and what is held out of training."""
    return {
        "generator_version": GENERATOR_VERSION,
        "corpus": plan.corpus,
        "seed": plan.seed,
        "clips": num_clips,
        "primitives": len(CORPORA[plan.corpus]),
        "ids_per_split": {name: len(ids) for name, ids in splits.items()},
        "fps": FPS,
        "frames": [MIN_FRAMES, MAX_FRAMES],
        "program_draws_per_clip": round(attempts / num_clips, 3),
        "heldout_pairs": [list(p) for p in sorted(plan.heldout_pairs)],
        "heldout_templates": sorted(
            {t.id for name in CORPORA[plan.corpus] for t in TEMPLATES[name] if t.heldout}
        )
        + [j.id for j in JOINERS if j.heldout],
        "heldout_caption_share_of_test": HELDOUT_CAPTION_SHARE,
        "std_floor": STD_FLOOR,
        "statistics_from": "train" if splits["train"] else "test",
    }


class _InProcess:
    """Pool's imap without processes, for workers=1."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        return None

    def imap(self, fn, items, chunksize: int = 1):
        return map(fn, items)
