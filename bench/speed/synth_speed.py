"""How fast `mogo data synth` makes clips: `python -m mogo.bench.speed.synth_speed --clips 500`.

Prints a markdown table with the projected time for the default 20,000-clip corpus.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from mogo.export.data.corpus import synthesize_corpus

FULL_CORPUS = 20_000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=500)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    print("| clips | workers | seconds | clips/s | projected minutes for 20,000 |")
    print("|---:|---:|---:|---:|---:|")
    for workers in args.workers:
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            synthesize_corpus(Path(tmp) / "corpus", args.clips, args.seed, progress=False,
                              workers=workers)
            seconds = time.perf_counter() - start
        rate = args.clips / seconds
        print(f"| {args.clips} | {workers} | {seconds:.1f} | {rate:.1f} | "
              f"{FULL_CORPUS / rate / 60:.1f} |", flush=True)


if __name__ == "__main__":
    main()
