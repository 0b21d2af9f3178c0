"""mogo bench eval, the semantic checks and the quality report on a small procedural corpus whose
every clip is listed as test, with an untrained tiny evaluator and the shipped bundle."""

import json
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from mogo.bench.quality import evaluate as evaluate_module
from mogo.bench.quality import semantic
from mogo.bench.quality.evaluate import EvalOptions, caption_items, evaluate
from mogo.cli import main
from mogo.export.data.humanml3d import HumanML3DFolder

MM_ARGS = ["--mm-captions", "1", "--mm-generations", "10"]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    from mogo.export.data.corpus import synthesize_corpus

    root = tmp_path_factory.mktemp("corpus")
    synthesize_corpus(root, num_clips=16, seed=0, progress=False, workers=1)
    ids = sorted(p.stem for p in (root / "programs").glob("*.json"))
    (root / "test.txt").write_text("".join(f"{i}\n" for i in ids))
    return root


@pytest.fixture(scope="module")
def evaluator_folder(corpus, tmp_path_factory):
    import torch

    from mogo.export.models.evaluator import Evaluator, EvaluatorConfig
    from mogo.export.models.text_encoder import train_tokenizer
    from mogo.export.onnx.evaluator_graphs import export_evaluator

    captions = [
        c.split("#")[0]
        for p in (corpus / "texts").glob("*.txt")
        for c in p.read_text().splitlines()
    ]
    tokenizer = train_tokenizer(captions, 100, 16)
    torch.manual_seed(0)
    model = Evaluator(EvaluatorConfig.tiny(tokenizer.get_vocab_size()))
    out = tmp_path_factory.mktemp("evaluator")
    export_evaluator(
        model, tokenizer, np.load(corpus / "Mean.npy"), np.load(corpus / "Std.npy"), out
    )
    return out


def test_eval_prints_the_table_without_torch(corpus, evaluator_folder, tmp_path):
    result = tmp_path / "eval.json"
    script = (
        "import sys\nfrom mogo.cli import main\n"
        f"code = main(['bench', 'eval', '--data', {str(corpus)!r}, '--evaluator', "
        f"{str(evaluator_folder)!r}, '--limit', '32', '--repeats', '2', "
        f"{', '.join(map(repr, MM_ARGS))}, '--json', {str(result)!r}])\n"
        "assert code == 0 and 'torch' not in sys.modules, (code, 'torch' in sys.modules)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    lines = done.stdout.splitlines()
    assert lines[0].startswith("| Methods | R-Precision Top-1 | Top-2 | Top-3 | FID |")
    assert [line.split(" | ")[0] for line in lines[2:5]] == [
        "| Ground truth",
        "| VQ reconstruction",
        "| Bundle",
    ]
    rows = json.loads(result.read_text())["rows"]
    assert rows["Ground truth"]["FID"] == pytest.approx([0.0, 0.0], abs=1e-9)  # rounding
    assert rows["Bundle"]["FID"][0] > rows["VQ reconstruction"]["FID"][0] > 0
    assert "MultiModality" in rows["Bundle"] and "MultiModality" not in rows["Ground truth"]
    assert all(np.isfinite(v).all() for row in rows.values() for v in row.values())


class MeanFeatures:
    """Another evaluator behind the seam: a motion is its mean first 8 features; a caption is
    that of a real clip it describes (captions repeat), so ground truth retrieves well."""

    embed_dim = 8

    def __init__(self, table: dict[str, np.ndarray]):
        self.table = table

    def embed_text(self, captions):
        return np.stack([self.table[c] for c in captions])

    def embed_motion(self, features):
        return np.stack([f[:, :8].mean(0) for f in features])


def replay_real_clips(monkeypatch, folder: HumanML3DFolder) -> None:
    """Generation replaced by the real clips: for tests of what comes after it."""

    def real(generator, items, seed, threads=1, label=""):
        return [
            SimpleNamespace(
                features=folder.features(item.clip_id)[item.start : item.end],
                joints=folder.joints(item.clip_id)[item.start : item.end],
            )
            for item in items
        ]

    monkeypatch.setattr(evaluate_module, "generate_items", real)


def test_another_evaluator_plugs_in(corpus, monkeypatch):
    folder = HumanML3DFolder(corpus, splits=("test",))
    replay_real_clips(monkeypatch, folder)
    items = caption_items(folder, "test", 32)
    fake = MeanFeatures(
        {i.caption: folder.features(i.clip_id)[i.start : i.end, :8].mean(0) for i in items}
    )
    options = EvalOptions(None, corpus, None, limit=32, repeats=2, mm_captions=0, regenerate=True)
    result = evaluate(options, fake)
    rows = result["rows"]
    assert result["items"] == 32 and "regenerated every repeat" in result["notes"][0]
    assert rows["Ground truth"]["Top-3"][0] > 0.5  # chance: 3/32
    assert rows["Ground truth"]["FID"][0] == pytest.approx(0, abs=1e-9)
    assert rows["VQ reconstruction"]["FID"][0] > 1e-9
    assert rows["Bundle"] == rows["Ground truth"]


@pytest.mark.parametrize(
    "case, message",
    [
        ("no_evaluator", "no such evaluator folder"),
        ("small_limit", "--limit must be at least 32"),
        ("no_test_split", "test.txt: split file missing"),
    ],
)
def test_bad_inputs_give_one_line_errors(case, message, corpus, evaluator_folder, tmp_path, capsys):
    data, evaluator, extra = corpus, evaluator_folder, []
    if case == "no_evaluator":
        evaluator = tmp_path / "missing"
    elif case == "small_limit":
        extra = ["--limit", "10"]
    else:
        data = tmp_path / "data"
        data.mkdir()
    assert main(["bench", "eval", "--data", str(data), "--evaluator", str(evaluator), *extra]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("mogo: error:") and message in error


def test_semantic_checks_pass_real_clips_and_fail_wrong_parameters(corpus):
    folder = HumanML3DFolder(corpus, splits=("test",))
    items = semantic.program_items(corpus, folder.ids("test"))
    assert len({item.primitive for item in items}) >= 10
    wrong = dict(left="right", right="left", both="left", forward="backward", backward="forward")
    flipped = 0
    for item in items:
        joints = folder.joints(item.clip_id)[item.start : item.end]
        assert semantic.check(item, joints, joints).passed, (item, semantic.check(item, joints))
        params = {
            k: wrong.get(v, v + 1 if k == "count" else v)
            if isinstance(v, (str, int))
            and not isinstance(v, bool)
            and k in ("hand", "foot", "direction", "count")
            else v
            for k, v in item.params.items()
        }
        if params != item.params:
            flipped += 1
            changed = semantic.SemanticItem(
                item.clip_id, item.caption, item.primitive, params, item.start, item.end
            )
            assert not semantic.check(changed, joints, joints).passed, changed
    assert flipped >= 10


def test_semantic_measurements_on_a_turned_clip():
    """A rigid T-ish pose facing +Z that walks 2 m along +X (its left) while turning 90
    degrees to its left."""
    from mogo.motion.skeleton import SKELETONS

    offsets = np.zeros((22, 3))
    names = SKELETONS["humanml3d"].joint_names
    for side, x in (("left", 0.1), ("right", -0.1)):
        offsets[names.index(f"{side}_hip")] = (x, 0, 0)
        offsets[names.index(f"{side}_shoulder")] = (2 * x, 0.5, 0)
    yaw = np.radians(np.linspace(0, 90, 21))
    rotation = np.stack(
        [
            np.stack([np.cos(yaw), np.zeros(21), np.sin(yaw)], -1),
            np.tile([0.0, 1, 0], (21, 1)),
            np.stack([-np.sin(yaw), np.zeros(21), np.cos(yaw)], -1),
        ],
        1,
    )
    root = np.stack([np.linspace(0, 2, 21), np.full(21, 0.9), np.zeros(21)], -1)
    joints = root[:, None] + np.einsum("tij,nj->tni", rotation, offsets)
    assert semantic.heading_change(joints) == pytest.approx(90, abs=1e-6)
    assert np.allclose(semantic.travel(joints), [0, 2], atol=1e-9)
    assert semantic.runs(np.array([1, 1, 0, 1, 0, 1, 1, 1], bool)) == 2


def test_quality_report(corpus, evaluator_folder, tmp_path, monkeypatch, capsys):
    from mogo.bench.quality import quality_report

    replay_real_clips(monkeypatch, HumanML3DFolder(corpus, splits=("test",)))
    (tmp_path / "ablation.md").write_text(
        "| variant | MPJPE (mm) |\n|---|---|\n| 6 levels | 20 |\n"
    )
    out = tmp_path / "QUALITY.md"
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "quality_report",
            "--data",
            str(corpus),
            "--evaluator",
            str(evaluator_folder),
            "--out",
            str(out),
            "--limit",
            "32",
            "--repeats",
            "1",
            "--mm-captions",
            "0",
            "--per-primitive",
            "1",
            "--ablation",
            str(tmp_path),
        ],
    )
    quality_report.main()
    text = out.read_text()
    for heading in (
        "## Text-motion metrics",
        "| Bundle |",
        "## Does the motion do what",
        "| all |",
        "## Feet",
        "| generated, feet planted |",
        "## MoSA-VQ ablation",
        "| 6 levels | 20 |",
    ):
        assert heading in text
    assert "Missing" in quality_report.ablation_section(tmp_path / "nothing")


def test_vq_reconstruction_writes_gifs_and_a_contact_sheet(corpus, tmp_path, monkeypatch, capsys):
    from PIL import Image

    from mogo.bench.quality import vq_reconstruction

    out = tmp_path / "recon"
    monkeypatch.setattr(
        sys, "argv", ["vq_reconstruction", "--data", str(corpus), "--out", str(out), "--clips", "2"]
    )
    vq_reconstruction.main()
    printed = capsys.readouterr().out
    errors = [
        float(line.split("MPJPE ")[1].split(" mm")[0])
        for line in printed.splitlines()
        if " frames, MPJPE " in line
    ]
    assert len(errors) == 2 and all(0 < e < 60 for e in errors)  # the shipped VQ: ~10-25 mm
    gifs = sorted(out.glob("*.gif"))
    assert len(gifs) == 2 and not any(g.stem.startswith("M") for g in gifs)
    with Image.open(gifs[0]) as gif:
        assert gif.width == 2 * gif.height and gif.n_frames >= vq_reconstruction.MIN_FRAMES
    with Image.open(out / "contact_sheet.png") as sheet:
        assert sheet.height == 4 * vq_reconstruction.THUMBNAIL


def test_vq_report_splits_the_error_of_the_shipped_vq(corpus, monkeypatch, capsys):
    from mogo.bench.quality import vq_report

    folder = HumanML3DFolder(corpus, splits=("test",))
    real = folder.features(folder.ids("test")[0])
    assert vq_report.clip_errors(real, real) == (0.0, 0.0, 0.0)
    turned = real.copy()
    turned[:, 0] += 0.01  # a yaw velocity bias: the trajectory turns, the poses are as they were
    whole, poses, trajectory = vq_report.clip_errors(real, turned)
    assert poses == 0.0 and whole == trajectory > 0
    monkeypatch.setattr(
        sys, "argv", ["vq_report", "--data", str(corpus), "--limit", "6", "--threads", "2"]
    )
    vq_report.main()
    row = capsys.readouterr().out.splitlines()[-1].split(" | ")
    assert row[0] == "| default" and row[1] == "6"
    mpjpe, poses, trajectory = map(float, row[2:5])
    assert 0 < poses < mpjpe < 60 and 0 < trajectory < mpjpe  # the shipped VQ: ~10-25 mm
