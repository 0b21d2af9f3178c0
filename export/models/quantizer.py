"""The residual quantiser of MoSA-VQ (mogo.export.models.vq): L levels of scale-adaptive residual
quantisation with EMA k-means codebooks, the modulation regulariser and the cross-level
decorrelation loss. The formulas are in vq.py's docstring."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import Tensor, nn

if TYPE_CHECKING:
    from mogo.export.models.vq import VQConfig


def cross_covariance(x: Tensor, y: Tensor, weight: Tensor) -> Tensor:
    """Batch covariance (C, C) between the columns of x and y (N, C), over the rows where
    `weight` (N,) is 1."""
    n = weight.sum()
    x = x - (weight[:, None] * x).sum(0) / n.clamp_min(1)
    y = y - (weight[:, None] * y).sum(0) / n.clamp_min(1)
    return (weight[:, None] * x).T @ y / (n - 1).clamp_min(1)


class ResidualQuantizer(nn.Module):
    """L levels of scale-adaptive residual quantisation with EMA codebooks.

    Buffers: codebook (L, K, C) in the scaled space u = W r + b; ema_count (L, K), ema_sum
    (L, K, C) the running k-means statistics; initialized (L,). W (scale) and b (bias), (L, C),
    are parameters with scale_bias, else fixed buffers of ones and zeros (same state_dict keys).
    """

    def __init__(self, config: VQConfig):
        super().__init__()
        self.config = config
        L, K, C = config.levels, config.codebook_size, config.code_dim
        self.register_buffer("codebook", torch.randn(L, K, C))
        self.register_buffer("ema_count", torch.ones(L, K))
        self.register_buffer("ema_sum", self.codebook.clone())
        self.register_buffer("initialized", torch.zeros(L, dtype=torch.bool))
        self._all_initialized = False  # a host-side copy of initialized.all(), once it holds
        if config.scale_bias:
            self.scale = nn.Parameter(torch.ones(L, C))
            self.bias = nn.Parameter(torch.zeros(L, C))
        else:
            self.register_buffer("scale", torch.ones(L, C))
            self.register_buffer("bias", torch.zeros(L, C))

    def _load_from_state_dict(self, *args, **kwargs):
        self._all_initialized = False  # re-read from the loaded buffer at the next update
        super()._load_from_state_dict(*args, **kwargs)

    def dequantize(self, ids: Tensor, active: Tensor | None = None) -> Tensor:
        """ids (B, T', k) of levels 0..k-1 (k <= L, 0 gives zeros) -> z_hat (B, T', C):
        sum over levels of (codebook[id] - b) / W, over the levels where active (B, k) is 1
        (all when None)."""
        k, K = ids.shape[-1], self.config.codebook_size
        flat = ids + K * torch.arange(k, device=ids.device)  # index into the first k codebooks
        q = F.embedding(flat, self.codebook[:k].flatten(0, 1))  # (B, T', k, C)
        phis = (q - self.bias[:k]) / self.scale[:k]
        if active is not None:
            phis = phis * active[:, None, :, None]
        return phis.sum(dim=-2)

    def dropped_levels(self, B: int, device: torch.device) -> Tensor:
        """(B, L) float: the levels each sample keeps under quantizer dropout (all of them
        outside training)."""
        return self._active_levels(B, device)

    def encode(self, z: Tensor) -> Tensor:
        """z (B, T', C) -> ids (B, T', L) int64; no training-time effects."""
        B, T, C = z.shape
        active = torch.ones(B * T, self.config.levels, device=z.device)
        return self._descend(z.reshape(B * T, C), active, update=False)[0].view(B, T, -1)

    def quantize(self, z: Tensor) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """z (B, T', C) -> z_hat (B, T', C) with a straight-through gradient, ids (B, T', L)
        and stats: the unweighted losses "commit", "modulation", "decorrelation" (with grad)
        and per level "perplexity", "usage" (share of codes used), "dead_codes" (re-drawn now).
        Training also updates the codebooks and applies quantizer dropout."""
        B, T, C = z.shape
        L, K = self.config.levels, self.config.codebook_size
        active = self._active_levels(B, z.device).repeat_interleave(T, dim=0)  # (B*T, L)
        ids, phis, residuals, dead = self._descend(z.reshape(B * T, C), active, self.training)
        z_hat = sum(phi * active[:, l, None] for l, phi in enumerate(phis)).view(B, T, C)

        rows = active.sum(0).clamp_min(1)  # (L,) rows using each level
        commit = sum(
            (residuals[l] - phis[l].detach()).square().mean(-1) @ active[:, l] / rows[l]
            for l in range(L)
        )
        counts = torch.zeros(L, K, device=z.device).scatter_add_(1, ids.T, active.T)
        probs = counts / rows[:, None]
        stats = dict(
            commit=commit,
            modulation=self._modulation(),
            decorrelation=self._decorrelation(phis, residuals, active),
            perplexity=(-(probs * probs.clamp_min(1e-12).log()).sum(1)).exp(),
            usage=(counts > 0).float().mean(1),
            dead_codes=dead,
        )
        return z_hat, ids.view(B, T, L), stats

    def _active_levels(self, B: int, device) -> Tensor:
        """(B, L) float, 1 for the levels each sample uses: all of them, except in training
        where with prob quantizer_dropout a sample keeps only the levels below a cut in 1..L."""
        L = self.config.levels
        keep = torch.full((B,), L, device=device)
        if self.training:
            cut = torch.randint(1, L + 1, (B,), device=device)
            keep = torch.where(
                torch.rand(B, device=device) < self.config.quantizer_dropout, cut, keep
            )
        return (torch.arange(L, device=device) < keep[:, None]).float()

    def _descend(
        self, r: Tensor, active: Tensor, update: bool
    ) -> tuple[Tensor, list[Tensor], list[Tensor], Tensor]:
        """Quantise rows r (N, C) level by level, rows taking part in level l where active
        (N, L) is 1. Returns ids (N, L); each level's phi (N, C), valued (q - b) / W with the
        gradient of Q taken as the identity; the residuals r^0..r^L; and with `update` (the EMA
        step) the number of codes re-drawn per level (L,). Once every codebook is initialised,
        nothing here waits for the device (no boolean indexing, no reading values back)."""
        dead = torch.zeros(self.config.levels, device=r.device)
        ids, phis, residuals = [], [], [r]
        if update and not self._all_initialized:
            self._all_initialized = bool(self.initialized.all())
        for l in range(self.config.levels):
            u = r * self.scale[l] + self.bias[l]  # (N, C) scaled residual
            if update and not self._all_initialized and not self.initialized[l]:
                self._initialize(l, u.detach()[active[:, l] > 0])
            codebook = self.codebook[l]  # (K, C)
            distance = (
                u.detach().square().sum(-1, keepdim=True)
                - 2 * u.detach() @ codebook.T
                + codebook.square().sum(-1)
            )  # (N, K)
            idx = distance.argmin(-1)
            q = codebook[idx] + (u - u.detach())  # straight-through: value q, gradient to u
            if update:
                dead[l] = self._ema_step(l, u.detach(), idx, active[:, l])
            phi = (q - self.bias[l]) / self.scale[l]
            r = r - phi * active[:, l, None]
            ids.append(idx)
            phis.append(phi)
            residuals.append(r)
        return torch.stack(ids, dim=-1), phis, residuals, dead

    @torch.no_grad()
    def _initialize(self, level: int, u: Tensor) -> None:
        """Codebook `level` := K distinct rows of u (N, C) (with repeats if N < K)."""
        if len(u) == 0:
            return
        K = self.config.codebook_size
        pick = (
            torch.randperm(len(u), device=u.device)[:K]
            if len(u) >= K
            else torch.randint(len(u), (K,), device=u.device)
        )
        self.codebook[level] = u[pick]
        self.ema_sum[level] = u[pick]
        self.ema_count[level] = 1.0
        self.initialized[level] = True

    @torch.no_grad()
    def _ema_step(self, level: int, u: Tensor, idx: Tensor, weight: Tensor) -> Tensor:
        """One EMA k-means step of codebook `level` on the rows of u (N, C) where weight (N,)
        is 1, assigned to codes idx (N,); codes whose EMA count falls below the threshold are
        re-drawn from those rows (with that count). Without such rows nothing changes.
        Returns how many codes were re-drawn (a 0-dim tensor)."""
        K, decay = self.config.codebook_size, self.config.ema_decay
        threshold = self.config.dead_code_threshold
        count = torch.zeros(K, device=u.device).index_add_(0, idx, weight)
        total = torch.zeros_like(self.ema_sum[level]).index_add_(0, idx, u * weight[:, None])
        ema_count = decay * self.ema_count[level] + (1 - decay) * count
        ema_sum = decay * self.ema_sum[level] + (1 - decay) * total
        present = weight.sum() > 0
        dead = (ema_count < threshold) & present
        drawn = u[torch.multinomial(weight + (~present).float(), K, replacement=True)]
        ema_count = torch.where(present, ema_count, self.ema_count[level])
        ema_sum = torch.where(present, ema_sum, self.ema_sum[level])
        self.ema_count[level] = torch.where(dead, threshold, ema_count)
        self.ema_sum[level] = torch.where(dead[:, None], threshold * drawn, ema_sum)
        codebook = torch.where(dead[:, None], drawn, ema_sum / ema_count.clamp_min(1e-6)[:, None])
        self.codebook[level] = torch.where(present, codebook, self.codebook[level])
        return dead.sum()

    def _modulation(self) -> Tensor:
        """sum_l ||W^l - 1||^2 + ||b^l||^2 (zero without scale_bias)."""
        return (self.scale - 1).square().sum() + self.bias.square().sum()

    def _decorrelation(self, phis: list[Tensor], residuals: list[Tensor], active: Tensor) -> Tensor:
        """sum_{l < L-1} ||Cov(phi^l, r^{l+1})||_F^2 over the rows that use level l + 1."""
        if self.config.decorrelation == 0:
            return torch.zeros((), device=active.device)
        return sum(
            (
                cross_covariance(phis[l], residuals[l + 1], active[:, l + 1]).square().sum()
                for l in range(self.config.levels - 1)
            ),
            torch.zeros((), device=active.device),
        )
