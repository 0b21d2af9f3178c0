"""A stream's state as text: `MotionStream.state()` writes it, `MotionGenerator.resume` reads it.

What keeps a stream going is small: its prompt, seed and sampler state (PCG64: a few ints), its
step, its re-anchoring state, the token rows its cache, streaming decoder and foot planter still
hold, and the frames the foot planter holds back. The KV cache is not kept: resuming makes it
again as the stream made it (TokenStream.rebuild: the prefill its slots came from, then one
step per slot since), so the resumed stream draws the same tokens and emits the same frames,
on the same machine and graphs.

The text is base64url of: MAGIC, a format version (1 byte), the payload's length (uint32 LE),
its sha256, then the payload: zlib-compressed JSON, arrays in it as base64 of little-endian
bytes. The sha256 catches a state cut short or altered in transit; it is not a signature:
anyone can write a state, so every field is checked (type, range, shape) as untrusted input.
A state from another bundle (another manifest sha256) or a newer format is refused.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import struct
import zlib
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from mogo.anchoring import Anchoring
from mogo.manifest import MANIFEST
from mogo.sampling import Sampling

if TYPE_CHECKING:
    from mogo.generator import MotionGenerator, MotionStream

MAGIC = b"MOGO"
VERSION = 1  # the format written; states of a newer one are refused
HEADER = struct.Struct("<4sBI32s")  # magic, version, payload length, sha256 of the payload
MAX_STATE_CHARS = 32768  # refused before decoding: a state is ~2-17 KB
MAX_PAYLOAD = 1 << 17  # bytes of JSON a payload may inflate to (a zip bomb stops here)
MAX_PROMPT_CHARS = 4096
MAX_STEPS = 1 << 40
MAX_ROWS = 4096  # cache slots (a window) and decoder rows a state may hold
MAX_UNREAD = 1024  # frames decoded but not yet read (frames() reads them one by one)


class StateError(ValueError):
    """A state this runtime refuses: corrupted, truncated, hostile, of another bundle or of a
    newer format. One line naming the problem."""


def bundle_identity(generator: MotionGenerator) -> str:
    """The sha256 of the bundle's manifest, which holds the sha256 of every file."""
    return hashlib.sha256(generator.bundle.path(MANIFEST).read_bytes()).hexdigest()


def write(stream: MotionStream) -> str:
    """The state of `stream` between two steps (the caller holds its lock)."""
    g, tokens, decoder = stream.generator, stream.tokens, stream.decoder
    rng = tokens.rng.bit_generator.state
    since = max(k for k, (frame, _) in enumerate(stream.prompts) if frame <= stream.frames_emitted)
    anchor, feet = stream.anchor, stream.feet
    payload: dict[str, Any] = {
        "bundle": bundle_identity(g),
        "seed": int(stream.seed),
        "sampling": {f.name: getattr(tokens.sampling, f.name) for f in fields(Sampling)},
        "window": tokens.window,
        "low_latency": decoder.every == 1,
        "prompts": [[int(frame), text] for frame, text in stream.prompts[since:]],
        "steps": stream.steps,
        "frames": stream.frames_emitted,
        "skip": stream._skip,
        "unread": _pack(stream._unread, "<f4"),
        "rng": [rng["state"]["state"], rng["state"]["inc"], rng["has_uint32"], rng["uinteger"]],
        "tokens": {
            "steps": tokens.steps,
            "ended": tokens.ended,
            "oldest": tokens._oldest,
            "prefilled": tokens.prefilled,
            "positions": _pack(tokens.positions, "<i8"),
            "slots": _pack(tokens.slot_tokens, "<u2"),
            "last": _pack(tokens.last[None], "<u2"),
        },
        "anchoring": None,
        "decoder": {
            "start": decoder._start,
            "pushed": decoder.pushed,
            "emitted": decoder.emitted,
            "tokens": _pack(decoder._tokens, "<u2"),
        },
        "joints": [float(stream._joints.half_angle), *map(float, stream._joints.xz)],
        "feet": None,
    }
    if anchor is not None:
        payload["anchoring"] = {
            "options": {f.name: getattr(anchor.anchoring, f.name) for f in fields(Anchoring)},
            "recent": _pack(anchor.recent, "<u2"),
            "anchors": anchor.anchors,
            "fresh": anchor.fresh,
            "holding": anchor.holding,
        }
    if feet is not None:
        payload["feet"] = {
            "flag": feet._flag.tolist(),
            "held": feet._held.tolist(),
            "since": [int(n) for n in feet._since],
            "pin": _pack(feet._pin, "<f8"),
            "released": _pack(feet._released, "<f8"),
            "shift": _pack(feet._shift, "<f8"),
            "backs": _pack(feet._backs, "<f8"),
            "features": _pack(feet._features, "<f4"),
            "rows": _pack(feet._joints, "<f4"),  # float32 joints widened: exact
        }
    body = zlib.compress(json.dumps(payload, separators=(",", ":")).encode(), 9)
    head = HEADER.pack(MAGIC, VERSION, len(body), hashlib.sha256(body).digest())
    return base64.urlsafe_b64encode(head + body).decode("ascii").rstrip("=")


@dataclass
class State:
    """A state read and checked: what a stream is made with (`options`), then `restore`."""

    prompt: str
    seed: int
    sampling: Sampling
    window: int | None
    plant_feet: bool
    anchoring: Anchoring | None
    low_latency: bool
    payload: dict

    def restore(self, stream: MotionStream) -> None:
        """Put the state into a stream just made with these options (no step drawn yet)."""
        _restore(self.payload, stream)


def read(text: object, generator: MotionGenerator) -> State:
    """A state's text -> State, or StateError naming what is wrong with it."""
    payload = _payload(text)
    if payload.get("bundle") != bundle_identity(generator):
        raise StateError(
            "the state comes from another bundle (its manifest sha256 differs): resume it on "
            "a server or generator with the same bundle"
        )
    p = _Fields(payload, "")
    prompts = p.list("prompts", 1, 64)
    for k, entry in enumerate(prompts):
        if not (
            isinstance(entry, list)
            and len(entry) == 2
            and _is_int(entry[0], 0, MAX_STEPS)
            and isinstance(entry[1], str)
            and 0 < len(entry[1]) <= MAX_PROMPT_CHARS
        ):
            raise StateError(f"state field 'prompts[{k}]' must be [frame, prompt], got {entry!r}")
    sampling_fields = p.object("sampling")
    try:
        sampling = Sampling(**{f.name: sampling_fields.get(f.name) for f in fields(Sampling)})
    except (TypeError, ValueError) as error:
        raise StateError(f"state field 'sampling': {error}") from None
    window = payload.get("window")
    if window is not None:
        window = p.int("window", 1, MAX_ROWS - 1)
    anchoring = None
    if payload.get("anchoring") is not None:
        options = _Fields(p.object("anchoring"), "anchoring.").object("options")
        try:
            anchoring = Anchoring(
                **{
                    f.name: _checked_option(options.get(f.name), f.type, f.name)
                    for f in fields(Anchoring)
                }
            )
        except (TypeError, ValueError) as error:
            raise StateError(f"state field 'anchoring.options': {error}") from None
    return State(
        prompts[-1][1],
        p.int("seed", 0, 1 << 128),
        sampling,
        window,
        payload.get("feet") is not None,
        anchoring,
        p.bool("low_latency"),
        payload,
    )


def _payload(text: object) -> dict:
    if not isinstance(text, str):
        raise StateError(f"a stream state is text, got {type(text).__name__}")
    if len(text) > MAX_STATE_CHARS:
        raise StateError(f"the state has {len(text)} characters; at most {MAX_STATE_CHARS}")
    try:
        raw = base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))
    except (binascii.Error, ValueError):
        raise StateError("not a stream state: not base64url text") from None
    if len(raw) < 5 or raw[:4] != MAGIC:
        raise StateError("not a stream state (it does not start as one)")
    if raw[4] > VERSION:
        raise StateError(
            f"the state is of format {raw[4]}, newer than this mogo reads ({VERSION}): "
            "upgrade mogo-edge"
        )
    if len(raw) < HEADER.size:
        raise StateError(f"the state is truncated: {len(raw)} bytes, its header alone is more")
    _, _, length, digest = HEADER.unpack_from(raw)
    body = raw[HEADER.size :]
    if len(body) < length:
        raise StateError(f"the state is truncated: {len(body)} of its {length} bytes")
    if len(body) > length or hashlib.sha256(body).digest() != digest:
        raise StateError("the state is corrupted: its sha256 does not match")
    inflate = zlib.decompressobj()
    try:
        data = inflate.decompress(body, MAX_PAYLOAD)
    except zlib.error:
        raise StateError("the state's payload is not zlib data") from None
    if inflate.unconsumed_tail or not inflate.eof:
        raise StateError(f"the state's payload inflates past {MAX_PAYLOAD} bytes")
    try:
        payload = json.loads(data, parse_constant=_no_constant)
    except (ValueError, RecursionError) as error:
        raise StateError(f"the state's payload is not JSON this mogo reads: {error}") from None
    if not isinstance(payload, dict):
        raise StateError("the state's payload is not a JSON object")
    return payload


def _restore(payload: dict, stream: MotionStream) -> None:
    g, L = stream.generator, stream.generator.tokens.num_levels
    codes = g.codebook_size
    p = _Fields(payload, "")
    stream.prompts = [(frame, text) for frame, text in payload["prompts"]]
    stream.steps = p.int("steps", 0, MAX_STEPS)
    stream.frames_emitted = p.int("frames", 0, MAX_STEPS)
    stream._skip = p.int("skip", 0, MAX_STEPS)
    stream._unread = p.array("unread", "<f4", (g.skeleton.num_joints, 3), MAX_UNREAD)
    state, inc, has_uint32, uinteger = p.list("rng", 4, 4)
    if not (
        _is_int(state, 0, (1 << 128) - 1)
        and _is_int(inc, 0, (1 << 128) - 1)
        and inc % 2 == 1
        and _is_int(has_uint32, 0, 1)
        and _is_int(uinteger, 0, (1 << 32) - 1)
    ):
        raise StateError("state field 'rng' is not a PCG64 state")
    tokens = stream.tokens
    if payload.get("anchoring") is not None:
        a = _Fields(p.object("anchoring"), "anchoring.")
        anchor = stream.anchor
        anchor.recent = a.array("recent", "<u2", (L,), anchor.anchoring.keep, codes)
        anchor.anchors, anchor.fresh = a.int("anchors", 0, MAX_STEPS), a.int("fresh", 0, MAX_STEPS)
        anchor.holding = a.bool("holding")
        if anchor.holding:  # the stream was made with its latest prompt, not the hold's
            anchor.kind(anchor.anchoring.hold_prompt)
            tokens.set_prompt(g.embed([anchor.anchoring.hold_prompt])[0])  # no slot yet
    tokens.rng.bit_generator.state = {
        "bit_generator": "PCG64",
        "state": {"state": state, "inc": inc},
        "has_uint32": has_uint32,
        "uinteger": uinteger,
    }
    _restore_tokens(_Fields(p.object("tokens"), "tokens."), tokens, L, codes)
    _restore_decoder(_Fields(p.object("decoder"), "decoder."), stream.decoder, L, codes)
    half_angle, *xz = p.list("joints", 3, 3)
    if not all(isinstance(v, float) for v in (half_angle, *xz)):
        raise StateError("state field 'joints' must be three numbers")
    stream._joints.half_angle, stream._joints.xz = half_angle, np.array(xz)
    if stream.feet is not None:
        _restore_feet(_Fields(p.object("feet"), "feet."), stream.feet, g)
    tokens.rebuild()


def _restore_tokens(t: _Fields, tokens, L: int, codes: int) -> None:
    """The token loop's cache rows and their positions, its last row and counts."""
    window = tokens.window
    slots = t.array("slots", "<u2", (L,), MAX_ROWS if window is None else window + 1, codes)
    positions = t.array("positions", "<i8", (), len(slots), MAX_STEPS)
    last = t.array("last", "<u2", (L,), 1, codes)
    steps = t.int("steps", 0, MAX_STEPS)
    if len(positions) != len(slots) or len(last) != 1 or np.any(positions >= max(steps, 1)):
        raise StateError("state field 'tokens': slots, positions and steps do not agree")
    tokens.positions, tokens.slot_tokens, tokens.last = positions, slots, last[0]
    tokens.steps, tokens.ended = steps, t.bool("ended")
    tokens._oldest = t.int("oldest", 1, max(1, window or 1))
    tokens.prefilled = t.int("prefilled", 0, len(slots))


def _restore_decoder(d: _Fields, decoder, L: int, codes: int) -> None:
    """The streaming decoder's held token rows and its counts."""
    held = decoder.left_context + decoder.lookahead + decoder.every
    rows = d.array("tokens", "<u2", (L,), held, codes)
    start, pushed, emitted = (d.int(name, 0, MAX_STEPS) for name in ("start", "pushed", "emitted"))
    if not start <= emitted <= pushed or pushed - start != len(rows):
        raise StateError("state field 'decoder': its counts and rows do not agree")
    decoder._tokens, decoder._start = rows, start
    decoder.pushed, decoder.emitted = pushed, emitted


def _restore_feet(f: _Fields, feet, g) -> None:
    """The foot planter's contacts, pins and the frames it still holds back."""
    contacts = len(feet.contacts)
    flag, held_, since = (f.list(name, contacts, contacts) for name in ("flag", "held", "since"))
    if not all(isinstance(v, bool) for v in flag + held_) or not all(
        _is_int(v, 0, MAX_STEPS) for v in since
    ):
        raise StateError("state field 'feet': flags or counts of the wrong type")
    feet._flag, feet._held, feet._since = np.array(flag), np.array(held_), np.array(since)
    feet._pin = f.array("pin", "<f8", (3,), contacts, exact=contacts)
    feet._released = f.array("released", "<f8", (3,), contacts, exact=contacts)
    feet._shift = f.array("shift", "<f8", (), 3, exact=3)
    feet._backs = f.array("backs", "<f8", (3,), len(feet._backs), exact=len(feet._backs))
    held = feet.lookahead  # the frames a planter of this stream's window holds back at most
    feet._features = f.array("features", "<f4", (g.manifest.feature_dim,), held)
    joints = f.array("rows", "<f4", (g.skeleton.num_joints, 3), held)
    if len(joints) != len(feet._features):
        raise StateError("state field 'feet': as many joint rows as feature rows needed")
    feet._joints = joints.astype(np.float64)


class _Fields:
    """Typed reads of one JSON object of a state: StateError naming the field."""

    def __init__(self, obj: dict, where: str):
        self.obj, self.where = obj, where

    def _get(self, name: str) -> object:
        if name not in self.obj:
            raise StateError(f"state field '{self.where}{name}' is missing")
        return self.obj[name]

    def _bad(self, name: str, wanted: str, value: object) -> StateError:
        shown = repr(value) if len(repr(value)) < 60 else type(value).__name__
        return StateError(f"state field '{self.where}{name}' must be {wanted}, got {shown}")

    def int(self, name: str, low: int, high: int) -> int:
        value = self._get(name)
        if not _is_int(value, low, high):
            raise self._bad(name, f"an integer in [{low}, {high}]", value)
        return value

    def bool(self, name: str) -> bool:
        value = self._get(name)
        if not isinstance(value, bool):
            raise self._bad(name, "true or false", value)
        return value

    def list(self, name: str, least: int, most: int) -> list:
        value = self._get(name)
        if not isinstance(value, list) or not least <= len(value) <= most:
            raise self._bad(name, f"a list of {least} to {most} entries", value)
        return value

    def object(self, name: str) -> dict:
        value = self._get(name)
        if not isinstance(value, dict):
            raise self._bad(name, "an object", value)
        return value

    def array(
        self,
        name: str,
        dtype: str,
        tail: tuple,
        most: int,
        below: float | None = None,
        exact: int | None = None,
    ) -> np.ndarray:
        """Rows of `tail` shape, at most `most` (exactly `exact`), values under `below`."""
        value = self._get(name)
        if not isinstance(value, str) or len(value) > 4 * MAX_PAYLOAD:
            raise self._bad(name, "base64 text", value)
        try:
            data = base64.b64decode(value, validate=True)
        except (binascii.Error, ValueError):
            raise self._bad(name, "base64 text", value) from None
        row = np.dtype(dtype).itemsize * int(np.prod(tail, dtype=np.int64))
        rows, extra = divmod(len(data), row)
        if extra or rows > most or (exact is not None and rows != exact):
            raise self._bad(name, f"at most {most} rows of {tail} {dtype}", f"{len(data)} bytes")
        array = np.frombuffer(data, dtype).reshape(rows, *tail)
        native = array.astype(array.dtype.newbyteorder("="))
        if native.dtype.kind == "f" and not np.all(np.isfinite(native)):
            raise self._bad(name, "finite numbers", "NaN or infinity")
        if below is not None and native.size and (native.min() < 0 or native.max() >= below):
            raise self._bad(name, f"values in [0, {below})", "others")
        return native.astype(np.int64) if native.dtype.kind in "iu" else native


def _pack(array: np.ndarray, dtype: str) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype).tobytes()).decode("ascii")


def _is_int(value: object, low: int, high: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high


def _checked_option(value: object, kind: object, name: str) -> object:
    """An Anchoring field from a state: an int in range, max_one_off's seconds (or None: the
    bundle's), or the hold prompt's text."""
    if kind in (str, "str"):
        if isinstance(value, str) and 0 < len(value) <= MAX_PROMPT_CHARS:
            return value
    elif kind in (float | None, "float | None"):  # NaN and infinity fail the comparison
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if value is None or (number and 0 < value <= MAX_ROWS):
            return value
    elif _is_int(value, 1, MAX_ROWS):
        return value
    raise StateError(f"state field 'anchoring.options.{name}' is out of range: {value!r}")


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a number a state holds")
