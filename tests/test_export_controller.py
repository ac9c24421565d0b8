"""A controller as an FMU, and the closed loop of two FMUs in Ecos against the Python master."""

from dataclasses import replace

import numpy as np
import pytest
from fmpy.validation import validate_fmu

from furuta_cosim.cosim import evaluate, prepare
from furuta_cosim.export import ecos_closed_loop, export_controller
from furuta_cosim.fmu.check import ecos_available
from furuta_cosim.fmu.session import PlantSession
from furuta_cosim.scenario import load_scenario

from helpers import DYNAMIC, run_cli


def _master(scenario, controller, delay):
    prepared = prepare(replace(load_scenario(scenario), delay=delay))
    with PlantSession.open(prepared.fmu) as session:
        return evaluate(prepared, session, controller)


@pytest.mark.parametrize("delay", [0, 1])
@pytest.mark.parametrize("controller", ["lqr-paper", "bo-paper"])
def test_the_controller_fmu_passes_fmpy_validate(tmp_path, controller, delay):
    path = export_controller(controller, tmp_path, delay=delay)
    assert path.parent == tmp_path and path.suffix == ".fmu"
    assert validate_fmu(str(path)) == []


def test_the_cli_exports_and_names_bad_input(tmp_path, capsys):
    code, out, _ = run_cli(capsys, "export-controller", "lqr-paper", "-o", str(tmp_path))
    assert code == 0 and out.strip() == str(tmp_path / "LqrPaperController.fmu")
    code, _, err = run_cli(capsys, "export-controller", "nosuch")
    assert code == 2 and "nosuch: no such controller" in err and len(err.strip().splitlines()) == 1


@pytest.mark.skipif(ecos_available() is not None, reason=f"Ecos cannot run: {ecos_available()}")
@pytest.mark.parametrize("controller", ["lqr-paper", "bo-paper", "dynamic"])
def test_plant_and_controller_fmus_in_ecos_match_the_master_with_one_sample_delay(tmp_path, controller):
    if controller == "dynamic":
        (tmp_path / "dynamic.yaml").write_text(DYNAMIC)
        controller = str(tmp_path / "dynamic.yaml")
    t, ecos = ecos_closed_loop(load_scenario("paper-step"), controller, delay=1)
    master = _master("paper-step", controller, delay=1)
    assert len(t) == len(master.trace.t) == 5000
    for name, values in ecos.items():
        assert np.max(np.abs(values - master.trace[name])) <= 1e-9, name
    # the loop did something, and the delay matters: without it the master differs
    assert np.max(np.abs(master.trace["theta0"])) > 1e-3
    plain = _master("paper-step", controller, delay=0)
    assert np.max(np.abs(plain.trace["theta1"] - master.trace["theta1"])) > 1e-5


def test_the_master_delay_holds_each_command_one_sample(tmp_path):
    plain = _master("paper-step", "lqr-paper", delay=0)
    delayed = _master("paper-step", "lqr-paper", delay=1)
    assert delayed.trace.u[0] == 0.0
    # the first command of the delayed loop is the undelayed loop's first (same start)
    assert delayed.trace.u[1] == pytest.approx(plain.trace.u[0], rel=1e-12)


def test_ecos_refuses_what_only_the_master_has(capsys):
    from furuta_cosim.errors import ConfigError

    with pytest.raises(ConfigError, match="needs the master for: .*noise"):
        ecos_closed_loop(load_scenario("noise"), "lqr-paper")


@pytest.mark.parametrize("value", ["2", "-1", "true", "0.5"])
def test_a_bad_timing_delay_is_one_line(tmp_path, capsys, value):
    text = load_scenario("paper-step").path.read_text()
    path = tmp_path / "s.yaml"
    path.write_text(text.replace("  control_period: 0.002", f"  control_period: 0.002\n  delay: {value}"))
    code, _, err = run_cli(capsys, "simulate", str(path), "-o", str(tmp_path / "o"))
    assert code == 2 and f"{path}: timing.delay: expected 0 or 1" in err


def test_the_ecos_loop_without_ecos_is_one_error_naming_the_extra(monkeypatch):
    from furuta_cosim import export
    from furuta_cosim.errors import ConfigError
    from furuta_cosim.fmu import check
    from furuta_cosim.scenario import load_scenario

    monkeypatch.setattr(check, "ecos_available",
                        lambda: "ecospy is not installed (the ecos extra: pip install -e '.[ecos]')")
    with pytest.raises(ConfigError, match=r"ecos_closed_loop runs the Ecos engine: ecospy is not installed "
                                          r"\(the ecos extra"):
        export.ecos_closed_loop(load_scenario("paper-step"), "lqr-paper", delay=1)


def test_the_controller_fmu_says_what_each_signal_is(tmp_path):
    """Every input said "control input" and the voltage "measured output": an engineer wiring
    the FMU into Simulink could not tell the pendulum's zero or a unit."""
    from fmpy import read_model_description

    md = read_model_description(str(export_controller("lqr-qube", tmp_path / "lqr.fmu")))
    signals = {v.name: v for v in md.modelVariables if v.causality in ("input", "output")
               and not v.name.startswith(("v_", "xc"))}
    assert {n: v.unit for n, v in signals.items()} == {"theta0": "rad", "dtheta0": "rad/s", "theta1": "rad",
                                                       "dtheta1": "rad/s", "i": "A", "r": "rad", "V": "V"}
    assert "0 = upright" in signals["theta1"].description and "minus pi" in signals["theta1"].description
    assert "prefilter F = -0.498073" in signals["r"].description
    assert signals["V"].causality == "output" and "clip" in signals["V"].description
    assert not any(v.description in ("control input", "measured output") for v in signals.values())
