"""Writing files so that a fault loses nothing: a file appears under its name only complete.

Each writer writes a temporary file beside the target (``.<name>.partial``) and renames it;
on any failure, Ctrl-C or SIGTERM included, the temporary file is removed.
"""

from __future__ import annotations

import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from furuta_cosim.errors import ConfigError


@contextmanager
def atomic(path: str | Path) -> Iterator[Path]:
    """``with atomic(target) as partial:`` write ``partial``; it becomes ``target`` at the end."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    try:
        yield partial
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def write_text(path: str | Path, text: str) -> Path:
    with atomic(path) as partial:
        partial.write_text(text)
    return Path(path)


def copy(source: str | Path, path: str | Path) -> Path:
    with atomic(path) as partial:
        shutil.copyfile(source, partial)
    return Path(path)


def output_file(path: str | Path, flag: str = "-o") -> Path:
    """Check before any work that ``path`` can be written as a file: one line otherwise."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError([f"{flag} {path}: is a folder; name a file"])
    writable_folder(path.parent, flag, path)
    return path


def output_folder(path: str | Path, flag: str = "-o") -> Path:
    """Check before any work that ``path`` can be used as an output folder."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError([f"{flag} {path}: exists and is not a folder"])
    writable_folder(path, flag, path)
    return path


def writable_folder(folder: Path, flag: str, named: Path) -> None:
    probe = folder
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise ConfigError([f"{flag} {named}: {probe} is not a folder"])
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ConfigError([f"{flag} {named}: {probe} is not writable"])
