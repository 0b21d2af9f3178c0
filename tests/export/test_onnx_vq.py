"""ONNX VQ encoder and decoder vs torch, and the streaming decoder vs an offline decode (tiny
config, random weights, each variant exported once per module)."""

from dataclasses import replace

import numpy as np
import onnx
import pytest
import torch

from mogo._session import cpu_session
from mogo.export.models.vq import MoSAVQ, VQConfig, decoder_receptive_field
from mogo.export.onnx.t2m_graphs import OPSET
from mogo.export.onnx.vq_graphs import export_vq_decoder, export_vq_encoder
from mogo.manifest import DecoderGraph, Graph
from mogo.stream_decoder import StreamingDecoder

VARIANTS = {
    "down1": dict(down_factor=1),
    "down2": dict(down_factor=2),
    "causal1": dict(causal=True),
    "causal2": dict(causal=True, down_factor=2),
}


@pytest.fixture(scope="module", params=list(VARIANTS))
def exported(request, tmp_path_factory):
    """(model, decoder entry, decoder session, folder) of a variant. The codebooks start from
    encoder outputs (one training-mode pass), so that ids vary, plus noise: that pass makes
    duplicate codes, and torch and onnxruntime break such exact ties differently. The
    convolutions get unit-gain weights: at the default init the farthest tokens of the decoder's
    receptive field move a frame by ~1e-7, too little for a stream to show whether it kept them."""
    torch.manual_seed(0)
    model = MoSAVQ(replace(VQConfig.tiny(), joint_weight=0.0, **VARIANTS[request.param]))
    for conv in model.modules():
        if isinstance(conv, torch.nn.Conv1d):
            torch.nn.init.kaiming_normal_(conv.weight, nonlinearity="linear")
    with torch.no_grad():
        model.train()(torch.randn(4, 32, model.config.feature_dim))
        model.quantizer.codebook += 1e-2 * torch.randn_like(model.quantizer.codebook)
    model.eval()
    folder = tmp_path_factory.mktemp(request.param)
    decoder = export_vq_decoder(model, folder / "vq_decoder.onnx")
    return model, decoder, cpu_session(folder / decoder.file), folder


@pytest.fixture(scope="module")
def encoder(exported):
    """(encoder entry, encoder session) of a variant; the causal encoder only at down 2."""
    model, _, _, folder = exported
    if model.config.causal and model.config.down_factor == 1:
        pytest.skip("the causal encoder is checked at down_factor 2")
    graph = export_vq_encoder(model, folder / "vq_encoder.onnx")
    return graph, cpu_session(folder / graph.file)


def streaming_decoder(
    graph: DecoderGraph, session, config: VQConfig, **changes
) -> StreamingDecoder:
    args = dict(
        left_context=graph.left_context,
        lookahead=graph.lookahead,
        codebook_size=config.codebook_size,
        ids_name=graph.inputs[0],
        features_name=graph.outputs[0],
    )
    return StreamingDecoder(session, **{**args, **changes})


def random_ids(rng, config, *shape) -> np.ndarray:
    return rng.integers(config.codebook_size, size=(*shape, config.levels))


def dims(value_info):
    return [d.dim_param or d.dim_value for d in value_info.type.tensor_type.shape.dim]


def check_graph(graph: Graph, folder, input_dims: list, output_width: int) -> None:
    """The opset, names and dims, dynamic ones named (an output's by an expression)."""
    proto = onnx.load(folder / graph.file)
    assert proto.opset_import[0].version == OPSET
    (graph_input,), (graph_output,) = proto.graph.input, proto.graph.output
    assert ((graph_input.name,), (graph_output.name,)) == (graph.inputs, graph.outputs)
    assert dims(graph_input) == input_dims
    batch, length, width = dims(graph_output)
    assert (batch, width) == ("batch", output_width) and isinstance(length, str)


def test_decoder_graph_and_its_receptive_field(exported):
    model, decoder, _, folder = exported
    c = model.config
    check_graph(decoder, folder, ["batch", "tokens", c.levels], c.feature_dim)
    left, lookahead = decoder_receptive_field(c)
    assert (decoder.left_context, decoder.lookahead) == (left, lookahead)
    assert lookahead == 0 if c.causal else lookahead > 0


def test_encoder_graph(exported, encoder):
    c, folder = exported[0].config, exported[3]
    check_graph(encoder[0], folder, ["batch", "frames", c.feature_dim], c.levels)


@torch.no_grad()
def test_encoder_gives_the_torch_ids(exported, encoder):
    """Batches 1 .. 4, lengths 1 .. 61, also not whole tokens (the last frame repeated)."""
    model, _, _, _ = exported
    graph, session = encoder
    down, seen = model.config.down_factor, set()
    for batch, frames in [(1, 1), (3, 5), (2, 8), (4, 37), (1, 61)]:
        x = torch.randn(batch, frames, model.config.feature_dim)
        (ids,) = session.run(list(graph.outputs), {graph.inputs[0]: x.numpy()})
        tokens = -(-frames // down)
        padded = torch.cat([x, x[:, -1:].expand(-1, tokens * down - frames, -1)], dim=1)
        expected = model.encode(padded).numpy()
        assert ids.dtype == np.int64 and ids.shape == (batch, tokens, model.config.levels)
        np.testing.assert_array_equal(ids, expected)
        seen.update(map(tuple, ids.reshape(-1, model.config.levels)))
    assert len(seen) > 20  # the ids vary: their agreement is no accident


@torch.no_grad()
def test_decoder_matches_torch(exported):
    model, decoder, session, _ = exported
    rng = np.random.default_rng(0)
    for batch, tokens in [(1, 1), (2, 2), (3, 7), (1, 50)]:
        ids = random_ids(rng, model.config, batch, tokens)
        (features,) = session.run(list(decoder.outputs), {decoder.inputs[0]: ids})
        expected = model.decode(torch.from_numpy(ids)).numpy()
        assert features.shape == (batch, tokens * model.config.down_factor, expected.shape[2])
        np.testing.assert_allclose(features, expected, rtol=0, atol=1e-4)


@pytest.mark.parametrize("every", [1, 4])
def test_stream_of_2000_tokens_in_random_pushes_equals_the_offline_decode(exported, every):
    """Push sizes 0 .. 5; the tokens held stay within the decoder's receptive field (plus the
    tokens waiting for a decode every `every`)."""
    model, graph, session, _ = exported
    rng = np.random.default_rng(1)
    ids = random_ids(rng, model.config, 2000)
    stream = streaming_decoder(graph, session, model.config, every=every)
    bound = graph.left_context + graph.lookahead + every - 1
    chunks, start = [], 0
    while start < len(ids):
        stop = start + int(rng.integers(0, 6))
        chunks.append(stream.push(ids[start:stop]))
        start = stop
        assert stream.buffered_tokens <= bound
        ready = max(0, min(start, 2000) - graph.lookahead)
        assert ready - every < stream.emitted <= ready or stream.emitted == ready
    chunks.append(stream.flush())
    offline = stream.decode_offline(ids)
    assert offline.shape == (2000 * model.config.down_factor, model.config.feature_dim)
    np.testing.assert_allclose(np.concatenate(chunks), offline, rtol=0, atol=1e-5)
    assert stream.pushed == stream.emitted == stream.buffered_tokens == 0  # ready again


def test_a_smaller_context_than_the_receptive_field_is_not_exact(exported):
    """The equality above needs the whole receptive field: one token less breaks it."""
    model, graph, session, _ = exported
    ids = random_ids(np.random.default_rng(2), model.config, 120)
    stream = streaming_decoder(
        graph,
        session,
        model.config,
        left_context=graph.left_context - 1,
        lookahead=max(0, graph.lookahead - 1),
    )
    frames = np.concatenate(
        [stream.push(ids[i : i + 1]) for i in range(len(ids))] + [stream.flush()]
    )
    assert np.abs(frames - stream.decode_offline(ids)).max() > 1e-3


def test_a_causal_stream_emits_each_token_frames_as_soon_as_it_is_pushed(exported):
    model, graph, session, _ = exported
    if not model.config.causal:
        pytest.skip("a centred decoder waits for its lookahead")
    down = model.config.down_factor
    ids = random_ids(np.random.default_rng(3), model.config, 60)
    stream = streaming_decoder(graph, session, model.config)
    offline = stream.decode_offline(ids)
    for t in range(len(ids)):
        frames = stream.push(ids[t : t + 1])
        np.testing.assert_allclose(frames, offline[t * down : (t + 1) * down], rtol=0, atol=1e-5)
    assert len(stream.flush()) == 0


def test_bad_ids_are_refused_clearly(exported):
    model, graph, session, _ = exported
    c = model.config
    stream = streaming_decoder(graph, session, model.config)
    good = random_ids(np.random.default_rng(4), c, 3)
    cases = [
        (good[:, :-1], "shape"),
        (good[0], "shape"),
        (good[None], "shape"),
        (good - c.codebook_size, rf"\[0, {c.codebook_size}\)"),
        (good + c.codebook_size, rf"\[0, {c.codebook_size}\)"),
        (good.astype(np.float32), "integers"),
    ]
    for ids, message in cases:
        for call in (stream.push, stream.decode_offline):
            with pytest.raises(ValueError, match=message):
                call(ids)
    fresh = streaming_decoder(graph, session, model.config)
    np.testing.assert_array_equal(stream.push(good), fresh.push(good))  # nothing was taken
