"""How fast `mogo data synth` makes clips, and how big they are:
`python -m mogo.bench.speed.synth_speed --clips 500 [--corpus v1 v2]`.

Prints a markdown table with the projected time and size of the default 20,000-clip corpus.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from mogo.export.data.animator import CORPORA, DEFAULT_CORPUS
from mogo.export.data.corpus import synthesize_corpus

FULL_CORPUS = 20_000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=500)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--corpus", nargs="+", choices=sorted(CORPORA), default=[DEFAULT_CORPUS])
    args = parser.parse_args()

    print(
        "| corpus | clips | workers | seconds | clips/s | projected minutes for 20,000 | "
        "projected GB for 20,000 |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for corpus in args.corpus:
        for workers in args.workers:
            with tempfile.TemporaryDirectory() as tmp:
                start = time.perf_counter()
                synthesize_corpus(
                    Path(tmp) / "corpus",
                    args.clips,
                    args.seed,
                    progress=False,
                    workers=workers,
                    corpus=corpus,
                )
                seconds = time.perf_counter() - start
                size = sum(p.stat().st_size for p in Path(tmp).rglob("*") if p.is_file())
            rate = args.clips / seconds
            print(
                f"| {corpus} | {args.clips} | {workers} | {seconds:.1f} | {rate:.1f} | "
                f"{FULL_CORPUS / rate / 60:.1f} | {size * FULL_CORPUS / args.clips / 1e9:.2f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
