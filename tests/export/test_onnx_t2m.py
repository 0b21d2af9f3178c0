"""ONNX level graphs and text encoder vs torch; the onnxruntime token loop vs the torch generator
(tiny config, random weights, exported once per module)."""

import numpy as np
import onnx
import pytest
import torch

from mogo._session import cpu_session
from mogo.export.models.generate_torch import generate, step_inputs
from mogo.export.models.t2m import T2M, T2MConfig
from mogo.export.models.text_encoder import (
    SmallTextEncoder,
    SmallTextEncoderConfig,
    encode_captions,
    train_tokenizer,
)
from mogo.export.onnx.t2m_graphs import OPSET, export_level, export_text_encoder
from mogo.sampling import Sampling, choose_token, make_rng, step_uniforms
from mogo.token_generator import LEVEL_INPUTS, TokenGenerator, balanced_groups

SAMPLED = Sampling(temperature=1.0, top_k=6, top_p=0.9)
GUIDED = Sampling(temperature=0.8, guidance=2.5)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(0)
    model = T2M(T2MConfig.tiny()).eval()
    folder = tmp_path_factory.mktemp("t2m")
    paths = [folder / f"level_{level}.onnx" for level in range(model.config.num_levels)]
    graphs = [export_level(model, level, path) for level, path in enumerate(paths)]
    return model, paths, graphs


@pytest.fixture(scope="module")
def model(exported):
    return exported[0]


@pytest.fixture(scope="module")
def generator(exported):
    model, paths, graphs = exported
    return TokenGenerator(paths, graphs, model.config.end_token)


def prompts(config, count, seed=0):
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(config.text_dim, generator=g) for _ in range(count)]


def dims(value_info):
    return [d.dim_param or d.dim_value for d in value_info.type.tensor_type.shape.dim]


def test_level_graphs_have_the_protocol_names_and_dynamic_axes(exported):
    model, paths, graphs = exported
    config = model.config
    for level, (path, graph) in enumerate(zip(paths, graphs, strict=False)):
        proto = onnx.load(path)
        assert proto.opset_import[0].version == OPSET
        inputs = {v.name: dims(v) for v in proto.graph.input}
        outputs = {v.name: dims(v) for v in proto.graph.output}
        assert tuple(inputs) == graph.inputs and tuple(outputs) == graph.outputs
        assert graph.file == path.name
        layers, H, dh = config.layers[level], config.heads[level], config.head_dim
        assert inputs["past_key_values.0.key"] == ["batch", H, "past", dh]
        assert len(graph.inputs) == len(LEVEL_INPUTS) + 2 * layers
        assert inputs["prompt"] == ["batch", config.text_dim]
        assert inputs["uncond"] == ["batch"]
        assert inputs["token_ids"] == ["batch", "seq", config.num_levels]
        assert inputs["positions"] == ["seq"] and inputs["past_positions"] == ["past"]
        assert outputs["logits"] == ["batch", config.num_classes(level)]
        for i in range(layers):
            for t in ("key", "value"):
                assert inputs[f"past_key_values.{i}.{t}"] == ["batch", H, "past", dh]
                batch, heads, total, width = outputs[f"present.{i}.{t}"]
                assert (batch, heads, width) == ("batch", H, dh)
                assert set(total.replace(" ", "").split("+")) == {"past", "seq"}


@torch.no_grad()
def test_level_graphs_match_torch_prefill_and_50_decodes(model, generator):
    """Prefill of the prefix and 4 steps on an empty cache, then 50 one-position decodes,
    conditional and unconditional rows."""
    config = model.config
    prompt = prompts(config, 1)[0].expand(2, -1)
    uncond = torch.tensor([False, True])
    g = torch.Generator().manual_seed(1)
    tokens = torch.randint(0, config.codebook_size, (1, 54, config.num_levels), generator=g)
    inputs = torch.nn.functional.pad(tokens, (0, 0, 1, 0)).expand(2, -1, -1)  # position n: n - 1
    for level in range(config.num_levels):
        positions, past_positions = torch.arange(5), torch.zeros(0, dtype=torch.long)
        cache, ort_cache = None, generator.empty_cache(level, 2)
        for _ in range(51):
            logits, cache = model.level_forward(
                level, prompt, uncond, inputs[:, positions], positions, past_positions, cache
            )
            ort_logits, ort_cache = generator.run(
                level,
                prompt.numpy(),
                uncond.numpy(),
                inputs[:, positions].numpy(),
                positions.numpy(),
                past_positions.numpy(),
                ort_cache,
            )
            np.testing.assert_allclose(ort_logits, logits.numpy(), rtol=0, atol=1e-4)
            past_positions = torch.cat([past_positions, positions])
            positions = positions[-1:] + 1
        for ort_tensor, tensor in zip(ort_cache, [t for pair in cache for t in pair], strict=False):
            assert ort_tensor.shape == (2, config.heads[level], 55, config.head_dim)
            np.testing.assert_allclose(ort_tensor, tensor.numpy(), rtol=0, atol=1e-4)


def test_greedy_stream_equals_torch_cached_and_recomputed(model, generator):
    prompt = prompts(model.config, 1)[0]
    tokens = generator.generate(prompt.numpy(), max_frames=30, sampling=Sampling(temperature=0))
    assert tokens.dtype == np.int64 and tokens.shape[1] == model.config.num_levels
    for use_cache in (True, False):
        expected = generate(
            model, prompt, max_frames=30, sampling=Sampling(temperature=0), use_cache=use_cache
        )
        np.testing.assert_array_equal(tokens, expected)


@pytest.mark.parametrize("settings, seed", [(SAMPLED, 3), (GUIDED, 4)])
def test_sampled_and_guided_streams_equal_torch(model, generator, settings, seed):
    prompt = prompts(model.config, 1)[0]
    tokens = generator.generate(prompt.numpy(), num_frames=25, sampling=settings, seed=seed)
    np.testing.assert_array_equal(
        tokens, generate(model, prompt, num_frames=25, seed=seed, sampling=settings)
    )
    assert len(np.unique(tokens[:, 0])) > 3


def test_end_token_and_forced_length(model, generator):
    """Free running, level 0 draws the end token (p ~ 1/17 a step with random weights); forced,
    the stream goes on: both as torch."""
    prompt = prompts(model.config, 1)[0]
    free = generator.generate(prompt.numpy(), max_frames=60, seed=2)
    assert 1 <= len(free) < 60
    np.testing.assert_array_equal(free, generate(model, prompt, max_frames=60, seed=2))
    forced = generator.generate(prompt.numpy(), num_frames=len(free) + 10, seed=2)
    assert len(forced) == len(free) + 10
    np.testing.assert_array_equal(forced, generate(model, prompt, num_frames=len(forced), seed=2))
    stream = generator.start(prompt.numpy(), seed=2)
    while stream.step() is not None:
        pass
    assert stream.ended and stream.step() is None and stream.steps == len(free)


def test_sliding_window_equals_torch_and_bounds_the_cache(model, generator):
    prompt = prompts(model.config, 1)[0]
    expected = generate(model, prompt, num_frames=24, seed=5, window=5, sampling=SAMPLED)
    assert not np.array_equal(
        expected, generate(model, prompt, num_frames=24, seed=5, sampling=SAMPLED)
    )
    stream = generator.start(prompt.numpy(), seed=5, sampling=SAMPLED, window=5, allow_end=False)
    np.testing.assert_array_equal(np.array([stream.step() for _ in range(24)]), expected)
    order = np.argsort(stream.positions)  # a full window overwrites its oldest slot in place
    np.testing.assert_array_equal(stream.positions[order], [0, 19, 20, 21, 22, 23])
    np.testing.assert_array_equal(stream.slot_tokens[order][1:], expected[18:23])
    assert {t.shape[2] for cache in stream.caches for t in cache} == {6}


@torch.no_grad()
def recomputed_continuation(model, prompt, ids, steps, sampling, seed):
    """Steps len(ids)..steps-1 of a forced-length stream that had drawn `ids` and goes on under
    `prompt`, recomputing the whole context at every step: what an exact switch must give."""
    L, end = model.config.num_levels, model.config.end_token
    uncond = torch.tensor([False, True][: 2 if sampling.guided else 1])
    prompt = prompt.expand(len(uncond), -1)
    rng = make_rng(seed)
    for _ in range(len(ids)):
        step_uniforms(rng, L)
    for step in range(len(ids), steps):
        uniforms = step_uniforms(rng, L)
        positions = torch.arange(step + 1)
        inputs = step_inputs(ids, positions, len(uncond))
        row = []
        for level in range(L):
            logits = model.level_forward(level, prompt, uncond, inputs, positions)[0].numpy()
            row.append(
                choose_token(
                    logits[0],
                    logits[1] if sampling.guided else None,
                    uniforms[level],
                    sampling,
                    None if level else end,
                )
            )
        ids = np.concatenate([ids, np.array([row], dtype=np.int64)])
    return ids


def test_set_prompt_reprefills_exactly(model, generator):
    first, second = prompts(model.config, 2, seed=6)
    sampling = Sampling(temperature=1.0, guidance=2.0)

    def stream(switch_to=None):
        s = generator.start(first.numpy(), seed=7, sampling=sampling, allow_end=False)
        rows = [s.step() for _ in range(8)]
        if switch_to is not None:
            s.set_prompt(switch_to.numpy())
        return np.array(rows + [s.step() for _ in range(12)])

    unswitched, switched = stream(), stream(second)
    np.testing.assert_array_equal(switched[:8], unswitched[:8])
    assert not np.array_equal(switched[8:], unswitched[8:])
    np.testing.assert_array_equal(
        switched, recomputed_continuation(model, second, switched[:8], 20, sampling, seed=7)
    )
    np.testing.assert_array_equal(stream(first), unswitched)  # re-prefill under the same prompt


def test_set_prompt_before_the_first_step_and_in_a_window(generator, model):
    first, second = prompts(model.config, 2, seed=8)
    stream = generator.start(first.numpy(), seed=9, allow_end=False)
    stream.set_prompt(second.numpy())
    np.testing.assert_array_equal(
        np.array([stream.step() for _ in range(6)]),
        generator.generate(second.numpy(), num_frames=6, seed=9),
    )
    stream = generator.start(first.numpy(), seed=9, window=3, allow_end=False)
    for _ in range(10):
        stream.step()
    positions = stream.positions.copy()
    stream.set_prompt(second.numpy())
    np.testing.assert_array_equal(stream.positions, positions)
    assert {t.shape[2] for cache in stream.caches for t in cache} == {4}
    assert stream.step() is not None and stream.positions.max() == 10


def test_generator_reads_the_cache_sizes_from_the_graphs(model, generator):
    c = model.config
    assert generator.cache_shapes == [
        (c.layers[l], c.heads[l], c.head_dim) for l in range(c.num_levels)
    ]


def test_generator_checks_names_and_runs_one_thread_without_spinning(exported):
    model, paths, graphs = exported
    with pytest.raises(ValueError, match="level_0.onnx: the graph's inputs are not the manifest"):
        TokenGenerator(paths, [graphs[1]] + graphs[1:], model.config.end_token)
    options = cpu_session(paths[2]).get_session_options()
    assert options.intra_op_num_threads == 1
    assert options.get_session_config_entry("session.intra_op.allow_spinning") == "0"


def test_text_encoder_graph_matches_torch(tmp_path):
    captions = ["a person walks forward.", "someone jumps up and down!", "a man waves"] * 3
    tokenizer = train_tokenizer(captions, vocab_size=60, max_length=10)
    torch.manual_seed(0)
    encoder = SmallTextEncoder(SmallTextEncoderConfig.tiny(tokenizer.get_vocab_size())).eval()
    path = tmp_path / "text_encoder.onnx"
    names = export_text_encoder(encoder, path, max_length=10)
    proto = onnx.load(path)
    assert [(v.name, dims(v)) for v in proto.graph.input] == [
        ("token_ids", ["batch", "seq"]),
        ("attention_mask", ["batch", "seq"]),
    ]
    assert [(v.name, dims(v)) for v in proto.graph.output] == [
        ("prompt_embedding", ["batch", encoder.output_dim])
    ]
    session = cpu_session(path)
    for batch in (
        captions[:3],
        ["a person walks forward and waves and jumps up and down"],
        ["jumps"],
    ):
        ids, mask = encode_captions(tokenizer, batch)
        (embedding,) = session.run(
            list(names.outputs), dict(zip(names.inputs, [ids.numpy(), mask.numpy()], strict=False))
        )
        with torch.no_grad():
            expected = encoder.encode(ids, mask).numpy()
        np.testing.assert_allclose(embedding, expected, rtol=0, atol=1e-5)


@pytest.mark.parametrize("window", [None, 4])
def test_continue_from_takes_a_clip_as_the_past(model, generator, window):
    prompt = prompts(model.config, 1, seed=10)[0]
    sampling = SAMPLED
    clip = np.random.default_rng(11).integers(0, model.config.codebook_size, (8, 3))
    stream = generator.start(
        prompt.numpy(), seed=12, sampling=sampling, window=window, allow_end=False
    )
    stream.continue_from(clip)
    for _ in range(len(clip)):  # the recomputation below draws after len(clip) steps' uniforms
        step_uniforms(stream.rng, model.config.num_levels)
    rows = np.array([stream.step() for _ in range(10)])
    if window is None:
        np.testing.assert_array_equal(
            rows, recomputed_continuation(model, prompt, clip, 18, sampling, seed=12)[8:]
        )
    else:
        np.testing.assert_array_equal(np.sort(stream.positions), [0, 14, 15, 16, 17])
    with pytest.raises(ValueError, match="continue from"):
        stream.continue_from(clip[:, :2])


def test_levels_run_concurrently_give_the_same_tokens(exported, generator):
    model, paths, graphs = exported
    parallel = TokenGenerator(paths, graphs, model.config.end_token, level_workers=2)
    assert len(parallel.level_groups) == 2
    twin = generator.with_level_workers(3)
    assert twin.sessions is generator.sessions and len(twin.level_groups) == 3
    assert len(generator.level_groups) == 1
    prompt = prompts(model.config, 1, seed=3)[0].numpy()
    for settings in (SAMPLED, GUIDED):
        for window in (None, 4):
            expected = generator.generate(
                prompt, num_frames=20, sampling=settings, seed=1, window=window
            )
            np.testing.assert_array_equal(
                parallel.generate(prompt, num_frames=20, sampling=settings, seed=1, window=window),
                expected,
            )
    switched = []
    for g in (generator, parallel):  # the re-prefill of a prompt switch, too
        stream = g.start(prompt, seed=2, window=4, allow_end=False)
        rows = [stream.step() for _ in range(6)]
        stream.set_prompt(-prompt)
        switched.append(np.array(rows + [stream.step() for _ in range(6)]))
    np.testing.assert_array_equal(*switched)


@pytest.mark.parametrize(
    "layers, groups, expected",
    [
        ([4, 3, 2, 2, 1, 1], 2, [[0, 3, 5], [1, 2, 4]]),  # 7 and 6 layers
        ([4, 3, 2, 2, 1, 1], 1, [[0, 1, 2, 3, 4, 5]]),
        ([2, 1, 1], 8, [[0], [1], [2]]),
        ([18, 16, 8, 4, 2, 2], 2, [[0, 3, 4, 5], [1, 2]]),  # 26 and 24
    ],
)
def test_balanced_groups(layers, groups, expected):
    assert balanced_groups(layers, groups) == expected
