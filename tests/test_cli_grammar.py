"""One grammar: `mogo bench WHAT` and `mogo export KIND`. Every old spelling still runs for a
release: it reaches the same verb with the same options as its new spelling, and says so in
one note on stderr. Each pair below runs to a bad input the verb itself refuses, so the verb
runs, in seconds."""

import pytest

from mogo.cli import build_parser, main
from mogo.cli_flags import current_spelling

MISSING = "/nonexistent/mogo"
OLD_AND_NEW = [
    ("bench --quick --threads 0", "bench quick --threads 0"),
    ("bench --smoke --threads 0", "bench latency --smoke --threads 0"),
    ("bench-serve --clients 0", "bench serve --clients 0"),
    ("long-streams --switches -1", "bench long-streams --switches -1"),
    (
        f"eval {MISSING} --data {MISSING} --evaluator {MISSING}",
        f"bench eval {MISSING} --data {MISSING} --evaluator {MISSING}",
    ),
    (f"real-motion {MISSING}", f"bench real-motion {MISSING}"),
    (
        f"export --portable --bundle {MISSING} --out OUT",
        f"export portable --bundle {MISSING} --out OUT",
    ),
    (
        f"export --text {MISSING} --bundle {MISSING} --out OUT",
        f"export text --text {MISSING} --bundle {MISSING} --out OUT",
    ),
    (
        f"export --vq {MISSING} --bundle {MISSING} --out OUT",
        f"export decoder --vq {MISSING} --bundle {MISSING} --out OUT",
    ),
    (
        f"export --vq {MISSING} --t2m {MISSING} --out OUT",
        f"export bundle --vq {MISSING} --t2m {MISSING} --out OUT",
    ),
]


def spelt(line: str, tmp_path) -> list[str]:
    return line.replace("OUT", str(tmp_path / "out")).split()


@pytest.mark.parametrize("old,new", OLD_AND_NEW, ids=[old for old, _ in OLD_AND_NEW])
def test_an_old_spelling_runs_as_its_new_one_with_a_note(old, new, tmp_path, capsys):
    assert main(spelt(new, tmp_path)) == 2
    refused = capsys.readouterr().err.splitlines()
    assert len(refused) == 1 and refused[0].startswith("mogo: error: ")
    assert main(spelt(old, tmp_path)) == 2
    note, *rest = capsys.readouterr().err.splitlines()
    assert (
        note.startswith("mogo: note: `mogo ")
        and f"is now `mogo {' '.join(new.split()[:2])}`;" in note
    )
    assert rest == refused
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("old,new", OLD_AND_NEW, ids=[old for old, _ in OLD_AND_NEW])
def test_an_old_spelling_parses_to_the_same_options(old, new, tmp_path, capsys):
    parser = build_parser()
    old_args = parser.parse_args(current_spelling(spelt(old, tmp_path), parser.old_spellings))
    assert vars(old_args) == vars(parser.parse_args(spelt(new, tmp_path)))


def test_every_old_spelling_is_tested(capsys):
    parser = build_parser()
    tested = {
        next(o for o in parser.old_spellings if o.rewrite(old.split()) is not None)
        for old, _ in OLD_AND_NEW
    }
    assert tested == set(parser.old_spellings)


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "--help"],
        ["bench", "latency", "--smoke"],
        ["export"],
        ["export", "portable"],
        ["generate"],
    ],
)
def test_todays_spellings_are_left_alone(argv, capsys):
    assert current_spelling(argv, build_parser().old_spellings) == argv
    assert capsys.readouterr().err == ""


def test_the_top_help_shows_one_grammar(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    verbs = capsys.readouterr().out
    assert "bench" in verbs and "export" in verbs
    assert not {"bench-serve", "long-streams", "real-motion", "eval "} & set(verbs.split())


def test_bench_alone_still_runs_the_latency_bench_with_a_note(capsys):
    assert current_spelling(["bench"], build_parser().old_spellings) == ["bench", "latency"]
    assert "`mogo bench` is now `mogo bench latency`" in capsys.readouterr().err
