"""Optimizer methods: a registry the spec, the CLI and tune read, so that a new method is one
class (here a Sobol sequence) that tune runs, resumes and summarizes like the shipped ones."""

import json

import pytest

from furuta_cosim.errors import ConfigError
from furuta_cosim.tuning import methods
from furuta_cosim.tuning.methods import METHODS, Method
from furuta_cosim.tuning.run import tune
from furuta_cosim.tuning.spec import load_spec


@pytest.fixture
def sobol(monkeypatch):
    monkeypatch.setattr(methods, "METHODS", dict(METHODS))
    for module in ("furuta_cosim.tuning.run", "furuta_cosim.cli"):
        monkeypatch.setattr(f"{module}.METHODS", methods.METHODS, raising=False)

    class Sobol(Method):
        name = "sobol"
        description = "a scrambled Sobol sequence"

        def search(self, run):
            from scipy.stats import qmc

            low, high = zip(*run.evaluator.space.bounds)
            points = qmc.scale(qmc.Sobol(len(low), seed=run.seed).random(run.n_calls), low, high)
            while len(run.records) < run.n_calls:
                first = len(run.records)
                run.evaluate([list(p) for p in points[first:first + run.batch]], "sobol")

    return Sobol


@pytest.mark.slow
def test_a_new_method_is_one_class(sobol, tmp_path):
    spec = load_spec("effort")
    document = tune(spec, tmp_path / "run", method="sobol", n_calls=4)
    history = [json.loads(line) for line in (tmp_path / "run" / "history.jsonl").read_text().splitlines()]
    assert document["method"] == "sobol" and len(history) == 4
    assert {r["origin"] for r in history} == {"sobol"}
    # a resumed run with the same method goes on; the summary is the same document
    again = tune(spec, tmp_path / "run", method="sobol", n_calls=4, resume=True)
    assert again["best"] == document["best"]
    from furuta_cosim.cli import build_parser

    help_text = build_parser()._subparsers._group_actions[0].choices["tune"].format_help()
    assert "{" + ",".join(methods.METHODS) + "}" in help_text and list(methods.METHODS)[-1] == "sobol"
    assert "sobol: a scrambled Sobol sequence" in " ".join(help_text.split())


def test_the_method_names_come_from_the_registry():
    with pytest.raises(ConfigError) as raised:
        tune(load_spec("effort"), "unused", method="nosuch")
    assert f"method: expected one of {', '.join(METHODS)}, got 'nosuch'" in str(raised.value)


def test_a_one_number_method_refuses_a_tradeoff_in_the_spec_and_in_tune(tmp_path):
    spec = tmp_path / "t.yaml"
    text = load_spec("tradeoff").path.read_text()
    assert "method: bo" in text
    spec.write_text(text.replace("method: bo", "method: de"))
    with pytest.raises(ConfigError) as raised:
        load_spec(spec)
    assert "optimizer.method: de (scipy's differential evolution) minimizes one number" in str(raised.value)
    with pytest.raises(ConfigError) as raised:
        tune(load_spec("tradeoff"), tmp_path / "run", method="de")
    assert "method: de (scipy's differential evolution) minimizes one number; a tradeoff " \
           "objective is searched by bo or random" in str(raised.value)
    assert not (tmp_path / "run").exists()


def test_a_method_registered_twice_is_refused(monkeypatch):
    monkeypatch.setattr(methods, "METHODS", dict(METHODS))
    with pytest.raises(ValueError, match="registered twice"):
        class Again(Method):
            name = "bo"
            description = "again"
