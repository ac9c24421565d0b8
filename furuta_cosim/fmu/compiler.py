"""Compiling C in the FMU cache: the compiler, its flags, cache entries sealed by their content
hash and built under a lock. The exporter compiles FMUs with it; the plant session its small
``step_io`` helper (so the session needs nothing of the exporter)."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

from furuta_cosim import paths
from furuta_cosim.errors import FmuError
from furuta_cosim.files import atomic

CFLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra", "-Werror",
          "-fvisibility=hidden") + tuple(os.environ.get("FURUTA_COSIM_EXTRA_CFLAGS", "").split())


def compiler() -> str:
    """The C compiler: ``CC`` when set, else gcc or cc (FmuError when there is none)."""
    chosen = os.environ.get("CC")
    if chosen:
        found = shutil.which(chosen)
        if not found:
            raise FmuError(f"CC={chosen}: no such compiler (unset CC to use gcc)")
        return found
    found = shutil.which("gcc") or shutil.which("cc")
    if not found:
        raise FmuError("no C compiler found: install gcc (Debian: apt-get install gcc) or set CC")
    return found


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def seal(target: Path) -> None:
    """Record the content hash of a new cache entry beside it (``<entry>.sha256``)."""
    with atomic(target.with_name(target.name + ".sha256")) as partial:
        partial.write_text(digest(target) + "\n")


def intact(target: Path, log) -> bool:
    """True when ``target`` is in the cache and matches the hash recorded at build time; a
    damaged entry (truncated, overwritten) is removed, saying so in one line."""
    if not target.is_file():
        return False
    seal = target.with_name(target.name + ".sha256")
    try:
        if seal.read_text().strip() == digest(target):
            return True
    except (OSError, UnicodeDecodeError):
        pass
    (log or _stderr)(f"the cached {target.name} is damaged or unverified: building it again")
    for damaged in (target, seal):
        try:
            damaged.unlink(missing_ok=True)
        except OSError:
            pass
    return False


def _stderr(line: str) -> None:
    print(line, file=sys.stderr)


def unwritable(error: OSError) -> FmuError:
    return FmuError(f"cannot write the FMU cache {paths.cache()} ({error.strerror or error}): "
                    "set FURUTA_COSIM_CACHE to a writable folder")


def build_helper(source: Path) -> Path | None:
    """Compile a small C helper of the package into the cache; None when that cannot be done
    (no compiler, a cache that cannot be written): callers then do without it."""
    text = source.read_bytes()
    key = hashlib.sha256(text + " ".join(CFLAGS).encode()).hexdigest()[:16]
    target = paths.cache() / f"{source.stem}-{key}.so"
    if intact(target, None):
        return target
    try:
        cc = compiler()
        target.parent.mkdir(parents=True, exist_ok=True)
        with atomic(target) as partial:
            result = subprocess.run([cc, *CFLAGS, str(source), "-o", str(partial)],
                                    capture_output=True, text=True)
            if result.returncode != 0:
                return None
        seal(target)
    except (FmuError, OSError):
        return None
    return target


_LOADED: dict = {}  # (ffi, source) -> the opened helper, or None when it cannot be had


def load_helper(ffi, source: Path):
    """The helper ``source`` built (:func:`build_helper`) and opened with the cffi ``ffi``,
    once per process; None when it cannot be built or loaded (callers then do without it)."""
    key = (id(ffi), str(source))
    if key not in _LOADED:
        path = build_helper(source)
        try:
            _LOADED[key] = ffi.dlopen(str(path)) if path else None
        except OSError:
            _LOADED[key] = None
    return _LOADED[key]


@contextmanager
def building(target: Path):
    """An exclusive lock on one cache entry (``<entry>.lock``) while it is built."""
    import fcntl

    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        handle = os.open(target.with_name(target.name + ".lock"),
                         os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
    except OSError as error:
        raise unwritable(error) from None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX)
        yield
    finally:
        os.close(handle)
