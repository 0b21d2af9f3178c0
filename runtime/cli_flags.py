"""The `mogo` grammar's shared parts, in one place: the flags several verbs take (declared here,
each verb naming only its own meaning), and the old spellings that still run for a release
with a note. The verbs of mogo.export, mogo.bench and mogo.serve use these too."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

BUNDLE_HELP = "bundle folder (default: the model shipped with mogo)"


def add_bundle(parser: argparse.ArgumentParser, help: str = BUNDLE_HELP, **options) -> None:
    """--bundle: a bundle folder (a verb that makes one from another passes required=True)."""
    parser.add_argument("--bundle", help=help, **options)


def add_bundle_argument(parser: argparse.ArgumentParser) -> None:
    """The bundle as the optional positional of the verbs that only read one (info, eval)."""
    parser.add_argument("bundle", nargs="?", help="bundle folder (default: the shipped one)")


def add_out(parser: argparse.ArgumentParser, what: str, default: str | None = None) -> None:
    """--out: where the verb writes `what`; required where there is no default."""
    parser.add_argument(
        "--out",
        default=default,
        required=default is None,
        help=what if default is None else f"{what} (default {default})",
    )


def add_threads(parser: argparse.ArgumentParser, help: str, **options) -> None:
    """--threads: how many cores (or, for a bench, the counts it tries)."""
    parser.add_argument("--threads", type=int, help=help, **options)


def add_overwrite(parser: argparse.ArgumentParser, help: str = "replace an existing file") -> None:
    parser.add_argument("--overwrite", action="store_true", help=help)


@dataclass(frozen=True)
class OldSpelling:
    """`mogo VERB [FLAG] ...`, now `mogo NEW ...`: the rest of the line is kept (FLAG dropped
    where `drop`). A VERB that is still a verb (bench, export) matches where a flag follows
    it, and alone only where `alone` (`mogo bench` ran the latency bench); with a subverb it
    is today's spelling."""

    verb: str
    new: str
    flag: str | None = None
    drop: bool = False
    alone: bool = False

    def spelt(self) -> str:
        return " ".join(filter(None, ["mogo", self.verb, self.flag]))

    def rewrite(self, argv: list[str]) -> list[str] | None:
        """Today's spelling of argv, or None where this old spelling is not it."""
        rest = argv[1:]
        if argv[:1] != [self.verb] or rest[:1] in (["-h"], ["--help"]):
            return None
        still_a_verb = self.verb == self.new.split()[0]
        if still_a_verb and not (rest[0].startswith("-") if rest else self.alone):
            return None
        given = [a for a in rest if a == self.flag or a.startswith(f"{self.flag}=")]
        if self.flag is not None and not given:
            return None
        return [*self.new.split(), *(a for a in rest if not (self.drop and a in given))]


def current_spelling(argv: list[str], old_spellings: tuple[OldSpelling, ...]) -> list[str]:
    """argv in today's grammar; an old spelling is rewritten with one note on stderr."""
    for old in old_spellings:
        if (new := old.rewrite(argv)) is not None:
            print(
                f"mogo: note: `{old.spelt()}` is now `mogo {old.new}`; the old spelling goes "
                "in the next release",
                file=sys.stderr,
            )
            return new
    return argv
