"""docs/layout.md stays true: every module of the code folders and examples/ has its line
(tests/ is listed by folder), and every file it lists exists."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LISTED_BY_FILE = ("runtime", "export", "bench", "examples")
DESCRIPTION_COLUMN = 25  # the tree's names stay left of it; longer descriptions wrap to it


def listed_paths() -> set[str]:
    """The paths of the tree in layout.md's code block, folders nested by indentation."""
    tree = (ROOT / "docs" / "layout.md").read_text().split("```\n")[1]
    folders: list[tuple[int, str]] = []
    paths = set()
    for line in tree.splitlines():
        entry = re.match(r"( *)(\S+)", line)
        if entry is None or len(entry[1]) >= DESCRIPTION_COLUMN:
            continue
        indent, name = len(entry[1]), entry[2]
        while folders and folders[-1][0] >= indent:
            folders.pop()
        paths.add("".join(folder for _, folder in folders) + name)
        if name.endswith("/"):
            folders.append((indent, name))
    return paths


def test_every_module_has_its_line():
    listed = listed_paths()
    modules = {
        path.relative_to(ROOT).as_posix()
        for folder in LISTED_BY_FILE
        for path in (ROOT / folder).rglob("*.py")
        if "__pycache__" not in path.parts
    }
    # a package's __init__ is listed where it holds more than the package (the API, bl_info)
    missing = sorted(
        m
        for m in modules - listed
        if not (m.endswith("/__init__.py") and f"{m.rsplit('/', 1)[0]}/" in listed)
    )
    assert not missing, f"docs/layout.md has no line for {', '.join(missing)}"


def test_every_listed_file_exists():
    gone = sorted(p for p in listed_paths() if p.endswith(".py") and not (ROOT / p).exists())
    assert not gone, f"docs/layout.md lists {', '.join(gone)}, which are not there"
