"""identify as a pipeline of stages: run by hand, stage by stage, it writes what identify()
writes; a stage is replaced alone (here the judge), and the rest of the run follows it."""

from __future__ import annotations

import json

import pytest
import yaml

from furuta_cosim.identify import pipeline
from furuta_cosim.identify.run import identify
from furuta_cosim.identify.verdict import judge

from helpers import synthetic_log


def _values(document: dict) -> dict:
    return {name: entry["value"] for name, entry in document["parameters"].items()}


@pytest.mark.slow
def test_the_stages_by_hand_give_identifys_fit(tmp_path):
    spec = synthetic_log(tmp_path)
    whole = identify(spec, tmp_path / "whole", profiles=False)
    options = pipeline.Options(profiles=False)
    loaded = pipeline.load(spec, tmp_path / "stages", options)
    assert not (tmp_path / "stages").exists() or not any((tmp_path / "stages").iterdir())  # nothing written yet
    checked = pipeline.precheck(loaded)
    fitted = pipeline.fit_stage(checked)
    assert not (tmp_path / "stages" / "fit.json").exists()                   # the fit writes only its checkpoint
    fitted = pipeline.verdict(pipeline.intervals(fitted))
    document = pipeline.write(fitted)
    assert _values(document) == _values(whole)                                # the same fit, to the last bit
    assert document["verdict"] == whole["verdict"]
    assert json.loads((tmp_path / "stages" / "fit.json").read_text())["verdict"] == whole["verdict"]
    assert sorted(p.name for p in (tmp_path / "stages").iterdir()) == sorted(whole["files"])


def test_a_replaced_judge_decides_what_is_written(tmp_path):
    """A stricter judge, swapped in alone: its reason refuses the plant file; the fit, the
    intervals and the writing are the defaults'."""
    said = "the replaced judge trusts no fit of fewer than 1000 samples"

    def strict(document, ranges, tolerance):
        found = judge(document, ranges, tolerance)
        return {**found, "trusted": False, "reasons": [said] + found["reasons"]}

    spec = synthetic_log(tmp_path)
    document = pipeline.Pipeline(judge=strict).run(spec, tmp_path / "strict", profiles=False)
    assert document["verdict"]["trusted"] is False and document["verdict"]["reasons"][0] == said
    plant = yaml.safe_load((tmp_path / "strict" / "plant.yaml").read_text())
    assert said in plant["rejected"]
    default = pipeline.Pipeline().run(spec, tmp_path / "default", profiles=False)
    assert default["verdict"]["trusted"] is True
    assert _values(document) == _values(default)                              # only the verdict moved
    assert "rejected" not in yaml.safe_load((tmp_path / "default" / "plant.yaml").read_text())


def test_a_bad_option_is_refused_by_load_before_anything_is_written(tmp_path):
    from furuta_cosim.errors import ConfigError

    spec = synthetic_log(tmp_path)
    with pytest.raises(ConfigError, match="starts: expected a whole number from 1 to 1000, got 0"):
        pipeline.Pipeline().run(spec, tmp_path / "out", starts=0)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
