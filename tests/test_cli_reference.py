"""docs/cli.md is the parsers' own reference: regenerated here and compared with the committed
page, so a changed option without a regenerated page fails, saying how to regenerate it."""

from pathlib import Path

from mogo.cli_reference import reference

PAGE = Path(__file__).resolve().parents[1] / "docs" / "cli.md"


def test_docs_cli_md_is_what_the_parsers_say():
    assert PAGE.read_text() == reference(), (
        "docs/cli.md is stale: regenerate it with `python -m mogo.cli_reference > docs/cli.md`"
    )


def test_every_verb_has_its_section_the_entry_points_too():
    page = reference()
    for verb in (
        "generate",
        "stream",
        "info",
        "data convert",
        "train vq",
        "export bundle",
        "export portable",
        "bench latency",
        "bench eval",
        "serve",
    ):
        assert f"\n## mogo {verb}\n" in page, verb
    assert "| `--bvh-names {mixamo,smpl}` | BVH (and GLB) joint names" in page
