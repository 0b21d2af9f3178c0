"""The text side of two bundles compared: `python -m mogo.bench.quality.text_encoder --data DIR
--before OLD [--after NEW] [--per-primitive N] [--seeds S] [--guidance G]` (torch-free; NEW
defaults to the shipped one).

Prints markdown tables:
- paraphrases from each phrasebook of mogo.bench.quality.paraphrases (key words no training
  caption uses; each of PHRASEBOOKS) of test-split single-segment items, generated with the
  item's real length and judged by the semantic checks (mogo.bench.quality.semantic), without
  and with the rule aligner;
- the in-vocabulary items themselves (their own test captions), the same way;
- which known caption each bundle plays the paraphrases and own captions as (where it plays
  one): the share that is a training caption of the item's own action, and of its action and
  the parameters it says (`played_rates`), no motion generated;
- the repertoire check of a bundle that has one: the share of test captions and of the
  paraphrases it accepts, and of the outside prompts (mogo.export.data.outside_repertoire.TEST,
  never used to set the threshold) it refuses;
- the text encoder's cost per prompt (median ms, batch of one, on `--threads`) and the
  bundle's size.
"""

from __future__ import annotations

import argparse
import collections
import time
import warnings
from pathlib import Path

import numpy as np

from mogo.bench.quality.paraphrases import (
    HELD_OUT,
    PHRASEBOOKS,
    caption_words,
    in_every_book,
    unseen_key_words,
)
from mogo.bench.quality.semantic import SemanticItem, check, program_items, stratified
from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.export.data.outside_repertoire import TEST
from mogo.generator import DEFAULT_BUNDLE, MotionGenerator
from mogo.repertoire import shown_caption


def pass_rate(
    generator: MotionGenerator,
    items: list[SemanticItem],
    prompts: list[str],
    real: list[np.ndarray],
    align: bool,
    seeds: int = 1,
    **sampling,
) -> tuple[float, dict[str, list[int]]]:
    """Share of generations that pass their item's check, `seeds` per item (item k of n with
    seeds k, n + k, 2n + k, ...); and per primitive [passed, generated]. `sampling`: options
    of MotionGenerator.generate (guidance=2, ...)."""
    per: dict[str, list[int]] = {}
    for k, (item, prompt) in enumerate(zip(items, prompts, strict=False)):
        for seed in range(k, seeds * len(items), len(items)):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    motion = generator.generate(
                        prompt,
                        seconds=item.frames / generator.fps,
                        seed=seed,
                        align=align,
                        **sampling,
                    )
                    passed = check(item, motion.joints, real[k]).passed
                except ValueError:  # the aligner found no motion in the prompt
                    passed = False
            counts = per.setdefault(item.primitive, [0, 0])
            counts[0] += passed
            counts[1] += 1
    return sum(c[0] for c in per.values()) / (seeds * len(items)), per


# What a phrasebook says of an item besides its action (mogo.bench.quality.paraphrases)
SAID = ("direction", "hand", "foot", "count", "angle")


def said(item: SemanticItem) -> tuple:
    return (item.primitive,) + tuple((k, item.params[k]) for k in SAID if k in item.params)


def known_captions(items: list[SemanticItem]) -> dict[str, tuple]:
    """Training caption, as Familiarity.played names it (mogo.repertoire.shown_caption) ->
    what it says (`said`) of the segment it most often covers."""
    counts: dict[str, collections.Counter] = {}
    for item in items:
        counts.setdefault(shown_caption(item.caption), collections.Counter())[said(item)] += 1
    return {caption: c.most_common(1)[0][0] for caption, c in counts.items()}


def played_rates(
    generator: MotionGenerator,
    items: list[SemanticItem],
    prompts: list[str],
    known: dict[str, tuple],
) -> tuple[int, float, float]:
    """Of the prompts played as a known caption (`generator.known(p).played`): how many, the
    share of them whose caption is of their item's action, and of its action and what it says
    (a caption of several actions is neither)."""
    played = [(item, generator.known(p).played) for item, p in zip(items, prompts, strict=False)]
    played = [(said(item), known.get(caption)) for item, caption in played if caption is not None]
    if not played:
        return 0, float("nan"), float("nan")
    return (
        len(played),
        float(np.mean([got is not None and got[0] == want[0] for want, got in played])),
        float(np.mean([got == want for want, got in played])),
    )


def encoder_ms(generator: MotionGenerator, prompts: list[str]) -> float:
    """Median ms of one prompt through the text graph (tokenizer included), batch of one."""
    times = []
    for prompt in prompts:
        start = time.perf_counter()
        generator.embed([prompt])
        times.append((time.perf_counter() - start) * 1000)
    return float(np.median(times))


def main() -> None:
    parser = _arguments()
    args = parser.parse_args()
    if args.seeds < 1:
        parser.error(f"--seeds must be at least 1, got {args.seeds}")
    folder = HumanML3DFolder(args.data, splits=("train", "test"))
    trained = caption_words(c.text for clip in folder.ids("train") for c in folder.captions(clip))
    items = stratified(program_items(args.data, folder.ids("test")), args.per_primitive, 0)
    books = in_every_book(items)
    seen = [w for book in PHRASEBOOKS for w in unseen_key_words(trained, book)]
    captions = [item.caption for item in items]
    real = [folder.joints(item.clip_id)[item.start : item.end] for item in items]
    bundles = {"before": args.before, "after": args.after}
    generators = {
        name: MotionGenerator.load(path, threads=args.threads) for name, path in bundles.items()
    }
    sampling = {} if args.guidance is None else dict(guidance=args.guidance)
    print(
        f"{len(items)} test items ({args.per_primitive} per primitive), {args.seeds} seed(s) "
        f"each{f', guidance {args.guidance:g}' if sampling else ''}; key words seen in "
        f"training captions: {', '.join(seen) or 'none'}.\n"
    )
    _pass_rates(generators, items, books, captions, real, args.seeds, sampling)
    known = known_captions(program_items(args.data, folder.ids("train")))
    _played_table(generators, items, books, captions, known)
    _repertoire_table(generators["after"], folder, books)
    print("\n| bundle | text encoder ms per prompt (median) | bundle MB |\n|---|---|---|")
    probe = [f"{p} ({k})" for k, p in enumerate(books[HELD_OUT.name][:60])]  # nothing cached
    for name, generator in generators.items():
        print(
            f"| {name} | {encoder_ms(generator, probe):.1f} | "
            f"{generator.manifest.total_bytes / 1e6:.1f} |"
        )


def _arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="the procedural corpus")
    parser.add_argument("--before", type=Path, required=True, help="the bundle compared with")
    parser.add_argument("--after", type=Path, default=DEFAULT_BUNDLE)
    parser.add_argument("--per-primitive", type=int, default=6)
    parser.add_argument(
        "--seeds",
        type=int,
        default=1,
        help="generations per item (seeds k, n + k, ...): less noise, more time",
    )
    parser.add_argument(
        "--guidance",
        type=float,
        default=None,
        help="classifier-free guidance scale (default: each bundle's own)",
    )
    parser.add_argument("--threads", type=int, default=2)
    return parser


def _pass_rates(generators, items, books, captions, real, seeds: int, sampling: dict) -> None:
    """The semantic checks' pass rate of each bundle on each phrasebook, with and without
    --align rules, and on the own captions; then per primitive."""
    print(
        "| bundle | "
        + " | ".join(f"{b} | {b}, --align rules" for b in books)
        + " | own captions |\n|---|"
        + "---|---|" * len(books)
        + "---|"
    )
    detail = {}
    for name, generator in generators.items():
        cells = []
        for book, prompts in books.items():
            plain, detail[name, book] = pass_rate(
                generator, items, prompts, real, False, seeds, **sampling
            )
            aligned, _ = pass_rate(generator, items, prompts, real, True, seeds, **sampling)
            cells += [f"{plain:.1%}", f"{aligned:.1%}"]
        own, _ = pass_rate(generator, items, captions, real, False, seeds, **sampling)
        print(f"| {name} ({generator.manifest.text.kind}) | {' | '.join(cells)} | {own:.1%} |")
    print(
        "\n| primitive | "
        + " | ".join(f"{book}, {name}" for name, book in detail)
        + " |\n|---|"
        + "---|" * len(detail)
    )
    for primitive in detail["after", HELD_OUT.name]:
        cells = " | ".join(f"{d[primitive][0]}/{d[primitive][1]}" for d in detail.values())
        print(f"| {primitive} | {cells} |")


def _played_table(generators, items, books, captions, known) -> None:
    """Where a bundle plays a prompt as a known caption: how often that caption does the
    prompt's action (and says what it says)."""
    print(
        "\nCaption played (where a bundle plays a prompt as a known caption): share of its "
        "own action / of its action and the "
        + ", ".join(SAID)
        + " it says\n\n| bundle | "
        + " | ".join([*books, "own captions"])
        + " |\n|---|"
        + "---|" * (len(books) + 1)
    )
    for name, generator in generators.items():
        if generator.repertoire is None or generator.repertoire.prompts is None:
            continue
        cells = [
            played_rates(generator, items, prompts, known)
            for prompts in [*books.values(), captions]
        ]
        print(
            f"| {name} | "
            + " | ".join(f"{action:.0%} / {both:.0%} (n {n})" for n, action, both in cells)
            + " |"
        )


def _repertoire_table(
    generator: MotionGenerator, folder: HumanML3DFolder, books: dict[str, list[str]]
) -> None:
    if generator.repertoire is None:
        return
    test = sorted({c.text for clip in folder.ids("test") for c in folder.captions(clip)})
    test = [test[k] for k in np.random.default_rng(0).permutation(len(test))[:500]]
    rows = {
        "test captions (accepted)": (test, True),
        **{f"{book} (accepted)": (prompts, True) for book, prompts in books.items()},
        "outside prompts, TEST list (refused)": (list(TEST), False),
    }
    threshold = generator.repertoire.threshold
    print(
        f"\nRepertoire check (threshold {threshold:.3f}, set at export on val captions and "
        "the CALIBRATION list):\n\n| prompts | n | rate |\n|---|---|---|"
    )
    for label, (texts, inside) in rows.items():
        familiar = [generator.known(t).familiar for t in texts]
        rate = np.mean(familiar) if inside else 1 - np.mean(familiar)
        print(f"| {label} | {len(texts)} | {rate:.1%} |")


if __name__ == "__main__":
    main()
