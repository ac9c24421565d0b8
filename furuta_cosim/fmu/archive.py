"""An FMU is a zip from anyone: its entries are checked before anything reads or extracts it.

Refused, each with one line naming the FMU and the entry: absolute names, ``..`` components,
backslashes or NUL in names, symbolic links, names given twice, more than
:data:`MAX_ENTRIES` entries, an entry over :data:`MAX_ENTRY_BYTES` or a total over
:data:`MAX_TOTAL_BYTES` (uncompressed, as the zip declares; extraction stops at the declared
size), and a zip without ``modelDescription.xml``. fmpy, Ecos and our own session extract only
what passed.
"""

from __future__ import annotations

import re
import stat
import zipfile
from pathlib import Path

from furuta_cosim.errors import FmuError

MAX_ENTRIES = 10_000
MAX_ENTRY_BYTES = 1 << 30   # 1 GiB: a shared library or a resource, uncompressed
MAX_TOTAL_BYTES = 2 << 30   # 2 GiB
_DRIVE = re.compile(r"^[A-Za-z]:")


def check_archive(fmu: str | Path) -> None:
    """Raise :class:`FmuError` (one line) unless ``fmu`` is a zip whose entries are safe to
    extract into a folder of their own.

    Parameters
    ----------
    fmu : path
        The FMU file.
    """
    try:
        with zipfile.ZipFile(fmu) as archive:
            entries = archive.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, RuntimeError) as error:
        raise FmuError(f"{fmu}: not a readable FMU (zip): {error}") from None
    if len(entries) > MAX_ENTRIES:
        raise FmuError(f"{fmu}: {len(entries)} entries, more than the {MAX_ENTRIES} allowed")
    seen, total = set(), 0
    for entry in entries:
        name = entry.filename
        problem = _unsafe(name, entry)
        if problem:
            raise FmuError(f"{fmu}: entry {name!r}: {problem}; refused before extracting anything")
        if name in seen:
            raise FmuError(f"{fmu}: entry {name!r} is in the zip twice")
        seen.add(name)
        if entry.file_size > MAX_ENTRY_BYTES:
            raise FmuError(f"{fmu}: entry {name!r} is {entry.file_size} bytes uncompressed, over "
                           f"the {MAX_ENTRY_BYTES} allowed")
        total += entry.file_size
    if total > MAX_TOTAL_BYTES:
        raise FmuError(f"{fmu}: {total} bytes uncompressed, over the {MAX_TOTAL_BYTES} allowed")
    if "modelDescription.xml" not in seen:
        raise FmuError(f"{fmu}: no modelDescription.xml at the top of the zip")


def _unsafe(name: str, entry: zipfile.ZipInfo) -> str | None:
    if not name or "\x00" in name or "\\" in name:
        return "a name with a backslash, NUL or nothing in it"
    if name.startswith("/") or _DRIVE.match(name):
        return "an absolute name"
    if ".." in name.split("/"):
        return "a name that leaves the FMU's folder (..)"
    if stat.S_ISLNK(entry.external_attr >> 16):
        return "a symbolic link"
    return None
