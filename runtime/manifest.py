"""The bundle manifest as code: the one schema of manifest.json, which `mogo export` writes
(`Manifest.to_json`) and everything else reads (`Manifest.from_json`).

The dataclasses below are the schema: each JSON key is a field of the same name, so adding a
key is adding a field. Reading checks every key and type and refuses a manifest that does not
match, naming the key ("manifest.json: t2m.levels[2].file: missing"). Each value is stored
once; what follows from it is a property (the end token, the feature size) or is read from the
graphs themselves (the cache sizes of the level graphs). A program in another language finds
here all it needs to run a bundle: the graphs and their input/output names, the decoder's
context, the normalisation, the sampling defaults, and the skeleton with the layout of the
features the decoder writes.

The model configs (`t2m.config`, `vq.config`) are the arguments that rebuild the torch models;
they are kept whole, and the runtime reads from them only the sizes declared in CONFIG_KEYS.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field

import numpy as np

from mogo._json_schema import KeyProblem, read, write
from mogo.motion.features import feature_layout
from mogo.motion.skeleton import Skeleton
from mogo.sampling import Sampling, SamplingError

FORMAT = "mogo-bundle"
FORMAT_VERSION = 2  # 2: skeleton and feature layout under "motion"; no value stored twice
MANIFEST = "manifest.json"


class BundleError(ValueError):
    """A bundle that cannot be used; the message names the file (and key) and the problem."""


@dataclass(frozen=True)
class FileEntry:
    bytes: int
    sha256: str


@dataclass(frozen=True)
class Graph:
    """An ONNX file of the bundle and its input and output names, in protocol order."""

    file: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]


@dataclass(frozen=True)
class DecoderGraph(Graph):
    """The VQ decoder: the frames of token t depend on tokens t - left_context .. t + lookahead."""

    left_context: int
    lookahead: int


@dataclass(frozen=True)
class StepDecoderGraph(Graph):
    """The low-latency decoder one token a call, its convolutions' context in a state vector
    (mogo.export.onnx.vq_step_graph): ids, position, state -> the frame of token position -
    lookahead, the next state."""

    lookahead: int
    state_size: int


@dataclass(frozen=True)
class Normalization:
    """.npy files (feature_dim,) float32: the graphs see (features - mean) / std."""

    mean: str
    std: str


@dataclass(frozen=True)
class FeatureBlock:
    """Columns start:stop of a feature row (see mogo.motion.features)."""

    name: str
    start: int
    stop: int


@dataclass(frozen=True)
class SkeletonSpec:
    """mogo.motion.skeleton.Skeleton as JSON (its fps is the bundle's)."""

    name: str
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]  # -1 for the root; what the chains give (checked), for readers
    chains: tuple[tuple[int, ...], ...]  # kinematic chains, the order of the features' IK
    raw_offsets: tuple[tuple[float, float, float], ...]  # unit bone directions
    face_joints: tuple[int, int, int, int]  # right hip, left hip, right shoulder, left shoulder
    left_foot: tuple[int, int]  # ankle, toe
    right_foot: tuple[int, int]
    rest_offsets: tuple[tuple[float, float, float], ...] | None = None  # metres, Y up

    @classmethod
    def of(cls, skeleton: Skeleton) -> SkeletonSpec:
        rest = None if skeleton.rest_offsets is None else _rows(skeleton.rest_offsets)
        return cls(
            skeleton.name,
            tuple(skeleton.joint_names),
            tuple(int(p) for p in skeleton.parents),
            tuple(map(tuple, skeleton.chains)),
            _rows(skeleton.raw_offsets),
            tuple(skeleton.face_joints),
            tuple(skeleton.left_foot),
            tuple(skeleton.right_foot),
            rest,
        )

    def skeleton(self, fps: float) -> Skeleton:
        rest = None if self.rest_offsets is None else np.array(self.rest_offsets, np.float64)
        return Skeleton(
            self.name,
            self.joint_names,
            self.chains,
            np.array(self.raw_offsets, np.float64),
            rest,
            self.face_joints,
            self.left_foot,
            self.right_foot,
            fps,
        )


@dataclass(frozen=True)
class MotionFormat:
    """What a frame of the bundle's motion is."""

    fps: float
    skeleton: SkeletonSpec
    features: tuple[FeatureBlock, ...]
    normalization: Normalization

    @classmethod
    def of(cls, skeleton: Skeleton, normalization: Normalization) -> MotionFormat:
        """Motion of `skeleton` in the features of mogo.motion.features (what `mogo export`
        writes, from the runtime's own definitions)."""
        return cls(
            skeleton.fps,
            SkeletonSpec.of(skeleton),
            tuple(FeatureBlock(*block) for block in feature_layout(skeleton)),
            normalization,
        )

    @property
    def feature_dim(self) -> int:
        return self.features[-1].stop


@dataclass(frozen=True)
class Pretrained:
    """A text encoder the project did not train: where it comes from, under which licence, and
    how far the graph that ships is from its fp32 reference (the lowest cosine of sentence
    embeddings on the check captions)."""

    name: str
    license: str
    packages: dict[str, str]  # the registry files it came from -> sha256
    files: dict[str, str]  # the files in them that were used -> sha256
    reference_min_cosine: float


@dataclass(frozen=True)
class Repertoire:
    """What the model was trained on, as unit sentence embeddings (the encoder graph's second
    output) of its training captions: a prompt whose nearest caption has a cosine below
    `threshold` is far from everything the model knows. The threshold's error rates, measured
    when it was set: the share of held-out captions it accepts, of outside prompts it refuses.
    `prompts`, where present: the same captions' prompt embeddings, by the encoder the level
    graphs were trained with; a prompt that encoder cannot read is played as the one of them
    nearest its adapted embedding (mogo.text_side)."""

    embeddings: str  # .npy (N, dim) float16
    captions: str  # .json: the N captions, in order
    threshold: float
    held_out_accepted: float
    outside_refused: float
    prompts: str | None = None  # .npy (N, text_dim) float16


@dataclass(frozen=True)
class TrainedEncoder:
    """The text encoder the level graphs were trained with, kept beside a pretrained one: a
    prompt all of whose words its tokenizer knows is read by it, exactly as in training."""

    tokenizer: str
    encoder: Graph


@dataclass(frozen=True)
class Text:
    """Prompt -> tokenizer (truncating at max_length) -> encoder graph -> prompt embedding.
    kind "SentenceEncoder": a pretrained encoder (`pretrained`) and an adapter in one graph,
    whose second output is the sentence embedding the `repertoire` is compared in, and
    optionally the encoder trained with the model (`trained`) for the prompts it reads whole;
    any other kind is a text encoder trained with the model, and nothing else."""

    tokenizer: str
    max_length: int
    kind: str  # the text encoder's class
    encoder: Graph
    pretrained: Pretrained | None = None
    repertoire: Repertoire | None = None
    trained: TrainedEncoder | None = None

    @property
    def sentence_encoder(self) -> bool:
        return self.kind == SENTENCE_ENCODER


SENTENCE_ENCODER = "SentenceEncoder"


@dataclass(frozen=True)
class T2M:
    """One graph per level, coarse to fine (protocol in mogo.token_generator); the cache
    sizes are in the graphs' input shapes."""

    config: dict
    levels: tuple[Graph, ...]

    @property
    def num_levels(self) -> int:
        return len(self.levels)


@dataclass(frozen=True)
class VQ:
    """`low_latency_decoder`: optional, a decoder of the same tokens with a shorter lookahead,
    for streams that ask for low latency (the frames come sooner); `low_latency_step`: the
    same decoder one token a call, which such streams step with where the bundle has it."""

    config: dict
    encoder: Graph
    decoder: DecoderGraph
    low_latency_decoder: DecoderGraph | None = None
    low_latency_step: StepDecoderGraph | None = None

    @property
    def levels(self) -> int:
        return self.config["levels"]

    @property
    def codebook_size(self) -> int:
        return self.config["codebook_size"]

    @property
    def down_factor(self) -> int:
        """Frames per token step."""
        return self.config["down_factor"]


@dataclass(frozen=True, kw_only=True)
class Defaults(Sampling):
    """A bundle's defaults: Sampling's options (its fields and checks, not a copy; flat in the
    manifest's "defaults", where one left out is Sampling's own), the KV window in token steps
    (None: unbounded) and the longest motion `generate` lets the model end on its own."""

    window: int | None
    max_seconds: float


@dataclass(frozen=True)
class TrainingRun:
    """How one model of the bundle was trained; recipe is the trainer's own record."""

    step: int
    recipe: dict | None = None
    data: str | None = None
    best_val_mpjpe_mm: float | None = None
    best_val_loss: float | None = None
    token_agreement_with_bundle: float | None = None  # a decoder replaced in a bundle


@dataclass(frozen=True)
class Int8Check:
    """Whether the level graphs are int8: greedy-token agreement with fp32 on check prompts."""

    used: bool
    greedy_token_agreement: float
    threshold: float
    prompts: int
    steps_per_prompt: int
    scheme: str

    def describe(self) -> str:
        return (
            f"{'used' if self.used else 'not used'}: greedy token agreement "
            f"{self.greedy_token_agreement:.1%} (threshold {self.threshold:.0%})"
        )


@dataclass(frozen=True)
class Fp16Storage:
    """Graphs whose large weights are stored as fp16 (computed in fp32), and what it costs."""

    files: tuple[str, ...]
    prompt_embedding_max_abs_difference: float | None = None
    vq_encoder_token_agreement: float | None = None
    vq_decoder_feature_max_abs_difference: float | None = None
    vq_low_latency_decoder_feature_max_abs_difference: float | None = None


@dataclass(frozen=True, kw_only=True)
class Manifest:
    format: str = FORMAT
    format_version: int = FORMAT_VERSION
    motion: MotionFormat
    text: Text
    t2m: T2M
    vq: VQ
    defaults: Defaults
    training: dict[str, TrainingRun] = field(default_factory=dict)
    int8: Int8Check | None = None
    fp16_storage: Fp16Storage | None = None
    files: dict[str, FileEntry] = field(default_factory=dict)  # every file: size and sha256

    @property
    def fps(self) -> float:
        return self.motion.fps

    @property
    def feature_dim(self) -> int:
        return self.motion.feature_dim

    @property
    def total_bytes(self) -> int:
        return sum(entry.bytes for entry in self.files.values())

    @property
    def end_token(self) -> int:
        """Level 0's extra class after the codes: the motion ends."""
        return self.vq.codebook_size

    def skeleton(self) -> Skeleton:
        return self.motion.skeleton.skeleton(self.fps)

    def graphs(self) -> list[Graph]:
        trained = () if self.text.trained is None else (self.text.trained.encoder,)
        low_latency = tuple(
            g for g in (self.vq.low_latency_decoder, self.vq.low_latency_step) if g is not None
        )
        return [
            self.text.encoder,
            *trained,
            *self.t2m.levels,
            self.vq.encoder,
            self.vq.decoder,
            *low_latency,
        ]

    def referenced_files(self) -> set[str]:
        """Every file the manifest names outside `files`."""
        norm, repertoire = self.motion.normalization, self.text.repertoire
        extra = (
            ()
            if repertoire is None
            else tuple(
                f for f in (repertoire.embeddings, repertoire.captions, repertoire.prompts) if f
            )
        )
        if self.text.trained is not None:
            extra += (self.text.trained.tokenizer,)
        return {norm.mean, norm.std, self.text.tokenizer, *extra, *(g.file for g in self.graphs())}

    @classmethod
    def from_json(cls, data: object, source: str = MANIFEST) -> Manifest:
        """The manifest of parsed JSON; BundleError naming `source` and the key where it does
        not match the schema."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise BundleError(f"{source}: not a {FORMAT} manifest")
        version = data.get("format_version")
        if type(version) is not int:
            raise BundleError(
                f"{source}: format_version: "
                + ("missing" if version is None else f"expected an integer, got {version!r}")
            )
        if version != FORMAT_VERSION:
            raise BundleError(
                f"{source}: format version {version!r}; this runtime reads "
                f"version {FORMAT_VERSION} (re-export the bundle with "
                "`mogo export`, or upgrade mogo)"
            )
        try:
            manifest = read(cls, data, "")
            manifest._check()
        except KeyProblem as problem:
            raise BundleError(f"{source}: {problem.path}: {problem.what}") from None
        except SamplingError as error:  # only Defaults is a Sampling
            raise BundleError(f"{source}: defaults.{error.option}: {error}") from None
        return manifest

    def to_json(self) -> dict:
        return write(self)

    def dumps(self) -> str:
        """The text of manifest.json: indented, each list of plain values on one line."""

        def one_line(match: re.Match) -> str:
            return re.sub(r"\n\s*", "", re.sub(r",\n\s*", ", ", match[0]))

        text = json.dumps(self.to_json(), indent=1)
        return re.sub(r"\[[^\[\]{}]*\]|\{[^\[\]{}]*\}", one_line, text) + "\n"

    def _check(self) -> None:
        """What the types alone do not say: sizes that must agree."""
        for part, keys in (("vq", CONFIG_KEYS), ("t2m", T2M_CONFIG_KEYS)):
            for name, kind in keys.items():
                value = getattr(self, part).config.get(name)
                if type(value) is not kind or not 1 <= value <= MAX_SIZE:
                    raise KeyProblem(
                        f"{part}.config.{name}",
                        f"missing or not a positive integer (at most {MAX_SIZE})",
                    )
        if self.vq.config["feature_dim"] != self.feature_dim:
            raise KeyProblem(
                "vq.config.feature_dim",
                f"{self.vq.config['feature_dim']}, the "
                f"feature layout (motion.features) has {self.feature_dim}",
            )
        if not self.t2m.levels:
            raise KeyProblem("t2m.levels", "empty")
        if self.t2m.num_levels != self.vq.levels:
            raise KeyProblem(
                "t2m.levels",
                f"{self.t2m.num_levels} graphs for {self.vq.levels} VQ levels (vq.config.levels)",
            )
        _check_ranges(self)
        _check_step(self.vq)
        _check_text(self.text)
        _check_skeleton(self.motion.skeleton)
        skeleton = self.skeleton()
        expected = MotionFormat.of(skeleton, self.motion.normalization).features
        if self.motion.features != expected:
            raise KeyProblem(
                "motion.features",
                "not the layout of mogo.motion.features for "
                f"the {skeleton.name} skeleton ({_layout_text(expected)})",
            )


CONFIG_KEYS = dict(feature_dim=int, levels=int, codebook_size=int, down_factor=int)  # of vq.config
T2M_CONFIG_KEYS = dict(text_dim=int, max_relative_distance=int)  # of t2m.config
MAX_SIZE = 2**20  # any size of the manifest: larger ones are a damaged or hostile manifest
MAX_FPS = 1000.0
MAX_GENERATE_SECONDS = 600.0  # of motion in one generate or play call; streams have no limit
MAX_DECODER_CONTEXT = 1024  # token steps back or ahead the decoder may need


def io_types(manifest: Manifest, graph: Graph) -> tuple[list[tuple[str, int | None]], ...]:
    """What the runtime feeds `graph` (one of the manifest's) and reads from it: for each input
    and output, its ONNX element type and the size of its last axis where the manifest fixes
    it (None: any). A graph that differs would crash or mislead the runtime far from here."""
    text_dim, levels = manifest.t2m.config["text_dim"], manifest.vq.levels
    floats = [("tensor(float)", None)] * max(len(graph.inputs), len(graph.outputs))
    trained = manifest.text.trained
    if graph is manifest.text.encoder or (trained is not None and graph is trained.encoder):
        return (
            [("tensor(int64)", None)] * len(graph.inputs),
            [("tensor(float)", text_dim)] + floats[: len(graph.outputs) - 1],
        )
    if graph is manifest.vq.encoder:
        return [("tensor(float)", manifest.feature_dim)], [("tensor(int64)", levels)]
    if graph is manifest.vq.decoder or graph is manifest.vq.low_latency_decoder:
        return [("tensor(int64)", levels)], [("tensor(float)", manifest.feature_dim)]
    if graph is manifest.vq.low_latency_step:
        state = ("tensor(float)", graph.state_size)
        return (
            [("tensor(int64)", levels), ("tensor(int64)", None), state],
            [("tensor(float)", manifest.feature_dim), state],
        )
    level = next(k for k, g in enumerate(manifest.t2m.levels) if g is graph)
    classes = manifest.vq.codebook_size + (1 if level == 0 else 0)  # level 0: and the end
    inputs = [
        ("tensor(float)", text_dim),
        ("tensor(bool)", None),
        ("tensor(int64)", levels),
        ("tensor(int64)", None),
        ("tensor(int64)", None),
    ]
    return (
        inputs[: len(graph.inputs)] + floats[: max(0, len(graph.inputs) - len(inputs))],
        [("tensor(float)", classes)] + floats[: len(graph.outputs) - 1],
    )


def _check_ranges(manifest: Manifest) -> None:
    """Numbers the runtime would otherwise trip over later, far from the manifest."""
    d = manifest.defaults  # its sampling options were checked by Sampling as it was read
    positive = {
        "motion.fps": (manifest.fps, MAX_FPS),
        "defaults.max_seconds": (d.max_seconds, MAX_GENERATE_SECONDS),
        "text.max_length": (manifest.text.max_length, MAX_SIZE),
        "defaults.window": (1 if d.window is None else d.window, MAX_SIZE),
    }
    decoders = {
        "vq.decoder": manifest.vq.decoder,
        "vq.low_latency_decoder": manifest.vq.low_latency_decoder,
    }
    at_least_zero = {
        f"{path}.{name}": getattr(decoder, name)
        for path, decoder in decoders.items()
        if decoder is not None
        for name in ("left_context", "lookahead")
    }
    for path, (value, most) in positive.items():
        if not value > 0:
            raise KeyProblem(path, f"{value!r}, must be > 0")
        if value > most:
            raise KeyProblem(path, f"{value!r}, must be at most {most:g}")
    for path, value in at_least_zero.items():
        if value < 0:
            raise KeyProblem(path, f"{value!r}, must be >= 0")
        if value > MAX_DECODER_CONTEXT:
            raise KeyProblem(path, f"{value!r} token steps, must be at most {MAX_DECODER_CONTEXT}")


def _check_step(vq: VQ) -> None:
    """The step decoder is the low-latency decoder's: it needs one, and waits as long."""
    step, window = vq.low_latency_step, vq.low_latency_decoder
    if step is None:
        return
    if window is None:
        raise KeyProblem(
            "vq.low_latency_step", "needs vq.low_latency_decoder, whose steps it takes"
        )
    if step.lookahead != window.lookahead:
        raise KeyProblem(
            "vq.low_latency_step.lookahead",
            f"{step.lookahead!r}, the low-latency decoder's is {window.lookahead}",
        )
    if not 1 <= step.state_size <= MAX_SIZE:
        raise KeyProblem(
            "vq.low_latency_step.state_size", f"{step.state_size!r}, must be 1 to {MAX_SIZE}"
        )


def _check_text(text: Text) -> None:
    if not text.sentence_encoder:
        return
    if text.repertoire is None or text.pretrained is None:
        raise KeyProblem("text", f"a {SENTENCE_ENCODER} needs its pretrained and repertoire")
    if len(text.encoder.outputs) != 2:
        raise KeyProblem(
            "text.encoder.outputs",
            "a sentence encoder graph has two: the prompt embedding and the sentence embedding",
        )
    if not -1.0 <= text.repertoire.threshold <= 1.0:
        raise KeyProblem("text.repertoire.threshold", "a cosine: between -1 and 1")


def _check_skeleton(spec: SkeletonSpec) -> None:
    joints = len(spec.joint_names)
    for name in ("parents", "raw_offsets", "rest_offsets"):
        value = getattr(spec, name)
        if value is not None and len(value) != joints:
            raise KeyProblem(f"motion.skeleton.{name}", f"{len(value)} rows for {joints} joints")
    indices = [*spec.face_joints, *spec.left_foot, *spec.right_foot, *sum(spec.chains, ())]
    if any(not 0 <= j < joints for j in indices):
        raise KeyProblem("motion.skeleton", f"a joint index outside 0..{joints - 1}")
    derived = tuple(int(p) for p in spec.skeleton(0.0).parents)
    if spec.parents != derived:
        raise KeyProblem(
            "motion.skeleton.parents", f"{list(spec.parents)}, the chains give {list(derived)}"
        )


def _layout_text(blocks: tuple[FeatureBlock, ...]) -> str:
    return ", ".join(f"{b.name} {b.start}:{b.stop}" for b in blocks)


def _rows(array: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(x) for x in row) for row in array)
