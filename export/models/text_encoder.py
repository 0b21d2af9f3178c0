"""The text side: a caption tokenizer and the text-encoder seam the motion model is conditioned on.

The motion model only ever sees a prompt embedding of `output_dim` floats from something that
satisfies `TextEncoder`; this file's `SmallTextEncoder` is one such, trained from scratch, and a
pretrained tower (e.g. CLIP's) can stand behind the same seam.

The tokenizer is a `tokenizers.Tokenizer` whose JSON holds the whole encoding (normalisation,
splitting, WordPiece, the [CLS] template, truncation, padding), so the CPU runtime reproduces
the ids with `Tokenizer.from_file` alone.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, replace
from typing import Protocol, runtime_checkable

import torch
from tokenizers import Tokenizer, decoders, models, normalizers, pre_tokenizers, processors
from torch import Tensor, nn

SPECIAL_TOKENS = ("[PAD]", "[UNK]", "[CLS]")  # ids 0, 1, 2
PAD_ID = 0


def train_tokenizer(captions: Iterable[str], vocab_size: int, max_length: int = 64) -> Tokenizer:
    """WordPiece on NFKD-normalised, accent-stripped, lowercased text split at whitespace and
    punctuation. An encoding is "[CLS] caption" truncated to `max_length` ids; a batch is
    padded with [PAD] to its longest.

    The vocabulary is built here rather than by the `tokenizers` trainer, whose choice among
    equally frequent merges changes from run to run: every character seen (alone and as a
    "##" continuation, so any word made of them still encodes), then whole words by falling
    frequency (ties alphabetical) up to `vocab_size`. The same captions always give the same
    tokenizer."""
    tokenizer = Tokenizer(models.WordPiece(unk_token="[UNK]"))
    tokenizer.normalizer = normalizers.Sequence(
        [normalizers.NFKD(), normalizers.StripAccents(), normalizers.Lowercase()]
    )
    tokenizer.pre_tokenizer = pre_tokenizers.Whitespace()
    words = Counter(
        word
        for caption in captions
        for word, _ in tokenizer.pre_tokenizer.pre_tokenize_str(
            tokenizer.normalizer.normalize_str(caption)
        )
    )
    characters = sorted({c for word in words for c in word})
    vocab = list(SPECIAL_TOKENS) + characters + [f"##{c}" for c in characters]
    known = set(vocab)
    ranked = sorted((w for w in words if w not in known), key=lambda w: (-words[w], w))
    vocab += ranked[: max(0, vocab_size - len(vocab))]
    tokenizer.model = models.WordPiece(
        {token: i for i, token in enumerate(vocab)}, unk_token="[UNK]"
    )
    tokenizer.add_special_tokens(list(SPECIAL_TOKENS))  # already ids 0-2; marks them special
    tokenizer.decoder = decoders.WordPiece()
    tokenizer.post_processor = processors.TemplateProcessing(
        single="[CLS] $A", special_tokens=[("[CLS]", vocab.index("[CLS]"))]
    )
    tokenizer.enable_truncation(max_length)
    tokenizer.enable_padding(pad_id=PAD_ID, pad_token="[PAD]")
    return tokenizer


def encode_captions(tokenizer: Tokenizer, captions: list[str]) -> tuple[Tensor, Tensor]:
    """-> token ids (B, S) int64, attention mask (B, S) int64 (1 on real tokens)."""
    encodings = tokenizer.encode_batch(captions)
    ids = torch.tensor([e.ids for e in encodings], dtype=torch.long)
    mask = torch.tensor([e.attention_mask for e in encodings], dtype=torch.long)
    return ids, mask


@runtime_checkable
class TextEncoder(Protocol):
    """The seam: token ids (B, S) int64 and attention mask (B, S) -> prompt embedding
    (B, output_dim)."""

    output_dim: int

    def encode(self, token_ids: Tensor, attention_mask: Tensor) -> Tensor: ...


@dataclass
class SmallTextEncoderConfig:
    vocab_size: int  # the tokenizer's
    width: int = 256
    layers: int = 4
    heads: int = 4
    max_length: int = 64  # = the tokenizer's truncation length
    dropout: float = 0.1

    def __post_init__(self):
        if self.width % self.heads:
            raise ValueError(f"width {self.width} is not a multiple of heads {self.heads}")

    @classmethod
    def tiny(cls, vocab_size: int) -> SmallTextEncoderConfig:
        return cls(vocab_size, width=32, layers=2, heads=2, max_length=16, dropout=0.0)


class TextLayer(nn.Module):
    """Pre-LN bidirectional transformer layer; padded keys are masked out."""

    def __init__(self, width: int, heads: int, dropout: float):
        super().__init__()
        self.heads = heads
        self.ln1 = nn.LayerNorm(width)
        self.qkv = nn.Linear(width, 3 * width)
        self.proj = nn.Linear(width, width)
        self.ln2 = nn.LayerNorm(width)
        self.mlp = nn.Sequential(
            nn.Linear(width, 4 * width), nn.GELU(), nn.Linear(4 * width, width)
        )
        self.drop = nn.Dropout(dropout)

    def forward(self, x: Tensor, mask: Tensor) -> Tensor:
        """x (B, S, W), mask (B, S) bool True on real tokens."""
        B, S, W = x.shape
        dh = W // self.heads
        q, k, v = self.qkv(self.ln1(x)).view(B, S, 3, self.heads, dh).permute(2, 0, 3, 1, 4)
        scores = q @ k.transpose(-1, -2) / math.sqrt(dh)  # (B, H, S, S)
        scores = scores.masked_fill(~mask[:, None, None, :], float("-inf"))
        y = (self.drop(scores.softmax(dim=-1)) @ v).transpose(1, 2).reshape(B, S, W)
        x = x + self.drop(self.proj(y))
        return x + self.drop(self.mlp(self.ln2(x)))


class SmallTextEncoder(nn.Module):
    """A small transformer over the caption, learned absolute positions, pooled by a masked mean
    over the real tokens ([CLS] included, so an empty caption still has one), so that every
    token feeds the prompt embedding directly rather than through one readout position."""

    def __init__(self, config: SmallTextEncoderConfig):
        super().__init__()
        self.config = config
        self.output_dim = config.width
        self.token_embedding = nn.Embedding(config.vocab_size, config.width)
        self.position_embedding = nn.Parameter(0.02 * torch.randn(config.max_length, config.width))
        self.layers = nn.ModuleList(
            TextLayer(config.width, config.heads, config.dropout) for _ in range(config.layers)
        )
        self.ln_f = nn.LayerNorm(config.width)
        self.drop = nn.Dropout(config.dropout)
        nn.init.normal_(self.token_embedding.weight, std=0.02)

    def forward(self, token_ids: Tensor, attention_mask: Tensor) -> Tensor:
        """token_ids (B, S) int64, S <= max_length; attention_mask (B, S) -> (B, width)."""
        mask = attention_mask.bool()
        positions = self.position_embedding[: token_ids.shape[1]]  # (S, W)
        x = self.drop(self.token_embedding(token_ids) + positions)
        for layer in self.layers:
            x = layer(x, mask)
        weights = mask[..., None].to(x.dtype)  # (B, S, 1)
        return (self.ln_f(x) * weights).sum(1) / weights.sum(1)

    encode = forward


# -- the kinds of text encoder a run can train -----------------------------------------------


@dataclass(frozen=True)
class TextEncoderKind:
    """One kind of encoder behind the `TextEncoder` seam, so the training loop never names a
    class: make_tokenizer(recipe, training captions) for a new run; make_config(recipe, prompt
    width the T2M takes, tokenizer) -> a plain dict saved in the checkpoint; build(config) -> the
    module (weights come from the checkpoint, or it is trained from its initialisation)."""

    make_tokenizer: Callable[[dict, list[str]], Tokenizer]
    make_config: Callable[[dict, int, Tokenizer], dict]
    build: Callable[[dict], nn.Module]


SMALL_VOCAB = dict(tiny=100, cpu_default=4000, paper=8000)
PROJECTION_HIDDEN = dict(tiny=16, cpu_default=512, paper=1024)  # a sentence tower's projection


def _small_base(preset: str) -> SmallTextEncoderConfig:
    return SmallTextEncoderConfig.tiny(0) if preset == "tiny" else SmallTextEncoderConfig(0)


def _small_tokenizer(recipe: dict, captions: list[str]) -> Tokenizer:
    preset = recipe["preset"]
    return train_tokenizer(captions, SMALL_VOCAB[preset], _small_base(preset).max_length)


def _small_config(recipe: dict, text_dim: int, tokenizer: Tokenizer) -> dict:
    return asdict(
        replace(
            _small_base(recipe["preset"]), vocab_size=tokenizer.get_vocab_size(), width=text_dim
        )
    )


def _small_build(config: dict) -> nn.Module:
    return SmallTextEncoder(SmallTextEncoderConfig(**config))


def _sentence_tokenizer(recipe: dict, captions: list[str]) -> Tokenizer:
    from mogo.export.models.sentence_encoder import sentence_tokenizer

    return sentence_tokenizer(recipe["sentence_encoder"])


def _sentence_config(recipe: dict, text_dim: int, tokenizer: Tokenizer) -> dict:
    from mogo.export.models.sentence_encoder import SentenceEmbedder

    width = SentenceEmbedder(recipe["sentence_encoder"]).embed(["a person walks."]).shape[1]
    return dict(
        folder=recipe["sentence_encoder"],
        in_dim=int(width),
        out_dim=text_dim,
        hidden=PROJECTION_HIDDEN[recipe["preset"]],
    )


def _sentence_build(config: dict) -> nn.Module:
    from mogo.export.models.sentence_encoder import SentenceTower

    return SentenceTower(**config)


# small: trained from scratch with the model; sentence: a frozen pretrained sentence encoder
# (an encoder folder: model.onnx, tokenizer.json, provenance.json) and a trained projection
TEXT_ENCODERS = dict(
    small=TextEncoderKind(_small_tokenizer, _small_config, _small_build),
    sentence=TextEncoderKind(_sentence_tokenizer, _sentence_config, _sentence_build),
)
