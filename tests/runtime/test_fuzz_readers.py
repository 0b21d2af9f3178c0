"""Fuzz targets (hypothesis) for every reader of files a user or a stranger may hand over:
BVH, DeepMimic, .npy, the bundle manifest and the prompts file. Whatever the bytes, a reader
gives a result or its one documented error (a one-line ValueError naming the file; BundleError
for the manifest; the CLI's one-line error for the prompts file), without a numpy warning and
bounded in time (hypothesis' deadline; sizes are checked before anything is allocated, see
docs/security.md). Small example counts: they run with the normal test suite."""

import copy
import json
import struct
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers import travelling_clip
from mogo import Motion
from mogo.cli import CliError, _read_schedule
from mogo.generator import DEFAULT_BUNDLE
from mogo.manifest import MANIFEST, BundleError, Manifest
from mogo.motion.deepmimic import VALUES_PER_FRAME
from mogo.motion.mocap import read_mocap
from mogo.motion.skeleton import SMPL_22
from mogo.motion.untrusted import read_npy

FUZZ = settings(
    max_examples=80,
    deadline=10_000,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)

HOSTILE_WORDS = st.sampled_from(
    [
        "-2",
        "0",
        "1",
        "3",
        "7",
        "100000000",
        "9" * 30,
        "1e308",
        "-1e308",
        "nan",
        "inf",
        "1e-300",
        "100000",
        "{",
        "}",
        "ROOT",
        "JOINT",
        "End",
        "Site",
        "OFFSET",
        "CHANNELS",
        "MOTION",
        "Frames:",
        "Frame",
        "Time:",
        "Xrotation",
        "Yposition",
        "Wrotation",
        "Hips",
        "\x00",
        "é",
    ]
)


LIBRARY_WORDS = (
    "broadcast",
    "unhashable",
    "Exceeds the limit",
    "allow_pickle",
    "array element with a sequence",
    "inhomogeneous",
    "Traceback",
    "Errno",
)


def one_line_error(call, *documented):
    """call() returns, or raises one of `documented` with a one-line message in our words
    (none of numpy's or Python's own); no warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            return call()
        except documented as error:
            message = str(error)
            assert message and "\n" not in message, message
            assert not any(word in message for word in LIBRARY_WORDS), message
            return None


@pytest.fixture(scope="module")
def bvh_tokens(tmp_path_factory):
    joints = travelling_clip(np.random.default_rng(0), SMPL_22, frames=6).astype(np.float32)
    clip = Motion(
        features=np.zeros((6, 263), np.float32),
        joints=joints,
        fps=20.0,
        tokens=np.zeros((2, 6), np.int64),
        skeleton=SMPL_22,
    )
    path = clip.save_bvh(tmp_path_factory.mktemp("bvh") / "walk.bvh")
    return path.read_text().split()


@FUZZ
@given(
    edits=st.lists(
        st.tuples(st.integers(0, 10**6), st.sampled_from(["put", "cut", "add"]), HOSTILE_WORDS),
        min_size=1,
        max_size=6,
    )
)
def test_fuzz_bvh(tmp_path_factory, bvh_tokens, edits):
    tokens = list(bvh_tokens)
    for where, how, word in edits:
        k = where % len(tokens)
        if how == "put":
            tokens[k] = word
        elif how == "cut":
            del tokens[k]
        else:
            tokens.insert(k, word)
    path = tmp_path_factory.mktemp("fuzz") / "clip.bvh"
    path.write_text(" ".join(tokens), encoding="utf-8")
    clip = one_line_error(lambda: read_mocap(path), ValueError)
    assert clip is None or np.all(np.isfinite(clip.joints))


JSON_LEAVES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**30), 10**30),
    st.floats(allow_nan=False, allow_infinity=False),
    st.sampled_from([0.0, -1.0, 1e9, 1e-9, 1e300]),
    st.text(max_size=3),
)
JSON = st.recursive(
    JSON_LEAVES,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner, max_size=3)
    ),
    max_leaves=30,
)


def standing_row():
    from mogo.motion.deepmimic import _LAYOUT

    row = [1 / 30, 0, 0.9, 0, 1, 0, 0, 0]
    for _, width in _LAYOUT:
        row += [1, 0, 0, 0] if width == 4 else [0.0]
    return row


@FUZZ
@given(
    frames=st.one_of(
        JSON,
        st.lists(
            st.lists(JSON_LEAVES, min_size=VALUES_PER_FRAME, max_size=VALUES_PER_FRAME), max_size=4
        ),
    ),
    changes=st.lists(
        st.tuples(st.integers(0, 3), st.integers(0, VALUES_PER_FRAME - 1), JSON_LEAVES), max_size=4
    ),
    depth=st.integers(1, 100_000),
)
def test_fuzz_deepmimic(tmp_path_factory, frames, changes, depth):
    rows = [standing_row() for _ in range(4)]
    for row, column, value in changes:
        rows[row][column] = value
    path = tmp_path_factory.mktemp("fuzz") / "clip.txt"
    for text in (
        json.dumps({"Frames": frames}),
        json.dumps({"Loop": "wrap", "Frames": rows}),
        '{"Frames": ' + "[" * depth + "]" * depth + "}",
    ):
        path.write_text(text, encoding="utf-8")
        clip = one_line_error(lambda: read_mocap(path), ValueError)
        assert clip is None or np.all(np.isfinite(clip.joints))


SHAPES = st.one_of(
    st.tuples(), st.lists(st.integers(-2, 10**13), max_size=4).map(tuple), st.text(max_size=8)
)


@FUZZ
@given(
    descr=st.sampled_from(["<f8", "<f4", "|O", "<U3", "|b1", "<c16", "V8", ">i2", "junk"]),
    shape=SHAPES,
    fortran=st.one_of(st.booleans(), st.integers()),
    payload=st.binary(max_size=200),
    version=st.sampled_from([b"\x01\x00", b"\x02\x00", b"\x03\x00", b"\x09\x09"]),
)
def test_fuzz_npy(tmp_path_factory, descr, shape, fortran, payload, version):
    header = f"{{'descr': '{descr}', 'fortran_order': {fortran}, 'shape': {shape!r}, }}"
    header += " " * ((64 - (12 + len(header) + 1) % 64) % 64) + "\n"
    size = struct.pack("<H" if version == b"\x01\x00" else "<I", len(header))
    path = tmp_path_factory.mktemp("fuzz") / "clip.npy"
    path.write_bytes(b"\x93NUMPY" + version + size + header.encode() + payload)
    array = one_line_error(lambda: read_npy(path), ValueError)
    assert array is None or array.nbytes <= len(payload)


@pytest.fixture(scope="module")
def shipped_manifest():
    return json.loads((DEFAULT_BUNDLE / MANIFEST).read_text())


def leaves(value, path=()):
    if isinstance(value, dict):
        for key, item in value.items():
            yield from leaves(item, path + (key,))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from leaves(item, path + (index,))
    yield path


@FUZZ
@given(
    picks=st.lists(
        st.tuples(st.integers(0, 10**6), st.one_of(JSON, st.just("__delete__"))),
        min_size=1,
        max_size=3,
    )
)
def test_fuzz_manifest(shipped_manifest, picks):
    document = copy.deepcopy(shipped_manifest)
    for pick, value in picks:
        paths = [p for p in leaves(document) if p]
        if not paths:
            break
        *parents, last = paths[pick % len(paths)]
        holder = document
        for key in parents:
            holder = holder[key]
        if value == "__delete__":
            del holder[last]
        else:
            holder[last] = value
    one_line_error(lambda: Manifest.from_json(document, "manifest.json"), BundleError)


@FUZZ
@given(
    lines=st.lists(
        st.one_of(
            st.text(max_size=30),
            st.builds(
                lambda s, p: f"{s} {p}",
                st.sampled_from(
                    ["1", "0", "-1", "nan", "inf", "1e999", "0.05", "600", "9" * 400, "1_0"]
                ),
                st.text(max_size=20),
            ),
        ),
        max_size=8,
    ),
    raw=st.binary(max_size=40),
)
def test_fuzz_prompts_file(tmp_path_factory, lines, raw):
    path = tmp_path_factory.mktemp("fuzz") / "plan.txt"
    for data in ("\n".join(lines).encode("utf-8", "surrogatepass"), raw):
        path.write_bytes(data)
        read = one_line_error(lambda: _read_schedule(path), CliError)
        if read is not None:
            schedule, numbers = read
            assert len(schedule) == len(numbers) and all(
                prompt.strip() and seconds > 0 for prompt, seconds in schedule
            )
