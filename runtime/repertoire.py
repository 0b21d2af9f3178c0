"""How close a prompt is to what the model was trained on.

A bundle with a pretrained sentence encoder reads any words, but its motion model still knows
only the actions of its training captions: "a person does a backflip" is read perfectly and
then played as whatever known caption it lands nearest. The bundle carries sentence embeddings
of its training captions (manifest `text.repertoire`); a prompt's score is the cosine of its
own sentence embedding with the nearest of them, and the threshold set at export (with its
error rates in the manifest) tells familiar from far.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from mogo.bundle import Bundle, BundleError
from mogo.manifest import Repertoire


@dataclass(frozen=True)
class Familiarity:
    """A prompt against the repertoire: `score`, the cosine with the nearest training caption;
    `nearest`, the closest captions, nearest first; `familiar`: score >= threshold."""
    score: float
    threshold: float
    nearest: tuple[str, ...]

    @property
    def familiar(self) -> bool:
        return self.score >= self.threshold

    def describe(self) -> str:
        """One line for the user."""
        nearest = ", ".join(repr(c) for c in self.nearest)
        if self.familiar:
            return f"close to what this model knows ({self.score:.2f}); nearest: {nearest}"
        return (f"far from what this model knows (similarity {self.score:.2f}, below "
                f"{self.threshold:.2f}); nearest: {nearest}")


class KnownCaptions:
    """The repertoire of a bundle: unit embeddings (N, dim) of N training captions, and where
    the bundle has them their prompt embeddings (N, text_dim), else None."""

    def __init__(self, bundle: Bundle, repertoire: Repertoire):
        self.threshold = repertoire.threshold
        path = bundle.path(repertoire.embeddings)
        try:
            self.embeddings = np.load(path, allow_pickle=False).astype(np.float32)
            self.captions = json.loads(bundle.path(repertoire.captions).read_text("utf-8"))
            self.prompts = None if repertoire.prompts is None else np.load(
                bundle.path(repertoire.prompts), allow_pickle=False).astype(np.float32)
        except (OSError, ValueError) as error:
            raise BundleError(f"{path}: not a repertoire: {error}") from None
        if (self.embeddings.ndim != 2 or not isinstance(self.captions, list)
                or len(self.captions) != len(self.embeddings)):
            raise BundleError(f"{path}: {self.embeddings.shape} embeddings for "
                              f"{len(self.captions)} captions")
        if self.prompts is not None and (self.prompts.ndim != 2
                                         or len(self.prompts) != len(self.captions)):
            raise BundleError(f"{bundle.path(repertoire.prompts)}: {self.prompts.shape} prompt "
                              f"embeddings for {len(self.captions)} captions")
        if self.prompts is not None:  # the cosine's denominators, once
            self._prompt_norms = np.linalg.norm(self.prompts, axis=1)

    def nearest_prompt(self, prompt: np.ndarray) -> np.ndarray:
        """The known prompt embedding (1, text_dim) at the highest cosine with `prompt`
        (1, text_dim): the level graphs play the exact embeddings they were trained on far
        better than an adapter's approximation of them (docs/text_encoder.md)."""
        similarity = self.prompts @ prompt[0] / self._prompt_norms
        return self.prompts[None, int(np.argmax(similarity))]

    def familiarity(self, sentence: np.ndarray, count: int = 3) -> Familiarity:
        """`sentence`: a prompt's unit sentence embedding (dim,)."""
        similarity = self.embeddings @ sentence
        order = np.argsort(-similarity, kind="stable")
        nearest = []
        for index in order:  # distinct captions, without the final full stop
            caption = self.captions[index].strip().rstrip(".")
            if caption not in nearest:
                nearest.append(caption)
            if len(nearest) == count:
                break
        return Familiarity(round(float(similarity[order[0]]), 4), self.threshold, tuple(nearest))
