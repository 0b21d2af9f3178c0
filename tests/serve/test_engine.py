"""The engine's VQ decoding: the windows of streams due on one round are decoded in one
batched call (mogo.stream_decoder.push_many), full windows by the unpadded decoder
(mogo.serve.interior), and every stream gets the frames its own per-stream decoder gives
(to a float rounding: the interior's matrix products are narrower)."""

import numpy as np
import pytest

pytest.importorskip("onnx")

from mogo.serve import engine as engine_module  # noqa: E402
from mogo.serve import interior  # noqa: E402
from mogo.serve.engine import Engine  # noqa: E402
from mogo.stream_decoder import StreamingDecoder  # noqa: E402


def play(generator, engine_parts, seconds: float = 9.0) -> dict[int, np.ndarray]:
    """Each stream's frames on the engine's own clock: three streams that start together,
    two later ones (other window lengths until they reach the common phase)."""
    engine = Engine(generator, 1, tokens=engine_parts)
    sampling = generator.sampling(None)
    starts = [0.0, 0.0, 0.0, 0.3, 1.1]
    got: dict[int, list] = {}
    now = 0.0
    while now < seconds:
        while starts and starts[0] <= now:
            stream = engine.open(
                f"a person walks {len(starts)} steps", len(starts), sampling, starts.pop(0)
            )
            got[stream.id] = []
        due = engine.due(now)
        for stream, _, joints in engine.round(due) if due else []:
            got[stream.id].append(joints)
        now = round(now + (0 if due else 0.05), 6)
    return {k: np.concatenate(v) for k, v in got.items()}


def test_batched_decoding_gives_each_stream_its_own_decoders_frames(
    generator, engine_parts, monkeypatch
):
    sizes = []
    decode = StreamingDecoder._decode_windows

    def counted(self, windows, *args):
        sizes.append(len(windows))
        return decode(self, windows, *args)

    monkeypatch.setattr(StreamingDecoder, "_decode_windows", counted)
    batched = play(generator, engine_parts)
    assert max(sizes) >= 3  # windows of several streams went in one call
    monkeypatch.setattr(
        engine_module,
        "push_many",
        lambda decoders, ids, interior: [d.push(i) for d, i in zip(decoders, ids, strict=False)],
    )
    sizes.clear()
    alone = play(generator, engine_parts)
    assert max(sizes) == 1
    assert batched.keys() == alone.keys()
    for k in batched:
        assert len(batched[k]) == len(alone[k]) > 100
        np.testing.assert_allclose(batched[k], alone[k], rtol=0, atol=1e-5)


def test_a_decoder_the_rewrite_cannot_cut_or_gets_wrong_decodes_whole_windows(
    generator, engine_parts, monkeypatch
):
    def refused(data):
        raise ValueError("an upsampling on the time path")

    def wrong(data):  # the padded graph: the wrong length for a cut of 31
        return data, 31

    for rewrite in (refused, wrong):
        monkeypatch.setattr(interior, "interior_graph", rewrite)
        engine = Engine(generator, 1, tokens=engine_parts)
        assert engine.interior is None
    stream = engine.open("a person walks forward", 1, generator.sampling(None), 0.0)
    frames = []
    while sum(map(len, frames)) < 120:  # past the first full window
        frames += [joints for _, _, joints in engine.round([stream])]
    assert np.isfinite(np.concatenate(frames)).all()
