"""Reference generator: the torch model, step by step, with the runtime's numpy sampler.

One step = every level once, coarse to fine, each sampling its token of that step from what
came before (levels are coupled only through past steps). Position 0 is the prompt prefix;
position n >= 1 holds the tokens of step n - 1 and predicts step n.

`use_cache=True` runs a prefill of the prefix and then one-position decodes on the KV cache;
`use_cache=False` recomputes the whole context every step (as the public prototype does). Both
give the same tokens. With the cache, `window=W` bounds memory and step time: once the cache
holds more than the prefix and W steps, the oldest step slots are dropped (kept keys keep their
absolute positions, so their distances stay exact). Until then the window changes nothing.
"""

from __future__ import annotations

import numpy as np
import torch

from mogo.export.models.t2m import T2M
from mogo.motion.skeleton import MAX_FRAMES
from mogo.sampling import Sampling, choose_token, make_rng, step_uniforms


@torch.no_grad()
def generate(
    model: T2M,
    prompt_embedding: torch.Tensor,
    num_frames: int | None = None,
    max_frames: int = MAX_FRAMES,
    sampling: Sampling = Sampling(),
    seed: int = 0,
    use_cache: bool = True,
    window: int | None = None,
) -> np.ndarray:
    """prompt_embedding (text_dim,) -> token ids (T, L) int64.

    num_frames given: exactly that many steps, the end token masked throughout. None: until
    level 0 draws the end token (masked at step 0, so T >= 1) or max_frames steps.
    """
    if model.training:
        raise ValueError(
            "generate needs model.eval() (dropout, prompt dropout and token "
            "corruption are training-only)"
        )
    if window is not None and (window < 1 or not use_cache):
        raise ValueError(f"window needs use_cache=True and >= 1 steps, got {window}")
    config = model.config
    L = config.num_levels
    uncond = torch.tensor([False, True][: 2 if sampling.guided else 1])
    prompt = prompt_embedding.reshape(1, -1).expand(len(uncond), -1)
    rng = make_rng(seed)
    steps = max_frames if num_frames is None else num_frames

    ids = np.zeros((0, L), dtype=np.int64)  # (T, L) sampled so far
    caches = [None] * L  # per level: per layer (key, value) (B, H, P, dh); None while empty
    cache_positions = None  # (P,) positions of the cache slots, shared by all levels
    for step in range(steps):
        uniforms = step_uniforms(rng, L)
        positions = torch.tensor([step]) if use_cache else torch.arange(step + 1)
        inputs = step_inputs(ids, positions, len(uncond))
        end_allowed = num_frames is None and step > 0
        row = []
        for level in range(L):
            logits, present = model.level_forward(
                level, prompt, uncond, inputs, positions, cache_positions, caches[level]
            )
            if use_cache:
                caches[level] = present
            logits = logits.double().numpy()
            forbid = None if level > 0 or end_allowed else config.end_token
            token = choose_token(
                logits[0], logits[1] if sampling.guided else None, uniforms[level], sampling, forbid
            )
            if token == config.end_token:
                return ids
            row.append(token)
        ids = np.concatenate([ids, np.array([row], dtype=np.int64)])
        if use_cache:
            cache_positions = positions if step == 0 else torch.cat([cache_positions, positions])
            if window is not None and len(cache_positions) > 1 + window:
                cache_positions, caches = _slid(cache_positions, caches, window)
    return ids


def _slid(cache_positions: torch.Tensor, caches: list, window: int) -> tuple[torch.Tensor, list]:
    """The KV caches cut to their first slot (the prompt) and their last `window` steps."""
    P = len(cache_positions)
    slots = torch.cat([torch.zeros(1, dtype=torch.long), torch.arange(P - window, P)])
    return cache_positions[slots], [
        [(k[:, :, slots], v[:, :, slots]) for k, v in c] for c in caches
    ]


def step_inputs(ids: np.ndarray, positions: torch.Tensor, batch: int) -> torch.Tensor:
    """Token ids (batch, S, L) at `positions`: step n - 1's tokens at position n, zeros at 0."""
    rows = torch.from_numpy(np.concatenate([np.zeros((1, ids.shape[1]), np.int64), ids]))
    return rows[positions].expand(batch, -1, -1)
