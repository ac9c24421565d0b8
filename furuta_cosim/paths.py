"""Where the project's own files are: the plant sources and the shipped YAML files.

Both live at the top of the repository (``fmu_src/``, ``scenarios/``), beside the package,
which is installed in editable mode (see the README). ``FURUTA_COSIM_ROOT`` points elsewhere.
"""

from __future__ import annotations

import os
from pathlib import Path


def root() -> Path:
    override = os.environ.get("FURUTA_COSIM_ROOT")
    path = Path(override) if override else Path(__file__).resolve().parent.parent
    if not (path / "fmu_src").is_dir():
        raise FileNotFoundError(
            f"fmu_src/ not found under {path}: install the project from its repository with "
            "'pip install -e .' or set FURUTA_COSIM_ROOT to the repository")
    return path


def fmu_sources() -> Path:
    return root() / "fmu_src"


def scenarios() -> Path:
    """The shipped YAML files (plants, controllers, scenarios, tuning specs, the cart-pole
    example in ``cart-pole/``)."""
    return root() / "scenarios"


def cache() -> Path:
    """Built FMUs, keyed by a hash of their sources: ``FURUTA_COSIM_CACHE`` or the user cache."""
    override = os.environ.get("FURUTA_COSIM_CACHE")
    if override:
        return Path(override)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "furuta-cosim"
