"""Writing files so that a fault loses nothing: a file appears under its name only complete.

Each writer writes a temporary file beside the target (``.<name>.<random>.partial``, created
exclusively, so a file or link planted there is never followed) and renames it; on any
failure, Ctrl-C or SIGTERM included, the temporary file is removed.

Nothing is written through a symbolic link under an output folder. :func:`folder` makes (or
takes) the folder a command writes into, the one the user named; below it, every folder a
writer makes or enters is checked and a link is refused with one line, whichever writer it is
(:func:`atomic` checks the target's folders, :func:`folder` the folders it makes). A link the
user named as the output folder itself is theirs, and is used.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from furuta_cosim.errors import ConfigError



@contextmanager
def atomic(path: str | Path) -> Iterator[Path]:
    """``with atomic(target) as partial:`` write ``partial``; it becomes ``target`` at the end."""
    path = Path(path)
    _make(path.parent)
    # named before it exists, so that an interruption at any point still removes it; created
    # exclusively under a name no one can guess, so nothing planted there is ever followed
    partial = path.with_name(f".{path.name}.{secrets.token_hex(8)}.partial")
    try:
        os.close(os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0),
                         0o666))
        try:
            yield partial
        except OSError as error:  # a full disk names no file: name the one being written
            if error.filename in (None, str(partial), partial):
                raise named(error, path) from None
            raise
        os.replace(partial, path)  # replaces a link at ``path`` itself, never its target
    finally:
        partial.unlink(missing_ok=True)


_ROOTS: set[Path] = set()  # the output folders of this process: links below them are refused


def folder(path: str | Path, *, root: bool = False) -> Path:
    """Make ``path`` (and its parents) if needed and return it. With ``root``, ``path`` is an
    output folder the user named: what is below it is checked by every writer. Otherwise the
    folders from the nearest output folder down to ``path`` must not be links.

    Parameters
    ----------
    path : path
        The folder.
    root : bool, optional
        Register ``path`` as an output folder.

    Raises
    ------
    ConfigError
        When a folder on the way is a symbolic link, or not a folder.
    """
    path = Path(path)
    if root:
        _ROOTS.add(Path(os.path.abspath(path)))
    _make(path)
    return path


def _make(path: Path) -> None:
    absolute = Path(os.path.abspath(path))
    roots = [r for r in _ROOTS if absolute == r or r in absolute.parents]
    if roots:
        probe = max(roots, key=lambda r: len(r.parts))
        probe.mkdir(parents=True, exist_ok=True)
        for part in absolute.relative_to(probe).parts:
            probe = probe / part
            if probe.is_symlink():
                raise ConfigError([f"{probe}: is a symbolic link; nothing is written through a link "
                                   "under an output folder (remove it, or choose another folder)"])
            try:
                probe.mkdir(exist_ok=True)
            except FileExistsError:
                raise ConfigError([f"{probe}: exists and is not a folder"]) from None
    else:
        path.mkdir(parents=True, exist_ok=True)


def named(error: OSError, path: str | Path) -> OSError:
    """``error`` as the same OSError about ``path`` (the CLI prints its file name)."""
    return OSError(error.errno, error.strerror or str(error), str(path))


def write_text(path: str | Path, text: str) -> Path:
    with atomic(path) as partial:
        partial.write_text(text)
    return Path(path)


def write_bytes(path: str | Path, data: bytes) -> Path:
    with atomic(path) as partial:
        partial.write_bytes(data)
    return Path(path)


def copy(source: str | Path, path: str | Path) -> Path:
    with atomic(path) as partial:
        shutil.copyfile(source, partial)
    return Path(path)


def output_file(path: str | Path, flag: str = "output") -> Path:
    """Check before any work that ``path`` can be written as a file: one line otherwise."""
    path = Path(path)
    if path.is_symlink():
        raise ConfigError([f"{flag} {path}: {path.name} is a symbolic link; nothing is written "
                           "through a link (remove it, or name another file)"])
    if path.is_dir():
        raise ConfigError([f"{flag} {path}: is a folder; name a file"])
    writable_folder(path.parent, flag, path)
    _ROOTS.add(Path(os.path.abspath(path.parent)))
    return path


def output_folder(path: str | Path, flag: str = "output") -> Path:
    """Check before any work that ``path`` can be used as an output folder."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError([f"{flag} {path}: exists and is not a folder"])
    writable_folder(path, flag, path)
    links = _links_below(path) if path.is_dir() else []
    if links:
        raise ConfigError([f"{flag} {path}: {link} is a symbolic link; nothing is written through "
                           "a link under an output folder (remove it, or choose another folder)"
                           for link in links[:10]])
    _ROOTS.add(Path(os.path.abspath(path)))
    return path


def _links_below(path: Path) -> list[Path]:
    """The symbolic links under ``path`` (not followed), in a stable order."""
    found = []
    for top, folders, names in os.walk(path):
        for name in sorted(folders + names):
            if os.path.islink(os.path.join(top, name)):
                found.append(Path(top, name).relative_to(path))
        folders[:] = sorted(f for f in folders if not os.path.islink(os.path.join(top, f)))
    return found


def writable_folder(folder: Path, flag: str, named: Path) -> None:
    probe = folder
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise ConfigError([f"{flag} {named}: {probe} is not a folder"])
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ConfigError([f"{flag} {named}: {probe} is not writable"])


def sweep_temporary() -> int:
    """Remove the temporary folders of this project's processes that are gone (killed, or a
    Dask worker that never ran its exit handlers): ``furuta-cosim-{fmu,build}-<pid>-*`` in the
    temporary directory whose process no longer runs. Returns how many were removed."""
    removed = 0
    try:
        entries = list(Path(tempfile.gettempdir()).iterdir())
    except OSError:
        return 0
    for entry in entries:
        match = _TEMPORARY.fullmatch(entry.name)
        if not match or int(match.group(1)) == os.getpid():
            continue
        try:
            os.kill(int(match.group(1)), 0)
            continue  # its process still runs
        except ProcessLookupError:
            pass
        except (PermissionError, OverflowError, OSError):
            continue  # another user's process, or no answer: leave it
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
            removed += 1
    return removed


_TEMPORARY = re.compile(r"furuta-cosim-(?:fmu|build)-(\d+)-.+")
_SWEPT = False


def temporary_folder(kind: str) -> Path:
    """A new temporary folder named after this process (``furuta-cosim-<kind>-<pid>-...``), so
    that :func:`sweep_temporary` can tell when it was left behind; the first one of a process
    sweeps those of processes that are gone."""
    global _SWEPT
    if not _SWEPT:
        _SWEPT = True
        sweep_temporary()
    return Path(tempfile.mkdtemp(prefix=f"furuta-cosim-{kind}-{os.getpid()}-"))
