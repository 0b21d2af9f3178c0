from dataclasses import asdict, replace

import numpy as np
import pytest
import torch

from mogo.export.models.motion_torch import features_to_joints as torch_features_to_joints
from mogo.export.models.quantizer import ResidualQuantizer, cross_covariance
from mogo.export.models.vq import MoSAVQ, VQConfig, decoder_receptive_field, reconstruction_metrics
from mogo.motion.features import features_to_joints, joints_to_features
from mogo.motion.quaternion import qrot, qyaw
from mogo.motion.skeleton import SMPL_22

TINY = VQConfig.tiny()


def smooth_clip(rng, frames=80):
    """A rest pose with smoothly swaying joints, walking a curve while turning ~1.5 turns."""
    pose = np.zeros((22, 3))
    for joint, parent in enumerate(SMPL_22.parents):
        if parent >= 0:
            pose[joint] = pose[parent] + SMPL_22.rest_offsets[joint]
    pose[:, 1] -= pose[:, 1].min()
    t = np.arange(frames)[:, None, None] / 20.0
    sway = 0.05 * np.sin(rng.uniform(1, 4, (1, 22, 3)) * t + rng.uniform(0, 6, (1, 22, 3)))
    facing = rng.uniform(-np.pi, np.pi) + 9.0 * (t[:, 0, 0] / t[-1, 0, 0]) ** 2
    heading = np.stack([np.sin(facing), np.zeros(frames), np.cos(facing)], -1)
    root = np.cumsum(0.05 * heading, axis=0)
    return qrot(qyaw(facing)[:, None], pose + sway) + root[:, None]


@pytest.fixture(scope="module")
def motion():
    """Normalised feature clips (4, 64, 263) float32 and their mean, std."""
    rng = np.random.default_rng(0)
    clips = np.stack([joints_to_features(smooth_clip(rng, 65))[0] for _ in range(4)])
    mean, std = clips.mean((0, 1)), clips.std((0, 1)) + 1e-2
    return torch.from_numpy((clips - mean) / std).float(), mean, std


def tiny_model(mean=None, std=None, **changes) -> MoSAVQ:
    torch.manual_seed(0)
    return MoSAVQ(replace(TINY, **changes), mean, std)


# -- torch joint recovery ----------------------------------------------------------------------


def test_torch_joints_match_numpy_on_random_features():
    features = np.random.default_rng(1).normal(scale=0.3, size=(3, 50, 263))
    expected = features_to_joints(features)
    np.testing.assert_allclose(
        torch_features_to_joints(torch.from_numpy(features)).numpy(), expected, atol=1e-9
    )
    got32 = torch_features_to_joints(torch.from_numpy(features).float())
    assert got32.dtype == torch.float32 and got32.shape == (3, 50, 22, 3)
    assert np.abs(got32.numpy() - expected).max() < 1e-5


def test_torch_joints_match_numpy_on_real_clips():
    rng = np.random.default_rng(2)
    pairs = [joints_to_features(smooth_clip(rng, 120)) for _ in range(2)]
    features = np.stack([f for f, _ in pairs])  # (2, 119, 263) float32
    got = torch_features_to_joints(torch.from_numpy(features)).numpy()
    assert np.abs(got - features_to_joints(features)).max() < 1e-5
    assert np.abs(got - np.stack([c[:-1] for _, c in pairs])).max() < 1e-4


def test_torch_joints_are_differentiable():
    features = torch.zeros(1, 10, 263, requires_grad=True)
    torch_features_to_joints(features)[0, -1, 5].sum().backward()
    assert features.grad[0, :-1, 1:3].abs().sum() > 0  # root velocities move the last frame


# -- config ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "change",
    [
        dict(down_factor=3),
        dict(levels=0),
        dict(codebook_size=1),
        dict(dropout=1.0),
        dict(quantizer_dropout=1.5),
        dict(ema_decay=1.0),
        dict(recon_loss="l2"),
        dict(commitment=-1.0),
        dict(feature_dim=100),
        dict(down_factor=4, stages=1),
    ],
)
def test_config_rejects_bad_values(change):
    with pytest.raises(ValueError, match="VQConfig"):
        replace(TINY, **change)


def test_presets_and_checkpoint_round_trip(motion):
    assert VQConfig.paper().width == 512 and VQConfig.paper().levels == 6
    assert VQConfig.cpu_default() == VQConfig()
    x, mean, std = motion
    model = tiny_model(mean=mean, std=std).eval()
    model.train()(x)  # initialise the codebooks
    copy = MoSAVQ(VQConfig(**asdict(model.config)))
    copy.load_state_dict(model.state_dict())
    ids = model.eval().encode(x)
    assert torch.equal(copy.eval().encode(x), ids)
    assert torch.equal(copy.decode(ids), model.decode(ids))
    assert torch.allclose(copy.std, torch.as_tensor(std, dtype=torch.float32))


# -- shapes and the quantizer ------------------------------------------------------------------


@pytest.mark.parametrize("down", [1, 2, 4])
@pytest.mark.parametrize("causal", [False, True])
def test_shapes(motion, down, causal):
    x = motion[0][:, :32]
    model = tiny_model(down_factor=down, causal=causal)
    out = model(x)
    assert out.recon.shape == x.shape and out.ids.shape == (4, 32 // down, TINY.levels)
    assert set(out.losses) == {"recon", "joints", "commit", "modulation", "decorrelation", "total"}
    assert all(v.shape == (TINY.levels,) for v in out.stats.values())
    ids = model.eval().encode(x)
    assert ids.dtype == torch.int64 and ids.shape == out.ids.shape
    assert model.decode(ids).shape == x.shape
    assert model.decode(ids[..., :1]).shape == x.shape


def test_dequantize_inverts_the_affine_map():
    torch.manual_seed(0)
    quantizer = ResidualQuantizer(TINY)
    with torch.no_grad():
        quantizer.scale.uniform_(0.5, 2.0)
        quantizer.bias.normal_()
    z = torch.randn(2, 8, TINY.code_dim)
    z_hat, ids, _ = quantizer.eval().quantize(z)
    assert torch.equal(quantizer.encode(z), ids)
    torch.testing.assert_close(quantizer.dequantize(ids), z_hat, rtol=0, atol=1e-6)
    # level 0 alone: (codebook[id] - b) / W
    expected = (quantizer.codebook[0][ids[..., 0]] - quantizer.bias[0]) / quantizer.scale[0]
    torch.testing.assert_close(quantizer.dequantize(ids[..., :1]), expected)


def test_straight_through_gradient_reaches_the_encoder(motion):
    quantizer = ResidualQuantizer(TINY).eval()
    z = torch.randn(2, 8, TINY.code_dim, requires_grad=True)
    upstream = torch.randn(2, 8, TINY.code_dim)
    (quantizer.quantize(z)[0] * upstream).sum().backward()
    torch.testing.assert_close(z.grad, upstream)  # d z_hat / d z = identity

    model = tiny_model()
    model(motion[0][:, :16]).losses["recon"].backward()
    assert model.encoder.net[0].conv.weight.grad.abs().sum() > 0
    assert model.quantizer.scale.grad.abs().sum() > 0


def test_ema_initialises_from_the_first_batch_and_redraws_dead_codes():
    torch.manual_seed(0)
    quantizer = ResidualQuantizer(TINY).train()
    z = torch.randn(4, 16, TINY.code_dim)
    quantizer.quantize(z)
    assert quantizer.initialized.all()
    rows = z.reshape(-1, TINY.code_dim)
    # level 0 (W = 1, b = 0): every code is the EMA of rows near it, started at rows of z
    assert torch.cdist(quantizer.codebook[0], rows).min(1).values.max() < 0.5

    before = quantizer.codebook.clone()
    with torch.no_grad():
        quantizer.codebook[0, 3] = 1e3  # far from every row: gets none, and its count is low
        quantizer.ema_count[0, 3] = 0.5
    _, _, stats = quantizer.quantize(z)
    assert stats["dead_codes"][0] >= 1
    assert torch.cdist(quantizer.codebook[0, 3:4], rows).min() < 1e-5  # re-drawn from a row
    assert not torch.equal(quantizer.codebook[1:], before[1:])  # the EMA moved the others

    state = {name: value.clone() for name, value in quantizer.state_dict().items()}
    with torch.no_grad():  # a level no row takes part in keeps its codebook and statistics
        quantizer._descend(rows, torch.tensor([1.0, 1.0, 0.0]).expand(len(rows), 3), update=True)
    assert torch.equal(quantizer.ema_count[2], state["ema_count"][2])
    assert torch.equal(quantizer.codebook[2], state["codebook"][2])
    assert not torch.equal(quantizer.ema_count[1], state["ema_count"][1])

    quantizer.eval()
    frozen = quantizer.codebook.clone()
    quantizer.quantize(z)
    assert torch.equal(quantizer.codebook, frozen)

    quantizer.train().load_state_dict(ResidualQuantizer(TINY).state_dict())  # uninitialised
    quantizer.quantize(z)
    assert quantizer.initialized.all()  # initialised again from this batch
    assert torch.cdist(quantizer.codebook[0], rows).min(1).values.max() < 0.5


def test_quantizer_dropout_only_in_training():
    quantizer = ResidualQuantizer(replace(TINY, quantizer_dropout=1.0))
    torch.manual_seed(0)
    active = quantizer.train()._active_levels(64, "cpu")
    kept = active.sum(1)
    assert kept.min() == 1 and kept.max() <= TINY.levels and (kept < TINY.levels).any()
    assert torch.equal(active, (torch.arange(TINY.levels) < kept[:, None]).float())  # prefixes
    assert torch.equal(quantizer.eval()._active_levels(64, "cpu"), torch.ones(64, TINY.levels))

    z = torch.randn(2, 8, TINY.code_dim)
    z_hat, ids, _ = quantizer.quantize(z)
    torch.testing.assert_close(quantizer.dequantize(ids), z_hat, rtol=0, atol=1e-6)


def test_decorrelation_of_known_cases():
    weight = torch.ones(4)
    x = torch.tensor([[1.0], [-1.0], [1.0], [-1.0]])
    independent = torch.tensor([[1.0], [1.0], [-1.0], [-1.0]])
    assert cross_covariance(x, independent, weight).square().sum() == 0
    # y = 3 x: Cov = 3 * sum(x^2) / (N - 1) = 4, so ||Cov||_F^2 = 16
    torch.testing.assert_close(
        cross_covariance(x, 3 * x, weight).square().sum(), torch.tensor(16.0)
    )
    # rows with weight 0 do not count
    masked = torch.cat([independent[:2], 5 * x[2:]])
    assert cross_covariance(x, masked, torch.tensor([1.0, 1.0, 0.0, 0.0])).square().sum() == 0


def test_scale_bias_and_decorrelation_switches(motion):
    x = motion[0][:, :16]
    plain = tiny_model(scale_bias=False, decorrelation=0.0)
    assert not list(plain.quantizer.parameters())
    assert plain.state_dict().keys() == tiny_model().state_dict().keys()
    losses = plain(x).losses
    assert losses["modulation"] == 0 and losses["decorrelation"] == 0
    c = plain.config
    torch.testing.assert_close(
        losses["total"],
        losses["recon"] + c.joint_weight * losses["joints"] + c.commitment * losses["commit"],
    )

    full = tiny_model()
    with torch.no_grad():
        full.quantizer.scale.fill_(1.5)
    losses = full(x).losses
    assert losses["modulation"] > 0 and losses["decorrelation"] > 0


def test_the_bias_learns_only_from_its_regulariser(motion):
    """(Q(W r + b) - b) / W with a straight-through Q: b cancels out of every gradient but the
    modulation term's, which pulls it to 0; W learns from the quantisation error alone."""
    model = tiny_model(modulation=0.0)
    model(motion[0][:, :16])  # initialises the codebooks
    with torch.no_grad():
        model.quantizer.bias.normal_(0, 0.1)
    model(motion[0][:, :16]).losses["total"].backward()
    assert torch.count_nonzero(model.quantizer.bias.grad) == 0
    assert torch.count_nonzero(model.quantizer.scale.grad) > 0


# -- decoder context ---------------------------------------------------------------------------


def changed_tokens(model, ids, position):
    """Tokens (sorted) whose decoded frames change when every level's id at `position` does."""
    other = ids.clone()
    other[:, position] = (other[:, position] + 1) % TINY.codebook_size
    with torch.no_grad():
        diff = (model.decode(other) - model.decode(ids)).abs().amax(dim=(0, 2))  # (T,)
    frames = torch.nonzero(diff > 0)[:, 0]
    return sorted(set((frames // model.config.down_factor).tolist()))


@pytest.mark.parametrize("down", [1, 2, 4])
@pytest.mark.parametrize("causal", [False, True])
def test_receptive_field_is_what_a_perturbation_reaches(down, causal):
    model = tiny_model(down_factor=down, causal=causal).eval()
    left, lookahead = decoder_receptive_field(model.config)
    assert lookahead == 0 if causal else lookahead > 0
    position = lookahead + 3
    ids = torch.randint(TINY.codebook_size, (1, position + left + 4, TINY.levels))
    # frames of token t depend on tokens t - left .. t + lookahead
    assert changed_tokens(model, ids, position) == list(
        range(position - lookahead, position + left + 1)
    )


@pytest.mark.parametrize("down", [1, 2])
def test_causal_decoder_ignores_later_tokens(down):
    model = tiny_model(down_factor=down, causal=True).eval()
    ids = torch.randint(TINY.codebook_size, (2, 20, TINY.levels))
    later = ids.clone()
    later[:, 11:] = torch.randint(TINY.codebook_size, (2, 9, TINY.levels))
    with torch.no_grad():
        a, b = model.decode(ids), model.decode(later)
    assert torch.equal(a[:, : 11 * down], b[:, : 11 * down])
    assert not torch.equal(a[:, 11 * down :], b[:, 11 * down :])


def test_receptive_field_of_the_presets():
    assert decoder_receptive_field(VQConfig.cpu_default()) == (31, 31)
    assert decoder_receptive_field(replace(VQConfig.cpu_default(), causal=True)) == (62, 0)
    for lookahead in (0, 4, 8):  # the same total context, moved to the left
        narrowed = replace(VQConfig.cpu_default(), decoder_lookahead=lookahead)
        assert decoder_receptive_field(narrowed) == (62 - lookahead, lookahead)


@pytest.mark.parametrize("lookahead", [0, 1, 2])
def test_a_narrowed_decoder_sees_at_most_its_lookahead(lookahead):
    model = tiny_model(decoder_lookahead=lookahead).eval()
    left, reach = decoder_receptive_field(model.config)
    assert reach == lookahead
    position = lookahead + 3
    ids = torch.randint(TINY.codebook_size, (1, position + left + 4, TINY.levels))
    assert changed_tokens(model, ids, position) == list(
        range(position - lookahead, position + left + 1)
    )


# -- training ----------------------------------------------------------------------------------


def test_overfitting_one_batch_lowers_the_loss(motion):
    x, mean, std = motion
    x = x[:, :32]
    model = tiny_model(mean=mean, std=std)
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(200):
        out = model(x)
        optimizer.zero_grad()
        out.losses["total"].backward()
        optimizer.step()
        losses.append(out.losses["total"].item())
    assert np.mean(losses[-5:]) < 0.3 * losses[0]

    metrics = reconstruction_metrics(model, [x[:2], x[2:]])
    assert model.training  # mode restored
    L = TINY.levels
    assert len(metrics["mpjpe_mm_by_levels"]) == len(metrics["level_gain"]) == L
    assert metrics["mpjpe_mm"] == metrics["mpjpe_mm_by_levels"][-1] >= 0
    assert metrics["feature_l1"] < metrics["feature_l1_by_levels"][0]
    assert sum(metrics["level_gain"]) == pytest.approx(1.0)
    assert all(0 < u <= 1 for u in metrics["codebook_usage"])
    assert all(1 <= p <= TINY.codebook_size for p in metrics["perplexity"])


def test_metrics_of_clips_batched_by_length_equal_those_clip_by_clip():
    from mogo.export.train.train_vq import clip_batches

    torch.manual_seed(0)
    model = MoSAVQ(TINY).eval()
    clips = [0.3 * torch.randn(1, frames, TINY.feature_dim) for frames in (20, 20, 31, 20, 31, 40)]
    batches = list(clip_batches(clips, torch.device("cpu"), batch_size=2))
    assert [tuple(b.shape[:2]) for b in batches] == [(2, 20), (1, 20), (2, 31), (1, 40)]
    one_by_one, batched = (
        reconstruction_metrics(model, clips),
        reconstruction_metrics(model, batches),
    )
    for name in ("mpjpe_mm", "feature_l1", "mpjpe_mm_by_levels", "codebook_usage"):
        np.testing.assert_allclose(batched[name], one_by_one[name], rtol=1e-5)
