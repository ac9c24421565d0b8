"""Imports point one way inside the packages whose layers the docs draw (Development): a change
to a lower module never needs one to a higher, and the identify pipeline's stages can be read
and replaced alone."""

from __future__ import annotations

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
