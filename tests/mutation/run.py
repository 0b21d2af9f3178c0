"""Mutation testing of the runtime core with cosmic-ray: a developer tool, not run in CI.

cosmic-ray makes one small bug at a time in a source file (an operator swapped, a constant
changed, a condition negated) and runs the tests that cover that file; a mutant no test
notices "survives". The score is the share killed. docs/mutation.md has the figures and the
survivors, each judged.

cosmic-ray writes mutants into the file in place, so this never touches your checkout: it
clones the committed HEAD into WORK/repo and imports `mogo` from that clone (WORK/import, put
first on PYTHONPATH). Sessions are sqlite files in WORK and resume where they stopped.

    pip install -e ".[dev,mutation]"
    python tests/mutation/run.py --work ~/mogo-mutation                  # all seven files
    python tests/mutation/run.py --work ~/mogo-mutation sampling bvh     # some of them
    python tests/mutation/run.py --work ~/mogo-mutation --report         # the table only
    python tests/mutation/run.py --work ~/mogo-mutation --retest         # new tests: survivors again

Each run first moves the clone to the checkout's HEAD (commit what you want measured); a file
whose source changed since its session was made gets a new session.

Mutants inside type annotations are skipped: with postponed annotations (`from __future__
import annotations`) they are never evaluated, so no test can tell them apart.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# Each core file and the tests that cover it, fastest and most telling first (pytest -x stops
# at the first failure).
CORE = {
    "sampling": ("runtime/sampling.py", "test_sampling.py test_golden.py test_token_loop.py"),
    "token_generator": (
        "runtime/token_generator.py",
        "test_token_loop.py test_golden.py test_sampling.py",
    ),
    "stream_decoder": ("runtime/stream_decoder.py", "test_stream_decoder.py test_golden.py"),
    "features": (
        "runtime/motion/features.py",
        "test_features_spec.py test_features.py test_golden.py test_stream_decoder.py",
    ),
    "bundle": ("runtime/bundle.py", "test_bundle_files.py test_golden.py"),
    "bvh": ("runtime/motion/bvh.py", "test_bvh.py test_bvh_external.py test_rig.py"),
    "generator": (
        "runtime/generator.py",
        "test_generator.py test_golden.py test_clip_edges.py "
        "test_arguments.py test_anchoring.py test_token_loop.py test_align.py "
        "test_text_side.py "
        # the shipped bundle has one frame a token; this one trains a tiny bundle
        # of two (needs torch, ~30 s)
        "../export/test_export_bundle.py::"
        "test_a_bundle_of_two_frames_per_token_runs_through_the_generator",
    ),
}
# a mutant that hangs a test fails it after TEST_TIMEOUT_S (pytest-timeout; the slowest test
# takes ~10 s on a quiet machine); one that hangs the whole run is stopped by cosmic-ray at
# TIMEOUT_FACTOR times the clean run's time (taken before each run: a busy machine is slower)
TEST_TIMEOUT_S, TIMEOUT_FACTOR, MIN_TIMEOUT_S = 60, 4, 60


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "names",
        nargs="*",
        metavar="NAME",
        help=f"core files to run (default: all): {', '.join(CORE)}",
    )
    parser.add_argument(
        "--work",
        type=Path,
        required=True,
        help="folder for the clone and the sessions (outside the checkout)",
    )
    parser.add_argument("--report", action="store_true", help="print the table, run nothing")
    parser.add_argument(
        "--retest", action="store_true", help="run the survivors again (after adding tests)"
    )
    args = parser.parse_args()
    unknown = sorted(set(args.names) - set(CORE))
    if unknown:
        parser.error(f"unknown core file {', '.join(unknown)}; choose from {', '.join(CORE)}")
    names = args.names or list(CORE)
    work = args.work.expanduser().resolve()
    if work == ROOT or ROOT in work.parents:
        parser.error("--work must be outside the checkout (mutants are written in place)")
    if not args.report:
        repo = prepare_clone(work)
        for name in names:
            run_session(work, repo, name, args.retest)
    print(report(work, names))
    return 0


def prepare_clone(work: Path) -> Path:
    """WORK/repo: a clone at the checkout's HEAD with no mutant left in it, importable as
    `mogo`."""
    repo = work / "repo"
    if not repo.exists():
        work.mkdir(parents=True, exist_ok=True)
        subprocess.run(["git", "clone", "-q", str(ROOT), str(repo)], check=True)
        for sub in ("bench", "export"):  # mogo.bench and mogo.export, as the install maps them
            (repo / "runtime" / sub).symlink_to(Path("..") / sub)
        (work / "import").mkdir()
        (work / "import" / "mogo").symlink_to(repo / "runtime")
    subprocess.run(["git", "checkout", "-q", "--", "runtime"], cwd=repo, check=True)
    subprocess.run(["git", "fetch", "-q", str(ROOT), "HEAD"], cwd=repo, check=True)
    subprocess.run(["git", "checkout", "-q", "--detach", "FETCH_HEAD"], cwd=repo, check=True)
    head = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"],
        cwd=repo,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    print(f"mutating a clone of {head} in {repo}", flush=True)
    return repo


def run_session(work: Path, repo: Path, name: str, retest: bool) -> None:
    """Init the session (anew where the file changed since), skip annotation mutants, run what
    is pending (and the survivors again, with `retest`: the tests changed), with progress."""
    path, tests = CORE[name]
    config, session = work / f"{name}.toml", work / f"{name}.sqlite"
    source = work / f"{name}.source"  # the sha256 of the file the session was made from
    digest = hashlib.sha256((repo / path).read_bytes()).hexdigest()
    if session.exists() and source.exists() and source.read_text() != digest:
        print(
            f"{name}: {path} changed since its session was made; starting a new one "
            f"(the old one is kept as {session.name}.old)",
            flush=True,
        )
        session.replace(session.with_name(session.name + ".old"))
    test_command = " ".join(
        [
            sys.executable,
            "-m pytest -q -x -p no:cacheprovider",
            f"--timeout {TEST_TIMEOUT_S}",
            *(f"tests/runtime/{test}" for test in tests.split()),
        ]
    )
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(work / "import"), os.environ.get("PYTHONPATH", "")]),
    }
    timeout = _clean_run_seconds(name, test_command, repo, env) * TIMEOUT_FACTOR
    config.write_text(
        f'[cosmic-ray]\nmodule-path = "{path}"\n'
        f"timeout = {max(MIN_TIMEOUT_S, round(timeout))}.0\n"
        f'excluded-modules = []\ntest-command = "{test_command}"\n\n'
        f'[cosmic-ray.distributor]\nname = "local"\n'
    )
    if not session.exists():
        subprocess.run(
            ["cosmic-ray", "init", str(config), str(session)], cwd=repo, env=env, check=True
        )
        skip_annotations(session, repo / path)
        source.write_text(digest)
    if retest:
        with sqlite3.connect(session) as db:
            db.execute("DELETE FROM work_results WHERE test_outcome = 'SURVIVED'")
    job = subprocess.Popen(
        ["cosmic-ray", "exec", str(config), str(session)],
        cwd=repo,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=(work / f"{name}.log").open("a"),
    )
    try:
        while job.poll() is None:
            time.sleep(30)
            done, total = _progress(session)
            print(f"{name}: {done}/{total} mutants", flush=True)
    finally:
        job.terminate()
        job.wait()
        subprocess.run(["git", "checkout", "-q", "--", "runtime"], cwd=repo, check=True)
    if job.returncode:
        sys.exit(
            f"cosmic-ray exec failed for {name} (exit {job.returncode}); see "
            f"{work / (name + '.log')}"
        )


def _clean_run_seconds(name: str, test_command: str, repo: Path, env: dict) -> float:
    """Run the tests once on the unmutated clone: they must pass (else every mutant would
    count as killed); how long they took sets the timeout."""
    start = time.perf_counter()
    clean = subprocess.run(test_command.split(), cwd=repo, env=env, capture_output=True, text=True)
    if clean.returncode:
        sys.exit(
            f"{name}: the tests fail without any mutant; fix them first:\n{clean.stdout[-2000:]}"
        )
    return time.perf_counter() - start


def skip_annotations(session: Path, source: Path) -> None:
    """Mark mutants that lie inside a type annotation as skipped (never evaluated)."""
    spans = []
    for node in ast.walk(ast.parse(source.read_text())):
        for annotation in _annotations(node):
            spans.append(
                (
                    (annotation.lineno, annotation.col_offset),
                    (annotation.end_lineno, annotation.end_col_offset),
                )
            )
    with sqlite3.connect(session) as db:
        rows = db.execute(
            "SELECT job_id, start_pos_row, start_pos_col, end_pos_row, end_pos_col "
            "FROM mutation_specs"
        ).fetchall()
        skipped = [
            (job,)
            for job, *pos in rows
            if any(a <= (pos[0], pos[1]) and (pos[2], pos[3]) <= b for a, b in spans)
        ]
        db.executemany(
            "INSERT OR REPLACE INTO work_results (worker_outcome, output, "
            "test_outcome, diff, job_id) VALUES ('SKIPPED', NULL, NULL, NULL, ?)",
            skipped,
        )


def _annotations(node: ast.AST) -> list[ast.expr]:
    """The annotation expressions a node holds (arguments, return, annotated assignment)."""
    if isinstance(node, ast.arg):
        return [node.annotation] if node.annotation else []
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
        return [node.returns] if node.returns else []
    if isinstance(node, ast.AnnAssign):
        return [node.annotation]
    return []


def _progress(session: Path) -> tuple[int, int]:
    with sqlite3.connect(session) as db:
        total = db.execute("SELECT COUNT(*) FROM work_items").fetchone()[0]
        done = db.execute("SELECT COUNT(*) FROM work_results").fetchone()[0]
    return done, total


def report(work: Path, names: list[str]) -> str:
    """A markdown table of the sessions in WORK; survivors go to WORK/NAME_survivors.md."""
    lines = [
        "| file | mutants | in annotations | not testable | killed | survived | pending | score |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name in names:
        session = work / f"{name}.sqlite"
        if not session.exists():
            continue
        with sqlite3.connect(session) as db:
            total = db.execute("SELECT COUNT(*) FROM work_items").fetchone()[0]
            outcomes = dict(
                db.execute(
                    "SELECT COALESCE(test_outcome, worker_outcome), COUNT(*) FROM work_results "
                    "GROUP BY 1"
                ).fetchall()
            )
            survivors = db.execute(
                "SELECT s.start_pos_row, s.operator_name, r.diff FROM work_results r "
                "JOIN mutation_specs s USING (job_id) WHERE r.test_outcome = 'SURVIVED' "
                "ORDER BY s.start_pos_row"
            ).fetchall()
        skipped, killed = outcomes.get("SKIPPED", 0), outcomes.get("KILLED", 0)
        survived = outcomes.get("SURVIVED", 0)
        untestable = sum(outcomes.values()) - skipped - killed - survived  # e.g. incompetent
        score = f"{100 * killed / (killed + survived):.1f}%" if killed + survived else "-"
        lines.append(
            f"| {CORE[name][0]} | {total} | {skipped} | {untestable} | {killed} "
            f"| {survived} | {total - sum(outcomes.values())} | {score} |"
        )
        (work / f"{name}_survivors.md").write_text(
            "".join(
                f"## line {row}: {operator}\n```diff\n{diff.strip()}\n```\n"
                for row, operator, diff in survivors
            )
        )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
