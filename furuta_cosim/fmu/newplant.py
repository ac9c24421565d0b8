"""``new-plant NAME``: a plant folder to start from (a declaration, its equations and a plant
file), which builds and simulates as written."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from furuta_cosim.errors import ConfigError

TEMPLATE = Path(__file__).parent / "template"
FILES = ("model.py", "model.c", "plant.yaml", "step.yaml")


def identifier(name: str) -> str:
    """The FMU's C name from a folder's name: ``my-cart`` -> ``MyCart``."""
    return "".join(part[:1].upper() + part[1:] for part in re.split(r"[^A-Za-z0-9]+", name) if part)


def new_plant(folder: str | Path) -> Path:
    """Write a plant folder to start from at ``folder`` and return it: ``model.py`` (a mass on
    a spring, declared), ``model.c`` (its equations), ``plant.yaml`` (a parameter set) and
    ``step.yaml`` (a scenario), all or none.

    Parameters
    ----------
    folder : path
        The new folder; it must not exist, and its name (a letter, then letters, digits, ``-``
        or ``_``) names the FMU (``my-cart`` -> ``MyCart``).
    """
    folder = Path(folder)
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_-]{0,63}", folder.name):
        raise ConfigError([f"{folder}: a plant folder's name starts with a letter, then letters, "
                           "digits, - or _ (at most 64): it names the FMU"])
    if folder.exists() or folder.is_symlink():
        raise ConfigError([f"{folder}: exists already; new-plant writes a new folder (choose another name)"])
    if not folder.parent.is_dir():
        raise ConfigError([f"{folder.parent}: no such folder"])
    name = identifier(folder.name)
    partial = folder.with_name(f".{folder.name}.partial-{os.getpid()}")
    try:
        partial.mkdir()
        for file in FILES:
            (partial / file).write_text((TEMPLATE / file).read_text().replace("IDENTIFIER", name))
        os.rename(partial, folder)   # all three files or none
    except OSError as error:
        raise ConfigError([f"{folder}: cannot be written ({error.strerror})"]) from None
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return folder
