"""`mogo blender-addon`: the Blender add-on shipped in this package (runtime/blender_addon, package
data that the runtime itself never imports) as the zip Blender installs (Preferences > Add-ons >
Install), its files under the add-on's folder name, byte-identical for the same sources."""
from __future__ import annotations

import errno
import io
import os
import zipfile
from pathlib import Path

from mogo import files

SOURCE = Path(__file__).resolve().parent / "blender_addon"
FOLDER = "mogo_blender"  # the add-on's module name inside Blender
_EPOCH = (1980, 1, 1, 0, 0, 0)  # zip's earliest date: the same bytes on every build


def addon_bytes() -> bytes:
    """The zip's bytes: every .py of the add-on, sorted, with a fixed date."""
    sources = sorted(SOURCE.glob("*.py"))
    if not sources:
        raise FileNotFoundError(errno.ENOENT, "the Blender add-on is missing from this install",
                                str(SOURCE))
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for path in sources:
            entry = zipfile.ZipInfo(f"{FOLDER}/{path.name}", _EPOCH)
            entry.compress_type, entry.external_attr = zipfile.ZIP_DEFLATED, 0o644 << 16
            archive.writestr(entry, path.read_bytes())
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
    return files.write_all([lambda temporary: temporary.write_bytes(data)], iter([[path]]),
                           replace=overwrite)[0]
