"""docs/api.md stays true: every member of MotionGenerator and MotionStream is listed there as
public or shared inside mogo (a new one must be placed), every listed one exists, and no
module borrows another's private name beyond the page's list."""

import ast
import re
from pathlib import Path

import pytest

from mogo import MotionGenerator

ROOT = Path(__file__).resolve().parents[1]
PAGE = (ROOT / "docs" / "api.md").read_text()


def listed(section: str) -> dict[str, set[str]]:
    """kind -> member names, from the table under `## section`."""
    table = PAGE.split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| (public|shared inside mogo) \| (.*) \|$", table, re.M)
    return {kind: set(re.findall(r"`(\w+)`", members)) for kind, members in rows}


def members(thing) -> set[str]:
    return {name for name in [*dir(type(thing)), *vars(thing)] if not name.startswith("_")}


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


@pytest.mark.parametrize("section", ["MotionGenerator", "MotionStream"])
def test_every_member_is_placed_and_every_placed_one_exists(generator, section):
    thing = generator if section == "MotionGenerator" else generator.stream("a person walks")
    kinds = listed(section)
    placed = set().union(*kinds.values())
    assert not kinds["public"] & kinds["shared inside mogo"]
    assert not members(thing) - placed, f"docs/api.md: place {members(thing) - placed}"
    assert not placed - members(thing), f"docs/api.md lists {placed - members(thing)}"


def private_borrowings() -> set[tuple[str, str]]:
    """(module file, name): a private name defined in one mogo module and imported or reached
    for (other than on self or cls) in another."""
    trees = {
        p: ast.parse(p.read_text())
        for d in ("runtime", "export", "bench")
        for p in (ROOT / d).rglob("*.py")
    }
    defined = {
        p: {
            n.name
            for n in ast.walk(t)
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
        }
        | {
            x.id if isinstance(x, ast.Name) else x.attr
            for n in ast.walk(t)
            if isinstance(n, ast.Assign)
            for target in n.targets
            for x in ast.walk(target)
            if isinstance(x, (ast.Name, ast.Attribute))
        }
        for p, t in trees.items()
    }
    anywhere = set().union(*defined.values())
    found = set()
    for path, tree in trees.items():
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mogo"):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.Attribute) and not (
                isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")
            ):
                names = [node.attr]
            else:
                continue
            found |= {
                (path.relative_to(ROOT).as_posix(), name)
                for name in names
                if re.fullmatch(r"_[^_]\w*", name)
                and name in anywhere
                and name not in defined[path]
            }
    return found


def test_no_new_borrowing_of_a_private_name():
    table = PAGE.split("\n## Private names still borrowed across modules\n", 1)[1]
    listed = {name.rsplit(".", 1)[-1] for name in re.findall(r"^\| `([\w.]+)` \|", table, re.M)}
    allowed = {name for name in listed if name.startswith("_")}
    new = sorted(f"{path}: {name}" for path, name in private_borrowings() if name not in allowed)
    assert not new, f"name these (or list them in docs/api.md): {', '.join(new)}"
