"""`mogo blender-addon`: the Blender add-on shipped in this package (runtime/blender/addon,
package data that the runtime itself never imports) as the zip Blender installs (Preferences >
Add-ons > Install), its files under the add-on's folder name, byte-identical for the same
sources.

The zip carries this runtime as a wheel, which the add-on's Install hands to pip: a user gets
this project, never PyPI's unrelated `mogo`, and needs no source tree. The wheel is written
from the installed package's own files (pip's wheel build needs the source tree and a build
backend, which an installed runtime does not have)."""

from __future__ import annotations

import base64
import errno
import hashlib
import io
import os
import zipfile
from dataclasses import fields
from importlib.metadata import requires, version
from pathlib import Path

from mogo import files
from mogo.cli import DISTRIBUTION
from mogo.sampling import Sampling

PACKAGE = Path(__file__).resolve().parents[1]  # the runtime, `mogo`
SOURCE = Path(__file__).resolve().parent / "addon"
FOLDER = "mogo_blender"  # the add-on's module name inside Blender
GENERATED = "sampling.py"  # the add-on module this writes into the zip (sampling_module)
# not the Python runtime: mogo.export and mogo.bench (torch's side), the JavaScript port (web)
NOT_RUNTIME = {"export", "bench", "web", "__pycache__"}
_EPOCH = (1980, 1, 1, 0, 0, 0)  # zip's earliest date: the same bytes on every build


def addon_bytes() -> bytes:
    """The zip's bytes: every .py of the add-on, sorted, its sampling.py (written here from
    Sampling) and the runtime's wheel, with a fixed date."""
    sources = sorted(SOURCE.glob("*.py"))
    if not sources:
        raise FileNotFoundError(
            errno.ENOENT, "the Blender add-on is missing from this install", str(SOURCE)
        )
    wheel_name, wheel = runtime_wheel()
    return _zip(
        [(f"{FOLDER}/{path.name}", path.read_bytes()) for path in sources]
        + [(f"{FOLDER}/{GENERATED}", sampling_module().encode()), (f"{FOLDER}/{wheel_name}", wheel)]
    )


def sampling_module() -> str:
    """The add-on's sampling.py: each option of mogo.sampling.Sampling with its type, default,
    limits and help. The panel registers before the runtime is installed, so it cannot import
    Sampling; this is Sampling written out, never a copy kept by hand."""
    options = [
        (f.name, type(f.default).__name__, f.default, f.metadata["low"], f.metadata["high"])
        + (f.metadata["help"],)
        for f in fields(Sampling)
    ]
    rows = "".join(f"    {option!r},\n" for option in options)
    return (
        '"""Written by `mogo blender-addon` from mogo.sampling.Sampling: (name, type, default, '
        'low, high, help)\nof each sampling option."""\n\nOPTIONS = (\n' + rows + ")\n"
    )


def runtime_wheel() -> tuple[str, bytes]:
    """This runtime as a wheel (file name, bytes): the `mogo` package without NOT_RUNTIME,
    and the base install's requirements, so that pip installs it anywhere."""
    release = version(DISTRIBUTION)
    stem = f"{DISTRIBUTION.replace('-', '_')}-{release}"
    entries = [
        (f"mogo/{path.relative_to(PACKAGE).as_posix()}", path.read_bytes())
        for path in sorted(PACKAGE.rglob("*"))
        if path.is_file()
        and path.suffix != ".pyc"
        and not NOT_RUNTIME & set(path.relative_to(PACKAGE).parts)
    ]
    base = [line for line in requires(DISTRIBUTION) or [] if "extra ==" not in line]
    metadata = "".join(
        [f"Metadata-Version: 2.1\nName: {DISTRIBUTION}\nVersion: {release}\n"]
        + [f"Requires-Dist: {line}\n" for line in base]
    )
    entries += [
        (f"{stem}.dist-info/METADATA", metadata.encode()),
        (
            f"{stem}.dist-info/WHEEL",
            b"Wheel-Version: 1.0\nGenerator: mogo blender-addon"
            b"\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
        ),
    ]
    record = "".join(f"{name},sha256={_digest(data)},{len(data)}\n" for name, data in entries)
    entries.append((f"{stem}.dist-info/RECORD", f"{record}{stem}.dist-info/RECORD,,\n".encode()))
    return f"{stem}-py3-none-any.whl", _zip(entries)


def _digest(data: bytes) -> str:
    return base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def _zip(entries: list[tuple[str, bytes]]) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in entries:
            entry = zipfile.ZipInfo(name, _EPOCH)
            entry.external_attr = 0o644 << 16
            entry.compress_type = (
                zipfile.ZIP_STORED if name.endswith(".whl") else zipfile.ZIP_DEFLATED
            )  # a wheel is deflated already
            archive.writestr(entry, data)
    return buffer.getvalue()


def write_addon(path: str | os.PathLike, overwrite: bool = False) -> Path:
    """Write the add-on zip whole at `path`; an existing file is kept unless `overwrite`."""
    path = Path(path)
    if path.suffix.lower() != ".zip":
        raise ValueError(f"the add-on file must end in .zip (Blender installs zips), got {path}")
    if os.path.lexists(path) and not overwrite:
        raise FileExistsError(errno.EEXIST, "exists (--overwrite replaces it)", str(path))
    files.check_replaceable([path])
    data = addon_bytes()
    return files.write_all(
        [lambda temporary: temporary.write_bytes(data)], iter([[path]]), replace=overwrite
    )[0]
