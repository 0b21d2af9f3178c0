"""No function of the code folders is longer than MAX_LINES (its decorators and docstring
included): a longer one is split into named steps. Tests are exempt (a table of cases may be
long)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("runtime", "export", "bench", "examples")
MAX_LINES = 60


def long_functions() -> dict[str, int]:
    """'path:name' -> lines, for every function over MAX_LINES."""
    found = {}
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    start = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                    lines = node.end_lineno - start + 1
                    if lines > MAX_LINES:
                        found[f"{path.relative_to(ROOT).as_posix()}:{node.name}"] = lines
    return found


def test_no_function_is_longer_than_60_lines():
    too_long = long_functions()
    assert not too_long, f"split these (lines): {too_long}"
