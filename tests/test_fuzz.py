"""A fuzzer over every loader (Hypothesis): a valid file of each kind, mutated the way a hostile
or careless user would (wrong types, empty and nested lists, huge, tiny and non-finite
numbers, unknown and missing keys, unicode and control characters, long names, a file cut
short), is either accepted with finite numbers, or refused with a ConfigError, FmuError or
DesignError whose every line names the file; never another exception, a crash or a hang.

In CI each loader gets a fixed-seed budget (FURUTA_COSIM_FUZZ_EXAMPLES examples, 60 by
default: under a minute for all of them). A longer search is the same test with a larger
budget, for example ``FURUTA_COSIM_FUZZ_EXAMPLES=2000 python -m pytest tests/test_fuzz.py``;
Hypothesis prints the smallest failing file it found.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
import shutil
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
import yaml

hypothesis = pytest.importorskip("hypothesis", reason="the test extra installs Hypothesis")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402

from furuta_cosim import paths  # noqa: E402
from furuta_cosim.errors import ConfigError, DesignError, FmuError  # noqa: E402

EXAMPLES = int(os.environ.get("FURUTA_COSIM_FUZZ_EXAMPLES", "60"))
BUDGET = settings(max_examples=EXAMPLES, derandomize=True, database=None,
                  deadline=timedelta(seconds=30), print_blob=True,
                  suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                         HealthCheck.data_too_large])
SHIPPED = paths.scenarios()

# -- what a hostile file holds ----------------------------------------------------------------
NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from([0, -0.0, 1e308, -1e308, 5e-324, 1e-300, 2**63, -1, 1e6, 1e-12]),
                    st.integers(min_value=-10**30, max_value=10**30))
TEXT = st.one_of(st.text(max_size=20),
                 st.text(alphabet=st.characters(max_codepoint=0x1f), min_size=1, max_size=5),
                 st.sampled_from(["", " ", "../../etc/passwd", "/dev/zero", "x" * 5000, "é\u202ekcab",
                                  "con", ".", "..", "null", "~", "true", "nan", "1e999"]))
SCALARS = st.one_of(st.none(), st.booleans(), NUMBERS, TEXT)
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=2)), max_leaves=6)
# sampled constants are copied: a later mutation in place must not change the strategy itself
HOSTILE = st.one_of(VALUES, st.sampled_from([[], [[]], [[[]]], {}, [{}], [None], [[1, 2], [3]]]).map(copy.deepcopy))


def _paths(node, prefix=()):
    """Every place in a document: (path, value)."""
    yield prefix, node
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _paths(value, prefix + (key,))
    elif isinstance(node, list):
        for k, value in enumerate(node[:6]):  # a trace's thousand rows are all alike
            yield from _paths(value, prefix + (k,))


@st.composite
def mutated(draw, document):
    """``document`` with one to three mutations at places drawn from it."""
    document = json.loads(json.dumps(document))  # a copy
    for _ in range(draw(st.integers(1, 3))):
        places = list(_paths(document))
        where, _ = draw(st.sampled_from(places))
        op = draw(st.sampled_from(["replace", "replace", "replace", "delete", "unknown key", "wrap"]))
        if not where:
            document = draw(HOSTILE) if op == "replace" else document
            continue
        parent = document
        for step in where[:-1]:
            parent = parent[step]
        last = where[-1]
        if op == "replace":
            parent[last] = draw(HOSTILE)
        elif op == "delete":
            del parent[last]
        elif op == "unknown key" and isinstance(parent[last], dict):
            parent[last][draw(TEXT)] = draw(SCALARS)
        elif op == "wrap":
            parent[last] = [parent[last]]
    return document


def _finite(value, where="result", depth=0) -> None:
    """No NaN or infinity anywhere in what a loader accepted."""
    if depth > 12:
        return
    if isinstance(value, float):
        assert math.isfinite(value), f"{where}: {value}"
    elif isinstance(value, np.ndarray) and value.dtype.kind == "f":
        assert np.all(np.isfinite(value)), where
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for field in dataclasses.fields(value):
            _finite(getattr(value, field.name), f"{where}.{field.name}", depth + 1)
    elif isinstance(value, dict) or hasattr(value, "items") and callable(value.items):
        for key, item in value.items():
            _finite(item, f"{where}[{key!r}]", depth + 1)
    elif isinstance(value, (list, tuple)):
        for k, item in enumerate(value):
            _finite(item, f"{where}[{k}]", depth + 1)


def holds(load, path: Path, finite: bool = True, also: tuple[str, ...] = ()):
    """The property: accepted with finite numbers, or refused with lines that name the file
    (or one of ``also``: the scenario whose terms a mutated FMU no longer meets)."""
    try:
        result = load(path)
    except (ConfigError, DesignError, FmuError) as error:
        lines = str(error).splitlines()
        assert lines, "an error without a message"
        for line in lines:
            assert any(name in line for name in (path.name, *also)), \
                f"a line that does not name {path.name}: {line!r}"
            assert line.isprintable(), f"a line with control characters: {line!r}"
        return None
    if finite:
        _finite(result)
    return result


def _write(path: Path, document, kind: str = "yaml") -> Path:
    if kind == "json":
        path.write_text(json.dumps(document, allow_nan=True))
    elif kind == "jsonl":  # one record per line; a document that is no list is one line
        lines = document if isinstance(document, list) else [document]
        path.write_text("".join(json.dumps(line, allow_nan=True) + "\n" for line in lines))
    else:
        path.write_text(yaml.safe_dump(document, allow_unicode=True))
    return path


def _cut(path: Path, fraction: float) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * fraction)])


CUT = st.one_of(st.none(), st.floats(0.0, 0.99))


# -- the loaders ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def place(tmp_path_factory):
    """A folder per example: the shipped files a loader may name, copied beside the mutated one."""
    root = tmp_path_factory.mktemp("fuzz")
    shutil.copytree(SHIPPED, root / "scenarios")
    counter = iter(range(10**9))

    def new(name: str) -> Path:
        return root / "scenarios" / f"fuzz-{next(counter)}-{name}"
    return new


def _scenario_then_prepare(path: Path):
    from furuta_cosim.cosim import prepare
    from furuta_cosim.scenario import load_scenario

    return prepare(load_scenario(path))


@pytest.mark.slow
@given(data=st.data())
@BUDGET
def test_scenario_files(place, data):
    document = yaml.safe_load((SHIPPED / "paper-step.yaml").read_text())
    path = _write(place("scenario.yaml"), data.draw(mutated(document)))
    if (fraction := data.draw(CUT)) is not None:
        _cut(path, fraction)
    holds(_scenario_then_prepare, path, finite=False)  # a prepared scenario holds inf bounds by design


# shipped files of a kind, each loaded by one function: (folder, files, loader, finite?)
SHIPPED_KINDS = {
    "controller": ("controllers", ["lqr-paper.yaml", "bo-paper.yaml", "toy-generalized.yaml"],
                   "furuta_cosim.controllers:load_controller", True),
    "plant": ("plants", ["paper-calibrated.yaml", "qube-servo-3.yaml", "toy.yaml"],
              "furuta_cosim.fmu.plants:load_plant", True),
    # a spec's search space holds inf bounds by design
    "spec": ("tuning", ["effort.yaml", "paper-spectral.yaml", "tradeoff.yaml"],
             "furuta_cosim.tuning.spec:load_spec", False),
}


@pytest.mark.slow
@pytest.mark.parametrize("kind", SHIPPED_KINDS)
@given(data=st.data())
@BUDGET
def test_shipped_files_of_each_kind(place, kind, data):
    import importlib

    folder, names, loader, finite = SHIPPED_KINDS[kind]
    module, function = loader.split(":")
    load = getattr(importlib.import_module(module), function)
    name = data.draw(st.sampled_from(names))
    document = yaml.safe_load((SHIPPED / folder / name).read_text())
    path = _write(place(f"{kind}.yaml"), data.draw(mutated(document)))
    holds(load, path, finite=finite)


MAPPING = {"control_input": "voltage",
           "states": {"theta0": {"variable": "arm_angle", "scale": 0.0174533}, "dtheta0": "arm_rate",
                      "theta1": "pend_angle", "dtheta1": "pend_rate", "i": "current"},
           "disturbances": {"tau0": "arm_torque", "tau1": "pend_torque"},
           "outputs": {"extra": "x"}, "ignore": ["y"], "initial": {"theta1": "pend_angle_0"}}


@pytest.mark.slow
@given(data=st.data())
@BUDGET
def test_mapping_files(place, data):
    from furuta_cosim.scenario import load_mapping

    path = _write(place("mapping.yaml"), data.draw(mutated(MAPPING)))
    holds(load_mapping, path)


@pytest.mark.slow
@given(data=st.data())
@BUDGET
def test_baselines(place, data):
    from furuta_cosim.regression import read_baseline

    document = yaml.safe_load((SHIPPED / "baselines" / "paper-step" / "lqr-paper.yaml").read_text())
    document["trace"]["rows"] = document["trace"]["rows"][:5]
    path = _write(place("baseline.yaml"), data.draw(mutated(document)))
    result = holds(read_baseline, path, finite=False)
    if result is not None:  # a metric stored as null is "never" (inf) by design; nothing else is
        _finite({k: v for k, v in result.items() if k != "metrics"})
        assert not any(math.isnan(v) for v in result["metrics"].values())


@pytest.fixture(scope="module")
def history_seed(tmp_path_factory):
    """A real history of three evaluations, and the bounds of its search space."""
    from furuta_cosim.tuning.objective import Evaluator
    from furuta_cosim.tuning.run import tune
    from furuta_cosim.tuning.spec import load_spec

    folder = tmp_path_factory.mktemp("history") / "run"
    spec = load_spec("paper-spectral")
    tune(spec, folder, n_calls=3, workers=1)
    lines = [json.loads(line) for line in (folder / "history.jsonl").read_text().splitlines()]
    return lines, Evaluator(spec).space.bounds


@pytest.mark.slow
@given(data=st.data())
@BUDGET
def test_history_lines(place, history_seed, data):
    from furuta_cosim.tuning.history import History

    lines, bounds = history_seed
    path = _write(place("history.jsonl"), data.draw(mutated(lines)), "jsonl")
    if (fraction := data.draw(CUT)) is not None:
        _cut(path, fraction)

    def load(p):
        history = History(p, True, bounds)
        history.close()
        return [{k: r[k] for k in ("index", "x", "objective") if k in r} for r in history.records]
    holds(load, path)


FRONT = {"criteria": ["effort", "tracking"],
         "points": [{"index": 0, "file": "front/00.yaml", "criteria": {"effort": 0.9, "tracking": 1.2}},
                    {"index": 4, "file": "front/01.yaml", "criteria": {"effort": 1.1, "tracking": 0.8}}],
         "baselines": {"lqr-paper": {"feasible": True, "criteria": {"effort": 1.0, "tracking": 1.0}}}}


@pytest.mark.slow
@given(data=st.data())
@BUDGET
def test_front_files(place, data, tmp_path_factory):
    from furuta_cosim.tuning.front import compare

    folder = place("run")
    folder.mkdir()
    _write(folder / "front.json", data.draw(mutated(FRONT)), "json")
    other = place("first")
    other.mkdir()
    _write(other / "front.json", FRONT, "json")
    out = place("compared")
    holds(lambda p: compare([other, folder], out), folder / "front.json")


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """The QUBE rig's experiment files and the identify spec, in a folder of their own."""
    root = tmp_path_factory.mktemp("rig")
    shutil.copytree(SHIPPED / "rigs" / "qube-servo-3", root / "rigs" / "qube-servo-3")
    shutil.copytree(SHIPPED / "identify", root / "identify")
    shutil.copytree(SHIPPED / "plants", root / "plants")
    return root


@pytest.mark.slow
@given(data=st.data())
@BUDGET
def test_identify_experiments(rig, data):
    from furuta_cosim.identify.experiment import load_experiment

    name = data.draw(st.sampled_from(["free-swing.yaml", "motor-7V.yaml"]))
    document = yaml.safe_load((rig / "rigs" / "qube-servo-3" / name).read_text())
    path = _write(rig / "rigs" / "qube-servo-3" / f"fuzz-{name}", data.draw(mutated(document)))
    holds(load_experiment, path)


@pytest.mark.slow
@given(data=st.data())
@BUDGET
def test_identify_specs(rig, data):
    from furuta_cosim.identify.spec import load_identify_spec

    document = yaml.safe_load((rig / "identify" / "qube-servo-3.yaml").read_text())
    path = _write(rig / "identify" / "fuzz-spec.yaml", data.draw(mutated(document)))
    holds(load_identify_spec, path)


# -- modelDescription.xml ---------------------------------------------------------------------
ATTRIBUTE_VALUES = st.one_of(TEXT, NUMBERS.map(repr), st.sampled_from(
    ["NaN", "INF", "-1", "0", "4294967296", "99999", "Real", "Clock", "output", "parameter", "exact", ""]))


@pytest.mark.slow
@given(data=st.data())
@BUDGET
def test_model_descriptions(place, data):
    """An attribute of the plant FMU's modelDescription.xml replaced, or the XML cut short:
    prepare reads it, checks names, units and interfaces, and refuses or accepts it."""
    import re
    import zipfile

    from furuta_cosim.cosim import prepare
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.scenario import load_scenario

    source = build_fmu("furuta")
    with zipfile.ZipFile(source) as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    text = entries["modelDescription.xml"].decode()
    attributes = list(re.finditer(r'(\w+)="([^"]*)"', text))
    for _ in range(data.draw(st.integers(1, 3))):
        match = data.draw(st.sampled_from(attributes))
        value = data.draw(ATTRIBUTE_VALUES).replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")
        text = text[:match.start(2)] + value + text[match.end(2):]
        attributes = list(re.finditer(r'(\w+)="([^"]*)"', text))
    if (fraction := data.draw(CUT)) is not None:
        text = text[:int(len(text) * fraction)]
    path = place("plant.fmu")
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in entries.items():
            archive.writestr(name, text.encode("utf-8", "surrogatepass") if name == "modelDescription.xml"
                             else content)
    holds(lambda p: prepare(load_scenario("paper-step"), fmu=p), path, finite=False, also=("paper-step.yaml",))
