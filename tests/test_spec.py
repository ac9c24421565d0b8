"""Tuning spec files: every bad key is one line naming the file and the key, exit 2, and no
run directory is made (the one place for spec validation)."""

import pytest
import yaml
from helpers import run_cli

from furuta_cosim import paths

SPEC = paths.scenarios() / "tuning" / "paper-spectral.yaml"


def edit(data, keys, value):
    target = data
    for key in keys[:-1]:
        target = target[key]
    if value is None:
        target.pop(keys[-1])
    else:
        target[keys[-1]] = value
    return data


@pytest.mark.parametrize("keys, value, key", [
    (("parameters", "Bc"), {"box": [1, -1]}, "parameters.Bc.box"),
    (("parameters", "Zc"), {"box": [0, 1]}, "parameters.Zc"),
    (("parameters", "Ac"), {"log": [-1]}, "parameters.Ac.log"),
    (("parameters", "Ac"), {"log": [-100, 100]}, "parameters.Ac.log"),   # values through 0
    (("parameters", "Dc"), {"lqr": [-2, 30]}, "parameters.Dc.lqr"),
    (("parameters", "Ac"), {"log": [-1, 2], "sign": 2}, "parameters.Ac.sign"),
    (("parameters", "Bc"), {"lqr": [-1, 2]}, "parameters.Bc"),
    (("parameters", "Dc"), None, "parameters.Dc"),
    (("parameters", "Cc"), {"box": [-1, 1], "entries": [[3, 0]]}, "parameters.Cc.entries"),
    (("parameters", "Dc"), {"lqr": [-2, 3], "R": 0}, "parameters.Dc.R"),
    (("parameters", "Cc"), {"fixed": [[1.0, 2.0]]}, "parameters.Cc.fixed"),
    (("parameters", "Dc"), {"around": "no-such", "box": [-1, 1]}, "parameters.Dc.around"),
    (("parameters", "Dc"), {"around": "toy-classical", "box": [-1, 1]}, "parameters.Dc.around"),
    (("parameters", "Dc"), {"around": "lqr-paper", "box": [[-1] * 5, [1, 1]]}, "parameters.Dc.box[1]"),
    (("parameters", "Dc"), {"around": "lqr-paper", "box": [[-1] * 5, [1, 1, -2, 1, 1]]},
     "parameters.Dc.box"),
    (("parameters", "Dc"), {"around": "lqr-paper", "box": [-1, 1], "fixed": [[0] * 5]},
     "parameters.Dc.fixed"),
    (("parameters", "Dc"), {"lqr": [-2, 3], "around": "lqr-paper"}, "parameters.Dc"),
    (("optimizer", "warm_start"), "no", "optimizer.warm_start"),
    (("controller", "n_xc"), -1, "controller.n_xc"),
    (("controller", "model"), "segway", "controller.model"),
    (("controller", "time"), "later", "controller.time"),
    (("controller", "period"), 0, "controller.period"),
    (("objective", "type"), "fastest", "objective.type"),
    (("objective",), {"type": "scenarios", "scenarios": ["no-such-scenario"],
                      "terms": [{"metric": "error.ISE"}]}, "objective.scenarios[0]"),
    (("objective",), {"type": "scenarios", "scenarios": ["paper-step"],
                      "terms": [{"metric": "error.Wobble"}]}, "objective.terms[0].metric"),
    (("objective",), {"type": "scenarios", "scenarios": ["paper-step"]}, "objective.terms"),
    (("optimizer", "batch"), 500, "optimizer.batch"),
    (("optimizer", "n_initial_points"), 500, "optimizer.n_initial_points"),
    (("optimizer", "method"), "annealing", "optimizer.method"),
    (("optimizer", "n_calls"), 0, "optimizer.n_calls"),
    (("optimizer", "gp_restarts"), 1.5, "optimizer.gp_restarts"),
    (("optimizer", "region"), "local", "optimizer.region"),
    (("optimizer", "initial"), "lqr-paper", "optimizer.initial"),
    (("optimizer", "initial"), ["no-such-controller"], "optimizer.initial[0]"),
    (("constraints", "stability_margin"), -1, "constraints.stability_margin"),
    (("constraints", "controller_stable"), "yes", "constraints.controller_stable"),
    (("constraints", "stop_early"), -0.5, "constraints.stop_early"),
    (("constraints", "stop_early"), True, "constraints.stop_early"),
    (("constraints", "stop_early"), "soon", "constraints.stop_early"),
    (("constraints", "stop_early"), 1e7, "constraints.stop_early"),
    (("variants",), [{"C1": "x"}], "variants[0].C1"),
    (("baselines",), "lqr-paper", "baselines"),
    # found by the hostile-input probe: a traceback or silently accepted before
    (("parameters", "Bc"), {"box": [-1e308, 1e308]}, "parameters.Bc.box"),
    (("parameters", "Cc"), {"fixed": [[]]}, "parameters.Cc.fixed"),
    (("variants",), [{"C1": 1e-4}], "variants"),
    (("optimizer", "front"), "parego", "optimizer.front"),
    (("constraints",), True, "constraints"),  # found by tests/test_fuzz.py: a TypeError
    (("extra",), 1, "extra"),
])
def test_bad_specs_are_one_line(tmp_path, capsys, keys, value, key):
    data = edit(yaml.safe_load(SPEC.read_text()), keys, value)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    code, _, err = run_cli(capsys, "tune", str(path), "-o", str(tmp_path / "run"))
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, lines
    assert lines[0].startswith(f"error: {path}: {key}"), lines[0]
    assert not (tmp_path / "run").exists()
