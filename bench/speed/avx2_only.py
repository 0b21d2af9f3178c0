"""`mogo bench avx2 COMMAND...`: COMMAND run as on a CPU with AVX2 but no AVX-512, AVX-VNNI or
AMX, so that onnxruntime's and numpy's AVX2 kernels can be timed on a machine that has more:
a CPU with AVX-512 (VNNI) runs the bundle's int8 graphs on other kernels, and users deploy on
both. The process and its children see the masked CPUID (avx2_only.c, compiled here with the
system's C compiler and loaded with LD_PRELOAD); the core is still this machine's, so compare
ratios measured on it, not milliseconds with a real AVX2-only CPU's. Programs with SIGSEGV
handlers of their own (Python's faulthandler, Node) run under it: the shim keeps theirs aside
and passes them every real fault. Linux on x86-64 only, with CPUID faulting (`cpuid_fault` in
/proc/cpuinfo; Intel CPUs have it since Ivy Bridge, in a VM where the hypervisor passes it
on)."""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

SHIM = Path(__file__).with_name("avx2_only.c")
MARK = "MOGO_BENCH_AVX2_ONLY"  # set in the masked process: what it reports of its CPU follows
HIDDEN = ("avx512", "amx", "avx_vnni", "avx_ifma")  # /proc/cpuinfo flags hidden, by prefix


class Unavailable(RuntimeError):
    """This machine cannot hide the features: why, in one line."""


def hidden(flag: str) -> bool:
    """Whether a /proc/cpuinfo flag names a feature the mask hides."""
    return flag.startswith(HIDDEN)


def masked() -> bool:
    """Whether this process runs under `mogo bench avx2`."""
    return os.environ.get(MARK) == "1"


def check_machine(flags: set[str] | None) -> None:
    """Unavailable unless this is Linux on x86-64 with AVX2 and CPUID faulting, and a C
    compiler is on the PATH."""
    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
        raise Unavailable(f"needs Linux on x86-64, not {platform.system()} on {platform.machine()}")
    if flags is None or "avx2" not in flags:
        raise Unavailable("this CPU has no AVX2 (per /proc/cpuinfo): there is nothing to time")
    if "cpuid_fault" not in flags:
        raise Unavailable(
            "this CPU (or its hypervisor) offers no CPUID faulting (no cpuid_fault in "
            "/proc/cpuinfo), which hiding its features needs"
        )
    if compiler() is None:
        raise Unavailable("needs a C compiler (cc or gcc; Debian: apt install gcc)")


def compiler() -> str | None:
    return shutil.which("cc") or shutil.which("gcc")


def build(folder: Path) -> Path:
    """The shim compiled into `folder`."""
    library = folder / "avx2_only.so"
    made = subprocess.run(
        [compiler(), "-O2", "-shared", "-fPIC", "-o", str(library), str(SHIM)],
        capture_output=True,
        text=True,
    )
    if made.returncode:
        raise Unavailable(f"the shim did not compile: {made.stderr.strip().splitlines()[-1]}")
    return library


def environment(library: Path) -> dict[str, str]:
    """This process's environment with the shim preloaded (before any preload already set)."""
    env = dict(os.environ)
    env["LD_PRELOAD"] = " ".join(filter(None, [str(library), env.get("LD_PRELOAD")]))
    env[MARK] = "1"
    return env


def confirm(env: dict[str, str], flags: set[str]) -> None:
    """Unavailable unless a Python under `env` sees AVX2 and, where this CPU has AVX-512, not
    it: the mask took hold (numpy reads CPUID at import, as onnxruntime does at load)."""
    probe = (  # numpy 2's module, or numpy 1's
        "import numpy; core = getattr(numpy, '_core', None) or numpy.core; "
        "f = core._multiarray_umath.__cpu_features__; print(int(f['AVX2']), int(f['AVX512F']))"
    )
    seen = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True
    ).stdout.split()
    if seen != ["1", "0"]:
        raise Unavailable(
            f"the mask did not take hold (numpy saw AVX2, AVX-512 = {' '.join(seen) or 'nothing'}"
            f"{'; this CPU has AVX-512' if 'avx512f' in flags else ''})"
        )


def run(command: list[str], flags: set[str] | None) -> int:
    """`command` under the mask; its exit status (a signal's number + 128 where one ended it).
    Unavailable where the machine cannot run it."""
    check_machine(flags)
    if shutil.which(command[0]) is None:
        raise Unavailable(f"no such command: {command[0]}")
    with tempfile.TemporaryDirectory(prefix="mogo-avx2-") as folder:
        env = environment(build(Path(folder)))
        confirm(env, flags)
        hidden_here = sorted(flag for flag in flags if hidden(flag))
        print(
            f"mogo bench avx2: hiding {', '.join(hidden_here) or 'nothing (none here)'}",
            file=sys.stderr,
            flush=True,
        )
        status = subprocess.run(command, env=env).returncode
    return 128 - status if status < 0 else status
