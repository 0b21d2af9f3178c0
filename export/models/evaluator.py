"""The text-motion evaluator: two encoders that map a caption and a motion to one embedding
space, so that generated motion can be scored against real motion and against its caption
(FID, R-precision, MM-Dist, ... in mogo.export.data.metrics).

Design (not Guo et al.'s GloVe + bi-GRU): the text side is our own WordPiece tokenizer and a
small transformer (`SmallTextEncoder`, the motion model's own text tower, trained afresh); the
motion side downsamples the 263-dim normalised features 4x with two strided convolutions, runs
a small bidirectional transformer and mean-pools the real frames. Transformers because they
train faster than GRUs per step on a CPU, and pooling over all frames gives the length
invariance a retrieval model needs. Both embeddings are L2-normalised, so the protocol's
Euclidean distances are a monotone function of cosine similarity, the quantity the loss trains.

Loss: the symmetric InfoNCE of CLIP with a learned temperature, not Guo et al.'s margin loss:
every caption in a batch is contrasted with every motion of it (B - 1 negatives, the same
retrieval among many that R-precision measures), and there is no margin to tune.

Its ONNX export, for `mogo.bench.quality.evaluator` to embed without torch, is in
mogo.export.onnx.evaluator_graphs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mogo.export.models.text_encoder import SmallTextEncoder, SmallTextEncoderConfig, TextLayer

DOWN = 4  # frames per motion-encoder position (two stride-2 convolutions)


@dataclass
class EvaluatorConfig:
    vocab_size: int  # the tokenizer's
    feature_dim: int = 263
    embed_dim: int = 512
    text_width: int = 256
    text_layers: int = 2
    text_heads: int = 4
    max_length: int = 64  # = the tokenizer's truncation length
    motion_width: int = 256
    motion_layers: int = 2
    motion_heads: int = 4
    max_frames: int = 256  # longest clip the learned positions cover
    dropout: float = 0.1

    def __post_init__(self):
        for side in ("text", "motion"):
            width, heads = getattr(self, f"{side}_width"), getattr(self, f"{side}_heads")
            if width % heads:
                raise ValueError(f"{side} width {width} is not a multiple of heads {heads}")

    @classmethod
    def tiny(cls, vocab_size: int, feature_dim: int = 263) -> EvaluatorConfig:
        return cls(
            vocab_size,
            feature_dim,
            embed_dim=16,
            text_width=32,
            text_layers=1,
            text_heads=2,
            max_length=16,
            motion_width=32,
            motion_layers=1,
            motion_heads=2,
            dropout=0.0,
        )


def downsampled_lengths(lengths: Tensor) -> Tensor:
    """Positions after the two stride-2 convolutions: floor(floor(T / 2) / 2), at least 1."""
    return (lengths // 2 // 2).clamp(min=1)


class MotionEncoder(nn.Module):
    """Normalised features (B, T, D) and lengths (B,) -> (B, width). Padded frames are zeroed
    after each convolution, so a clip's embedding does not depend on what it is batched with."""

    def __init__(self, config: EvaluatorConfig):
        super().__init__()
        w = config.motion_width
        self.conv1 = nn.Conv1d(config.feature_dim, w, kernel_size=4, stride=2, padding=1)
        self.conv2 = nn.Conv1d(w, w, kernel_size=4, stride=2, padding=1)
        self.position_embedding = nn.Parameter(0.02 * torch.randn(config.max_frames // DOWN + 1, w))
        self.layers = nn.ModuleList(
            TextLayer(w, config.motion_heads, config.dropout) for _ in range(config.motion_layers)
        )
        self.ln_f = nn.LayerNorm(w)
        self.drop = nn.Dropout(config.dropout)

    def forward(self, features: Tensor, lengths: Tensor) -> Tensor:
        x = features.transpose(1, 2)  # (B, D, T)
        half = lengths // 2
        x = F.gelu(self.conv1(x)) * _mask(half, x.shape[-1] // 2)[:, None, :]
        x = F.gelu(self.conv2(x))
        mask = _mask(downsampled_lengths(lengths), x.shape[-1])  # (B, S) bool
        x = x.transpose(1, 2) * mask[..., None]
        x = self.drop(x + self.position_embedding[: x.shape[1]])
        for layer in self.layers:
            x = layer(x, mask)
        weights = mask[..., None].to(x.dtype)
        return (self.ln_f(x) * weights).sum(1) / weights.sum(1)


def _mask(lengths: Tensor, size: int) -> Tensor:
    return torch.arange(size, device=lengths.device)[None, :] < lengths[:, None]


class Evaluator(nn.Module):
    """Both towers, their projections to `embed_dim` and the learned temperature."""

    def __init__(self, config: EvaluatorConfig):
        super().__init__()
        self.config = config
        self.text_encoder = SmallTextEncoder(
            SmallTextEncoderConfig(
                config.vocab_size,
                config.text_width,
                config.text_layers,
                config.text_heads,
                config.max_length,
                config.dropout,
            )
        )
        self.motion_encoder = MotionEncoder(config)
        self.text_projection = nn.Linear(config.text_width, config.embed_dim)
        self.motion_projection = nn.Linear(config.motion_width, config.embed_dim)
        self.log_scale = nn.Parameter(torch.tensor(math.log(1 / 0.07)))

    def embed_text(self, token_ids: Tensor, attention_mask: Tensor) -> Tensor:
        """-> (B, embed_dim), unit length."""
        return F.normalize(
            self.text_projection(self.text_encoder(token_ids, attention_mask)), dim=-1
        )

    def embed_motion(self, features: Tensor, lengths: Tensor) -> Tensor:
        """Normalised features (B, T, D) and lengths (B,) -> (B, embed_dim), unit length."""
        return F.normalize(self.motion_projection(self.motion_encoder(features, lengths)), dim=-1)

    def loss(
        self, token_ids: Tensor, attention_mask: Tensor, features: Tensor, lengths: Tensor
    ) -> tuple[Tensor, Tensor]:
        """Symmetric InfoNCE over the batch -> (loss, in-batch top-1 retrieval accuracy)."""
        text = self.embed_text(token_ids, attention_mask)
        motion = self.embed_motion(features, lengths)
        logits = self.log_scale.clamp(max=math.log(100)).exp() * text @ motion.T
        target = torch.arange(len(logits), device=logits.device)
        loss = (F.cross_entropy(logits, target) + F.cross_entropy(logits.T, target)) / 2
        return loss, (logits.argmax(1) == target).float().mean()

    forward = loss  # what DistributedDataParallel calls
