"""RQHC-Transformer, torch reference generator and the shared numpy sampler (tiny configs)."""

import numpy as np
import pytest
import torch

from mogo.export.models.generate_torch import generate
from mogo.export.models.t2m import T2M, RelativeAttention, T2MConfig, corrupt_tokens
from mogo.sampling import Sampling, choose_token, choose_tokens, make_rng, step_uniforms

B, T = 2, 12


@pytest.fixture
def model():
    torch.manual_seed(0)
    return T2M(T2MConfig.tiny()).eval()


def batch(config, seed=0):
    g = torch.Generator().manual_seed(seed)
    prompt = torch.randn(B, config.text_dim, generator=g)
    tokens = torch.randint(0, config.codebook_size, (B, T, config.num_levels), generator=g)
    return prompt, tokens


def test_configs():
    for config in (T2MConfig.tiny(), T2MConfig.cpu_default()):
        assert len(config.layers) == len(config.heads) == config.num_levels
    assert T2MConfig.cpu_default() == T2MConfig()
    with pytest.raises(ValueError, match="one entry per level"):
        T2MConfig(layers=[1, 1])


def test_paper_config_parameter_count_on_meta():
    with torch.device("meta"):
        model = T2M(T2MConfig.paper())
    count = sum(p.numel() for p in model.parameters())
    print(f"paper config: {count / 1e6:.1f}M parameters")
    assert 560e6 < count < 580e6  # 571.8M; the paper reports ~600M, its prototype 578M
    with torch.device("meta"):
        assert 10e6 < sum(p.numel() for p in T2M(T2MConfig.cpu_default()).parameters()) < 14e6


def test_shapes_and_loss(model):
    config = model.config
    prompt, tokens = batch(config)
    logits = model(prompt, tokens)
    K = config.codebook_size
    assert [tuple(x.shape) for x in logits] == [(B, T + 1, K + 1), (B, T + 1, K), (B, T + 1, K)]
    model.train()
    total, accuracy = model.loss(prompt, tokens, torch.tensor([T, 5]))
    total.backward()
    assert total.ndim == 0 and accuracy.shape == (config.num_levels,)
    assert model.levels[2].blocks[0].attn.phi.grad is not None


def test_loss_ignores_ids_past_the_length(model):
    prompt, tokens = batch(model.config)
    lengths = torch.tensor([T, 5])
    other = tokens.clone()
    other[1, 5:] = (other[1, 5:] + 3) % model.config.codebook_size
    assert torch.equal(
        model.loss(prompt, tokens, lengths)[0], model.loss(prompt, other, lengths)[0]
    )


def test_loss_targets_end_token_at_length():
    torch.manual_seed(0)
    config = T2MConfig.tiny()
    model = T2M(config).eval()
    with torch.no_grad():  # level 0 always says "end": right exactly at position length
        model.levels[0].head.bias[config.end_token] = 100.0
    prompt, tokens = batch(config)
    _, accuracy = model.loss(prompt, tokens, torch.tensor([T, 5]))
    assert accuracy[0] == pytest.approx(2 / (T + 1 + 6))


def test_causal_in_time(model):
    prompt, tokens = batch(model.config)
    base = model(prompt, tokens)
    for step in (0, 4, T - 1):
        changed = tokens.clone()
        changed[:, step] = (changed[:, step] + 1) % model.config.codebook_size
        for level, (a, b) in enumerate(zip(base, model(prompt, changed), strict=False)):
            # positions <= step predict steps <= step and read steps < step
            torch.testing.assert_close(a[:, : step + 1], b[:, : step + 1], rtol=0, atol=0)
            if step < T - 1:
                assert not torch.allclose(a[:, step + 1], b[:, step + 1]), level


def test_levels_read_only_past_steps_of_coarser_and_own_levels(model):
    """Level l's prediction of step i reads levels <= l of steps < i: never the coarser tokens of
    step i itself (one pass per step), never a finer level."""
    L = model.config.num_levels
    prompt, tokens = batch(model.config)
    base = model(prompt, tokens)
    i = 5
    for changed_level in range(L):
        changed = tokens.clone()
        changed[:, i, changed_level] += 1
        changed %= model.config.codebook_size
        logits = model(prompt, changed)
        for level in range(L):
            torch.testing.assert_close(
                logits[level][:, : i + 1], base[level][:, : i + 1], rtol=0, atol=0
            )
            same_next = torch.equal(logits[level][:, i + 1], base[level][:, i + 1])
            assert same_next == (changed_level > level), (changed_level, level)


def test_relative_attention_is_translation_invariant():
    torch.manual_seed(0)
    attention = RelativeAttention(dim=16, heads=2, head_dim=8, max_distance=3, dropout=0.0)
    x = torch.randn(2, 9, 16)
    positions = torch.tensor([0, 1, 2, 3, 4, 8, 9, 10, 11])  # a gap, as after a window slide
    out, _ = attention(x, positions, positions)
    shifted, _ = attention(x, positions + 100, positions + 100)
    torch.testing.assert_close(out, shifted, rtol=0, atol=1e-6)
    _, past = attention(x[:, :6], positions[:6] + 7, positions[:6] + 7)
    tail, _ = attention(x[:, 6:], positions[6:] + 7, positions + 7, past)
    torch.testing.assert_close(out[:, 6:], tail, rtol=0, atol=1e-6)


def test_cache_matches_recomputation(model):
    """Prefill of the prefix + 5 steps, then 20 one-position decodes, cond and uncond rows."""
    config = model.config
    g = torch.Generator().manual_seed(1)
    prompt = torch.randn(1, config.text_dim, generator=g).expand(2, -1)
    uncond = torch.tensor([False, True])
    tokens = torch.randint(0, config.codebook_size, (1, 25, config.num_levels), generator=g)
    tokens = tokens.expand(2, -1, -1)
    full = model(prompt, tokens, uncond)
    inputs = torch.nn.functional.pad(tokens, (0, 0, 1, 0))  # position n: step n - 1
    empty = torch.zeros(0, dtype=torch.long)
    for level in range(config.num_levels):
        heads, dh = config.heads[level], config.head_dim
        no_past = [(torch.zeros(2, heads, 0, dh),) * 2] * config.layers[level]
        positions = torch.arange(6)
        logits, past = model.level_forward(
            level, prompt, uncond, inputs[:, :6], positions, empty, no_past
        )  # an empty cache, as an export feeds
        torch.testing.assert_close(logits, full[level][:, 5], rtol=0, atol=1e-5)
        for n in range(6, 26):
            logits, past = model.level_forward(
                level,
                prompt,
                uncond,
                inputs[:, n : n + 1],
                torch.tensor([n]),
                torch.arange(n),
                past,
            )
            torch.testing.assert_close(logits, full[level][:, n], rtol=0, atol=1e-5)
        assert past[0][0].shape == (2, heads, 26, dh)


@pytest.mark.parametrize(
    "sampling, seed",
    [
        (Sampling(temperature=0.0), 0),
        (Sampling(temperature=1.0, top_k=6, top_p=0.9), 3),
        (Sampling(temperature=0.8, guidance=2.5), 4),
    ],
)
def test_generate_cached_equals_recomputed(model, sampling, seed):
    prompt = torch.randn(model.config.text_dim)
    cached = generate(model, prompt, num_frames=20, sampling=sampling, seed=seed, use_cache=True)
    recomputed = generate(
        model, prompt, num_frames=20, sampling=sampling, seed=seed, use_cache=False
    )
    assert cached.shape == (20, model.config.num_levels) and cached.dtype == np.int64
    np.testing.assert_array_equal(cached, recomputed)


def test_sliding_window_equals_full_cache_until_exceeded(model):
    prompt = torch.randn(model.config.text_dim)
    full = generate(model, prompt, num_frames=20, seed=5)
    np.testing.assert_array_equal(generate(model, prompt, num_frames=20, seed=5, window=19), full)
    windowed = generate(model, prompt, num_frames=20, seed=5, window=6)
    np.testing.assert_array_equal(windowed[:7], full[:7])  # step 7 is the first to lose a step
    assert windowed.shape == full.shape


def test_end_token_and_forced_length():
    torch.manual_seed(0)
    config = T2MConfig.tiny()
    model = T2M(config).eval()
    prompt = torch.randn(config.text_dim)
    with torch.no_grad():
        model.levels[0].head.bias[config.end_token] = 100.0  # the model wants to stop at once
    assert generate(model, prompt, num_frames=7).shape == (7, 3)
    assert generate(model, prompt, num_frames=7, sampling=Sampling(temperature=0)).shape == (7, 3)
    assert generate(model, prompt).shape == (1, 3)  # the end token is masked at step 0 only
    with torch.no_grad():
        model.levels[0].head.bias[config.end_token] = -100.0  # never stops
    assert generate(model, prompt, max_frames=9).shape == (9, 3)


def test_condition_dropout_uses_the_null_embedding():
    torch.manual_seed(0)
    config = T2MConfig.tiny()
    config.token_corruption = 0.0
    prompt, tokens = batch(config)
    model = T2M(config)
    null = torch.ones(B, dtype=torch.bool)
    expected_uncond = model.eval()(prompt, tokens, null)
    expected_cond = model(prompt, tokens)
    model.train()
    for prob, expected in ((1.0, expected_uncond), (0.0, expected_cond)):
        config.cond_drop_prob = prob
        for a, b in zip(model(prompt, tokens), expected, strict=False):
            torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert not torch.allclose(expected_uncond[0], expected_cond[0])


def test_token_corruption():
    torch.manual_seed(0)
    tokens = torch.randint(0, 512, (64, 50, 6))
    assert torch.equal(corrupt_tokens(tokens, 0.0, 512), tokens)
    corrupted = corrupt_tokens(tokens, 0.5, 512)
    assert corrupted.min() >= 0 and corrupted.max() < 512
    assert 0.47 < (corrupted != tokens).float().mean() < 0.53


def test_generate_needs_eval_mode(model):
    with pytest.raises(ValueError, match="eval"):
        generate(model.train(), torch.randn(model.config.text_dim), num_frames=2)


# The numpy sampler (mogo.sampling), shared with the CPU runtime.

PROBS = np.array([0.15, 0.5, 0.05, 0.3])  # sorted: ids 1, 3, 0, 2; cumulative .5 .8 .95 1
LOGITS = np.log(PROBS) + 3.0


UNIFORMS = np.linspace(0, 1, 401, endpoint=False)


def drawn(sampling, uniforms=UNIFORMS, **kw):
    return {choose_token(LOGITS, None, u, sampling, **kw) for u in uniforms}


def test_temperature_zero_is_argmax():
    rng = np.random.default_rng(0)
    for _ in range(20):
        logits = rng.normal(size=17)
        assert choose_token(logits, None, rng.random(), Sampling(temperature=0)) == logits.argmax()
    assert drawn(Sampling(temperature=0)) == {1}
    assert drawn(Sampling(temperature=0), forbid=1) == {3}


def test_inverse_cdf():
    sampling = Sampling()
    for uniform, token in ((0.0, 1), (0.49, 1), (0.51, 3), (0.79, 3), (0.81, 0), (0.96, 2)):
        assert choose_token(LOGITS, None, uniform, sampling) == token
    assert drawn(sampling, forbid=1) == {0, 2, 3}


def test_top_k_and_top_p_masks():
    assert drawn(Sampling(top_k=1)) == {1}
    assert drawn(Sampling(top_k=3)) == {0, 1, 3}
    assert drawn(Sampling(top_p=0.5)) == {1}
    assert drawn(Sampling(top_p=0.75)) == {1, 3}
    assert drawn(Sampling(top_p=0.9)) == {0, 1, 3}
    assert drawn(Sampling(top_k=2, top_p=0.9)) == {1, 3}
    assert drawn(Sampling(temperature=100.0)) == {0, 1, 2, 3}


@pytest.mark.parametrize(
    "sampling",
    [
        Sampling(),
        Sampling(temperature=0),
        Sampling(top_k=5),
        Sampling(top_p=0.6),
        Sampling(top_k=7, top_p=0.8),
        Sampling(temperature=0.7, guidance=2.0),
    ],
)
def test_rows_chosen_together_equal_rows_chosen_alone(sampling):
    """The levels of a step are sampled in one call, shorter rows padded with -inf: each row
    gets the token it would get alone (ties included: integer logits)."""
    rng = np.random.default_rng(0)
    for _ in range(50):
        widths = [13] + [12] * 4
        cond = np.full((5, 13), -np.inf)
        uncond = np.full((5, 13), -np.inf)
        for row, width in enumerate(widths):
            cond[row, :width] = rng.integers(-3, 4, width)
            uncond[row, :width] = rng.integers(-3, 4, width)
        uniforms, forbid = rng.random(5), [int(rng.integers(13)), None, 3, None, None]
        together = choose_tokens(
            cond, uncond if sampling.guided else None, uniforms, sampling, forbid
        )
        for row, width in enumerate(widths):
            alone = choose_token(
                cond[row, :width], uncond[row, :width], uniforms[row], sampling, forbid[row]
            )
            assert together[row] == alone


def test_guidance():
    cond, uncond = np.array([1.0, 2.0, 0.0]), np.array([0.0, 3.0, 0.5])
    assert choose_token(cond, uncond, 0.3, Sampling(temperature=0, guidance=0.0)) == 1
    assert choose_token(cond, uncond, 0.3, Sampling(temperature=0, guidance=3.0)) == 0
    assert choose_token(cond, None, 0.3, Sampling(temperature=0)) == 1
    with pytest.raises(ValueError, match="unconditional"):
        choose_token(cond, None, 0.3, Sampling(guidance=2.0))
    with pytest.raises(ValueError):
        Sampling(top_p=0.0)


def test_sampler_is_deterministic_for_a_seed(model):
    np.testing.assert_array_equal(step_uniforms(make_rng(7), 6), step_uniforms(make_rng(7), 6))
    prompt = torch.randn(model.config.text_dim)
    a = generate(model, prompt, num_frames=15, seed=11)
    np.testing.assert_array_equal(a, generate(model, prompt, num_frames=15, seed=11))
    assert not np.array_equal(a, generate(model, prompt, num_frames=15, seed=12))
