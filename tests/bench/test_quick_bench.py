"""`mogo bench quick`: this machine's figures beside the README's, with the runtime alone."""

import re
from pathlib import Path

from mogo.bench.speed import quick

README = Path(__file__).resolve().parents[2] / "README.md"


def test_it_runs_without_torch_and_prints_both_columns(run_without_torch):
    done = run_without_torch(
        "from mogo.cli import main\nassert main(['bench', 'quick', '--threads', '1']) == 0\n",
        block_export=False,
    )  # the parser lists export's verbs
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert out.startswith("this machine: ") and "onnxruntime" in out
    assert (
        re.search(r"^  AVX2 (yes|no), AVX-512 (yes|no), AVX-512 VNNI (yes|no)", out, re.MULTILINE)
        or "NEON" in out
        or "unknown" in out
    )
    first_readme, clip_readme = quick.README[1]
    row = re.search(
        rf"^\| 1 \| (\d+) ms / {first_readme:.0f} ms \((\d+\.\d)x\) \| "
        rf"(\d+\.\d+) s / {clip_readme:.3f} s \((\d+\.\d)x\) \| (\d+\.\d+) ms \| "
        r"(?:\d+ ms|-) \|$",  # a low-latency stream's first frame, where the bundle has one
        out,
        re.MULTILINE,
    )
    assert row, out
    first, first_ratio, clip, clip_ratio, step = map(float, row.groups())
    assert first > 0 and clip > 0 and step > 0
    assert abs(first_ratio - first / first_readme) < 0.1  # how many times the README's
    assert abs(clip_ratio - clip / clip_readme) < 0.1
    assert "| 2 |" not in out


def test_the_readme_figures_are_the_readme_table():
    text = README.read_text()
    for threads, (first_ms, clip_s) in quick.README.items():
        assert f"| {threads} | {first_ms:.0f} ms | {clip_s * 1e3:.0f} ms |" in text


def test_a_cpu_without_vnni_is_told_what_that_means():
    rows = {1: dict(first_ms=60.0, clip_s=0.3, step_ms=2.0, low_latency_first_ms=None)}
    avx2 = quick.report(rows, "some CPU", {"avx", "avx2", "fma"})
    assert "AVX2 yes, AVX-512 no, AVX-512 VNNI no, AVX-VNNI no" in avx2
    assert "No VNNI here" in avx2
    assert "No VNNI here" not in quick.report(rows, "some CPU", {"avx2", "avx512f", "avx512_vnni"})
    arm = quick.report(rows, "some ARM", {"fp", "asimd"})
    assert "NEON yes, NEON dot product no" in arm and "AVX" not in arm.split("README")[0]
