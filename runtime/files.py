"""Files written whole: each to a temporary file beside it, then renamed into place, and a set
of files (the .bvh .gif .npy .json of one take) renamed together. A crash, a full disk,
Ctrl-C, SIGTERM or SIGHUP thus leaves the old files or the new ones, never half a file nor a mix
of two sets; writers of one folder take turns at the renames (a lock on the folder), so two
takes written at once over the same name never mix either. Only regular files are replaced:
never a symbolic link, a device, a FIFO or a socket (docs/security.md, "Files").

A writer is a function that writes one file's content to the path it is given (a temporary
name, so it must not go by the name's suffix)."""

from __future__ import annotations

import contextlib
import errno
import itertools
import os
import secrets
import signal
import stat
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: no folder lock (its renames never replace an open file anyway)
    fcntl = None

Writer = Callable[[Path], None]
NUMBERING_ROOM = len("-999")  # the bytes a name keeps free for numbered takes
HELD_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)  # delivered after the renames, not inside


def check_folder(folder: str | os.PathLike) -> Path:
    """The folder, checked before any work is done for it: one that takes files, or a missing
    one whose nearest existing parent does (nothing is created here)."""
    folder = Path(folder)
    existing = _nearest_existing(folder)
    made = "" if existing == folder else f" (so {folder} cannot be made in it)"
    if os.path.islink(existing) and not existing.exists():
        raise FileNotFoundError(
            errno.ENOENT,
            f"a symbolic link that leads nowhere (a loop or a missing target){made}",
            str(existing),
        )
    if not existing.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, f"not a folder{made}", str(existing))
    if not os.access(existing, os.W_OK | os.X_OK):
        raise PermissionError(errno.EACCES, f"the folder is not writable{made}", str(existing))
    longest = _name_max(existing)
    for part in folder.relative_to(existing).parts if existing != folder else ():
        if len(os.fsencode(part)) > longest:
            raise OSError(
                errno.ENAMETOOLONG, f"a folder name longer than {longest} bytes", str(folder)
            )
    return folder


def check_name(name: str, folder: Path, suffixes: Sequence[str], what: str = "name") -> None:
    """A ValueError unless `name` is a plain file name that stays inside `folder` and fits its
    file system with each suffix (and a number, see numbered)."""
    if not isinstance(name, str):
        raise TypeError(f"{what} must be a string, got {type(name).__name__}")
    if name in ("", ".", "..") or any(c in name for c in {"/", os.sep, os.altsep or "/", "\0"}):
        raise ValueError(
            f"{what} must be a file name, without a folder: not empty, '.', '..' "
            f"nor with '/' in it, got {name!r}"
        )
    if not name.isprintable():  # controls, bidi overrides, zero-width, lone surrogates
        raise ValueError(
            f"{what} must be a file name without control, invisible or "
            f"bidirectional characters (they hide what a name says), got {name!r}"
        )
    room = _name_max(folder) - max(len(s) for s in suffixes) - NUMBERING_ROOM
    size = len(os.fsencode(name))
    if size > room:
        raise ValueError(f"{what} is too long: {size} bytes, at most {room} in {folder}")


def check_replaceable(paths: Iterable[Path]) -> None:
    """An OSError naming the path where something other than a regular file has the name a
    file is to replace: a folder (IsADirectoryError), a symbolic link, a device, a FIFO or a
    socket (FileExistsError). Renaming over them would replace the link or the node itself."""
    for path in paths:
        try:
            mode = os.lstat(path).st_mode
        except FileNotFoundError:
            continue
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(errno.EISDIR, "a folder is in the way of this file", str(path))
        if not stat.S_ISREG(mode):
            raise FileExistsError(
                errno.EEXIST,
                f"{_KINDS.get(stat.S_IFMT(mode), 'not a file')} "
                "is in the way of this file; only regular files are replaced",
                str(path),
            )


_KINDS = {
    stat.S_IFLNK: "a symbolic link",
    stat.S_IFCHR: "a device",
    stat.S_IFBLK: "a device",
    stat.S_IFIFO: "a FIFO",
    stat.S_IFSOCK: "a socket",
}


def numbered(folder: Path, name: str, suffixes: Sequence[str]) -> Iterator[list[Path]]:
    """The paths of name, name-2, name-3, ... (each with every suffix) where none is taken."""
    for number in itertools.count(1):
        stem = name if number == 1 else f"{name}-{number}"
        paths = [folder / (stem + suffix) for suffix in suffixes]
        if not any(os.path.lexists(path) for path in paths):
            yield paths


def write_all(
    writers: Sequence[Writer], candidates: Iterable[Sequence[Path]], replace: bool
) -> list[Path]:
    """Each writer's file, all or none, under the first candidate list of paths (one path per
    writer, all in one folder): with replace, over the files there; without, where none
    exists, going on to the next list should another program take a name meanwhile."""
    candidates = iter(candidates)
    paths = list(next(candidates))
    folder = check_folder(paths[0].parent)
    if replace:
        check_replaceable(paths)  # before the work, and again as the files are replaced
    folder.mkdir(parents=True, exist_ok=True)
    with _temporaries(folder, len(writers)) as temporaries:
        for write, temporary, path in zip(writers, temporaries, paths, strict=False):
            try:
                write(temporary)
                _fsync(temporary)
            except OSError as error:  # named by the file the user asked for
                raise (
                    OSError(error.errno, error.strerror, str(path)) if error.errno else error
                ) from None
        with _folder_lock(folder), _interrupts_held():  # the temporaries gone before a signal
            while True:
                try:
                    _rename_all(temporaries, paths, replace)
                    break
                except FileExistsError:
                    if replace:
                        raise
                    paths = list(next(candidates))
            _remove(temporaries)
        return paths


def _rename_all(temporaries: Sequence[Path], paths: Sequence[Path], replace: bool) -> None:
    """Each temporary renamed onto its path, all or none: with replace, the old files are
    moved aside first and put back should a rename fail (signals are held by the caller)."""
    if replace:
        check_replaceable(paths)
    aside, placed = [], []
    try:
        for temporary, path in zip(temporaries, paths, strict=False):
            if replace and os.path.lexists(path):
                aside.append((_new_name(path.parent, ".old"), path))
                os.replace(path, aside[-1][0])
            _place(temporary, path)
            placed.append((temporary, path))
    except BaseException:
        for temporary, path in reversed(placed):
            os.replace(path, temporary)
        for old, path in reversed(aside):
            os.replace(old, path)
        raise
    for old, _ in aside:
        os.unlink(old)


def _place(temporary: Path, path: Path) -> None:
    """Give the temporary file the name `path`, never replacing a file there
    (FileExistsError). It keeps its temporary name too, so that a failure can undo this."""
    try:
        os.link(temporary, path)
    except FileExistsError:
        raise
    except OSError:  # a file system without hard links: check, then rename
        if os.path.lexists(path):
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(path)) from None
        os.rename(temporary, path)


@contextlib.contextmanager
def _temporaries(folder: Path, count: int) -> Iterator[list[Path]]:
    """`count` new empty files in `folder`, hidden, removed on the way out, however it goes
    (after the renames they are only a second name of the files written)."""
    temporaries: list[Path] = []
    try:
        with _interrupts_held():
            for _ in range(count):
                temporaries.append(_new_name(folder, ".tmp"))
                os.close(os.open(temporaries[-1], os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        yield temporaries
    finally:
        with _interrupts_held():
            _remove(temporaries)


def _remove(temporaries: Sequence[Path]) -> None:
    for temporary in temporaries:
        with contextlib.suppress(OSError):
            temporary.unlink()


@contextlib.contextmanager
def _folder_lock(folder: Path) -> Iterator[None]:
    """An exclusive lock on the folder itself (flock on its descriptor: no lock file to leave
    behind), so that the renames of two writers never interleave. Where the file system has
    no such locks (some network ones), the renames go on unlocked."""
    if fcntl is None:
        yield
        return
    descriptor = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX)
        except OSError as error:
            if error.errno not in (errno.ENOLCK, errno.EBADF, errno.EOPNOTSUPP, errno.EINVAL):
                raise
        yield
    finally:
        os.close(descriptor)  # releases the lock


@contextlib.contextmanager
def _interrupts_held() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP delivered after the block rather than inside it (main
    thread only). The `mogo` command turns SIGTERM and SIGHUP into an exit that runs every
    cleanup (mogo.cli), so temporaries are removed then too."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = {}
    for number in HELD_SIGNALS:
        handler = signal.getsignal(number)
        if handler is not None and handler is not signal.SIG_IGN:
            previous[number] = signal.signal(number, lambda n, _: received.append(n))
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        for number in dict.fromkeys(received):
            signal.raise_signal(number)


def _new_name(folder: Path, suffix: str) -> Path:
    return folder / f".mogo-{secrets.token_hex(6)}{suffix}"


def _fsync(path: Path) -> None:
    """The file's content on the disk before its rename is (a crash keeps old or new)."""
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def _nearest_existing(path: Path) -> Path:
    """The path itself or its nearest parent that is there (a link that leads nowhere too)."""
    while not os.path.lexists(path) and path != path.parent:
        path = path.parent
    return path


def _name_max(folder: Path) -> int:
    """The longest file name, in bytes, the folder's file system takes."""
    try:
        return os.pathconf(_nearest_existing(folder), "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):  # no pathconf (Windows) or no answer
        return 255
