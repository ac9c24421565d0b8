"""Compiling generated Python source so that tracebacks still show it.

The hot loop's functions (sample loop, controllers, Kalman filter) are generated as source
and compiled. Each source is registered with :mod:`linecache` under a name of its own, so a
traceback through it shows the failing line like any other file. Identical sources share one
name; the registry keeps the most recent entries only, so a tuning run that compiles
thousands of candidates does not grow without bound.
"""

from __future__ import annotations

import hashlib
import linecache
from collections import OrderedDict

_KEEP = 512
_REGISTERED: OrderedDict[str, None] = OrderedDict()


def filename(kind: str, source: str) -> str:
    digest = hashlib.blake2b(source.encode(), digest_size=6).hexdigest()
    return f"<furuta-cosim {kind} {digest}>"


def compile_source(source: str, kind: str, entry: str):
    """Execute ``source`` and return its top-level ``entry``; ``kind`` names it in tracebacks."""
    name = filename(kind, source)
    # mtime None: linecache.checkcache leaves the entry alone
    linecache.cache[name] = (len(source), None, source.splitlines(True), name)
    _REGISTERED[name] = None
    _REGISTERED.move_to_end(name)
    while len(_REGISTERED) > _KEEP:
        old, _ = _REGISTERED.popitem(last=False)
        linecache.cache.pop(old, None)
    namespace: dict = {}
    exec(compile(source, name, "exec"), namespace)  # noqa: S102 (numbers and names we generate)
    return namespace[entry]
