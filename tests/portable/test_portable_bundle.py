"""`mogo export portable`: every op and opset against the lists of the engines it targets,
and our runtime generating through it."""

import subprocess
import sys

import numpy as np
import onnx

from mogo import MotionGenerator, Sampling

# Unity's inference engine (Sentis 2.1): "Sentis supports most models in ONNX format with an
# opset version between 7 and 15" (https://docs.unity3d.com/Packages/com.unity.sentis@latest),
# and the names of its table of supported ONNX operators, every row, as published
# (https://docs.unity3d.com/Packages/com.unity.sentis@2.1/manual/supported-operators.html;
# the package's own Documentation~/supported-operators.md). Gelu is not among them (a layer
# Sentis makes itself); its "Unsupported operators" list names DequantizeLinear,
# DynamicQuantizeLinear and MatMulInteger, which the shipped level graphs use.
SENTIS_MAX_OPSET = 15
SENTIS_OPS = {
    "Abs",
    "Acos",
    "Acosh",
    "Add",
    "And",
    "ArgMax",
    "ArgMin",
    "Asin",
    "Asinh",
    "Atan",
    "Atanh",
    "AveragePool",
    "BatchNormalization",
    "Bernoulli",
    "Cast",
    "CastLike",
    "Ceil",
    "Celu",
    "Clip",
    "Compress",
    "Concat",
    "Constant",
    "ConstantOfShape",
    "Conv",
    "ConvTranspose",
    "Cos",
    "Cosh",
    "CumSum",
    "DepthToSpace",
    "Div",
    "Dropout",
    "Einsum",
    "Elu",
    "Equal",
    "Erf",
    "Exp",
    "Expand",
    "Flatten",
    "Floor",
    "Gather",
    "GatherElements",
    "GatherND",
    "Gemm",
    "GlobalAveragePool",
    "GlobalMaxPool",
    "Greater",
    "GreaterOrEqual",
    "GridSample",
    "Hardmax",
    "HardSigmoid",
    "HardSwish",
    "Identity",
    "InstanceNormalization",
    "IsInf",
    "IsNaN",
    "LayerNormalization",
    "LeakyRelu",
    "Less",
    "LessOrEqual",
    "Log",
    "LogSoftmax",
    "LRN",
    "LSTM",
    "MatMul",
    "Max",
    "MaxPool",
    "Mean",
    "Min",
    "Mod",
    "Mul",
    "Multinomial",
    "Neg",
    "NonMaxSuppression",
    "NonZero",
    "Not",
    "OneHot",
    "Or",
    "Pad",
    "Pow",
    "PRelu",
    "RandomNormal",
    "RandomNormalLike",
    "RandomUniform",
    "RandomUniformLike",
    "Range",
    "Reciprocal",
    "ReduceL1",
    "ReduceL2",
    "ReduceLogSum",
    "ReduceLogSumExp",
    "ReduceMax",
    "ReduceMean",
    "ReduceMin",
    "ReduceProd",
    "ReduceSum",
    "ReduceSumSquare",
    "Relu",
    "Reshape",
    "Resize",
    "RoiAlign",
    "Round",
    "Scatter",
    "ScatterElements",
    "ScatterND",
    "Selu",
    "Shape",
    "Shrink",
    "Sigmoid",
    "Sign",
    "Sin",
    "Sinh",
    "Size",
    "Slice",
    "Softmax",
    "Softplus",
    "Softsign",
    "SpaceToDepth",
    "Split",
    "Sqrt",
    "Squeeze",
    "Sub",
    "Sum",
    "Tan",
    "Tanh",
    "ThresholdedRelu",
    "Tile",
    "TopK",
    "Transpose",
    "Trilu",
    "Unsqueeze",
    "Upsample",
    "Where",
    "Xor",
}
# onnxruntime-web's WebAssembly backend "compiles the native ONNX Runtime CPU engine into
# WebAssembly ... full ONNX operator coverage" (https://www.npmjs.com/package/onnxruntime-web):
# any standard op of the default domain at the opsets onnxruntime reads (7 and up); the
# JavaScript port's tests run these graphs in it (tests/portable/test_js_port.py).
ORT_WEB_MIN_OPSET = 7
INT8_OPS = {"DynamicQuantizeLinear", "MatMulInteger", "DequantizeLinear", "QuantizeLinear"}


def test_every_graph_is_float_at_an_opset_both_engines_take(portable_bundle):
    generator_manifest = MotionGenerator.load(portable_bundle).manifest
    for graph in generator_manifest.graphs():
        model = onnx.load(portable_bundle / graph.file)
        opsets = {o.domain: o.version for o in model.opset_import}
        assert set(opsets) == {""}, f"{graph.file}: {opsets}"
        assert ORT_WEB_MIN_OPSET <= opsets[""] <= SENTIS_MAX_OPSET, graph.file
        ops = {node.op_type for node in model.graph.node}
        assert ops <= SENTIS_OPS, f"{graph.file}: {sorted(ops - SENTIS_OPS)} not in Sentis's table"
        assert not ops & INT8_OPS
        for op in ops:
            assert onnx.defs.has(op, opsets[""], ""), f"{graph.file}: {op} at opset {opsets['']}"
        onnx.checker.check_model(model, full_check=True)


def test_the_default_bundle_is_what_the_check_refuses():
    """The check above can fail: the shipped int8 graphs are at opset 20 with ops Sentis
    lists as unsupported, and Gelu."""
    model = onnx.load(MotionGenerator.load().bundle.path("level_0.onnx"))
    assert {o.version for o in model.opset_import if o.domain == ""} == {20}
    ops = {node.op_type for node in model.graph.node}
    assert ops - SENTIS_OPS == {
        "DynamicQuantizeLinear",
        "MatMulInteger",
        "DequantizeLinear",
        "Gelu",
    }


def test_greedy_tokens_agree_with_the_int8_bundle(portable_generator):
    """Teacher-forced, as the int8 check of `mogo export` counts: at each step of the int8
    bundle's greedy stream, does the portable bundle pick the same tokens given the same past?
    (The int8 graphs quantise activations; the float ones do not: the logits differ a little,
    and so do the tokens where two are close.)"""
    int8 = MotionGenerator.load()
    greedy = Sampling(temperature=0)
    same = total = 0
    for prompt in ("a person walks forward", "a person jumps", "a person waves"):
        embedding = int8.embed([prompt])[0]
        np.testing.assert_allclose(portable_generator.embed([prompt])[0], embedding, atol=1e-3)
        reference = int8.tokens.generate(embedding, 16, sampling=greedy)
        for n in range(len(reference)):
            stream = portable_generator.tokens.start(embedding, sampling=greedy, allow_end=False)
            if n:
                stream.continue_from(reference[:n])
            same += int(np.sum(stream.step() == reference[n]))
            total += reference.shape[1]
    assert same / total >= 0.95, same / total


def test_generate_through_the_portable_bundle(portable_generator):
    motion = portable_generator.generate("a person walks forward", seconds=2, seed=3)
    assert motion.joints.shape == (40, 22, 3)
    assert np.all(np.isfinite(motion.joints))
    travelled = np.linalg.norm(motion.joints[-1, 0, [0, 2]] - motion.joints[0, 0, [0, 2]])
    assert travelled > 0.5  # a walk goes somewhere


def test_the_command_refuses_a_portable_export_without_a_bundle(tmp_path):
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "mogo",
            "export",
            "portable",
            "--out",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "mogo: error: the following arguments are required: --bundle "
        "(see mogo export portable --help)"
    ]
    assert not (tmp_path / "out").exists()
