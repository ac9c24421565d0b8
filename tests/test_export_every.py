"""Every controller the project ships, exported: the FMU computes what the master runs (to
1e-9 of the command, with the one-sample delay and without), or the export is refused in one
line naming what the FMU cannot hold."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from furuta_cosim.controllers import load_controller
from furuta_cosim.cosim import prepare
from furuta_cosim.cosim.evaluation import compile_controller
from furuta_cosim.errors import ConfigError
from furuta_cosim.export import REFERENCE_INPUT, export_controller
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.scenario import load_scenario

from helpers import ROOT, one_line

SHIPPED = sorted(p.stem for p in (ROOT / "scenarios" / "controllers").glob("*.yaml"))
# a scenario of each model the shipped controllers run on: where the master compiles them
SCENARIO = {"paper-printed": "paper-step", "derived:qube-servo-3": "qube-step", "toy": "toy-step"}
AGREE = 1e-9   # of the command's scale


def _inputs(names: list[str], steps: int, seed: int) -> np.ndarray:
    """Fed-back signals and references that move the law through its whole range: each a
    random walk, the reference a few steps."""
    rng = np.random.default_rng(seed)
    walk = np.cumsum(rng.normal(0.0, 0.02, size=(steps, len(names))), axis=0)
    walk[:, -1] = np.repeat(rng.uniform(-0.5, 0.5, size=steps // 50 + 1), 50)[:steps]
    return walk


def test_the_list_is_every_shipped_controller():
    assert len(SHIPPED) >= 6 and {"lqr-paper", "bo-paper", "lqr-qube", "swingup-qube"} <= set(SHIPPED)


@pytest.mark.parametrize("delay", [0, 1])
@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_controller_exports_as_it_runs_or_is_refused(tmp_path, name, delay):
    cfile = load_controller(name)
    if cfile.swingup is not None:
        with pytest.raises(ConfigError) as refused:
            export_controller(name, tmp_path, delay=delay)
        line = str(refused.value)
        assert len(line.splitlines()) == 1
        assert "swing-up is not a linear law" in line and "lqr-qube" in line
        assert not list(tmp_path.iterdir())   # nothing written
        return
    prepared = prepare(replace(load_scenario(SCENARIO[cfile.model]), delay=delay))
    runtime = compile_controller(prepared, name).runtime
    fmu = export_controller(name, tmp_path, delay=delay)
    names = [*prepared.states, REFERENCE_INPUT]
    signals = _inputs(names, 400, seed=sum(map(ord, name)) + delay)
    master, exported = [], []
    with PlantSession.open(fmu) as session:
        session.reset()
        output = [prepared.control_input]   # the command the FMU writes
        session.set_io(names, output)
        runtime.reset()
        for row in signals:
            # the command at this sample: the FMU's output with this sample's inputs set
            session.set(dict(zip(names, row)))
            exported.append(session.get(output)[0])
            session.step(list(row), prepared.control_period)
            master.append(runtime(list(row[:-1]), float(row[-1])))
    master, exported = np.array(master), np.array(exported)
    scale = max(1.0, float(np.max(np.abs(master))))
    assert np.max(np.abs(exported - master)) <= AGREE * scale, name
    assert np.max(np.abs(master)) > 1e-2          # the law did something
    if delay:
        assert master[0] == 0.0 and exported[0] == 0.0


def test_the_cli_refuses_a_swing_up_in_one_line_and_writes_nothing(tmp_path, capsys):
    for command in (["export-controller", "swingup-qube", "-o", str(tmp_path)],
                    ["export-ssp", "swingup-qube", "-o", str(tmp_path / "loop.ssp")]):
        assert "a swing-up is not a linear law" in one_line(capsys, *command)
    assert not list(tmp_path.iterdir())
