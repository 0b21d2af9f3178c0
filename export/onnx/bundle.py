"""`mogo export`: trained models -> a bundle folder the torch-free runtime loads.

The manifest (its schema: mogo.manifest) holds everything the runtime needs to know about
the model: graph input/output names, fps, skeleton and feature layout, normalisation files, the
decoder's context, sampling defaults, how it was trained, and each file's size and sha256.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper
from tokenizers import Tokenizer

from mogo.bundle import Bundle, write_manifest
from mogo.export.models.t2m import T2M as T2MModel
from mogo.export.onnx.t2m_graphs import export_level, export_text_encoder
from mogo.export.onnx.vq_graphs import export_vq_decoder, export_vq_encoder, random_ids
from mogo.export.onnx.vq_step_graph import export_vq_step_decoder
from mogo.manifest import (
    T2M,
    VQ,
    Defaults,
    Fp16Storage,
    Graph,
    Int8Check,
    Manifest,
    MotionFormat,
    Normalization,
    Text,
    TrainingRun,
)
from mogo.motion.skeleton import MAX_SECONDS, Skeleton
from mogo.sampling import Sampling
from mogo.token_generator import TokenGenerator

INT8_MIN_AGREEMENT = 0.98  # share of greedy tokens int8 must keep to replace fp32
CHECK_STEPS = 40  # steps of each check prompt
CHECK_PROMPTS = 16  # distinct val captions the int8 check generates from
DEFAULT_SAMPLING = Sampling(top_p=0.9)  # what a bundle's manifest says, under Sampling's names
DEFAULTS = dict(**asdict(DEFAULT_SAMPLING), window=128, max_seconds=MAX_SECONDS)


def export_bundle(vq_run: Path, t2m_run: Path, out: Path, int8: bool = False) -> Manifest:
    """`mogo export`: the trained runs (their best.pt) -> a bundle folder; returns the manifest."""
    from mogo.export.models.runs import (
        load_checkpoint,
        load_t2m,
        load_vq,
        read_tokens,
        t2m_checkpoint,
        tokens_sha256,
        vq_checkpoint,
    )
    from mogo.motion.skeleton import skeleton_for_feature_dim

    vq = load_vq(vq_run)
    t2m, text_encoder, tokenizer = load_t2m(t2m_run)
    vq_state = load_checkpoint(vq_checkpoint(vq_run))
    t2m_state = load_checkpoint(t2m_checkpoint(t2m_run))
    if t2m_state["config"]["vq"]["sha256"] != tokens_sha256(vq_state, vq_checkpoint(vq_run)):
        raise ValueError(
            f"{t2m_run} was trained on the tokens of another VQ checkpoint than "
            f"{vq_checkpoint(vq_run)}"
        )
    skeleton = skeleton_for_feature_dim(vq.config.feature_dim)
    train, val = (
        list(
            dict.fromkeys(
                str(c) for c in read_tokens(Path(t2m_run) / "tokens" / f"{split}.npz")["captions"]
            )
        )
        for split in ("train", "val")
    )
    provenance = dict(
        vq=_vq_provenance(vq_state),
        t2m=TrainingRun(
            step=t2m_state["step"],
            recipe=t2m_state["config"]["recipe"],
            data=t2m_state["config"]["data"],
            best_val_loss=t2m_state.get("best_val_loss"),
        ),
    )
    return write_bundle(
        Path(out),
        vq=vq,
        t2m=t2m,
        text_encoder=text_encoder,
        tokenizer=tokenizer,
        skeleton=skeleton,
        provenance=provenance,
        check_prompts=val[:CHECK_PROMPTS],
        int8=int8,
        captions=dict(train=train, val=val),
    )


LOW_LATENCY_DECODER = "vq_decoder_low_latency.onnx"
LOW_LATENCY_STEP = "vq_decoder_low_latency_step.onnx"  # the same decoder, a token a call


def replace_vq_decoder(vq_run: Path, bundle_dir: Path, out: Path) -> Manifest:
    """`mogo export decoder --vq RUN --bundle OLD`: a new bundle, OLD with the VQ decoder of
    RUN, for a decoder fine-tune of OLD's own VQ (`mogo train vq --init OLD --tune decoder`), which needs
    none of OLD's training runs. A decoder of a shorter lookahead (`--decoder-lookahead`) goes
    beside OLD's as its low-latency decoder (replacing any OLD had), with its step graph
    (mogo.export.onnx.vq_step_graph); else it replaces OLD's.
    Every other file is copied byte for byte, so RUN's encoder must give OLD's tokens
    (checked through OLD's encoder graph) and RUN must share OLD's normalisation: that is what
    OLD's level graphs were trained on. Returns the manifest."""
    from mogo.export.models.runs import load_checkpoint, load_vq, vq_checkpoint

    old = Bundle.load(bundle_dir)
    vq = load_vq(vq_run)
    low_latency, agreement = _decoder_fits(vq, old, vq_run, bundle_dir)
    out = new_folder(out)
    manifest = old.manifest
    decoder = LOW_LATENCY_DECODER if low_latency else manifest.vq.decoder.file
    written = {decoder, LOW_LATENCY_STEP} if low_latency else {decoder}
    for name in manifest.files:
        if name not in written:
            shutil.copy2(old.path(name), out / name)
    graph = export_vq_decoder(vq, out / decoder)
    step = export_vq_step_decoder(vq, out / LOW_LATENCY_STEP) if low_latency else None
    if step is not None:
        store_weights_fp16(out / LOW_LATENCY_STEP)
    codes = _check_codes(vq)
    before, after = _outputs_before_and_after_fp16(out / decoder, {"ids": codes.numpy()})
    difference = float(np.abs(before - after).max())
    storage = manifest.fp16_storage or Fp16Storage(files=())
    storage = replace(
        storage,
        files=tuple(sorted(set(storage.files) | written)),
        **{
            f"{'vq_low_latency' if low_latency else 'vq'}_decoder_feature_max_abs_difference": difference
        },
    )
    trained = replace(
        _vq_provenance(load_checkpoint(vq_checkpoint(vq_run))),
        token_agreement_with_bundle=agreement,
    )
    role = "low_latency_decoder" if low_latency else "decoder"
    return write_manifest(
        out,
        replace(
            manifest,
            vq=replace(
                manifest.vq, **{role: graph}, **({"low_latency_step": step} if step else {})
            ),
            fp16_storage=storage,
            training={**manifest.training, "vq_" + role if low_latency else "vq": trained},
        ),
    )


def _decoder_fits(vq, old: Bundle, vq_run: Path, bundle_dir: Path) -> tuple[bool, float]:
    """Whether RUN's decoder is a low-latency one, and its encoder's token agreement with
    OLD's; a ValueError where RUN is not a decoder fine-tune of OLD's VQ."""
    from mogo.export.models.vq import VQConfig
    from mogo.export.onnx.vq_graphs import MIN_TOKEN_AGREEMENT, token_agreement

    centred = VQConfig(**old.manifest.vq.config)
    if replace(vq.config, decoder_lookahead=centred.decoder_lookahead) != centred:
        raise ValueError(f"{vq_run} is another VQ model than {bundle_dir}'s (its config differs)")
    if not (np.array_equal(vq.mean.numpy(), old.mean) and np.array_equal(vq.std.numpy(), old.std)):
        raise ValueError(
            f"{vq_run} normalises with other statistics than {bundle_dir} (trained on other data?)"
        )
    agreement = token_agreement(vq, old)
    if agreement < MIN_TOKEN_AGREEMENT:
        raise ValueError(
            f"{vq_run}'s encoder gives other tokens than {bundle_dir}'s (agreement "
            f"{agreement:.1%}): only a decoder fine-tune of the bundle's VQ fits its "
            "level graphs"
        )
    return vq.config.decoder_lookahead != centred.decoder_lookahead, agreement


def _vq_provenance(state: dict) -> TrainingRun:
    return TrainingRun(
        step=state["step"],
        recipe=state.get("recipe"),
        data=state.get("data"),
        best_val_mpjpe_mm=state.get("best_val_mpjpe_mm"),
    )


def new_folder(out: Path) -> Path:
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out} is not empty; choose a new folder for the bundle")
    out.mkdir(parents=True, exist_ok=True)
    return out


def write_bundle(
    out: Path,
    *,
    vq,
    t2m: T2MModel,
    text_encoder,
    tokenizer: Tokenizer,
    skeleton: Skeleton,
    provenance: dict[str, TrainingRun],
    check_prompts: list[str],
    int8: bool = False,
    defaults: dict | None = None,
    captions: dict[str, list[str]] | None = None,
) -> Manifest:
    """Export every graph into the new folder `out` and write its manifest; returns it.
    With `int8`, the level graphs are quantised and kept only if greedy tokens on
    `check_prompts` agree with fp32 on at least INT8_MIN_AGREEMENT of steps (measured either
    way and written into the manifest). A text encoder on a pretrained sentence encoder
    (SentenceTower) ships as that encoder's graph and the projection, with the repertoire of
    the train `captions` (dict train=, val=)."""
    from mogo.export.models.sentence_encoder import SentenceTower

    out = new_folder(out)
    tower = isinstance(text_encoder, SentenceTower)
    text = _text_side(out, text_encoder, tokenizer, (captions or {}) if tower else None)
    levels = tuple(
        export_level(t2m, level, out / f"level_{level}.onnx")
        for level in range(t2m.config.num_levels)
    )
    vq_graphs = VQ(
        config=asdict(vq.config),
        encoder=export_vq_encoder(vq, out / "vq_encoder.onnx"),
        decoder=export_vq_decoder(vq, out / "vq_decoder.onnx"),
    )
    np.save(out / "mean.npy", vq.mean.detach().cpu().numpy().astype(np.float32))
    np.save(out / "std.npy", vq.std.detach().cpu().numpy().astype(np.float32))
    manifest = Manifest(
        motion=MotionFormat.of(skeleton, Normalization(mean="mean.npy", std="std.npy")),
        text=text,
        t2m=T2M(config=asdict(t2m.config), levels=levels),
        vq=vq_graphs,
        defaults=Defaults(**dict(DEFAULTS, **(defaults or {}))),
        training=provenance,
    )
    if int8:
        check = _quantize_levels(
            out, levels, manifest.end_token, text_encoder, tokenizer, check_prompts
        )
        manifest = replace(manifest, int8=check)
    storage = _store_graphs_fp16(out, vq, tokenizer, check_prompts, text=not tower)
    return write_manifest(out, replace(manifest, fp16_storage=storage))


def _text_side(out: Path, text_encoder, tokenizer: Tokenizer, captions: dict | None) -> Text:
    """The text side's files in `out`: a sentence tower's (`captions` given: its repertoire),
    or the small encoder's graph and tokenizer."""
    if captions is not None:
        from mogo.export.onnx.text_bundle import sentence_text_side

        if not captions:
            raise ValueError("a sentence-encoder bundle needs the training captions")
        return sentence_text_side(out, text_encoder, captions["train"], captions["val"])
    tokenizer.save(str(out / "tokenizer.json"))
    max_length = tokenizer.truncation["max_length"]
    return Text(
        tokenizer="tokenizer.json",
        max_length=max_length,
        kind=type(text_encoder).__name__,
        encoder=export_text_encoder(text_encoder, out / "text_encoder.onnx", max_length),
    )


FP16_MIN_ELEMENTS = 1024  # smaller tensors (biases, norms) stay fp32


def store_weights_fp16(path: Path) -> None:
    """Keep the graph's large fp32 weights as fp16 in the file, each cast back to fp32 by a
    Cast node: onnxruntime folds those casts when it creates the session, so compute stays
    fp32 and the file is half the size."""
    model = onnx.load(path)
    casts = []
    for weight in model.graph.initializer:
        if weight.data_type != onnx.TensorProto.FLOAT or np.prod(weight.dims) < FP16_MIN_ELEMENTS:
            continue
        name = weight.name
        half = numpy_helper.from_array(
            numpy_helper.to_array(weight).astype(np.float16), f"{name}_fp16"
        )
        weight.CopyFrom(half)
        casts.append(onnx.helper.make_node("Cast", [half.name], [name], to=onnx.TensorProto.FLOAT))
    for cast in reversed(casts):
        model.graph.node.insert(0, cast)
    onnx.save(model, path)


@torch.no_grad()
def _store_graphs_fp16(
    out: Path, vq, tokenizer: Tokenizer, prompts: list[str], text: bool = True
) -> Fp16Storage:
    """fp16 storage (`store_weights_fp16`) for the text encoder (unless not `text`: a
    pretrained encoder's graph ships as published) and the VQ encoder and decoder,
    measured against fp32: the largest prompt-embedding difference on the check prompts, VQ
    token agreement on features decoded from random tokens, and the largest difference of
    those decoded features (normalised units). Compute stays fp32 (the casts are folded when
    the session is made), so decoding speed is unchanged (measured: onnxruntime 1.32). The
    level graphs are int8 or fp32 (see `_quantize_levels`)."""
    encoded = tokenizer.encode_batch(prompts or ["a person walks forward."])
    ids = np.array([e.ids for e in encoded], np.int64)
    mask = np.array([e.attention_mask for e in encoded], np.int64)
    codes = _check_codes(vq)
    features = vq.eval().decode(codes).numpy()
    feeds = {
        "text_encoder.onnx": {"token_ids": ids, "attention_mask": mask},
        "vq_encoder.onnx": {"features": features},
        "vq_decoder.onnx": {"ids": codes.numpy()},
    }
    if not text:
        del feeds["text_encoder.onnx"]
    before, after = {}, {}
    for name, feed in feeds.items():
        before[name], after[name] = _outputs_before_and_after_fp16(out / name, feed)

    def largest_difference(name: str) -> float:
        return float(np.abs(before[name] - after[name]).max())

    agreement = np.mean(before["vq_encoder.onnx"] == after["vq_encoder.onnx"])
    return Fp16Storage(
        files=tuple(sorted(feeds)),
        prompt_embedding_max_abs_difference=largest_difference("text_encoder.onnx")
        if text
        else None,
        vq_encoder_token_agreement=round(float(agreement), 4),
        vq_decoder_feature_max_abs_difference=largest_difference("vq_decoder.onnx"),
    )


def _check_codes(vq) -> torch.Tensor:
    """The token ids (4, 60, L) that the fp16 storage check decodes."""
    return random_ids(vq.config, 4, 60, seed=0)


def _outputs_before_and_after_fp16(path: Path, feed: dict) -> tuple[np.ndarray, np.ndarray]:
    """The graph's first output on `feed`, then `store_weights_fp16` on it, then the output
    again."""
    from mogo._session import cpu_session

    before = cpu_session(path).run(None, feed)[0]
    store_weights_fp16(path)
    return before, cpu_session(path).run(None, feed)[0]


def quantize_level_graph(source: Path, target: Path) -> None:
    """The int8 scheme of a bundle's level graphs (see `_quantize_levels`), `source` -> `target`."""
    from onnxruntime.quantization import QuantType, quantize_dynamic
    from onnxruntime.quantization.shape_inference import quant_pre_process

    prepared = target.with_name(f"pre_{target.name}")
    quant_pre_process(str(source), str(prepared), skip_symbolic_shape=True)
    quantize_dynamic(
        prepared, target, op_types_to_quantize=["MatMul", "Gather"], weight_type=QuantType.QUInt8
    )
    prepared.unlink()


@torch.no_grad()
def _quantize_levels(
    out: Path,
    levels: Sequence[Graph],
    end_token: int,
    text_encoder,
    tokenizer: Tokenizer,
    prompts: list[str],
) -> Int8Check:
    """Dynamic int8 (QUInt8 weights of the MatMuls, the setting that kept accuracy on a CPU
    without VNNI, where QInt8 did not, and of the token-embedding Gathers, which each level
    graph holds its own copy of) of every level graph, checked by token agreement:
    at every step of fp32's greedy stream, does int8 pick the same tokens given the same
    past (teacher-forced, so one early difference does not count twice)? The quantised graphs
    replace the fp32 ones only if they pass."""
    if not prompts:
        raise ValueError("the int8 accuracy check needs at least one prompt")
    staging = out / "int8"
    staging.mkdir()
    for level in levels:
        quantize_level_graph(out / level.file, staging / level.file)
    encoded = tokenizer.encode_batch(prompts)
    ids = torch.tensor([e.ids for e in encoded])
    mask = torch.tensor([e.attention_mask for e in encoded])
    embeddings = text_encoder.encode(ids, mask).numpy()
    fp32 = TokenGenerator([out / l.file for l in levels], levels, end_token)
    quantised = TokenGenerator([staging / l.file for l in levels], levels, end_token)
    greedy = Sampling(temperature=0.0)
    same = total = 0
    for embedding in embeddings:
        reference = fp32.generate(embedding, num_frames=CHECK_STEPS, sampling=greedy)
        for n in range(CHECK_STEPS):  # int8's choice at step n given fp32's steps before it
            stream = quantised.start(embedding, sampling=greedy, allow_end=False)
            if n:
                stream.continue_from(reference[:n])
            same += int(np.sum(stream.step() == reference[n]))
            total += reference.shape[1]
    agreement = same / total
    used = agreement >= INT8_MIN_AGREEMENT
    if used:
        for level in levels:
            shutil.move(staging / level.file, out / level.file)
    shutil.rmtree(staging)
    return Int8Check(
        used=used,
        greedy_token_agreement=round(agreement, 4),
        threshold=INT8_MIN_AGREEMENT,
        prompts=len(prompts),
        steps_per_prompt=CHECK_STEPS,
        scheme="dynamic QUInt8 weights of MatMul and Gather (token embeddings)",
    )
