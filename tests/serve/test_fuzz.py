"""Fuzz targets (hypothesis, bounded: a fixed number of examples, no deadline) for the
server's two readers: a WebSocket message and a POST /v1/generate body. Any input gives a
result or the one documented error, ProtocolError (sent back as an error message or a 400);
what the readers pass on is then checked by the generator, whose TypeError or ValueError
the server sends back the same way."""

import json
import warnings

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mogo.generator import checked_seed
from mogo.serve import protocol

EXAMPLES = settings(
    max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

FIELDS = sorted(protocol.START_FIELDS | protocol.LATER_FIELDS | protocol.CLIP_FIELDS)
values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats()
    | st.text(max_size=40)
    | st.sampled_from(["a person walks", "bvh", "npy", "\ud800", "", " "]),
    lambda inner: (
        st.lists(inner, max_size=4)
        | st.dictionaries(st.sampled_from(FIELDS) | st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)
objects = st.dictionaries(st.sampled_from(FIELDS), values, max_size=6)
messages = (
    st.text(max_size=200)
    | values.map(json.dumps)
    | objects.map(json.dumps)
    | st.integers(1, 5000).map(lambda n: "[" * n)
    | st.integers(4000, 5000).map(lambda n: json.dumps({"prompt": "x" * n}))
)


def utf8(text: str) -> bytes:
    return text.encode("utf-8", "surrogatepass")  # a lone surrogate: bytes that are not UTF-8


@EXAMPLES
@given(message=messages | st.binary(max_size=50), first=st.booleans())
def test_a_websocket_message_gives_a_result_or_a_protocol_error(generator, message, first):
    try:
        body = protocol.read(message)
        if first:
            start = protocol.start(body)
        else:
            prompt = protocol.later(body)
    except protocol.ProtocolError as error:
        assert str(error) and "\n" not in str(error)
        return
    if not first:
        assert prompt is None or isinstance(prompt, str)
        return
    assert isinstance(start.prompt, str) and isinstance(start.binary, bool)
    try:  # what Server.open checks next, before the engine
        generator.sampling(None, **start.options)
        checked_seed(start.seed)
    except (TypeError, ValueError) as error:
        assert str(error)


@EXAMPLES
@given(
    data=st.binary(max_size=300)
    | messages.map(utf8)
    | objects.map(lambda o: utf8(json.dumps(o, ensure_ascii=False))),
    charset=st.none()
    | st.sampled_from(["utf-8", "UTF8", "latin-1", "bogus", ""])
    | st.text(max_size=10),
)
def test_an_http_body_gives_a_clip_request_or_a_protocol_error(generator, data, charset):
    try:
        clip = protocol.clip(protocol.body(data, charset))
    except protocol.ProtocolError as error:
        assert str(error) and "\n" not in str(error)
        return
    assert clip.format in protocol.CLIP_FORMATS
    try:  # what the generator checks next (MotionGenerator.generate's arguments)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # notes on the prompt: not errors
            generator.read_prompt(clip.prompt, "prompt")
        if clip.seconds is not None:
            generator._seconds(clip.seconds)
        if clip.seed is not None:
            checked_seed(clip.seed)
    except (TypeError, ValueError) as error:
        assert str(error)
