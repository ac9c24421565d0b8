"""Helpers shared by the tests (imported as ``helpers``; fixtures stay in conftest.py)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGES = ROOT / "docs" / "pages"


def documentation() -> dict[str, str]:
    """The README and every page of the docs site, by path relative to the repository."""
    files = [ROOT / "README.md"] + sorted(PAGES.glob("*.md"))
    return {str(p.relative_to(ROOT)): p.read_text() for p in files}


def page(name: str) -> str:
    """One page of the docs site (``tuning.md``)."""
    return (PAGES / name).read_text()


def section(text: str, heading: str) -> str:
    """The section of ``text`` under the heading ``heading`` (any level), up to the next
    heading of the same or a higher level."""
    match = re.search(rf"^(#+) {re.escape(heading)}\n", text, re.M)
    if not match:
        raise AssertionError(f"no heading {heading!r}")
    level = len(match.group(1))
    rest = text[match.end():]
    end = re.search(rf"^#{{1,{level}}} ", rest, re.M)
    return rest[:end.start()] if end else rest


def python_blocks() -> list[tuple[str, str]]:
    """Every ```python block of the documentation, as (where, code)."""
    return [(f"{name} python block {k}", block) for name, text in documentation().items()
            for k, block in enumerate(re.findall(r"```python\n(.*?)```", text, re.S))]
