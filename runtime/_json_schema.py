"""JSON <-> frozen dataclasses, checked: the reader behind mogo.manifest. `read` turns parsed
JSON into a dataclass type (fields typed int, float, str, bool, X | None, tuple[...], dict[str,
...] and nested dataclasses), refusing unknown keys, missing keys, wrong types and non-finite
numbers with a KeyProblem that names the key path; `write` is its inverse."""

from __future__ import annotations

import dataclasses
import math
import types
import typing


class KeyProblem(Exception):
    """What is wrong at `path`, a key path like t2m.levels[2].file."""

    def __init__(self, path: str, what: str):
        super().__init__(f"{path}: {what}")
        self.path, self.what = path, what


_NAMES = {
    int: "an integer",
    float: "a number",
    str: "a string",
    bool: "true or false",
    dict: "an object",
    list: "a list",
}


def read(kind, value, path: str):
    """`value` (parsed JSON) as `kind` (a type of the schema), or KeyProblem at `path`."""
    args = typing.get_args(kind)
    if typing.get_origin(kind) in (typing.Union, types.UnionType):  # X | None
        if value is None:
            return None
        return read(next(a for a in args if a is not type(None)), value, path)
    if dataclasses.is_dataclass(kind):
        return _read_object(kind, _expect(value, dict, path), path)
    if typing.get_origin(kind) is tuple:
        items = _expect(value, list, path)
        if Ellipsis not in args and len(items) != len(args):
            raise KeyProblem(path, f"{len(items)} items, expected {len(args)}")
        item_kinds = [args[0]] * len(items) if Ellipsis in args else args
        return tuple(
            read(k, v, f"{path}[{i}]")
            for i, (k, v) in enumerate(zip(item_kinds, items, strict=False))
        )
    if typing.get_origin(kind) is dict:
        return {
            key: read(args[1], v, f"{path}.{key}") for key, v in _expect(value, dict, path).items()
        }
    if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(min(abs(value), math.inf)):  # NaN, Infinity (JSON allows them)
            raise KeyProblem(path, f"expected a finite number, got {value!r}")
        return float(value)
    return _expect(value, kind, path)


def _read_object(cls, value: dict, path: str):
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in dataclasses.fields(cls)}
    for key in value:
        if key not in known:
            raise KeyProblem(_join(path, key), "unknown key")
    values = {}
    for name, f in known.items():
        if name in value:
            values[name] = read(hints[name], value[name], _join(path, name))
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise KeyProblem(_join(path, name), "missing")
    return cls(**values)


def _expect(value, kind, path: str):
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise KeyProblem(path, f"expected {_NAMES.get(kind, kind.__name__)}, got {value!r}")
    return value


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def write(value):
    """A schema object as plain JSON values; a None field with a None default is left out."""
    if dataclasses.is_dataclass(value):
        return {
            f.name: write(getattr(value, f.name))
            for f in dataclasses.fields(value)
            if not (getattr(value, f.name) is None and f.default is None)
        }
    if isinstance(value, (tuple, list)):
        return [write(v) for v in value]
    if isinstance(value, dict):
        return {key: write(v) for key, v in value.items()}
    return value
