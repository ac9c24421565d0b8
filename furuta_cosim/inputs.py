"""Reading a file a user names: the one place that opens it.

A path the user gives may name anything: a FIFO (``open()`` waits for a writer for ever), a
device (``/dev/zero`` never ends), a socket, a folder. :func:`regular` refuses all but a plain
file before anything opens it (``os.stat``, which follows the user's own links), and again on
the opened descriptor (opened without blocking, so a FIFO swapped in between cannot hold the
process); :func:`read_input` then reads at most its limit, so a file that grows, or lies about
its size, is refused at the limit and never read whole.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from furuta_cosim.errors import ConfigError


def _kind(mode: int) -> str:
    return ("folder" if stat.S_ISDIR(mode) else "FIFO" if stat.S_ISFIFO(mode) else "socket" if stat.S_ISSOCK(mode)
            else "device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "special file")


def _refused(path: Path, mode: int, what: str) -> ConfigError:
    kind = _kind(mode)
    return ConfigError([f"{what}{path}: a {kind}, not a file: refused before it is opened"
                        + (" (nothing would ever end the read)" if kind in ("FIFO", "device", "socket") else "")])


def regular(path: str | Path, what: str = "") -> Path:
    """``path`` if it names a plain file (through links), else one line: missing, not a usable
    name, unreadable, or a folder, FIFO, socket or device. ``what`` prefixes the line (a key)."""
    path = Path(path)
    try:
        status = os.stat(path)
    except ValueError:   # a NUL in the name
        raise ConfigError([f"{what}{str(path)[:80]!r}: not a usable file name"]) from None
    except FileNotFoundError:
        raise ConfigError([f"{what}{path}: file not found"]) from None
    except RuntimeError:  # a loop of links, as pathlib reports it
        raise ConfigError([f"{what}{path}: a loop of symbolic links"]) from None
    except OSError as error:
        raise ConfigError([f"{what}{path}: cannot be read ({error.strerror or error.__class__.__name__})"]) from None
    if not stat.S_ISREG(status.st_mode):
        raise _refused(path, status.st_mode, what)
    return path


def read_input(path: str | Path, limit: int, what: str = "", beyond: str = "not a file this reads") -> bytes:
    """The bytes of the plain file ``path`` (:func:`regular`), at most ``limit`` of them: a
    longer file is one line naming the limit (and ``beyond``: what that makes it)."""
    path = regular(path, what)
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as error:
        raise ConfigError([f"{what}{path}: cannot be read ({error.strerror or error.__class__.__name__})"]) from None
    with os.fdopen(descriptor, "rb") as handle:
        mode = os.fstat(handle.fileno()).st_mode
        if not stat.S_ISREG(mode):
            raise _refused(path, mode, what)
        if os.fstat(handle.fileno()).st_size > limit:
            raise ConfigError([f"{what}{path}: larger than {_size(limit)}: {beyond}"])
        try:
            raw = handle.read(limit + 1)
        except OSError as error:
            raise ConfigError([f"{what}{path}: cannot be read ({error.strerror or error.__class__.__name__})"]) from None
    if len(raw) > limit:
        raise ConfigError([f"{what}{path}: larger than {_size(limit)}: {beyond}"])
    return raw


def _size(limit: int) -> str:
    return f"{limit // 1_000_000} MB" if limit >= 1_000_000 else f"{limit} bytes"
