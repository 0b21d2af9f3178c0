"""`mogo export` end to end on tiny runs: the bundle it writes loads in the runtime, whose
tokens are the torch reference's; int8 and fp16 storage are measured, not assumed."""

import shutil
from dataclasses import replace

import numpy as np
import onnx
import pytest
import torch
from onnx import numpy_helper

from helpers import make_tiny_humanml3d
from mogo.bundle import file_sha256, read_manifest, write_manifest
from mogo.cli import main
from mogo.export.models.generate_torch import generate
from mogo.export.models.runs import load_checkpoint, load_t2m, load_vq
from mogo.export.models.text_encoder import encode_captions
from mogo.export.onnx import bundle as onnx_bundle
from mogo.export.onnx.vq_graphs import vq_from_bundle
from mogo.generator import MotionGenerator
from mogo.manifest import SkeletonSpec
from mogo.motion.feet import LOOKAHEAD, SHORT, planted
from mogo.motion.skeleton import SMPL_22
from mogo.sampling import Sampling
from mogo.stream_decoder import StepDecoder, StreamingDecoder

PROMPT = "a person walks forward."


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    data = make_tiny_humanml3d(root / "data")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        common = ["--config", "tiny", "--batch-size", "4", "--steps", "3", "--warmup", "1"]
        assert (
            main(
                [
                    "train",
                    "vq",
                    "--data",
                    str(data),
                    "--out",
                    str(root / "vq"),
                    "--crop-frames",
                    "40",
                    "--val-clips",
                    "2",
                    *common,
                ]
            )
            == 0
        )
        assert (
            main(
                [
                    "train",
                    "t2m",
                    "--data",
                    str(data),
                    "--vq",
                    str(root / "vq"),
                    "--out",
                    str(root / "t2m"),
                    *common,
                ]
            )
            == 0
        )
        assert (
            main(
                [
                    "export",
                    "bundle",
                    "--vq",
                    str(root / "vq"),
                    "--t2m",
                    str(root / "t2m"),
                    "--out",
                    str(root / "bundle"),
                ]
            )
            == 0
        )
    finally:
        torch.set_num_threads(threads)
    return root


def test_the_manifest_describes_the_bundle(runs):
    manifest = read_manifest(runs / "bundle")
    expected = {
        "manifest.json",
        "tokenizer.json",
        "text_encoder.onnx",
        "vq_encoder.onnx",
        "vq_decoder.onnx",
        "mean.npy",
        "std.npy",
    } | {f"level_{l}.onnx" for l in range(3)}
    assert {p.name for p in (runs / "bundle").iterdir()} == expected
    assert set(manifest.files) == expected - {"manifest.json"}
    assert manifest.motion.skeleton == SkeletonSpec.of(SMPL_22) and manifest.fps == 20.0
    assert manifest.skeleton().feature_dim == manifest.feature_dim == 263
    assert manifest.t2m.num_levels == 3 and manifest.training["t2m"].step == 3
    assert manifest.int8 is None
    storage = manifest.fp16_storage
    assert storage.files == ("text_encoder.onnx", "vq_decoder.onnx", "vq_encoder.onnx")
    assert storage.prompt_embedding_max_abs_difference < 1e-2
    assert storage.vq_encoder_token_agreement > 0.9
    assert 0 < storage.vq_decoder_feature_max_abs_difference < 1e-2


@pytest.mark.parametrize("sampling", [Sampling(temperature=0.0), Sampling(top_p=0.9)])
def test_runtime_tokens_are_the_torch_references(runs, sampling):
    generator = MotionGenerator.load(runs / "bundle")
    motion = generator.generate(PROMPT, seconds=1.5, seed=3, sampling=sampling)
    t2m, text_encoder, tokenizer = load_t2m(runs / "t2m")
    with torch.no_grad():
        embedding = text_encoder.encode(*encode_captions(tokenizer, [PROMPT]))[0]
    reference = generate(t2m, embedding, num_frames=30, seed=3, sampling=sampling)
    assert np.array_equal(motion.tokens, reference)


def _int8_check(runs, folder, **patches):
    """Quantise a copy of the runs' bundle with mogo.export.onnx.bundle's names patched;
    returns the check and the sha256 of each level graph before and after."""
    bundle = folder / "bundle"
    shutil.copytree(runs / "bundle", bundle)
    levels = read_manifest(bundle).t2m.levels
    _, text_encoder, tokenizer = load_t2m(runs / "t2m")
    before = [file_sha256(bundle / level.file) for level in levels]
    with pytest.MonkeyPatch.context() as patch:
        for name, value in patches.items():
            patch.setattr(onnx_bundle, name, value)
        check = onnx_bundle._quantize_levels(
            bundle,
            levels,
            read_manifest(bundle).end_token,
            text_encoder,
            tokenizer,
            [PROMPT, "someone jumps."],
        )
    assert check.prompts == 2 and not (bundle / "int8").exists()
    return check, before, [file_sha256(bundle / level.file) for level in levels]


def _negated(source, target):
    """A 'quantiser' that ruins the graph: every float weight negated."""
    model = onnx.load(str(source))
    for tensor in model.graph.initializer:
        array = numpy_helper.to_array(tensor)
        if np.issubdtype(array.dtype, np.floating):
            tensor.CopyFrom(numpy_helper.from_array(-array, tensor.name))
    onnx.save(model, str(target))


def test_int8_levels_are_checked_and_kept_only_if_they_agree(runs, tmp_path):
    """The gate, not the number: int8 replaces fp32 exactly when its measured agreement
    reaches the threshold, and the measurement sees a perfect and a ruined quantiser."""
    low, fp32, int8 = _int8_check(runs, tmp_path / "low", INT8_MIN_AGREEMENT=0.0)
    assert low.used and low.threshold == 0.0 and int8 != fp32
    above = low.greedy_token_agreement + 1e-4  # above the unrounded agreement too
    high, fp32_again, kept = _int8_check(runs, tmp_path / "high", INT8_MIN_AGREEMENT=above)
    assert not high.used and kept == fp32 == fp32_again
    assert high.greedy_token_agreement == low.greedy_token_agreement
    below = low.greedy_token_agreement - 1e-4
    just, _, int8_again = _int8_check(runs, tmp_path / "just", INT8_MIN_AGREEMENT=below)
    assert just.used and int8_again == int8
    same, _, copied = _int8_check(runs, tmp_path / "same", quantize_level_graph=shutil.copy)
    assert same.greedy_token_agreement == 1.0 and same.used and copied == fp32
    ruined, _, kept = _int8_check(runs, tmp_path / "ruined", quantize_level_graph=_negated)
    assert ruined.greedy_token_agreement < 0.5 and not ruined.used and kept == fp32


def test_export_refuses_a_used_folder_and_mismatched_runs(runs, capsys):
    assert (
        main(
            [
                "export",
                "bundle",
                "--vq",
                str(runs / "vq"),
                "--t2m",
                str(runs / "t2m"),
                "--out",
                str(runs / "bundle"),
            ]
        )
        == 2
    )
    assert "is not empty" in capsys.readouterr().err
    assert (
        main(
            [
                "export",
                "bundle",
                "--vq",
                str(runs / "t2m"),
                "--t2m",
                str(runs / "t2m"),
                "--out",
                str(runs / "other"),
            ]
        )
        == 2
    )
    assert "best.pt: not a `mogo train vq` checkpoint" in capsys.readouterr().err
    assert (
        main(
            [
                "export",
                "bundle",
                "--vq",
                str(runs / "vq"),
                "--t2m",
                str(runs / "vq"),
                "--out",
                str(runs / "other"),
            ]
        )
        == 2
    )
    assert "best.pt: not a `mogo train t2m` checkpoint" in capsys.readouterr().err
    assert not (runs / "other").exists()


def test_export_takes_a_decoder_fine_tune_of_the_t2ms_vq_only(runs, tmp_path, capsys):
    data = runs / "data"
    common = [
        "--data",
        str(data),
        "--config",
        "tiny",
        "--batch-size",
        "4",
        "--steps",
        "1",
        "--crop-frames",
        "40",
        "--val-clips",
        "2",
        "--init",
        str(runs / "vq"),
    ]
    assert (
        main(["train", "vq", "--out", str(tmp_path / "decoder"), "--tune", "decoder", *common]) == 0
    )
    assert main(["train", "vq", "--out", str(tmp_path / "all"), *common]) == 0
    assert (
        main(
            [
                "export",
                "bundle",
                "--vq",
                str(tmp_path / "decoder"),
                "--t2m",
                str(runs / "t2m"),
                "--out",
                str(tmp_path / "bundle"),
            ]
        )
        == 0
    )
    MotionGenerator.load(tmp_path / "bundle").generate(PROMPT, seconds=1.0, seed=0)
    assert (
        main(
            [
                "export",
                "bundle",
                "--vq",
                str(tmp_path / "all"),
                "--t2m",
                str(runs / "t2m"),
                "--out",
                str(tmp_path / "other"),
            ]
        )
        == 2
    )
    assert "trained on the tokens of another VQ checkpoint" in capsys.readouterr().err


def test_a_bundles_vq_reads_back_into_torch(runs, tmp_path):
    model, trained = vq_from_bundle(runs / "bundle"), load_vq(runs / "vq")
    read, original = model.state_dict(), trained.state_dict()
    for name in original:
        if name.startswith(
            (
                "encoder",
                "decoder",
                "quantizer.codebook",
                "quantizer.scale",
                "quantizer.bias",
                "mean",
                "std",
            )
        ):
            stored = (
                original[name] if original[name].numel() < 1024 else original[name].half().float()
            )  # what fp16 storage keeps
            assert torch.equal(read[name], stored), name
    bundle = tmp_path / "bundle"  # a graph whose scale was altered (and re-hashed) is caught
    shutil.copytree(runs / "bundle", bundle)
    graph = onnx.load(bundle / "vq_decoder.onnx")
    scale = next(
        t
        for t in graph.graph.initializer
        if np.array_equal(numpy_helper.to_array(t), original["quantizer.scale"].numpy())
    )
    scale.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(scale) * 2, scale.name))
    onnx.save(graph, bundle / "vq_decoder.onnx")
    write_manifest(bundle, read_manifest(bundle))
    with pytest.raises(ValueError, match="do not read back into the model"):
        vq_from_bundle(bundle)


def test_a_bundles_decoder_is_fine_tuned_and_replaced_without_its_runs(runs, tmp_path, capsys):
    bundle, data = runs / "bundle", runs / "data"
    common = [
        "--data",
        str(data),
        "--config",
        "tiny",
        "--batch-size",
        "4",
        "--steps",
        "2",
        "--val-clips",
        "2",
        "--warmup",
        "0",
    ]
    tuned = tmp_path / "tuned"
    assert (
        main(
            [
                "train",
                "vq",
                "--out",
                str(tuned),
                "--init",
                str(bundle),
                "--tune",
                "decoder",
                "--whole-clips",
                "--lr",
                "1e-2",
                *common,
            ]
        )
        == 0
    )
    recipe = load_checkpoint(tuned / "best.pt")["recipe"]
    manifest = read_manifest(bundle)
    assert recipe["init"] == str(bundle.resolve()) and recipe["whole_clips"]
    assert recipe["tokens_sha256"] == manifest.files["vq_encoder.onnx"].sha256
    new = tmp_path / "new"
    assert (
        main(["export", "decoder", "--vq", str(tuned), "--bundle", str(bundle), "--out", str(new)])
        == 0
    )
    written = read_manifest(new)
    changed = {name for name, entry in written.files.items() if entry != manifest.files[name]}
    assert changed == {"vq_decoder.onnx"} and written.files.keys() == manifest.files.keys()
    assert all(
        file_sha256(new / name) == file_sha256(bundle / name)
        for name in written.files
        if name not in changed
    )
    assert written.training["vq"].recipe["tune"] == "decoder"
    assert written.training["vq"].token_agreement_with_bundle == 1.0
    assert written.training["t2m"] == manifest.training["t2m"]
    assert 0 < written.fp16_storage.vq_decoder_feature_max_abs_difference < 1e-2
    assert replace(written, files={}, training={}, fp16_storage=None) == replace(
        manifest, files={}, training={}, fp16_storage=None
    )  # the rest as it was
    old_motion = MotionGenerator.load(bundle).generate(PROMPT, seconds=1.0, seed=0)
    new_motion = MotionGenerator.load(new).generate(PROMPT, seconds=1.0, seed=0)
    assert np.array_equal(old_motion.tokens, new_motion.tokens)
    assert not np.allclose(old_motion.features, new_motion.features)


@pytest.fixture(scope="module")
def low_latency_bundle(runs, tmp_path_factory):
    """The tiny bundle with a low-latency decoder (1 token ahead) beside its centred one:
    `mogo train vq --tune decoder --decoder-lookahead 1`, then `mogo export decoder`."""
    root = tmp_path_factory.mktemp("low_latency")
    tuned = [
        *("train", "vq", "--out", str(root / "tuned"), "--init", str(runs / "bundle")),
        *("--tune", "decoder", "--decoder-lookahead", "1", "--data", str(runs / "data")),
        *("--config", "tiny", "--batch-size", "4", "--steps", "2", "--val-clips", "2"),
        *("--warmup", "0", "--crop-frames", "40"),
    ]
    assert main(tuned) == 0
    export = ["export", "decoder", "--vq", str(root / "tuned"), "--bundle", str(runs / "bundle")]
    assert main([*export, "--out", str(root / "new")]) == 0
    return root / "new"


def test_a_shorter_lookahead_decoder_goes_beside_the_centred_one(
    runs, low_latency_bundle, tmp_path, capsys
):
    bundle, data, new = runs / "bundle", runs / "data", low_latency_bundle
    assert (
        main(
            [
                "train",
                "vq",
                "--out",
                str(tmp_path / "all"),
                "--init",
                str(runs / "vq"),
                "--decoder-lookahead",
                "1",
                "--data",
                str(data),
                "--config",
                "tiny",
                "--steps",
                "1",
                "--crop-frames",
                "40",
            ]
        )
        == 2
    )  # the encoder would change
    assert "differs from None of --init" in capsys.readouterr().err
    old, written = read_manifest(bundle), read_manifest(new)
    assert written.files.keys() - old.files.keys() == {
        "vq_decoder_low_latency.onnx",
        "vq_decoder_low_latency_step.onnx",
    }
    assert all(written.files[name] == entry for name, entry in old.files.items())
    low = written.vq.low_latency_decoder
    assert (low.file, low.lookahead) == ("vq_decoder_low_latency.onnx", 1)
    assert written.vq.decoder == old.vq.decoder and written.vq.config == old.vq.config
    assert written.training["vq_low_latency_decoder"].recipe["decoder_lookahead"] == 1
    assert 0 < written.fp16_storage.vq_low_latency_decoder_feature_max_abs_difference < 1e-2
    centred, generator = MotionGenerator.load(bundle), MotionGenerator.load(new)
    same = [g.generate(PROMPT, seconds=1.0, seed=0) for g in (centred, generator)]
    assert np.array_equal(same[0].features, same[1].features)  # generate: the centred decoder
    with pytest.raises(ValueError, match="no low-latency decoder"):
        centred.stream(PROMPT, low_latency=True)
    streams = [
        generator.stream(PROMPT, seed=3, anchoring=False, plant_feet=False, low_latency=low)
        for low in (False, True)
    ]
    first = [next(k for k in range(1, 60) if len(stream.step())) for stream in streams]
    assert first == [old.vq.decoder.lookahead + 1, 2]  # frames once their lookahead exists
    resumed = generator.resume(streams[1].state())  # mogo.stream_state: low latency too
    for _ in range(20):
        np.testing.assert_array_equal(resumed.step(), streams[1].step())
    assert written.vq.low_latency_step.lookahead == 1
    ids = np.random.default_rng(0).integers(0, written.vq.codebook_size, (50, written.vq.levels))
    stepped = generator.streaming_decoder(low_latency=True)  # the step graph, a token a call
    window = StreamingDecoder(new / low.file, low.left_context, 1, written.vq.codebook_size)
    assert isinstance(stepped, StepDecoder)
    np.testing.assert_allclose(stepped.push(ids), window.decode_offline(ids)[:49], atol=1e-4)


def test_a_low_latency_stream_plants_its_feet_with_the_short_window(low_latency_bundle):
    """Its frames wait the decoder's token and SHORT's 2 frames, not 8; however they are read
    (step by step, frames() in uneven chunks, finish() of a cut) they are the one-pass
    planting of its own decoded frames, and a resumed stream goes on with the same bytes."""
    generator = MotionGenerator.load(low_latency_bundle)
    ahead = generator.manifest.vq.low_latency_decoder.lookahead

    def stream(**options):
        return generator.stream(PROMPT, seed=5, low_latency=True, **options)

    stepped = stream()
    assert stepped.feet.lookahead == SHORT.lookahead < LOOKAHEAD
    assert stepped.lookahead_steps == ahead + SHORT.lookahead
    out = [stepped.step() for _ in range(60)]
    wait = ahead + SHORT.lookahead  # steps drawn before the first frame is final
    assert [len(frames) for frames in out] == [0] * wait + [1] * (60 - wait)
    frames = np.concatenate(out)
    raw = stream(plant_feet=False)
    raw.advance(60)
    raw = raw.finish()
    offline = planted(raw.features, raw.joints, generator.skeleton, window=SHORT)
    assert np.array_equal(frames, offline[: len(frames)])
    read, rng = stream(), np.random.default_rng(0)
    chunks = [list(read.frames(int(rng.integers(0, 9)))) for _ in range(12)]
    read_frames = [frame for chunk in chunks for frame in chunk]
    assert np.array_equal(read_frames, offline[: len(read_frames)])
    cut = stream()
    cut.advance(40)
    assert np.array_equal(cut.finish().joints, frames[:40])  # as the stream goes on
    for taken_at in (0, 3, 9, 30):  # before the first frame, and with frames held back
        original = stream()
        for _ in range(taken_at):
            original.step()
        resumed = generator.resume(original.state())
        for k in range(25):
            if k == 4:
                original.set_prompt("a person jumps.")
                resumed.set_prompt("a person jumps.")
            np.testing.assert_array_equal(resumed.step(), original.step())


def test_replacing_a_bundles_decoder_refuses_what_does_not_fit(runs, tmp_path, capsys):
    bundle, data = runs / "bundle", runs / "data"
    common = [
        "--data",
        str(data),
        "--config",
        "tiny",
        "--batch-size",
        "4",
        "--steps",
        "1",
        "--val-clips",
        "2",
        "--crop-frames",
        "40",
    ]
    assert (
        main(["train", "vq", "--out", str(tmp_path / "all"), "--init", str(bundle), *common]) == 2
    )
    assert "a bundle keeps no codebook statistics" in capsys.readouterr().err
    assert main(["train", "vq", "--out", str(tmp_path / "other"), "--seed", "1", *common]) == 0
    assert main(["train", "vq", "--out", str(tmp_path / "smaller"), "--levels", "2", *common]) == 0
    for run, message in (("other", "gives other tokens than"), ("smaller", "config differs")):
        assert (
            main(
                [
                    "export",
                    "decoder",
                    "--vq",
                    str(tmp_path / run),
                    "--bundle",
                    str(bundle),
                    "--out",
                    str(tmp_path / "new"),
                ]
            )
            == 2
        )
        assert message in capsys.readouterr().err
    new = ["--vq", str(runs / "vq"), "--bundle", str(bundle), "--out", str(tmp_path / "new")]
    with pytest.raises(SystemExit) as refused:  # a decoder's bundle keeps its level graphs
        main(["export", "decoder", *new, "--int8"])
    assert refused.value.code == 2
    assert "unrecognized arguments: --int8" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_a_bundle_of_two_frames_per_token_runs_through_the_generator(tmp_path):
    """down_factor 2: every token decodes to two frames, in generate, in a stream and in the
    offline decode of the same tokens alike."""
    data = make_tiny_humanml3d(tmp_path / "data")
    common = [
        "--data",
        str(data),
        "--config",
        "tiny",
        "--batch-size",
        "4",
        "--steps",
        "2",
        "--warmup",
        "0",
    ]
    assert (
        main(
            [
                "train",
                "vq",
                "--out",
                str(tmp_path / "vq"),
                "--down-factor",
                "2",
                "--crop-frames",
                "40",
                "--val-clips",
                "2",
                *common,
            ]
        )
        == 0
    )
    assert (
        main(
            ["train", "t2m", "--vq", str(tmp_path / "vq"), "--out", str(tmp_path / "t2m"), *common]
        )
        == 0
    )
    assert (
        main(
            [
                "export",
                "bundle",
                "--vq",
                str(tmp_path / "vq"),
                "--t2m",
                str(tmp_path / "t2m"),
                "--out",
                str(tmp_path / "bundle"),
            ]
        )
        == 0
    )
    generator = MotionGenerator.load(tmp_path / "bundle")
    assert generator.down_factor == 2
    motion = generator.generate(PROMPT, seconds=1.5, seed=2)
    assert motion.joints.shape == (30, 22, 3) and len(motion.tokens) == 15
    # not re-anchored: an untrained model ends its clips early, and a re-anchored stream then
    # starts a fresh one (mogo.anchoring) where generate's forced length goes on
    stream = generator.stream(PROMPT, seed=2, anchoring=False)
    stream.advance(15)
    streamed = stream.finish()  # its last frames see right context drawn past the cut
    assert np.array_equal(streamed.tokens, motion.tokens)
    np.testing.assert_allclose(streamed.joints, motion.joints, atol=1e-5)
    lookahead = generator.manifest.vq.decoder.lookahead
    longer = generator.stream(PROMPT, seed=2, anchoring=False)
    longer.advance(15 + lookahead)
    context = longer.finish().tokens
    offline = generator.decode(context, [], frames=30)
    assert offline.joints.shape == (30, 22, 3)
    np.testing.assert_allclose(streamed.joints, offline.joints, atol=1e-5)
    # encoding reads whole tokens only: a frame left over is not read
    odd = replace(motion, features=np.concatenate([motion.features, motion.features[-1:]]))
    assert np.array_equal(generator.encode_motion(odd), generator.encode_motion(motion))
    assert generator.encode_motion(motion).shape == (15, generator.tokens.num_levels)
    # an odd number of frames takes the token that holds the last of them
    assert len(generator.generate(PROMPT, seconds=1.55, seed=2).tokens) == 16
    assert len(generator.decode(context, [], frames=29).tokens) == 15
    # a switch after 7 token steps is recorded at their 14th frame, whatever is still pending
    switched = generator.stream(PROMPT, seed=2, anchoring=False)
    switched.advance(7)
    switched.set_prompt("a person jumps.")
    assert switched.prompts == [(0, PROMPT), (14, "a person jumps.")]
    # going on from the clip: its own frames are not emitted again, 2 new frames a token step
    going_on = generator.stream(PROMPT, seed=3, anchoring=False)
    going_on.continue_from(motion)
    going_on.advance(6)
    assert going_on.finish().joints.shape == (12, 22, 3)


def test_the_long_stream_bench_counts_a_switch_from_the_frames_received(
    low_latency_bundle, monkeypatch
):
    """`mogo bench long-streams --low-latency`'s streams: at each set_prompt the caller has
    every frame drawn but those the stream's decoder and feet still hold (and a burst)."""
    from mogo.bench import long_streams

    monkeypatch.setattr(long_streams, "_generator", None)  # the worker's, of this bundle
    generator = MotionGenerator.load(low_latency_bundle)
    schedule = ((PROMPT, 60), ("a person jumps.", 40), (PROMPT, 40))
    for low in (False, True):
        task = long_streams.Task("switches", "stream", "on", 0, schedule, low_latency=low)
        made = long_streams._stream(str(low_latency_bundle), task)
        stream = generator.stream(PROMPT, low_latency=low)
        held = stream.lookahead_steps * generator.down_factor  # frames drawn, not yet out
        lags = [start - got for start, got in zip(made.switches, made.received, strict=True)]
        assert len(lags) == 2 and all(held <= lag < held + stream.decoder.every for lag in lags)
