"""RQHC-Transformer: one causal transformer per residual-quantisation level (the MOGO paper).

Sequence of level l (positions 0..n):
    position 0: p + q_l                 p = projected prompt embedding, q_l = level embedding
    position i: x_l^i = sum_{j <= l} E_j(t_j^{i-1})   the tokens of step i-1 at levels 0..l
Position i predicts t_l^i (step i; on level 0 also the end-of-motion class K). Level l never
sees a token of step i before predicting step i, not even a coarser one, so all levels of a
step are sampled in one pass. Each level j has its own embedding table E_j (a code id means
something different at every residual level); tables are shared by the level blocks reading them.

The end token is an output class only: generation stops when it is drawn, so it is never an
input. In training, positions after the last real step hold any valid id (causal attention keeps
them from affecting earlier positions; the loss masks them).

Attention is Transformer-XL relative (paper eq. 6) computed from explicit positions, with nothing
positional in the cached keys/values, so a cache can drop its oldest slots (keeping the prefix)
and stay exact for what it keeps. `level_forward` is the one step API for prefill and decode,
and the shape of an exported level graph.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

KV = tuple[Tensor, Tensor]  # key, value: (B, H, P, head_dim) each


@dataclass
class T2MConfig:
    """Defaults are `cpu_default()`: width 256, depth 13 (coarse levels deepest), ~12M
    parameters, a few ms a step on one CPU core and trainable on a CPU; a 128-d prompt
    embedding, ample for the procedural corpus's vocabulary and small in a bundle."""

    num_levels: int = 6  # L
    codebook_size: int = 512  # K; level 0 has one more class, the end token (id K)
    dim: int = 256  # D, every level block
    layers: list[int] = field(default_factory=lambda: [4, 3, 2, 2, 1, 1])  # per level
    heads: list[int] = field(default_factory=lambda: [4, 4, 4, 4, 4, 4])  # per level
    head_dim: int = 64  # inner attention width = heads * head_dim (need not equal D)
    text_dim: int = 128  # size of the prompt embedding the text encoder gives
    max_relative_distance: int = 64  # R: distances >= R share one learned embedding
    dropout: float = 0.1
    cond_drop_prob: float = 0.1  # training: prompt replaced by the null embedding (for CFG)
    token_corruption: float = 0.5  # training: input tokens replaced by random ids (prototype)
    mlp_ratio: int = 4

    def __post_init__(self):
        if not len(self.layers) == len(self.heads) == self.num_levels:
            raise ValueError(
                f"layers {self.layers} and heads {self.heads} need one entry per "
                f"level ({self.num_levels})"
            )

    @property
    def end_token(self) -> int:
        return self.codebook_size

    def num_classes(self, level: int) -> int:
        return self.codebook_size + 1 if level == 0 else self.codebook_size

    @classmethod
    def paper(cls) -> T2MConfig:
        """Paper config (D 1024, 50 layers) behind a CLIP ViT-B/32 text tower (512-d)."""
        return cls(dim=1024, layers=[18, 16, 8, 4, 2, 2], heads=[16, 12, 6, 2, 2, 2], text_dim=512)

    @classmethod
    def cpu_default(cls) -> T2MConfig:
        return cls()

    @classmethod
    def tiny(cls) -> T2MConfig:
        """For tests: 3 levels, 16 codes, R = 4 so that distances get clipped."""
        return cls(
            num_levels=3,
            codebook_size=16,
            dim=32,
            layers=[2, 1, 1],
            heads=[2, 1, 1],
            head_dim=16,
            text_dim=24,
            max_relative_distance=4,
            dropout=0.0,
        )


class RelativeAttention(nn.Module):
    """Causal multi-head attention with learned relative positions (Transformer-XL, eq. 6):

        A_ij = q_i.k_j + q_i.phi_d + u.k_j + v.phi_d,   d = min(pos_i - pos_j, R),  pos_j <= pos_i

    phi is a learned table per head over the R + 1 clipped distances; the q.phi terms are
    computed once per distance and gathered, which is cheap when R is small.
    """

    def __init__(self, dim: int, heads: int, head_dim: int, max_distance: int, dropout: float):
        super().__init__()
        self.heads, self.head_dim, self.max_distance = heads, head_dim, max_distance
        self.qkv = nn.Linear(dim, 3 * heads * head_dim)
        self.proj = nn.Linear(heads * head_dim, dim)
        self.phi = nn.Parameter(0.02 * torch.randn(heads, max_distance + 1, head_dim))
        self.u = nn.Parameter(torch.zeros(heads, 1, head_dim))
        self.v = nn.Parameter(torch.zeros(heads, 1, head_dim))
        self.drop = nn.Dropout(dropout)

    def forward(
        self, x: Tensor, query_pos: Tensor, key_pos: Tensor, past: KV | None = None
    ) -> tuple[Tensor, KV]:
        """x (B, S, D); query_pos (S,) positions of x; key_pos (P + S,) positions of the past
        keys then of x. Returns (B, S, D) and the present (key, value), (B, H, P + S, dh)."""
        B, S, _ = x.shape
        q, k, v = self.qkv(x).view(B, S, 3, self.heads, self.head_dim).permute(2, 0, 3, 1, 4)
        if past is not None:
            k = torch.cat([past[0], k], dim=2)
            v = torch.cat([past[1], v], dim=2)
        content = (q + self.u) @ k.transpose(-1, -2)  # (B, H, S, P+S)
        by_distance = (q + self.v) @ self.phi.transpose(-1, -2)  # (B, H, S, R+1)
        offset = query_pos[:, None] - key_pos[None, :]  # (S, P+S)
        distance = offset.clamp(0, self.max_distance)[None, None].expand(B, self.heads, -1, -1)
        scores = (content + by_distance.gather(-1, distance)) / math.sqrt(self.head_dim)
        scores = scores.masked_fill(offset < 0, float("-inf"))
        attention = self.drop(scores.softmax(dim=-1))
        y = (attention @ v).transpose(1, 2).reshape(B, S, self.heads * self.head_dim)
        return self.proj(y), (k, v)


class Block(nn.Module):
    """Pre-LN transformer layer."""

    def __init__(self, config: T2MConfig, heads: int):
        super().__init__()
        D = config.dim
        self.ln1 = nn.LayerNorm(D)
        self.attn = RelativeAttention(
            D, heads, config.head_dim, config.max_relative_distance, config.dropout
        )
        self.ln2 = nn.LayerNorm(D)
        self.mlp = nn.Sequential(
            nn.Linear(D, config.mlp_ratio * D), nn.GELU(), nn.Linear(config.mlp_ratio * D, D)
        )
        self.drop = nn.Dropout(config.dropout)

    def forward(
        self, x: Tensor, query_pos: Tensor, key_pos: Tensor, past: KV | None
    ) -> tuple[Tensor, KV]:
        a, present = self.attn(self.ln1(x), query_pos, key_pos, past)
        x = x + self.drop(a)
        return x + self.drop(self.mlp(self.ln2(x))), present


class LevelBlock(nn.Module):
    """The causal stack of one level: its level embedding q_l, layers, final norm and head."""

    def __init__(self, config: T2MConfig, level: int):
        super().__init__()
        self.level_embedding = nn.Parameter(0.02 * torch.randn(config.dim))
        self.blocks = nn.ModuleList(
            Block(config, config.heads[level]) for _ in range(config.layers[level])
        )
        self.ln_f = nn.LayerNorm(config.dim)
        self.head = nn.Linear(config.dim, config.num_classes(level))

    def forward(
        self, x: Tensor, query_pos: Tensor, key_pos: Tensor, past: list[KV] | None
    ) -> tuple[Tensor, list[KV]]:
        """x (B, S, D) -> normed hidden states (B, S, D) and one present (key, value) per layer."""
        presents = []
        for i, block in enumerate(self.blocks):
            x, present = block(x, query_pos, key_pos, None if past is None else past[i])
            presents.append(present)
        return self.ln_f(x), presents


class T2M(nn.Module):
    """The L level blocks with their shared inputs: token tables, prompt projection, null prompt."""

    def __init__(self, config: T2MConfig):
        super().__init__()
        self.config = config
        D, K = config.dim, config.codebook_size
        self.token_embeddings = nn.ModuleList(nn.Embedding(K, D) for _ in range(config.num_levels))
        self.prompt_proj = nn.Linear(config.text_dim, D)
        self.null_prompt = nn.Parameter(0.02 * torch.randn(D))
        self.levels = nn.ModuleList(LevelBlock(config, l) for l in range(config.num_levels))
        self.drop = nn.Dropout(config.dropout)
        for module in self.modules():
            if isinstance(module, (nn.Linear, nn.Embedding)):
                nn.init.normal_(module.weight, std=0.02)
            if isinstance(module, nn.Linear):
                nn.init.zeros_(module.bias)

    def prompt_prefix(self, prompt: Tensor, uncond: Tensor) -> Tensor:
        """prompt (B, text_dim), uncond (B,) bool -> p (B, D); the null embedding where uncond."""
        return torch.where(uncond[:, None], self.null_prompt, self.prompt_proj(prompt))

    def _level(
        self,
        level: int,
        prefix: Tensor,
        token_ids: Tensor,
        positions: Tensor,
        past_positions: Tensor | None,
        past: list[KV] | None,
    ) -> tuple[Tensor, list[KV]]:
        """Inputs of `level` at `positions` (prefix where 0, else token embeddings), through its
        stack. prefix (B, D); token_ids (B, S, >= level+1); positions (S,)."""
        x = sum(self.token_embeddings[j](token_ids[:, :, j]) for j in range(level + 1))
        start = prefix + self.levels[level].level_embedding  # (B, D)
        x = torch.where((positions == 0)[None, :, None], start[:, None, :], x)  # (B, S, D)
        key_pos = positions if past_positions is None else torch.cat([past_positions, positions])
        return self.levels[level](self.drop(x), positions, key_pos, past)

    def level_forward(
        self,
        level: int,
        prompt: Tensor,
        uncond: Tensor,
        token_ids: Tensor,
        positions: Tensor,
        past_positions: Tensor | None = None,
        past: list[KV] | None = None,
    ) -> tuple[Tensor, list[KV]]:
        """One call of one level, prefill (S >= 1) or decode (S = 1), same code.

        prompt (B, text_dim) float; uncond (B,) bool; token_ids (B, S, L) int64: row s holds
        the tokens of step positions[s] - 1 (levels > `level` are ignored; any valid id where
        the position is 0, the prompt prefix); positions (S,) int64 absolute positions of the new
        inputs; past_positions (P,) int64 and past (per layer (key, value), (B, H, P, dh)) the
        cache, or None for none. Returns the logits of the last position (B, K[+1]) and the
        present cache (per layer, (B, H, P + S, dh)), whose positions are past + positions.
        """
        h, presents = self._level(
            level, self.prompt_prefix(prompt, uncond), token_ids, positions, past_positions, past
        )
        return self.levels[level].head(h[:, -1]), presents

    def forward(self, prompt: Tensor, tokens: Tensor, uncond: Tensor | None = None) -> list[Tensor]:
        """prompt (B, text_dim); tokens (B, T, L) valid ids -> per level logits (B, T+1, K[+1]),
        position i predicting step i. In training the prompt is dropped (cond_drop_prob, unless
        `uncond` is given) and input tokens are corrupted (token_corruption)."""
        B, T, L = tokens.shape
        if uncond is None:
            uncond = torch.zeros(B, dtype=torch.bool, device=tokens.device)
            if self.training:
                uncond = torch.rand(B, device=tokens.device) < self.config.cond_drop_prob
        if self.training and self.config.token_corruption > 0:
            tokens = corrupt_tokens(tokens, self.config.token_corruption, self.config.codebook_size)
        inputs = F.pad(tokens, (0, 0, 1, 0))  # (B, T+1, L): position i holds step i-1
        positions = torch.arange(T + 1, device=tokens.device)
        prefix = self.prompt_prefix(prompt, uncond)
        return [
            self.levels[l].head(self._level(l, prefix, inputs, positions, None, None)[0])
            for l in range(L)
        ]

    def loss(self, prompt: Tensor, tokens: Tensor, lengths: Tensor) -> tuple[Tensor, Tensor]:
        """Cross-entropy summed over levels (each a mean over real positions; level 0 also
        predicts the end token at position `length`). tokens (B, T, L), ids past a length may
        be anything. Returns (total loss, per-level token accuracy (L,))."""
        B, T, L = tokens.shape
        steps = torch.arange(T + 1, device=tokens.device)[None, :]  # (1, T+1)
        real = steps < lengths[:, None]  # (B, T+1) positions predicting a real step
        tokens = tokens.masked_fill(~real[:, :T, None], 0)
        targets = F.pad(tokens, (0, 0, 0, 1))  # (B, T+1, L)
        losses, accuracies = [], []
        for level, logits in enumerate(self(prompt, tokens)):
            target, mask = targets[..., level], real
            if level == 0:
                target = torch.where(steps == lengths[:, None], self.config.end_token, target)
                mask = steps <= lengths[:, None]
            weight = mask.float() / mask.sum()  # a mean over the masked positions, computed
            # without boolean indexing, which would make the host wait for the device
            losses.append(
                (F.cross_entropy(logits.transpose(1, 2), target, reduction="none") * weight).sum()
            )
            accuracies.append(((logits.argmax(-1) == target).float() * weight).sum())
        return torch.stack(losses).sum(), torch.stack(accuracies).detach()


def corrupt_tokens(tokens: Tensor, rate: float, codebook_size: int) -> Tensor:
    """Each id replaced, with probability `rate`, by a uniformly random one."""
    noise = torch.randint_like(tokens, codebook_size)
    return torch.where(torch.rand(tokens.shape, device=tokens.device) < rate, noise, tokens)


class TextToMotion(nn.Module):
    """Text encoder and T2M as one module: one DDP wrapper, one optimizer, one state_dict."""

    def __init__(self, text_encoder: nn.Module, t2m: T2M):
        super().__init__()
        self.text_encoder, self.t2m = text_encoder, t2m

    def forward(
        self, caption_ids: Tensor, caption_mask: Tensor, tokens: Tensor, lengths: Tensor
    ) -> tuple[Tensor, Tensor]:
        """-> T2M.loss: (loss, per-level token accuracy (L,))."""
        return self.t2m.loss(self.text_encoder.encode(caption_ids, caption_mask), tokens, lengths)
