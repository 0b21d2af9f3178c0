"""The /v1/stream protocol: what a client may send, what the server sends (docs/serve.md).

Client -> server, JSON text messages:
    {"prompt": "...", "seed": 1, "temperature": .., "top_k": .., "top_p": .., "guidance": ..,
     "binary": false, "plant_feet": true, "low_latency": false}
                                             first message: starts the stream (seed optional)
    {"resume": STATE, "from": i, "binary": false}
                                             first message instead: goes on with the stream a
                                             "state" message gave, sending frames from i on
    {"prompt": "..."}                        later: switch the prompt from the next step on
    {"state": true}                          later: ask for the stream's state now
    {"stop": true}                           later: end the stream (the server closes)
HTTP POST /v1/generate: one such JSON object (UTF-8), {"prompt", "seconds", "seed", "format"}.
Server -> client:
    {"type": "started", "stream": id, "seed": s, "fps": 20, "joints": [names], "parents": [..],
     "frame": i}                             the first frame to come (0, or a resume's)
    {"type": "frames", "index": i, "joints": [[[x, y, z] x 22] x n]}   frames i .. i+n-1, metres
    {"type": "state", "frame": i, "state": STATE}   resume from frame i (mogo.stream_state):
                                             on request, after a switch, every few seconds
    {"type": "drain", "frame": i, "state": STATE}   the server stops: resume elsewhere (it
                                             then closes the socket, 1001 going away)
    {"type": "switched", "prompt": "...", "index": i}    frames from i on follow the prompt
    {"type": "error", "error": "..."}
    binary (if asked): one message per burst, little-endian uint32 index, uint32 n, then
    float32 joints (n, 22, 3).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from mogo.sampling import Sampling
from mogo.stream_state import MAX_STATE_CHARS

MAX_MESSAGE_CHARS = 4096  # longer messages get an error (a prompt: text.max_length tokens, 128)
MAX_FIRST_CHARS = MAX_STATE_CHARS + 1024  # a socket's first message: it may resume a state
START_FIELDS = {
    "prompt",
    "seed",
    "binary",
    "plant_feet",
    "low_latency",
    *Sampling.__dataclass_fields__,
}
RESUME_FIELDS = {"resume", "from", "binary"}
LATER_FIELDS = {"prompt", "stop", "state"}
STATE = "state"  # what `later` returns for a state request
STATE_EVERY_SECONDS = 5.0  # each client gets its stream's state this often (and after a switch)
CLIP_FIELDS = {"prompt", "seconds", "seed", "format"}
CLIP_FORMATS = {
    "bvh": "text/plain",
    "npy": "application/octet-stream",
    "json": "application/json",
    "glb": "model/gltf-binary",
}  # -> content type


class ProtocolError(ValueError):
    """A client message the server refuses: its text goes back as an error message."""


class ServerFull(ProtocolError):
    """A stream past the server's cap: refused, and the socket closed."""


@dataclass
class Clip:
    prompt: object  # checked by the generator, as seconds and seed
    seconds: object
    seed: object
    format: str


@dataclass
class Start:
    prompt: str
    seed: int | None
    options: dict[str, Any]
    binary: bool
    plant_feet: bool  # as the API's plant_feet (mogo.motion.feet): on unless turned off
    low_latency: bool  # as the API's stream(low_latency=...): the bundle's low-latency decoder


@dataclass
class Resume:
    state: str  # checked by mogo.stream_state
    first: int | None  # the first frame to send (None: the state's)
    binary: bool


def read(text: object, first: bool = False) -> dict:
    """A client message (text) -> its JSON object, or ProtocolError. A socket's `first` may
    be longer if it resumes a state."""
    if not isinstance(text, str):
        raise ProtocolError("messages must be JSON text, not binary")
    limit = MAX_FIRST_CHARS if first and '"resume"' in text else MAX_MESSAGE_CHARS
    if len(text) > limit:
        raise ProtocolError(f"message of {len(text)} characters; at most {limit}")
    try:
        message = json.loads(text)
    except json.JSONDecodeError as error:
        raise ProtocolError(f"not JSON: {error.msg} at character {error.pos}") from None
    except RecursionError:  # "[[[[...": json's parser recurses
        raise ProtocolError("not JSON this server reads: nested too deeply") from None
    if not isinstance(message, dict):
        raise ProtocolError(f"a message must be a JSON object, got {type(message).__name__}")
    return message


def body(data: bytes, charset: str | None) -> dict:
    """An HTTP request's body (JSON is UTF-8, RFC 8259) -> its JSON object, or ProtocolError."""
    if charset is not None and charset.lower() not in ("utf-8", "utf8"):
        raise ProtocolError(f"charset {charset!r}: the body must be JSON in UTF-8")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ProtocolError(f"the body is not UTF-8 (byte {error.start})") from None
    return read(text)


def clip(message: dict) -> Clip:
    """A POST /v1/generate body."""
    known(message, CLIP_FIELDS)
    fmt = message.get("format", "bvh")
    if not isinstance(fmt, str) or fmt not in CLIP_FORMATS:
        raise ProtocolError(f'"format" must be one of {", ".join(CLIP_FORMATS)}, got {fmt!r}')
    return Clip(message.get("prompt"), message.get("seconds"), message.get("seed"), fmt)


def start(message: dict) -> Start:
    """The first message of a stream."""
    known(message, START_FIELDS)
    if "prompt" not in message:
        raise ProtocolError('the first message needs "prompt"')
    prompt, seed, binary = message["prompt"], message.get("seed"), message.get("binary", False)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise ProtocolError(f'"seed" must be an integer >= 0, got {seed!r}')
    plant_feet = message.get("plant_feet", True)
    low_latency = message.get("low_latency", False)
    for name, value in (
        ("binary", binary),
        ("plant_feet", plant_feet),
        ("low_latency", low_latency),
    ):
        if not isinstance(value, bool):
            raise ProtocolError(f'"{name}" must be true or false, got {value!r}')
    options = {k: v for k, v in message.items() if k in Sampling.__dataclass_fields__}
    return Start(_text(prompt), seed, options, binary, plant_feet, low_latency)


def resume(message: dict) -> Resume:
    """A first message that resumes a stream."""
    known(message, RESUME_FIELDS)
    state, first, binary = message["resume"], message.get("from"), message.get("binary", False)
    if not isinstance(state, str):
        raise ProtocolError(f'"resume" must be a state (text), got {type(state).__name__}')
    if first is not None and (isinstance(first, bool) or not isinstance(first, int) or first < 0):
        raise ProtocolError(f'"from" must be a frame index >= 0, got {first!r}')
    if not isinstance(binary, bool):
        raise ProtocolError(f'"binary" must be true or false, got {binary!r}')
    return Resume(state, first, binary)


def later(message: dict) -> str | None:
    """A message after the first: the new prompt, STATE for a state request, None for stop."""
    known(message, LATER_FIELDS)
    if len(message) == 1 and message.get("stop") is True:
        return None
    if len(message) == 1 and message.get("state") is True:
        return STATE
    if len(message) != 1 or "prompt" not in message:
        raise ProtocolError(
            'send {"prompt": "..."} to switch, {"state": true} for the state or '
            '{"stop": true} to end'
        )
    return _text(message["prompt"])


def started(stream_id: int, seed: int, fps: float, joint_names, parents, frame: int = 0) -> str:
    return json.dumps(
        {
            "type": "started",
            "stream": stream_id,
            "seed": seed,
            "fps": fps,
            "joints": [str(name) for name in joint_names],
            "parents": [int(parent) for parent in parents],
            "frame": frame,
        }
    )


def state(frame: int, text: str, drain: bool = False) -> str:
    """The stream's state, from frame `frame` on; `drain`: the server is stopping."""
    return json.dumps({"type": "drain" if drain else "state", "frame": frame, "state": text})


def frames(index: int, joints: np.ndarray, binary: bool) -> str | bytes:
    """One burst: frames index .. index + n - 1, (n, J, 3) metres."""
    if binary:
        return struct.pack("<II", index, len(joints)) + joints.astype("<f4").tobytes()
    return json.dumps(
        {
            "type": "frames",
            "index": index,
            "joints": np.round(joints.astype(np.float64), 4).tolist(),
        }
    )


def error(text: str) -> str:
    return json.dumps({"type": "error", "error": text})


def switched(prompt: str, index: int) -> str:
    """A switch accepted: frames from `index` on follow `prompt`."""
    return json.dumps({"type": "switched", "prompt": prompt, "index": index})


def note(text: str) -> str:
    return json.dumps({"type": "note", "note": text})


def known(message: dict, fields: set[str]) -> None:
    unknown = sorted(set(message) - fields)
    if unknown:
        raise ProtocolError(
            f"unknown field {unknown[0]!r}; the fields are {', '.join(sorted(fields))}"
        )


def _text(prompt: object) -> str:
    if not isinstance(prompt, str):
        raise ProtocolError(f'"prompt" must be text, got {type(prompt).__name__}')
    return prompt
