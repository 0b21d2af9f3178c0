"""How often a paraphrase's action can be read from MiniLM's sentence embedding at all:
`python -m mogo.bench.training.text_reading --data DIR --run RUN [--bundle B]
[--per-primitive N]` (RUN a `mogo train text` run, B defaults to the shipped bundle).

A prompt in other words is played as a known caption (docs/text_encoder.md), and a caption of
another action cannot pass the semantic checks. This asks whether a reading of MiniLM's
embedding learnt from what the text run had (its train captions that cover one program
segment, and their subject and verb variants, each labelled with that segment's action) picks
the action better than the bundle does. Prints one markdown table: per phrasebook
(mogo.bench.quality.paraphrases) and for the items' own captions, the share of prompts whose
action is read right by
- the bundle: the action of the known caption it plays the prompt as (`played_rates`; prompts
  it plays as written are not counted, its n says how many are);
- the nearest action centroid (the normalized mean of an action's embeddings);
- a vote of the 10 nearest labelled texts (cosine);
- a linear softmax head (cross-entropy weighted by class, AdamW, a little input noise).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from mogo.align_words import spoken_numbers
from mogo.bench.quality.paraphrases import in_every_book
from mogo.bench.quality.semantic import program_items, stratified
from mogo.bench.quality.text_encoder import known_captions, played_rates
from mogo.export.data.humanml3d import DatasetError, HumanML3DFolder
from mogo.export.models.sentence_encoder import CAPTIONS, ENCODER, SentenceEmbedder
from mogo.generator import DEFAULT_BUNDLE, MotionGenerator
from mogo.repertoire import shown_caption

NEIGHBOURS = 10


def labelled_texts(run: Path, known: dict[str, tuple]) -> tuple[np.ndarray, np.ndarray]:
    """The unit sentence embeddings (N, 384) of the run's train texts whose caption covers
    one program segment, and that segment's action (N,). A variant's target is its
    caption's, so its caption is found by its target."""
    arrays = np.load(run / CAPTIONS)
    texts, targets = arrays["train_text"], arrays["train_target"]
    caption_of = {
        targets[k].tobytes(): str(texts[k]) for k in np.flatnonzero(~arrays["train_variant"])
    }
    said = [known.get(shown_caption(caption_of[target.tobytes()])) for target in targets]
    keep = np.array([s is not None for s in said])
    return arrays["train_sentence"][keep], np.array([s[0] for s in said if s is not None])


def centroid_head(x: np.ndarray, y: np.ndarray, actions: list[str]):
    centroids = np.stack([x[y == a].mean(0) for a in actions])
    centroids /= np.linalg.norm(centroids, axis=1, keepdims=True)
    return lambda e: np.argmax(e @ centroids.T, axis=1)


def vote_head(x: np.ndarray, y: np.ndarray, actions: list[str]):
    labels = np.array([actions.index(a) for a in y])

    def read(e: np.ndarray) -> np.ndarray:
        nearest = np.argsort(-(e @ x.T), axis=1)[:, :NEIGHBOURS]
        return np.array(
            [np.bincount(labels[row], minlength=len(actions)).argmax() for row in nearest]
        )

    return read


def linear_head(x: np.ndarray, y: np.ndarray, actions: list[str], steps: int = 3000):
    torch.manual_seed(0)
    inputs = torch.from_numpy(x)
    labels = torch.tensor([actions.index(a) for a in y])
    counts = torch.bincount(labels, minlength=len(actions)).float()
    weight = counts.sum() / counts / len(actions)  # every action counts alike
    head = torch.nn.Linear(x.shape[1], len(actions))
    optimizer = torch.optim.AdamW(head.parameters(), 3e-3, weight_decay=1e-4)
    for _ in range(steps):
        batch = torch.randint(len(labels), (512,))
        noisy = inputs[batch] + 0.01 * torch.randn(512, x.shape[1])
        loss = F.cross_entropy(head(noisy), labels[batch], weight=weight)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    @torch.no_grad()
    def read(e: np.ndarray) -> np.ndarray:
        return head(torch.from_numpy(e)).argmax(1).numpy()

    return read


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="the procedural corpus")
    parser.add_argument("--run", type=Path, required=True, help="a `mogo train text` run")
    parser.add_argument("--bundle", type=Path, default=DEFAULT_BUNDLE)
    parser.add_argument("--per-primitive", type=int, default=20)
    args = parser.parse_args()
    if not (args.run / CAPTIONS).is_file():
        parser.error(f"{args.run}: no {CAPTIONS} (not a `mogo train text` run)")
    if args.per_primitive < 1:
        parser.error(f"--per-primitive must be at least 1, got {args.per_primitive}")
    try:
        folder = HumanML3DFolder(args.data, splits=("train", "test"))
        known = known_captions(program_items(args.data, folder.ids("train")))
        items = stratified(program_items(args.data, folder.ids("test")), args.per_primitive, 0)
    except (DatasetError, FileNotFoundError) as error:  # no corpus, or one without programs
        parser.error(str(error))
    prompts = {**in_every_book(items), "own captions": [item.caption for item in items]}
    x, y = labelled_texts(args.run, known)
    actions = sorted(set(y))
    heads = {
        "nearest centroid": centroid_head(x, y, actions),
        f"{NEIGHBOURS} nearest vote": vote_head(x, y, actions),
        "linear head": linear_head(x, y, actions),
    }
    embedder = SentenceEmbedder(args.run / ENCODER)
    generator = MotionGenerator.load(args.bundle, threads=2)
    truth = np.array([actions.index(item.primitive) for item in items])
    print(
        f"{len(items)} test items ({args.per_primitive} per primitive); heads learnt from "
        f"{len(y)} labelled train texts of {args.run}.\n\n| prompts | the bundle's caption | "
        + " | ".join(heads)
        + " |\n|---|---|"
        + "---|" * len(heads)
    )
    for name, texts in prompts.items():
        n, bundle, _ = played_rates(generator, items, texts, known)
        sentences = embedder.embed([spoken_numbers(t) for t in texts])
        cells = [f"{np.mean(read(sentences) == truth):.1%}" for read in heads.values()]
        print(f"| {name} | {bundle:.1%} (n {n}) | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
