"""The unpadded VQ decoder (mogo.serve.interior): a window's interior frames as the exported
decoder makes them, to a float rounding, in any batch; streams pushed together through it get
the frames of their own decoders; graphs it cannot cut are refused (the engine then decodes
whole windows)."""

import numpy as np
import pytest

pytest.importorskip("onnx")

from onnx import TensorProto, helper  # noqa: E402

from mogo._session import cpu_session  # noqa: E402
from mogo.serve.interior import interior_graph  # noqa: E402
from mogo.stream_decoder import push_many  # noqa: E402


@pytest.fixture(scope="module")
def interior(generator):
    data, cut = interior_graph(
        generator.bundle.path(generator.manifest.vq.decoder.file).read_bytes()
    )
    return cpu_session(data), cut


def test_a_window_decodes_to_its_interior(generator, interior):
    session, cut = interior
    decoder = generator.manifest.vq.decoder
    assert cut == decoder.left_context == decoder.lookahead
    whole = generator.streaming_decoder().session
    ids = np.random.default_rng(0).integers(0, generator.codebook_size, (5, 100, 6))
    for length in (2 * cut + 1, 2 * cut + 8, 100):
        expected = whole.run(None, {"ids": ids[:, :length]})[0][:, cut : length - cut]
        got = session.run(None, {"ids": ids[:, :length]})[0]
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5)
        for row in range(len(ids)):  # rows apart: the same alone as in the batch
            alone = session.run(None, {"ids": ids[row : row + 1, :length]})[0][0]
            np.testing.assert_array_equal(alone, got[row])


def test_streams_pushed_through_it_get_their_own_decoders_frames(generator, interior):
    """Streams of different ages, a token each a step: first windows whole, the others
    through the interior."""
    starts = [0, 0, 5, 40]
    together = [generator.streaming_decoder() for _ in starts]
    alone = [generator.streaming_decoder() for _ in starts]
    ids = np.random.default_rng(1).integers(0, generator.codebook_size, (len(starts), 140, 6))
    for step in range(140):
        live = [k for k, start in enumerate(starts) if start <= step]
        rows = [ids[k, step - starts[k]][None] for k in live]
        for k, row, frames in zip(
            live, rows, push_many([together[k] for k in live], rows, interior), strict=False
        ):
            np.testing.assert_allclose(frames, alone[k].push(row), rtol=0, atol=1e-5)
    assert all(d.emitted > 2 * d.left_context for d in together[:3])


def conv_graph(join: str = "Add", **conv) -> bytes:
    """x -> Conv -> `join` with x: a residual block as the decoder's."""
    conv = {"pads": [1, 1], "kernel_shape": [3], **conv}
    weight = helper.make_tensor("w", TensorProto.FLOAT, [1, 1, 3], [1.0, 2.0, 3.0])
    nodes = [
        helper.make_node("Conv", ["x", "w"], ["y"], name="conv", **conv),
        helper.make_node(
            join, ["x", "y"], ["z"], name="join", **({"axis": 2} if join == "Concat" else {})
        ),
    ]
    graph = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 1, "t"])],
        [helper.make_tensor_value_info("z", TensorProto.FLOAT, [1, 1, "t"])],
        [weight],
    )
    return helper.make_model(graph).SerializeToString()


def test_a_residual_block_is_cut_and_graphs_it_cannot_cut_are_refused():
    data, cut = interior_graph(conv_graph())
    x = np.arange(7, dtype=np.float32).reshape(1, 1, 7)
    whole = cpu_session(conv_graph()).run(None, {"x": x})[0]
    assert cut == 1
    np.testing.assert_array_equal(cpu_session(data).run(None, {"x": x})[0], whole[..., 1:-1])
    for graph, message in [
        (conv_graph(pads=[2, 0]), "not the same on both sides"),
        (conv_graph(pads=[2, 2]), "does not keep the length"),
        (conv_graph(strides=[2]), "strides"),
        (conv_graph("Mul"), "joined by Mul, not Add"),
        (conv_graph("Concat"), "Concat on the time path"),
    ]:
        with pytest.raises(ValueError, match=message):
            interior_graph(graph)
