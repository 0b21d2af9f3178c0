"""A bundle's text side: prompts in, prompt embeddings out, and how close a prompt is to
what the model knows.

The text graph reads a prompt with its tokenizer (a bundle with a sentence encoder:
all-MiniLM-L6-v2 and an adapter, docs/text_encoder.md). Where the bundle also keeps the
encoder the model was trained with (manifest `text.trained`), a prompt that encoder reads
whole (every word known, nothing cut) is embedded by it, exactly as in training. The
repertoire (mogo.repertoire) scores the sentence embedding against the training captions.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
from tokenizers import Tokenizer

from mogo._session import NamedGraph
from mogo.align_words import spoken_numbers
from mogo.arguments import UnfamiliarPromptWarning, checked_prompt, read_prompt, short, word_reading
from mogo.bundle import Bundle, BundleError
from mogo.motion.untrusted import parse_json, read_text
from mogo.repertoire import Familiarity, KnownCaptions

ENCODED_PROMPTS = 256  # prompts whose text-graph outputs are kept


class TextSide:
    """The text graphs and tokenizers of one bundle, with a cache of encoded prompts."""

    def __init__(self, bundle: Bundle, threads: int):
        text = self._spec = bundle.manifest.text
        self.tokenizer = _tokenizer(bundle.path(text.tokenizer))
        self._counter = Tokenizer.from_str(self.tokenizer.to_str())  # sees what is cut
        self._counter.no_truncation()
        self._graph = NamedGraph(bundle, text.encoder, threads)
        repertoire, trained = text.repertoire, text.trained
        self.repertoire = None if repertoire is None else KnownCaptions(bundle, repertoire)
        self._trained = (
            None
            if trained is None
            else (
                _tokenizer(bundle.path(trained.tokenizer)),
                NamedGraph(bundle, trained.encoder, threads),
            )
        )
        self._encoded = functools.lru_cache(ENCODED_PROMPTS)(self._encode_one)
        # scored when a prompt is read and again when asked (a server's notes): ~0.2 ms each
        self.familiarity = functools.lru_cache(ENCODED_PROMPTS)(self._familiarity)

    def embed(self, texts: Sequence[str]) -> np.ndarray:
        """Prompt embeddings (B, text_dim) float32."""
        if isinstance(texts, str):  # not one embedding per character
            raise TypeError("texts must be a list of prompts, got one str")
        texts = [checked_prompt(t, f"texts[{k}]") for k, t in enumerate(texts)]
        if not texts:
            raise ValueError("no prompt given")
        return np.concatenate([self._encoded(text).prompt for text in texts])

    def vocabulary(self) -> set[str]:
        """The whole words of the tokenizer the model was trained with."""
        tokenizer = self.tokenizer if self._trained is None else self._trained[0]
        return {w for w in tokenizer.get_vocab() if w.isalpha()}

    def _familiarity(self, text: str) -> Familiarity:
        """The repertoire's score of a checked prompt (a bundle with a repertoire): `familiarity`,
        cached."""
        encoded = self._encoded(text)
        return self.repertoire.familiarity(encoded.sentence[0], encoded.played)

    def read(self, text: object, name: str, stacklevel: int) -> str:
        """A prompt checked where it enters the API (mogo.arguments.read_prompt), with an
        UnfamiliarPromptWarning where it is far from the repertoire (`stacklevel`: the
        caller's frame for the warning)."""
        spec = self._spec
        text = read_prompt(
            text,
            self._counter,
            spec.max_length,
            None if spec.sentence_encoder else len(self.vocabulary()),
            name,
            stacklevel + 1,
        )
        if self.repertoire is not None and not (familiarity := self.familiarity(text)).familiar:
            warnings.warn(familiarity.describe(), UnfamiliarPromptWarning, stacklevel=stacklevel)
        return text

    def _encode_one(self, text: str) -> _Encoded:
        """A prompt's embeddings, the prompt embedding by the encoder trained with the model
        where the bundle has it and it reads the whole prompt (every word, nothing cut at its
        length); cached, since a prompt is encoded for its repertoire check and again for its
        tokens. Numbers are read as the captions spell them (mogo.align_words.spoken_numbers).
        A prompt the trained encoder cannot read is played as a known caption (the one nearest
        its adapted embedding, mogo.repertoire), where the repertoire has their prompt
        embeddings."""
        text = spoken_numbers(text)
        outputs = _run(self._graph, self.tokenizer.encode(text))
        sentence = outputs[1] if len(outputs) > 1 else None  # a sentence encoder's
        if self._trained is not None:
            tokenizer, graph = self._trained
            encoding = tokenizer.encode(text)
            if not encoding.overflowing and word_reading(text, encoding) == (True, []):
                return _Encoded(_run(graph, encoding)[0], sentence, None)
        if self.repertoire is not None and self.repertoire.prompts is not None:
            index = self.repertoire.nearest(outputs[0], text)
            return _Encoded(
                self.repertoire.prompts[[index]], sentence, self.repertoire.captions[index]
            )
        return _Encoded(outputs[0], sentence, None)


class _Encoded(NamedTuple):
    prompt: np.ndarray  # (1, text_dim): what the level graphs get
    sentence: np.ndarray | None  # (1, dim): a sentence encoder's unit embedding
    played: str | None  # the known caption played instead of the prompt's own embedding


def _run(graph: NamedGraph, encoding) -> list[np.ndarray]:
    """Every output of a text graph for one encoded prompt."""
    ids, mask = (np.array([v], np.int64) for v in (encoding.ids, encoding.attention_mask))
    return graph.run_all(ids, mask)


def check_text_files(bundle: Bundle) -> None:
    """The tokenizers and the repertoire a TextSide reads, read and checked without opening
    its graphs (what `mogo info` verifies beside the graphs)."""
    text = bundle.manifest.text
    _tokenizer(bundle.path(text.tokenizer))
    if text.trained is not None:
        _tokenizer(bundle.path(text.trained.tokenizer))
    if text.repertoire is not None:
        KnownCaptions(bundle, text.repertoire)


def _tokenizer(path: Path) -> Tokenizer:
    """A bundle's tokenizer; BundleError for one that is not, or that holds a regular
    expression: a pattern such as (.+)+\\d takes exponential time on a long prompt, and the
    tokenizers `mogo export` writes (WordPiece, BERT's pre-tokenizer) use none."""
    try:
        text = read_text(path, "tokenizer")
        document = parse_json(text, str(path))
    except ValueError as error:
        raise BundleError(str(error)) from None
    pending = [document]
    while pending:
        value = pending.pop()
        if isinstance(value, dict):
            if "Regex" in value:
                raise BundleError(
                    f"{path}: a tokenizer with a regular expression "
                    f"({short(str(value['Regex']))}), which may take exponential "
                    "time on a prompt; bundles' tokenizers use none"
                )
            pending.extend(value.values())
        elif isinstance(value, list):
            pending.extend(value)
    try:
        return Tokenizer.from_str(text)
    except Exception as error:  # tokenizers raises a bare Exception
        cause = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise BundleError(f"{path}: not a tokenizer file: {cause}") from None
