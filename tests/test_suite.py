"""The suite as a contributor runs it: `python -m pytest` leaves the slow tests out and says
so, `--full` runs them, and the README's whole-suite command is the one CI runs."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def collected(*args: str) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    return done.stdout


def test_the_slow_folders_run_only_with_full():
    fast = collected("tests/export/test_captions.py", "tests/test_boundaries.py")
    assert "tests/export/test_captions.py::" not in fast
    assert "tests/test_boundaries.py::" in fast
    assert re.search(r"^\d+ slow tests were not run: add --full", fast, re.MULTILINE)
    full = collected("--full", "tests/export/test_captions.py", "tests/test_boundaries.py")
    assert "tests/export/test_captions.py::" in full and "not run" not in full


def test_the_readmes_whole_suite_command_is_what_ci_runs():
    readme = (ROOT / "README.md").read_text()
    block = re.search(
        r"\*\*The whole test suite\*\* \(what CI runs\):\n\n```bash\n(.+)\n```", readme
    ).group(1)
    ci = (ROOT / ".ci" / "run").read_text()
    (line,) = [line for line in ci.splitlines() if "python -m pytest" in line]
    steps = iter(line.split(" && "))  # CI may run more steps (a lint gate) between them
    assert all(step in steps for step in block.split(" && ")) and "--full" in block, line
    assert '"$status" -eq 5' in ci  # no tests collected is a failure
