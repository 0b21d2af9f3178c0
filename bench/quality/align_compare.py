"""Prompt alignment on held-out paraphrases: `python -m mogo.bench.quality.align_compare --data DIR
[--limit N] [--seeds S] [--evaluator DIR]`.

Builds free-form requests from the ground-truth programs of the test split with paraphrase
templates written here, which the corpus never used ("could you have somebody wander ahead,
and afterwards give a wave with the right hand"), and compares the default bundle without
and with the rule aligner. Prints a markdown table of what can be measured without the
evaluator:

- words the bundle's tokenizer does not know, in the request and in the aligned steps;
- whether alignment found as many steps as the program has segments;
- direction of travel: for each straight walk / jog / run segment, whether the root moved
  within 45 degrees of the asked direction (forward, backward, left, right in the body frame
  at the segment's start) by at least 0.2 m, over the segment's span (without alignment:
  the ground-truth span; with it: the aligned step's span when the steps match the segments).

With --evaluator (a `mogo train evaluator` export) the generated clips are also scored against
the program's own caption and the real clip: R-precision, FID and MM-Dist over the same
programs and seeds (mogo.bench.quality.evaluate.score, 20 repeats).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from mogo.align import plain_words
from mogo.bench.quality.evaluate import COLUMNS, score
from mogo.bench.quality.evaluator import OnnxEvaluator
from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.generator import MotionGenerator

DIRECTIONS = {
    "forward": ["ahead", "straight ahead", "forward"],
    "backward": ["backwards", "back"],
    "left": ["over to the left", "to the left"],
    "right": ["over to the right", "to the right"],
}
WRAPPERS = [
    "could you have somebody {}",
    "i want the guy to {}",
    "make them {}",
    "{} please",
    "the character should {}",
    "{}",
]
JOINERS = [
    ", and afterwards ",
    " and once that's done, ",
    "; next, ",
    ", then ",
    " and after that ",
]
LOCOMOTION = ("walk", "jog", "run")


def times(n: int) -> str:
    return {1: "once", 2: "twice"}.get(n, f"{n} times")


def counted(n: int, noun: str, plural: str | None = None) -> str:
    return f"a {noun}" if n == 1 else f"{n} {plural or noun + 's'}"


def paraphrase(segment: dict, rng: np.random.Generator) -> str:
    """One segment as an imperative request in words of our own."""
    p = segment["params"]

    def pick(options):
        return options[int(rng.integers(len(options)))]

    n = p.get("count", 1)
    hand = p.get("hand", "right")
    phrases = {
        "walk": lambda: pick(["wander {d}", "take a walk {d}", "amble {d}", "go {d} on foot"]),
        "jog": lambda: pick(["jog {d}", "do a little jog {d}", "trot {d}"]),
        "run": lambda: pick(["sprint {d}", "run {d} as fast as possible", "hurry {d}"]),
        "turn": lambda: pick(
            [
                f"turn toward the {'left' if p['angle'] > 0 else 'right'}",
                f"rotate to the {'left' if p['angle'] > 0 else 'right'}",
            ]
        ),
        "jump": lambda: pick(
            [
                f"hop {'forward' if p['forward'] else 'in place'} {times(n)}",
                f"jump {'ahead' if p['forward'] else 'on the spot'} {times(n)}",
            ]
        ),
        "squat": lambda: pick([f"do {counted(n, 'squat')}", f"crouch down {times(n)}"]),
        "sit": lambda: pick(["have a seat", "sit down on a chair", "plop down into a chair"]),
        "bow": lambda: pick(["take a bow", "bow to the audience"]),
        "wave": lambda: pick(
            [f"wave the {hand} hand {times(n)}", f"give a wave with the {hand} hand"]
        ),
        "raise_arms": lambda: pick(
            [f"lift the {hand} arm up high", f"put the {hand} arm in the air"]
        ),
        "clap": lambda: pick([f"clap {times(n)}", f"applaud {times(n)}"]),
        "punch": lambda: pick(
            [
                f"jab {times(n)} with the {hand} hand",
                f"throw {counted(n, 'punch', 'punches')} with the {hand} fist",
            ]
        ),
        "kick": lambda: pick(
            [f"kick out the {p.get('foot')} leg", f"do a kick with the {p.get('foot')} foot"]
        ),
        "spin": lambda: pick(
            [f"spin all the way around to the {p.get('direction')}", "twirl around"]
        ),
        "stretch": lambda: pick(["stretch out", "do a big stretch"]),
        "jumping_jacks": lambda: pick(
            [f"do {counted(n, 'star jump')}", f"do jumping jacks {times(n)}"]
        ),
        "idle": lambda: pick(
            [f"stand still for {round(p['seconds'])} seconds", "wait for a moment"]
        ),
    }
    text = phrases[segment["primitive"]]()
    return text.format(d=pick(DIRECTIONS[p["direction"]])) if "{d}" in text else text


def request(program: dict, rng: np.random.Generator) -> str:
    parts = [paraphrase(s, rng) for s in program["segments"]]
    text = parts[0]
    for part in parts[1:]:
        text += JOINERS[int(rng.integers(len(JOINERS)))] + part
    return WRAPPERS[int(rng.integers(len(WRAPPERS)))].format(text)


def straight_locomotion(program: dict) -> list[int]:
    return [
        k
        for k, s in enumerate(program["segments"])
        if s["primitive"] in LOCOMOTION and abs(s["params"]["turn"]) < 10
    ]


def went_the_right_way(joints: np.ndarray, start: int, end: int, direction: str) -> bool:
    """Root displacement within 45 degrees of the asked direction, at least 0.2 m, in the
    body frame at `start` (left = left hip - right hip; forward = left x up)."""
    across = joints[start, 1, [0, 2]] - joints[start, 2, [0, 2]]
    left = across / np.linalg.norm(across)
    forward = np.array([-left[1], left[0]])
    wanted = {"forward": forward, "backward": -forward, "left": left, "right": -left}[direction]
    moved = joints[min(end, len(joints)) - 1, 0, [0, 2]] - joints[start, 0, [0, 2]]
    distance = np.linalg.norm(moved)
    return distance >= 0.2 and moved @ wanted >= np.cos(np.pi / 4) * distance


def unknown_fraction(texts: list[str], vocabulary: set[str]) -> float:
    words = [w for text in texts for w in plain_words(text) if w.isalpha()]
    return sum(w not in vocabulary for w in words) / max(1, len(words))


def main() -> None:
    args = _arguments().parse_args()
    folder = HumanML3DFolder(args.data, splits=("test",))
    programs = []
    for clip in folder.ids("test"):
        program = json.loads((args.data / "programs" / f"{clip}.json").read_text())
        if program["mirror_of"] is None:
            programs.append(program)
        if len(programs) == args.text_limit:
            break
    generator = MotionGenerator.load(threads=1)
    vocabulary = generator.vocabulary()
    rules = generator.aligner(True)
    requests = [request(p, np.random.default_rng(k)) for k, p in enumerate(programs)]
    alignments = [rules.align(text) for text in requests]
    matched = [
        len(a.steps) == len(p["segments"]) for a, p in zip(alignments, programs, strict=False)
    ]
    before = unknown_fraction(requests, vocabulary)
    after = unknown_fraction([s.prompt for a in alignments for s in a.steps], vocabulary)

    start = time.perf_counter()
    walking = [k for k, p in enumerate(programs) if straight_locomotion(p)][: args.limit]
    right, scored = _walks(
        generator,
        rules,
        folder,
        [(programs[k], requests[k], alignments[k], matched[k]) for k in walking],
        args.seeds,
    )
    elapsed = time.perf_counter() - start

    checks = len(right["without"])
    print(
        f"Held-out paraphrases of {len(programs)} test programs (default bundle, rule "
        f"aligner); direction over {checks} straight walk/jog/run segments of "
        f"{len(walking)} programs x {args.seeds} seeds ({elapsed:.0f} s generating).\n"
    )
    print("| measure | without alignment | with alignment |\n|---|---|---|")
    print(f"| words unknown to the tokenizer | {before:.1%} | {after:.1%} |")
    print(f"| steps = program segments | - | {np.mean(matched):.1%} |")
    print(
        f"| direction of travel right | {np.mean(right['without']):.1%} | "
        f"{np.mean(right['with']):.1%} |"
    )
    if args.evaluator is None:
        print("| R-precision / FID / MM-Dist | needs --evaluator | needs --evaluator |")
        return
    _print_evaluator_rows(args.evaluator, scored)


def _arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="the procedural corpus folder")
    parser.add_argument(
        "--limit",
        type=int,
        default=40,
        help="programs with a straight walk/jog/run that are generated",
    )
    parser.add_argument(
        "--text-limit",
        type=int,
        default=2000,
        help="programs whose requests are aligned (text measures only)",
    )
    parser.add_argument("--seeds", type=int, default=2, help="generations per program")
    parser.add_argument(
        "--evaluator", type=Path, help="an evaluator folder: adds R-precision, FID and MM-Dist"
    )
    return parser


def _walks(generator, rules, folder, walks: list, seeds: int) -> tuple[dict, dict]:
    """Each straight walk/jog/run program generated from its request with and without the
    rules, `seeds` times: whether each segment went the right way, and what the evaluator
    scores (the caption, the real clip, both generations)."""
    right = {"without": [], "with": []}
    scored: dict[str, list] = {"caption": [], "real": [], "without": [], "with": []}
    for program, text, alignment, matched in walks:
        seconds = program["frames"] / program["fps"]
        scaled = alignment.scaled(seconds)
        aligned_spans = np.cumsum([0] + [round(s.seconds * generator.fps) for s in scaled.steps])
        for seed in range(seeds):
            plain = generator.generate(text, seconds=seconds, seed=seed)
            aligned = generator.generate(text, seconds=seconds, seed=seed, align=rules)
            scored["caption"].append(program["captions"][0]["text"])
            scored["real"].append(folder.features(program["id"]))
            scored["without"].append(plain.features)
            scored["with"].append(aligned.features)
            for index in straight_locomotion(program):
                segment = program["segments"][index]
                direction = segment["params"]["direction"]
                span = segment["span"]
                right["without"].append(went_the_right_way(plain.joints, *span, direction))
                if matched:
                    span = aligned_spans[index], aligned_spans[index + 1]
                right["with"].append(went_the_right_way(aligned.joints, *span, direction))
    return right, scored


def _print_evaluator_rows(evaluator_folder: Path, scored: dict) -> None:
    evaluator = OnnxEvaluator(evaluator_folder)
    text = evaluator.embed_text(scored["caption"])
    real = evaluator.embed_motion(scored["real"])
    rows = {
        kind: score(
            text,
            real,
            lambda k, m=evaluator.embed_motion(scored[kind]): m,  # noqa: B008
            repeats=20,
            seed=0,  # the embedding bound once per kind, on purpose
        )
        for kind in ("without", "with")
    }
    for column in [c for c in COLUMNS if c in ("R-Precision Top-1", "Top-3", "FID", "MM-Dist")]:
        cells = " | ".join(
            f"{rows[k][column][0]:.3f} ± {rows[k][column][1]:.3f}" for k in ("without", "with")
        )
        print(f"| {column} (vs the program's caption and clip, {len(text)} clips) | {cells} |")


if __name__ == "__main__":
    main()
