"""Reading files that may be hostile (bundles, clips, mapping and motion files): JSON and .npy
with every size checked before anything is allocated, and each problem one ValueError line
naming the file, never numpy's or json's own words (docs/security.md)."""

from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path

import numpy as np

MAX_TEXT_BYTES = 256 * 2**20  # a JSON, BVH or prompts file read whole: larger is refused


def checked_finite(
    array: np.ndarray, where: str, error: type[Exception] = ValueError, why: str = ""
) -> np.ndarray:
    """`array`, or `error` saying that `where` (a file, or what the array is) holds NaN or
    infinite values: the one check, in one wording, of every array read or written."""
    if not np.all(np.isfinite(array)):
        raise error(f"{where}: holds NaN or infinite values{why}")
    return array


def read_text(path: str | os.PathLike, what: str = "file", max_bytes: int = MAX_TEXT_BYTES) -> str:
    """A text file read whole (undecodable bytes replaced), refused past `max_bytes` before it
    is all read (a device such as /dev/zero or a FIFO, that may never end, is refused)."""
    path = Path(path)
    try:
        with _open_file(path) as handle:
            data = handle.read(max_bytes + 1)
    except OSError as error:
        raise ValueError(f"{path}: cannot read it ({error.strerror or error})") from None
    if len(data) > max_bytes:
        raise ValueError(f"{path}: larger than {max_bytes // 2**20} MiB; not a {what}")
    return data.decode("utf-8-sig", errors="replace")


def parse_json(text: str, source: str) -> object:
    """Parsed JSON, or a ValueError "SOURCE: ..." in one line: not JSON (where), nested too
    deeply, or a number too long to read."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(
            f"{source}: not valid JSON (line {error.lineno}, column {error.colno}: {error.msg})"
        ) from None
    except RecursionError:
        raise ValueError(f"{source}: JSON nested too deeply") from None
    except ValueError:  # Python's limit on the digits of an integer
        raise ValueError(f"{source}: a number in the JSON is too long to read") from None


def read_json(path: str | os.PathLike, what: str = "JSON file") -> object:
    return parse_json(read_text(path, what), str(path))


def read_npy(path: str | os.PathLike) -> np.ndarray:
    """A .npy array file, without pickle: the header's shape and type are checked against the
    file's size before the array is allocated (a 1 KB file may claim 480 TiB)."""
    path = Path(path)
    fmt = np.lib.format
    try:
        with _open_file(path) as handle:
            if handle.read(len(fmt.MAGIC_PREFIX)) != fmt.MAGIC_PREFIX:
                raise ValueError(f"{path}: not a .npy array file")
            handle.seek(0)
            version = fmt.read_magic(handle)
            header = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}.get(
                version
            )
            if header is None:
                raise ValueError(
                    f"{path}: .npy format version {version[0]}.{version[1]}, expected 1.0 or 2.0"
                )
            shape, fortran, dtype = header(handle)
            if dtype.hasobject:
                raise ValueError(
                    f"{path}: holds Python objects, not numbers (never read: "
                    "that would run code from the file)"
                )
            claimed = math.prod(shape) * dtype.itemsize
            present = os.fstat(handle.fileno()).st_size - handle.tell()
            if claimed != present:
                raise ValueError(
                    f"{path}: its header claims an array of shape {shape} "
                    f"({claimed} bytes), the file holds {present} bytes"
                )
            handle.seek(0)
            return fmt.read_array(handle, allow_pickle=False)
    except OSError as error:
        raise ValueError(f"{path}: cannot read it ({error.strerror or error})") from None
    except (ValueError, EOFError, SyntaxError, TypeError) as error:
        if str(error).startswith(f"{path}: "):
            raise
        raise ValueError(f"{path}: not a plain .npy array (a damaged header)") from None


def _open_file(path: Path):
    """`path` open for reading if it is a regular file (a FIFO is not waited on); ValueError
    naming it otherwise."""
    descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    if not stat.S_ISREG(os.fstat(descriptor).st_mode):
        os.close(descriptor)
        raise ValueError(f"{path}: not a regular file")
    return os.fdopen(descriptor, "rb")
