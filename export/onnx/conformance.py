"""Conformance vectors: cases made by our runtime on the portable bundle, which a port of the
token loop (docs/spec.md) checks itself against, and the one rule it checks them by.

    python -m mogo.export.onnx.conformance      # rewrites runtime/web/conformance.json
                                                # and runtime/web/words.json

Three kinds of case, in one JSON file (no pickle, ~320 KB):
- "random": a seed's first uniforms from numpy's PCG64 (the port's random stream);
- "sampler": one level's logits, the options and a uniform -> the token (float64 rules of
  mogo.sampling, exact);
- "generate": a schedule of prompts (text, embedding, steps; one for `generate`, several
  for the token loop switched between them, not re-anchored), seed, sampling, window and step count -> the uniforms of every step, the
  tokens, each token's margin and gap, and the joints (feet not planted; some cases also with them
  planted, `joints_planted`).
Tokens must match exactly, except from the first step where ours had a near tie (its margin
below `tolerances`): there a port may pick the other token, and the case stops comparing.
Joints are compared only for a case whose tokens all matched, within `tolerances.joints_m`.
"""

from __future__ import annotations

import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from mogo import MotionGenerator
from mogo.generator import DEFAULT_BUNDLE
from mogo.sampling import Sampling, choose_tokens, make_rng

VECTORS = Path(__file__).resolve().parents[2] / "runtime" / "web" / "conformance.json"
WORDS = VECTORS.with_name("words.json")  # what the port needs of mogo.anchoring's words
FORMAT = "mogo-conformance"
TOLERANCES = dict(  # other CPUs move the logits by ~5e-6 (docs/portable.md)
    tie_logit=1e-3,  # the chosen token's guided logit this close to a neighbour's: a near tie
    tie_mass=1e-5,  # sampled: the draw (or the top-p cut) this close to an edge of the chosen
    # token's share, as a share of the kept probability, is a near tie (greedy: margin = gap)
    joints_m=1e-3,  # joints: largest difference, metres
    prompt_embedding=1e-3,
)  # the text encoder's output, largest difference
GENERATE = (  # name, [(prompt, token steps), ...], seed, sampling options, window (None: the
    # bundle's, 128 steps: the 5-s walk's 100 + 31 steps go past it); 20 steps a second
    ("walk_5s", [("a person walks forward", 100)], 0, {}, None),
    ("jump_greedy", [("a person jumps", 40)], 1, dict(temperature=0.0), None),
    (
        "wave_guided_window8",
        [("a person waves with the right hand", 40)],
        2,
        dict(temperature=0.8, top_k=50, guidance=2.0),
        8,
    ),
    ("walk_then_jump", [("a person walks forward", 60), ("a person jumps", 40)], 4, {}, None),
)
PLANTED = ("jump_greedy", "wave_guided_window8")  # cases that also hold their joints with the
# feet planted (two short ones: the file's size)
SAMPLER_CLASSES = 64  # logits of a sampler case: the rule is the same for any number
SEEDS = (0, 1, 12345, 2**40 + 7)
DRAWS = 12


def margins(
    cond: np.ndarray,
    uncond: np.ndarray | None,
    uniform: float,
    sampling: Sampling,
    forbid: int | None,
) -> tuple[float, float]:
    """How far one level's draw is from picking another token, as (margin, gap). `gap`: the
    logits (guided) of the chosen token and of its nearest neighbour in the sorted order, a
    difference that float noise can reverse (codes with twin logits are common). `margin`:
    greedy, the same gap; sampled, the distance of the draw (and of the top-p cut) from the
    edges of the chosen token's share, over the kept total. The arithmetic of mogo.sampling."""
    z = np.asarray(cond, np.float64)
    if sampling.guided:
        u = np.asarray(uncond, np.float64)
        z = np.where(np.isneginf(z) & np.isneginf(u), -np.inf, u + sampling.guidance * (z - u))
    if forbid is not None:
        z = z.copy()
        z[forbid] = -np.inf
    logits = np.sort(z[np.isfinite(z)])[::-1]
    if sampling.temperature == 0:
        gap = float(logits[0] - logits[1]) if len(logits) > 1 else math.inf
        return gap, gap
    z = logits / sampling.temperature
    keep = len(z) if not sampling.top_k else min(len(z), sampling.top_k)
    p = np.where(np.arange(len(z)) < keep, np.exp(z - z[0]), 0.0)
    c = np.cumsum(p)
    edge = math.inf
    if sampling.top_p < 1:
        cut = sampling.top_p * c[keep - 1]
        edge = float(np.min(np.abs((c - p)[1:keep] - cut)) / c[keep - 1]) if keep > 1 else edge
        keep = int(np.count_nonzero((c - p)[:keep] < cut))
    total = c[keep - 1]
    target = uniform * total
    index = int(np.count_nonzero(c[:keep] <= target))
    low = c[index - 1] if index else 0.0
    neighbours = [logits[i] for i in (index - 1, index + 1) if 0 <= i < len(logits)]
    gap = min((abs(logits[index] - n) for n in neighbours), default=math.inf)
    return min(edge, float(min(target - low, c[index] - target) / total)), float(gap)


def make_vectors(bundle_dir: Path) -> dict:
    """Every case, made by our runtime on the (portable) bundle at `bundle_dir`."""
    generator = MotionGenerator.load(bundle_dir)
    manifest = generator.manifest
    return dict(
        format=FORMAT,
        version=1,
        bundle=dict(
            made_by="mogo export --portable --bundle <the default bundle>",
            graphs={g.file: manifest.files[g.file].sha256 for g in manifest.graphs()},
        ),
        tolerances=TOLERANCES,
        random=[dict(seed=seed, uniforms=make_rng(seed).random(DRAWS).tolist()) for seed in SEEDS],
        sampler=_sampler_cases(SAMPLER_CLASSES),
        generate=[_generate_case(generator, *case) for case in GENERATE],
    )


def _sampler_cases(classes: int) -> list[dict]:
    rng = np.random.default_rng(7)
    cases = []
    options = [
        dict(temperature=0.0),
        {},
        dict(top_p=0.9),
        dict(top_k=5),
        dict(temperature=0.5),
        dict(temperature=2.0, top_p=0.5, top_k=100),
        dict(guidance=3.0, top_p=0.9),
        dict(guidance=0.0),
        dict(temperature=0.0, guidance=2.0),
    ]
    for k, option in enumerate(options):
        sampling = Sampling(**option)
        cond = (rng.normal(size=classes) * 3).astype(np.float32)
        uncond = (rng.normal(size=classes) * 3).astype(np.float32) if sampling.guided else None
        if k == 1:  # ties: the lower id first
            cond[[3, 9, 40]] = cond.max() + 1
        forbid = classes - 1 if k % 2 else None
        uniform = float(rng.random())
        token = choose_tokens(
            cond[None],
            None if uncond is None else uncond[None],
            np.array([uniform]),
            sampling,
            [forbid],
        )[0]
        cases.append(
            dict(
                sampling=vars(sampling),
                uniform=uniform,
                forbid=forbid,
                cond=cond.tolist(),
                uncond=None if uncond is None else uncond.tolist(),
                token=int(token),
            )
        )
    return cases


def _generate_case(
    generator: MotionGenerator,
    name: str,
    schedule: list[tuple[str, int]],
    seed: int,
    options: dict,
    window: int | None,
) -> dict:
    """`generate` (one prompt) or the token loop switched between several prompts, of the
    given token steps, the lookahead's steps drawn beyond them, the feet not planted; each
    level's logits caught on their way to the sampler to measure the margins."""
    sampling = generator.sampling(**options)
    tokens_gen = generator.tokens.with_level_workers(1)
    caught = _catching(tokens_gen)
    entries = [
        dict(prompt=prompt, prompt_embedding=generator.embed([prompt])[0].tolist(), steps=steps)
        for prompt, steps in schedule
    ]
    frames = sum(steps for _, steps in schedule) * generator.down_factor
    case = dict(
        name=name,
        schedule=entries,
        seed=seed,
        sampling=vars(sampling),
        window=generator.defaults.window if window is None else window,
        steps=frames // generator.down_factor + generator.manifest.vq.decoder.lookahead,
        frames=frames,
    )
    uniforms = make_rng(seed).random((case["steps"], tokens_gen.num_levels))
    case_margins = []

    def measured(row: np.ndarray) -> np.ndarray:
        n = len(case_margins)
        case_margins.append(
            [
                margins(
                    logits[0],
                    logits[1] if sampling.guided else None,
                    uniforms[n, level],
                    sampling,
                    tokens_gen.end_token if level == 0 else None,
                )
                for level, logits in enumerate(caught[-tokens_gen.num_levels :])
            ]
        )
        return row

    tokens = run_tokens(tokens_gen, case, measured)
    joints, planted = _joints(generator, schedule, tokens, frames, seed, planted=name in PLANTED)
    if planted is not None:
        case["joints_planted"] = planted
    return dict(
        case,
        uniforms=uniforms.tolist(),
        tokens=tokens.tolist(),
        margins=[[float(f"{m:.3g}") for m, _ in row] for row in case_margins],
        gaps=[[float(f"{g:.3g}") for _, g in row] for row in case_margins],
        joints=joints,
    )


def _joints(generator, schedule, tokens: np.ndarray, frames: int, seed: int, planted: bool):
    """A case's joints from its tokens, rounded: the feet not planted, and planted where
    asked (None otherwise). Each prompt starts at the frame the token loop switched to it."""
    prompts, start = [], 0
    for prompt, steps in schedule:
        prompts.append((start, prompt))
        start += steps * generator.down_factor
    motion = generator.decode(tokens, prompts, frames, seed, plant_feet=False)
    if not planted:
        return _rounded(motion.joints), None
    return _rounded(motion.joints), _rounded(generator.decode(tokens, prompts, frames, seed).joints)


def _catching(tokens_gen) -> list[np.ndarray]:
    """The list that every level's logits are appended to on their way to the sampler."""
    caught: list[np.ndarray] = []
    run = tokens_gen.run

    def catching(level, *args):
        logits, presents = run(level, *args)
        caught.append(logits)
        return logits, presents

    tokens_gen.run = catching
    return caught


def _rounded(joints: np.ndarray) -> list:
    return np.round(joints.astype(np.float64), 5).tolist()


def run_tokens(tokens_gen, case: dict, each=lambda row: row) -> np.ndarray:
    """A case's token loop: the first prompt, each next one switched to (set_prompt) before
    its steps, the remaining steps under the last; `each` sees every row as it is drawn."""
    schedule = case["schedule"]
    stream = tokens_gen.start(
        np.float32(schedule[0]["prompt_embedding"]),
        case["seed"],
        Sampling(**case["sampling"]),
        case["window"],
        allow_end=False,
    )
    rows = []
    for k, entry in enumerate(schedule):
        if k:
            stream.set_prompt(np.float32(entry["prompt_embedding"]))
        rows += [each(stream.step()) for _ in range(entry["steps"])]
    rows += [each(stream.step()) for _ in range(case["steps"] - len(rows))]
    return np.array(rows)


def compare_tokens(case: dict, tokens: np.ndarray, tolerances: dict) -> tuple[int, str | None]:
    """(steps that agree, the problem or None). Steps agree until the first difference; a
    difference where our token had a near tie (its gap below tie_logit, or sampled, its
    margin below tie_mass) ends the comparison without a problem."""
    expected = np.asarray(case["tokens"])
    tokens = np.asarray(tokens)
    if tokens.shape != expected.shape:
        return 0, f"{case['name']}: tokens of shape {tokens.shape}, expected {expected.shape}"
    for n, (row, want) in enumerate(zip(tokens, expected, strict=True)):
        for level in np.flatnonzero(row != want):
            margin, gap = case["margins"][n][level], case["gaps"][n][level]
            if gap < tolerances["tie_logit"] or margin < tolerances["tie_mass"]:
                return n, None
            return n, (
                f"{case['name']}: step {n} level {level}: token {row[level]}, expected "
                f"{want[level]} (margin {margin:g}, gap {gap:g}: no tie)"
            )
    return len(expected), None


def anchoring_words(generator: MotionGenerator) -> dict:
    """mogo.anchoring's rules as data, for a port's re-anchoring: which primitive each verb
    form asks for (mogo.align.primitive_of on the verb tables), the nouns, the primitives
    that happen once, the words that count (those `settles` alone, among every word the
    bundle's vocabulary, the verb tables and the numbers hold), standing still, and the
    Anchoring defaults (its hold prompt included)."""
    from dataclasses import asdict

    from mogo.align import conjugate, primitive_of
    from mogo.align_wordnet import WORDNET_VERBS
    from mogo.align_words import NOUNS, NUMBERS
    from mogo.align_words import VERBS as HAND_VERBS
    from mogo.anchoring import ONE_OFF, STILL, Anchoring, settles

    forms = {
        form
        for table in (WORDNET_VERBS, HAND_VERBS)
        for verbs in table.values()
        for verb in verbs
        for form in (verb, conjugate(verb, "s"), conjugate(verb, "ing"))
    }
    verbs = {w: p for w in sorted(forms) if (p := primitive_of([w])) is not None}
    words = generator.vocabulary() | forms | set(NOUNS) | set(NUMBERS)
    counts = sorted(w for w in words if settles(w) and primitive_of([w]) not in ONE_OFF)
    return dict(
        verbs=verbs,
        nouns=dict(sorted(NOUNS.items())),
        one_off=sorted(ONE_OFF),
        counts=counts,
        still=STILL,
        anchoring=dict(  # max_one_off in token steps for the port
            asdict(Anchoring()),
            max_one_off=Anchoring().one_off_steps(
                generator.defaults.max_seconds, generator.fps / generator.down_factor
            ),
        ),
    )


def main(argv: list[str]) -> None:
    from mogo.export.onnx.portable import export_portable

    out = Path(argv[0]) if argv else VECTORS
    with tempfile.TemporaryDirectory() as folder:
        export_portable(DEFAULT_BUNDLE, Path(folder) / "bundle")
        vectors = make_vectors(Path(folder) / "bundle")
    out.write_text(json.dumps(vectors, separators=(",", ":")) + "\n")
    print(f"wrote {out}: {out.stat().st_size / 1e3:.0f} KB")
    WORDS.write_text(json.dumps(anchoring_words(MotionGenerator.load()), indent=0) + "\n")
    print(f"wrote {WORDS}")


if __name__ == "__main__":
    main(sys.argv[1:])
