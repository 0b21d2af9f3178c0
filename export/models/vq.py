"""MoSA-VQ: the motion scale-adaptive residual VQ-VAE of MOGO (the paper, AAAI 2026).

    x (B, T, D) normalised -> Encoder -> z (B, T', C) -> ResidualQuantizer -> ids (B, T', L)
    ids -> dequantize -> z_hat (B, T', C) -> Decoder -> x_hat (B, T, D),     T = T' * down_factor

Per level l, with a learnable diagonal scale W^l and bias b^l (the "scale-adaptive" part):

    q^l = Q(W^l * r^l + b^l)    nearest entry of codebook l, r^0 = z
    phi^l = (q^l - b^l) / W^l   the level's decoded contribution
    r^{l+1} = r^l - phi^l,      z_hat = sum_l phi^l

Codebooks live in the scaled space u = W r + b and are EMA k-means (not gradient-trained):
initialised from the first training batch, dead codes re-drawn from current residuals.
With the straight-through Q, b cancels out of every gradient but the modulation term's, which
pulls it to 0, so b stays 0 in training (the EMA codebooks follow any shift of u anyway); W
learns from the quantisation error q - u alone.
`dequantize` (what the ONNX decoder graph and the runtime run) needs only ids.

The convolutions are either centred or causal (all padding on the left): a causal model has
zero lookahead, so a stream can decode every frame as soon as its token exists. Between the
two, `decoder_lookahead` = n keeps the centred taps of the decoder's last convolutions while
their right context adds up to at most n tokens and makes the others causal: a stream waits n
tokens for a frame instead of the centred decoder's 31. `decoder_receptive_field` derives the
decoder's context from its layers.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mogo.export.models.motion_torch import features_to_joints, num_joints_for_feature_dim
from mogo.export.models.quantizer import ResidualQuantizer

RECON_LOSSES = ("l1", "smooth_l1")


@dataclass
class VQConfig:
    """Defaults are `cpu_default()`: width 192, 2 stages of 3 residual blocks, 6 levels of
    512 x 64 codes, one token per frame. ~2.8M parameters; the decoder costs ~1.3M
    multiply-adds a frame (0.26 GMAC for a 196-frame clip, a few ms in onnxruntime on one core)
    and a training step of 64 crops x 64 frames takes about a second on 2 CPU cores, so a few
    thousand steps fit well within an hour. Width 192 rather than the prototype's 512: the cost
    is quadratic in width and a CPU budget allows ~7x fewer steps at 512. Six levels and 512
    codes as in the paper and prototype; 64-dim codes (not 512) because the EMA codebooks and
    the nearest-code search scale with it and the latent of a 192-wide model needs no more.
    """

    feature_dim: int = 263  # D: 263 HumanML3D, 251 KIT-ML
    width: int = 192
    depth: int = 3  # residual blocks per stage
    dilation_growth: int = 3  # dilations 1, 3, 9, ...
    stages: int = 2  # conv + residual blocks; the first log2(down_factor) of them halve time
    down_factor: int = 1  # frames per token: 1 (paper), 2 or 4
    levels: int = 6  # L
    codebook_size: int = 512  # K per level
    code_dim: int = 64  # C
    dropout: float = 0.1
    causal: bool = False  # convolutions see only the past: zero lookahead when streaming
    decoder_lookahead: int | None = None  # at most this many tokens of right context (None: all)
    scale_bias: bool = True  # learnable W^l, b^l (eq. 1-2); False: plain residual VQ
    recon_loss: str = "l1"  # "l1" (paper) or "smooth_l1" (prototype), also for joints
    joint_weight: float = 0.5  # joint positions (metres) recovered from features
    commitment: float = 0.02  # beta
    modulation: float = 1e-3  # gamma on sum_l ||W^l - 1||^2 + ||b^l||^2
    decorrelation: float = 1e-2  # lambda on sum_{l<L-1} ||Cov(phi^l, r^{l+1})||_F^2
    quantizer_dropout: float = 0.2  # training: chance a sample keeps only levels < random cut
    ema_decay: float = 0.99
    dead_code_threshold: float = 1.0  # codes whose EMA count falls below it are re-drawn

    def __post_init__(self):
        def need(ok: bool, what: str, value):
            if not ok:
                raise ValueError(f"VQConfig: {what}, got {value!r}")

        for name in ("feature_dim", "width", "stages", "dilation_growth", "levels", "code_dim"):
            need(getattr(self, name) >= 1, f"{name} must be >= 1", getattr(self, name))
        need(self.depth >= 0, "depth must be >= 0", self.depth)
        need(
            self.decoder_lookahead is None or self.decoder_lookahead >= 0,
            "decoder_lookahead must be >= 0",
            self.decoder_lookahead,
        )
        need(self.down_factor in (1, 2, 4), "down_factor must be 1, 2 or 4", self.down_factor)
        need(
            self.stages >= self.down_stages,
            f"stages must be >= log2(down_factor) = {self.down_stages}",
            self.stages,
        )
        need(self.codebook_size >= 2, "codebook_size must be >= 2", self.codebook_size)
        need(0 <= self.dropout < 1, "dropout must be in [0, 1)", self.dropout)
        need(
            0 <= self.quantizer_dropout <= 1,
            "quantizer_dropout must be in [0, 1]",
            self.quantizer_dropout,
        )
        need(0 < self.ema_decay < 1, "ema_decay must be in (0, 1)", self.ema_decay)
        need(
            self.recon_loss in RECON_LOSSES,
            f"recon_loss must be one of {RECON_LOSSES}",
            self.recon_loss,
        )
        for name in (
            "joint_weight",
            "commitment",
            "modulation",
            "decorrelation",
            "dead_code_threshold",
        ):
            need(getattr(self, name) >= 0, f"{name} must be >= 0", getattr(self, name))
        if self.joint_weight > 0:
            try:
                num_joints_for_feature_dim(self.feature_dim)
            except ValueError as error:
                raise ValueError(f"VQConfig: joint_weight > 0 needs joints: {error}") from None

    @property
    def down_stages(self) -> int:
        return int(math.log2(self.down_factor))

    @classmethod
    def cpu_default(cls) -> VQConfig:
        return cls()

    @classmethod
    def paper(cls) -> VQConfig:
        """The prototype's sizes: width 512, 6 levels of 512 x 512 codes, dropout 0.2 (the
        paper's Table 3 uses 8192 x 128 codes: `dataclasses.replace` for that)."""
        return cls(width=512, code_dim=512, dropout=0.2)

    @classmethod
    def tiny(cls) -> VQConfig:
        """For tests: seconds on one core."""
        return cls(width=32, depth=2, levels=3, codebook_size=16, code_dim=8, dropout=0.0)


class Conv(nn.Module):
    """Conv1d over (B, C, T) with explicit zero padding: centred, or causal (all on the left),
    so that output i never sees an input after the last frame it covers."""

    def __init__(
        self,
        c_in: int,
        c_out: int,
        kernel: int,
        stride: int = 1,
        dilation: int = 1,
        causal: bool = False,
    ):
        super().__init__()
        total = (kernel - 1) * dilation + 1 - stride  # keeps T' = T / stride
        self.left = total if causal else total // 2
        self.right = total - self.left
        self.conv = nn.Conv1d(c_in, c_out, kernel, stride, dilation=dilation)

    def forward(self, x: Tensor) -> Tensor:
        return self.conv(F.pad(x, (self.left, self.right)))

    def make_causal(self) -> None:
        self.left, self.right = self.left + self.right, 0


class ResBlock(nn.Module):
    """x + dropout(conv1(act(conv3_dilated(act(x))))), no normalisation (the prototype's)."""

    def __init__(self, width: int, dilation: int, dropout: float, causal: bool):
        super().__init__()
        self.net = nn.Sequential(
            nn.ReLU(),
            Conv(width, width, 3, dilation=dilation, causal=causal),
            nn.ReLU(),
            Conv(width, width, 1),
            nn.Dropout(dropout),
        )

    def forward(self, x: Tensor) -> Tensor:
        return x + self.net(x)


def res_stack(config: VQConfig, reverse: bool) -> nn.Sequential:
    """`depth` blocks with dilations 1, g, g^2, ... (reversed in the decoder, to mirror)."""
    dilations = [config.dilation_growth**i for i in range(config.depth)]
    return nn.Sequential(
        *(
            ResBlock(config.width, d, config.dropout, config.causal)
            for d in (dilations[::-1] if reverse else dilations)
        )
    )


class Encoder(nn.Module):
    """(B, T, D) -> (B, T / down_factor, C); each of the first log2(down) stages halves T."""

    def __init__(self, config: VQConfig):
        super().__init__()
        W, causal = config.width, config.causal
        layers = [Conv(config.feature_dim, W, 3, causal=causal), nn.ReLU()]
        for stage in range(config.stages):
            if stage < config.down_stages:
                layers.append(Conv(W, W, 4, stride=2, causal=causal))
            else:
                layers.append(Conv(W, W, 3, causal=causal))
            layers.append(res_stack(config, reverse=False))
        layers.append(Conv(W, config.code_dim, 3, causal=causal))
        self.net = nn.Sequential(*layers)

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x.transpose(1, 2)).transpose(1, 2)


class Decoder(nn.Module):
    """(B, T', C) -> (B, T' * down_factor, D); each of the last log2(down) stages doubles T."""

    def __init__(self, config: VQConfig):
        super().__init__()
        W, causal = config.width, config.causal
        layers = [Conv(config.code_dim, W, 3, causal=causal), nn.ReLU()]
        for stage in range(config.stages):
            layers.append(res_stack(config, reverse=True))
            if stage >= config.stages - config.down_stages:
                layers.append(nn.Upsample(scale_factor=2, mode="nearest"))
            layers.append(Conv(W, W, 3, causal=causal))
        layers += [
            Conv(W, W, 3, causal=causal),
            nn.ReLU(),
            Conv(W, config.feature_dim, 3, causal=causal),
        ]
        self.net = nn.Sequential(*layers)
        if config.decoder_lookahead is not None:
            budget = config.decoder_lookahead
            for conv in reversed([m for m in self.net.modules() if isinstance(m, Conv)]):
                if conv.right > budget:
                    conv.make_causal()
                budget -= conv.right

    def forward(self, z: Tensor) -> Tensor:
        return self.net(z.transpose(1, 2)).transpose(1, 2)


def _input_span(module: nn.Module, lo: int, hi: int) -> tuple[int, int]:
    """The input positions [lo', hi'] that outputs [lo, hi] of `module` depend on."""
    if isinstance(module, nn.Sequential):
        for layer in reversed(module):
            lo, hi = _input_span(layer, lo, hi)
        return lo, hi
    if isinstance(module, Conv):
        (k,), (s,), (d,) = module.conv.kernel_size, module.conv.stride, module.conv.dilation
        return lo * s - module.left, hi * s - module.left + (k - 1) * d
    if isinstance(module, ResBlock):  # the union of the identity and the block's path
        inner_lo, inner_hi = _input_span(module.net, lo, hi)
        return min(lo, inner_lo), max(hi, inner_hi)
    if isinstance(module, nn.Upsample):
        return lo // int(module.scale_factor), hi // int(module.scale_factor)
    if isinstance(module, (nn.ReLU, nn.Dropout)):
        return lo, hi
    raise TypeError(f"no receptive-field rule for {type(module).__name__}")


def decoder_receptive_field(config: VQConfig) -> tuple[int, int]:
    """(left_context, lookahead) in tokens: the frames of token t depend exactly on tokens
    t - left_context .. t + lookahead (lookahead 0 when causal). Walks the decoder's layers."""
    with torch.device("meta"):
        decoder = Decoder(config)
    t, s = 0, config.down_factor
    lo, hi = _input_span(decoder.net, t * s, t * s + s - 1)
    return t - lo, hi - t


@dataclass
class VQOutput:
    recon: Tensor  # (B, T, D) normalised features
    ids: Tensor  # (B, T', L) int64
    losses: dict[str, Tensor]  # unweighted terms and their weighted sum "total"
    stats: dict[str, Tensor]  # per level: perplexity, usage, dead_codes


class MoSAVQ(nn.Module):
    """Encoder, residual quantizer and decoder, with the normalisation statistics as buffers
    (`mean`, `std`, (D,)) so that a checkpoint (state_dict + asdict(config)) is self-contained."""

    def __init__(
        self,
        config: VQConfig,
        mean: np.ndarray | Tensor | None = None,
        std: np.ndarray | Tensor | None = None,
    ):
        super().__init__()
        self.config = config
        D = config.feature_dim
        for name, value, default in (("mean", mean, 0.0), ("std", std, 1.0)):
            value = (
                torch.full((D,), default)
                if value is None
                else torch.as_tensor(value, dtype=torch.float32).clone()
            )
            if value.shape != (D,):
                raise ValueError(f"{name} must have shape ({D},), got {tuple(value.shape)}")
            self.register_buffer(name, value)
        self.encoder = Encoder(config)
        self.quantizer = ResidualQuantizer(config)
        self.decoder = Decoder(config)

    def encode(self, x: Tensor) -> Tensor:
        """Normalised features (B, T, D), T a multiple of down_factor -> ids (B, T', L) int64.
        Deterministic in eval mode (call .eval() first: dropout)."""
        return self.quantizer.encode(self.encoder(x))

    def decode(self, ids: Tensor) -> Tensor:
        """ids (B, T', k) of the first k levels -> normalised features (B, T' * down, D)."""
        return self.decoder(self.quantizer.dequantize(ids))

    def forward(self, x: Tensor, decoder_only: bool = False) -> VQOutput:
        """x (B, T, D) normalised -> VQOutput; losses.total = recon + joint_weight * joints +
        commitment * commit + modulation * modulation + decorrelation * decorrelation.
        decoder_only: fine-tune the decoder alone, on the tokens of the frozen encoder."""
        if x.shape[1] % self.config.down_factor:
            raise ValueError(
                f"{x.shape[1]} frames is not a multiple of down_factor {self.config.down_factor}"
            )
        if decoder_only:
            return self._decoder_forward(x)
        z_hat, ids, stats = self.quantizer.quantize(self.encoder(x))
        recon = self.decoder(z_hat)
        c = self.config
        losses = dict(
            recon=self._distance(recon, x),
            joints=self._joint_loss(recon, x),
            commit=stats.pop("commit"),
            modulation=stats.pop("modulation"),
            decorrelation=stats.pop("decorrelation"),
        )
        losses["total"] = (
            losses["recon"]
            + c.joint_weight * losses["joints"]
            + c.commitment * losses["commit"]
            + c.modulation * losses["modulation"]
            + c.decorrelation * losses["decorrelation"]
        )
        return VQOutput(recon, ids, losses, stats)

    def _decoder_forward(self, x: Tensor) -> VQOutput:
        """x's tokens come from the encoder and codebooks in eval mode, without gradient or
        codebook update (the tokens a trained T2M predicts stay valid); only the decoder learns,
        with the reconstruction losses and quantizer dropout of the full forward."""
        encoder_was_training = self.encoder.training
        self.encoder.eval()
        with torch.no_grad():
            ids = self.encode(x)
            active = self.quantizer.dropped_levels(len(x), x.device)
        self.encoder.train(encoder_was_training)
        recon = self.decoder(self.quantizer.dequantize(ids, active))
        zero = torch.zeros((), device=x.device)
        losses = dict(
            recon=self._distance(recon, x),
            joints=self._joint_loss(recon, x),
            commit=zero,
            modulation=zero,
            decorrelation=zero,
        )
        losses["total"] = losses["recon"] + self.config.joint_weight * losses["joints"]
        L, K = self.config.levels, self.config.codebook_size
        counts = torch.zeros(L, K, device=x.device).scatter_add_(
            1, ids.reshape(-1, L).T, active.repeat_interleave(ids.shape[1], dim=0).T
        )
        probs = counts / counts.sum(1, keepdim=True).clamp_min(1)
        stats = dict(
            perplexity=(-(probs * probs.clamp_min(1e-12).log()).sum(1)).exp(),
            usage=(counts > 0).float().mean(1),
            dead_codes=torch.zeros(L, device=x.device),
        )
        return VQOutput(recon, ids, losses, stats)

    def joints(self, x: Tensor) -> Tensor:
        """Normalised features (B, T, D) -> recovered joint positions (B, T, J, 3) in metres."""
        return features_to_joints(x * self.std + self.mean)

    def _distance(self, a: Tensor, b: Tensor) -> Tensor:
        if self.config.recon_loss == "smooth_l1":
            return F.smooth_l1_loss(a, b)
        return F.l1_loss(a, b)

    def _joint_loss(self, recon: Tensor, x: Tensor) -> Tensor:
        if self.config.joint_weight == 0:
            return torch.zeros((), device=x.device)
        return self._distance(self.joints(recon), self.joints(x))


@torch.no_grad()
def reconstruction_metrics(model: MoSAVQ, batches: Iterable[Tensor]) -> dict:
    """Reconstruction quality over batches of normalised features (B, T, D), in eval mode;
    errors are means over clips (each clip's own mean over its frames and joints).

    mpjpe_mm: mean joint position error (global positions, root trajectory included) in mm;
    feature_l1: mean |x_hat - x| on normalised features; both also `_by_levels`, decoding with
    the first k levels, k = 1..L. level_gain[k-1]: the share of the feature error of decoding
    no level at all (a zero latent) that level k removes (sums to that share of all levels).
    codebook_usage / perplexity: per level, over all tokens.
    """
    was_training = model.training
    model.eval()
    L, K = model.config.levels, model.config.codebook_size
    l1 = torch.zeros(L + 1, dtype=torch.float64)  # sums over batches, index = levels used
    mpjpe = torch.zeros(L + 1, dtype=torch.float64)
    counts = torch.zeros(L, K, dtype=torch.float64)
    clips = 0
    for x in batches:
        ids = model.encode(x)
        joints = model.joints(x)
        for k in range(L + 1):
            recon = model.decode(ids[..., :k])
            l1[k] += (recon - x).abs().mean(dim=(1, 2)).sum().item()
            mpjpe[k] += (model.joints(recon) - joints).norm(dim=-1).mean(dim=(1, 2)).sum().item()
        for l in range(L):
            counts[l] += torch.bincount(ids[..., l].flatten(), minlength=K).double().cpu()
        clips += len(x)
    model.train(was_training)
    if clips == 0:
        raise ValueError("no batches to measure")
    l1, mpjpe = l1 / clips, 1000 * mpjpe / clips
    probs = counts / counts.sum(1, keepdim=True)
    perplexity = (-(probs * probs.clamp_min(1e-12).log()).sum(1)).exp()
    gain = (l1[:-1] - l1[1:]) / (l1[0] - l1[-1]).clamp_min(1e-12)
    return dict(
        mpjpe_mm=mpjpe[-1].item(),
        feature_l1=l1[-1].item(),
        mpjpe_mm_by_levels=mpjpe[1:].tolist(),
        feature_l1_by_levels=l1[1:].tolist(),
        level_gain=gain.tolist(),
        codebook_usage=(counts > 0).double().mean(1).tolist(),
        perplexity=perplexity.tolist(),
    )
