"""Reference kinds: each evaluates as written, and a new kind is one class (registered by
being defined) that scenario files, their checks and their error messages take at once."""

import numpy as np
import pytest

from furuta_cosim import references
from furuta_cosim.errors import ConfigError
from furuta_cosim.references import KINDS, Kind
from furuta_cosim.scenario import load_scenario

T = np.array([0.0, 0.5, 1.0, 1.5, 2.0])


EXAMPLES = [
    ("constant", {"value": 3.0}, [3, 3, 3, 3, 3]),
    ("step", {"time": 1.0, "amplitude": 2.0, "initial": -1.0}, [-1, -1, 2, 2, 2]),
    ("sine", {"amplitude": 1.0, "period": 2.0, "offset": 1.0}, [1, 2, 1, 0, 1]),
    ("square", {"amplitude": 1.0, "period": 2.0, "duty": 0.25}, [1, -1, -1, -1, 1]),
    ("ramp", {"slope": 2.0, "start": 1.0, "initial": 1.0}, [1, 1, 1, 2, 3]),
    ("table", {"points": ((0.0, 0.0), (1.0, 4.0))}, [0, 0, 4, 4, 4]),
    ("table", {"points": ((0.0, 0.0), (1.0, 4.0)), "interpolation": "linear"}, [0, 2, 4, 4, 4]),
]


@pytest.mark.parametrize("name, params, expected", EXAMPLES)
def test_each_kind_evaluates_by_hand(name, params, expected):
    assert np.allclose(KINDS[name].value(params, T), expected, atol=1e-12)


def test_every_kind_has_an_example_and_settles_exactly_when_it_ends_constant():
    """``settles`` (step metrics are computed) is what a kind does, read from the registry:
    each registered kind's example is constant from some time on exactly when it settles."""
    assert {name for name, _, _ in EXAMPLES} == set(KINDS)
    late = np.array([100.0, 100.25, 100.5, 101.0, 137.3])
    for name, params, _ in EXAMPLES:
        values = KINDS[name].value(params, late)
        assert KINDS[name].settles == bool(np.ptp(values) == 0.0), name


def _scenario(tmp_path, signal: str):
    path = tmp_path / "s.yaml"
    path.write_text("name: s\ndescription: d\nplant: {model: furuta}\ntiming: {duration: 1.0}\n"
                    f"reference: {{output: theta0, signal: {signal}}}\ncontrollers: [lqr-paper]\n")
    return path


def test_a_new_kind_is_one_class(tmp_path, monkeypatch):
    monkeypatch.setattr(references, "KINDS", dict(KINDS))
    monkeypatch.setattr("furuta_cosim.scenario.KINDS", references.KINDS)

    class Chirp(Kind):
        name = "chirp"
        required = ("amplitude", "rate")
        positive = ("rate",)

        @staticmethod
        def value(p, t):
            return p["amplitude"] * np.sin(p["rate"] * t ** 2)

    scenario = load_scenario(_scenario(tmp_path, "{type: chirp, amplitude: 0.1, rate: 2.0}"))
    assert np.allclose(scenario.reference(T), 0.1 * np.sin(2.0 * T ** 2)) and not scenario.reference.settles
    with pytest.raises(ConfigError) as raised:
        load_scenario(_scenario(tmp_path, "{type: chirp, amplitude: 0.1, rate: 0}"))
    assert "reference.signal.rate: must be > 0, got 0" in str(raised.value)
    with pytest.raises(ConfigError) as raised:
        load_scenario(_scenario(tmp_path, "{type: nosuch, value: 1}"))
    assert "table, chirp, got 'nosuch'" in str(raised.value)


def test_a_kind_registered_twice_is_refused(monkeypatch):
    monkeypatch.setattr(references, "KINDS", dict(KINDS))
    with pytest.raises(ValueError, match="registered twice"):
        class Again(Kind):
            name = "step"


def test_the_every_key_scenario_of_the_docs_shows_every_kind():
    import re

    from helpers import page

    text = page("scenarios.md")
    example = re.search(r"```yaml\n(.*?)```", text[text.index("Every key of a scenario file"):], re.S).group(1)
    assert set(re.findall(r"\{type: (\w+),", example)) >= set(KINDS)
    assert "<!-- generated: reference-kinds -->" in text  # its table, written from the registry
