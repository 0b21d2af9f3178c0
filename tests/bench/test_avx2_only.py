"""`mogo bench avx2`: a command run as on a CPU with AVX2 alone, and what the suite proves with
it: the golden contract and the served streams' tokens hold on onnxruntime's AVX2 kernels,
those of the machines where the byte-pinned tests of old failed. Where this machine cannot
hide its features (no CPUID faulting, no C compiler, not x86-64 Linux) these runs skip; where
it has AVX-512 VNNI, the hiding must change which kernels onnxruntime picks."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mogo.bench.speed import avx2_only
from mogo.bench.speed.quick import cpu

FLAGS = cpu()[1]
TESTS = Path(__file__).resolve().parents[1]


def _unavailable() -> str | None:
    try:
        avx2_only.check_machine(FLAGS)
    except avx2_only.Unavailable as why:
        return str(why)
    return None


needs_mask = pytest.mark.skipif(
    _unavailable() is not None, reason=f"mogo bench avx2 cannot run here: {_unavailable()}"
)

# what the masked process reports: numpy's view of the CPU, onnxruntime's uint8 x int8
# products (exact only on VNNI or AMX kernels: mogo.serve.rowwise), and what the bench prints
PROBE = """
import numpy
core = getattr(numpy, "_core", None) or numpy.core
features = core._multiarray_umath.__cpu_features__
from mogo.serve.rowwise import signed_products_exact
from mogo.bench.speed.quick import cpu, features_line
print(features["AVX2"], features["AVX512F"], signed_products_exact())
print(features_line(cpu()[1]))
"""


def _mogo(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mogo", "bench", "avx2", *args], capture_output=True, text=True
    )


@needs_mask
def test_the_command_sees_avx2_alone_and_onnxruntime_takes_other_kernels():
    masked = _mogo(sys.executable, "-c", PROBE)
    assert masked.returncode == 0, masked.stderr
    seen, line = masked.stdout.splitlines()
    assert seen.split()[:2] == ["True", "False"]
    assert "AVX2 yes, AVX-512 no, AVX-512 VNNI no, AVX-VNNI no, AMX-INT8 no" in line
    if "avx512f" in FLAGS:
        assert "hiding" in masked.stderr and "avx512f" in masked.stderr
    plain = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True)
    if plain.stdout.split()[2] == "True":  # VNNI or AMX here: their products are exact
        assert seen.split()[2] == "False"  # AVX2's kernel adds pairs in 16 bits, saturating


@needs_mask
def test_a_double_dash_ends_its_own_options():
    done = _mogo("--", sys.executable, "-c", "print('ran')")
    assert done.returncode == 0 and done.stdout == "ran\n", done.stderr


@needs_mask
def test_children_are_masked_too_and_their_status_comes_back():
    child = "import subprocess, sys; sys.exit(subprocess.run([sys.executable, '-c', sys.argv[1]]).returncode)"
    inner = (
        "import numpy, sys; core = getattr(numpy, '_core', None) or numpy.core; "
        "sys.exit(7 if core._multiarray_umath.__cpu_features__['AVX512F'] else 5)"
    )
    assert _mogo(sys.executable, "-c", child, inner).returncode == 5


@needs_mask
def test_a_real_crash_still_crashes_and_the_programs_own_handler_sees_it():
    crash = "import ctypes; ctypes.string_at(0)"
    assert _mogo(sys.executable, "-c", crash).returncode == 128 + 11  # not swallowed
    # faulthandler's SIGSEGV handler, set before onnxruntime reads CPUID: kept aside, it
    # still reports the real fault, and the CPUID reads after it are answered
    reported = _mogo(sys.executable, "-X", "faulthandler", "-c", f"import onnxruntime; {crash}")
    assert reported.returncode == 128 + 11 and "Fatal Python error: Segmentation fault" in (
        reported.stderr
    )


def test_bad_use_is_one_line():
    for args, says in [
        ((), "needs a command"),
        (("--",), "needs a command"),
        (("no-such-command-here",), "no such command"),
    ]:
        if says == "no such command" and _unavailable():  # the machine is checked first
            says = _unavailable()
        done = _mogo(*args)
        assert done.returncode == 2
        assert done.stderr.startswith("mogo: error: ") and says in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr


def test_an_unfit_machine_is_named():
    with pytest.raises(avx2_only.Unavailable, match="no AVX2"):
        avx2_only.check_machine({"sse2"} if sys.platform == "linux" else None)
    if sys.platform == "linux" and avx2_only.platform.machine() == "x86_64":
        with pytest.raises(avx2_only.Unavailable, match="CPUID faulting"):
            avx2_only.check_machine({"avx2"})


def _pytest_on_avx2_kernels(*tests: str) -> str:
    """pytest on `tests` (node ids under tests/) in a process that sees AVX2 alone (its
    faulthandler's SIGSEGV handler kept aside by the shim); its output."""
    command = [sys.executable, "-m", "pytest", *(str(TESTS / test) for test in tests)]
    command += ["-q", "-rs", "--full", "-p", "no:cacheprovider"]
    done = _mogo(*command)
    return done.stdout + done.stderr


@needs_mask
def test_the_golden_contract_holds_on_avx2_kernels():
    output = _pytest_on_avx2_kernels(
        "runtime/test_golden.py::test_the_case_keeps_the_determinism_contract"
    )
    cases = len(json.loads((TESTS / "runtime" / "golden.json").read_text())["cases"])
    assert f"{cases} passed" in output and "failed" not in output, output[-3000:]


@needs_mask
def test_served_streams_draw_mogo_streams_tokens_on_avx2_kernels():
    """Where AVX2's uint8 x int8 products saturate, the server keeps uint8 weights: its row-wise
    graphs on them, stepping streams together, still draw `mogo stream`'s tokens."""
    output = _pytest_on_avx2_kernels(
        "serve/test_served_streams.py::test_served_streams_draw_the_tokens_of_mogo_stream"
    )
    assert " passed" in output and "failed" not in output and "skipped" not in output, output[
        -3000:
    ]
