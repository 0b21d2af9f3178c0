"""docs/cli.md written from the `mogo` parsers themselves, every verb of every entry point
included, so the reference cannot drift from the command (tests/test_cli_reference.py). The
usage lines are spelt here, not by argparse's help formatter, whose layout changes between
Python versions.

    python -m mogo.cli_reference > docs/cli.md
"""

import argparse

from mogo.cli import build_parser

WIDTH = 100  # usage lines wrapped at a fixed width, whatever the terminal
HEADER = """# The `mogo` command

Every verb, its options and their help, generated from the parsers (do not edit by hand):

    python -m mogo.cli_reference > docs/cli.md

Some verbs need an extra: `train`, `export` and `bench latency` the `train` extra, `serve`
and `bench serve` the `serve` extra. Every bad input ends with one `mogo: error: ...` line and
exit status 2.
"""


def reference() -> str:
    """The whole command reference as markdown."""
    parser = build_parser()
    commands = list(_commands(parser))
    index = [
        f"- [`{name}`](#{name.replace(' ', '-')})" + (f": {summary}" if summary else "")
        for name, _, summary in commands
    ]
    sections = [_section(*command) for command in commands]
    old = [
        "## Old spellings",
        "",
        "They still run, with a note on stderr, until the next release.",
        "",
        "| old | now |",
        "|---|---|",
        *(f"| `{o.spelt()}` | `mogo {o.new}` |" for o in parser.old_spellings),
    ]
    return "\n".join([HEADER, *index, "", *sections, *old]).rstrip() + "\n"


def _commands(parser: argparse.ArgumentParser, summary: str = ""):
    """(prog, parser, its one-line help) for the parser and every subcommand under it."""
    yield parser.prog, parser, summary
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help for choice in action._choices_actions}
            for name, sub in action.choices.items():
                yield from _commands(sub, helps.get(name) or "")


def _section(name: str, parser: argparse.ArgumentParser, summary: str) -> str:
    actions = [
        a
        for a in parser._actions
        if a.help != argparse.SUPPRESS and not isinstance(a, argparse._HelpAction)
    ]
    lines = [f"## {name}", ""]
    if about := parser.description or summary:
        lines += [about, ""]
    lines += [
        "```text",
        *_wrapped(
            name,
            [_usage(a) for a in actions if a.option_strings]
            + [_usage(a) for a in actions if not a.option_strings],
        ),
        "```",
        "",
    ]
    rows = [
        f"| `{_spelling(a)}` | {_help(a, name)} |"
        for a in actions
        if not isinstance(a, argparse._SubParsersAction)
    ]
    if rows:
        lines += ["| argument | what it is |", "|---|---|", *rows, ""]
    return "\n".join(lines)


def _wrapped(name: str, parts: list[str]) -> list[str]:
    """`name parts...` in lines of at most WIDTH, never breaking a part, as argparse does."""
    lines = [name]
    for part in parts:
        if len(lines[-1]) + 1 + len(part) > WIDTH:
            lines.append(" " * len(name))
        lines[-1] += " " + part
    return lines


def _metavar(action: argparse.Action) -> str:
    if action.metavar is not None:
        return " ".join(action.metavar) if isinstance(action.metavar, tuple) else action.metavar
    if action.choices is not None:
        return "{" + ",".join(map(str, action.choices)) + "}"
    return action.dest if not action.option_strings else action.dest.upper()


def _values(action: argparse.Action) -> str:
    """What follows the option (or stands for the positional), by its nargs."""
    metavar = _metavar(action)
    return {
        None: metavar,
        "?": f"[{metavar}]",
        "*": f"[{metavar} ...]",
        "+": f"{metavar} [{metavar} ...]",
        argparse.REMAINDER: "...",
        argparse.PARSER: f"{metavar} ...",
    }.get(
        action.nargs, " ".join([metavar] * (action.nargs if isinstance(action.nargs, int) else 1))
    )


def _spelling(action: argparse.Action) -> str:
    values = _values(action) if action.nargs != 0 else ""
    if not action.option_strings:
        return values
    return ", ".join(action.option_strings) + (f" {values}" if values else "")


def _usage(action: argparse.Action) -> str:
    if not action.option_strings:
        return _values(action)
    values = f" {_values(action)}" if action.nargs != 0 else ""
    spelt = " | ".join(action.option_strings) if action.nargs == 0 else action.option_strings[0]
    return f"{spelt}{values}" if action.required else f"[{spelt}{values}]"


def _help(action: argparse.Action, prog: str) -> str:
    """The help as argparse shows it (its %-fields filled in), safe in a table cell."""
    if not action.help:
        return ""
    fields = dict(vars(action), prog=prog)
    if action.choices is not None:
        fields["choices"] = ", ".join(map(str, action.choices))
    return (action.help % fields).replace("|", "\\|")


if __name__ == "__main__":
    print(reference(), end="")
