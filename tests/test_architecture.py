"""Imports point one way inside the packages whose layers the docs draw (Development): a change
to a lower module never needs one to a higher, and the identify pipeline's stages can be read
and replaced alone."""

from __future__ import annotations

import re
import sys

import pytest

from helpers import ROOT

sys.path.insert(0, str(ROOT / "tools"))
import import_cycles  # noqa: E402


@pytest.mark.parametrize("package", ["furuta_cosim/identify", "furuta_cosim/ssp", "furuta_cosim/cosim",
                                     "furuta_cosim/design", "furuta_cosim/report"])
def test_no_import_cycle(package):
    edges = import_cycles.graph(ROOT / package)
    assert len(edges) >= 4, edges
    assert import_cycles.cycles(edges) == []


def test_the_cycle_finder_finds_one():
    assert import_cycles.cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert import_cycles.cycles({"a": {"b"}, "b": set()}) == []


# What stays the Furuta's (its rig: boards, supervisor, swing-up, trials on a rig, the rig's
# loop analysis, the plant files' rig limits; identify's closed-loop replay of its logs; the
# paper's reproduction) is named here; everything else of the core runs any plant folder.
FURUTA_ONLY = {"design/rigloop.py", "tuning/plausible.py", "tuning/rig.py", "tuning/trials.py",
               "fmu/plants.py", "report/rig.py"}
CORE = ("cosim", "design", "tuning", "ssp", "fmu", "report", "regression.py", "export.py",
        "metrics.py", "scenario.py", "controllers.py", "simulation.py", "models.py",
        "scenario_source.py", "lqr_file.py")


def test_the_core_names_no_state_of_the_furuta_pendulum():
    """The state view comes from the plant's declaration: no module of the core names the
    Furuta's states (a cart-pole runs through the same code, tests/test_cart_pole.py)."""
    root = ROOT / "furuta_cosim"
    files = [p for part in CORE for p in ((root / part).rglob("*.py") if (root / part).is_dir() else [root / part])]
    assert len(files) >= 60
    naming = sorted(str(p.relative_to(root)) for p in files
                    if re.search(r"\b(d?theta[01])\b", p.read_text()) and str(p.relative_to(root)) not in FURUTA_ONLY)
    assert naming == []
