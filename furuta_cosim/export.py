"""A controller file as an FMI 2.0 co-simulation FMU, for tools with no Python in the loop.

The controller at its period is a discrete linear system from the fed-back signals x and the
reference r to the control input u::

    xc[k+1] = Ac xc[k] + Bc x[k]
    u[k]    = F r[k] - Cc xc[k] - Dc x[k]

which is exactly the project's linear plant model (``fmu_src/linear``) with
A = Ac, B = [Bc 0], C = -Cc, D = [-Dc F]; so the controller FMU is built by the same
exporter and glue as the plants. Its inputs are named after the model's states (the plant's
fed-back outputs) and ``r``, its output after the model's input (``V``). A static controller
(n_xc = 0) keeps one inert state (C has no zero-size arrays): it never reaches the output.

With ``delay=1`` the FMU holds each command for one sample (a state z: z[k+1] = u computed
at k, output z), so it has no direct feedthrough, and a master that exchanges values as
Ecos, libcosim and ``simulate LOOP.ssp`` do (Jacobi: every FMU steps, then every output is
copied) runs the loop of ``timing.delay: 1``; a Gauss-Seidel master runs another (measured on
the docs' SSP page).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from furuta_cosim.controllers import check_fits, load_controller
from furuta_cosim.defaults import MAX_MAGNITUDE
from furuta_cosim.design.controller import discretize_controller
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.plants import LinearSpec, PlantSet
from furuta_cosim.scenario_source import noise_input
from furuta_cosim.signals import controller_state

REFERENCE_INPUT = "r"

# what an FMU of this exporter cannot hold: it is a linear law (the linear plant model's C),
# and a swing-up's energy law and its switches to and from the catch are not
_NOT_LINEAR = ("{source}: a swing-up is not a linear law, and the FMU this exporter builds holds one "
               "(u = F r - Cc xc - Dc x): its energy pumping and its switches to and from the catch would be "
               "dropped; export its balance controller ({balance}) for the loop near upright, and run the "
               "swing-up in furuta-cosim (simulate, rig run)")


def _signals(linear, tracked: str | None, F: float, delay: bool, noise=()) -> list[tuple[str, str, str]]:
    """(name, unit, description) of the controller FMU's inputs and output: each fed-back
    signal as the plant model declares it (its unit and its zero: the declaration of the plant
    the controller's model was linearized from, else the default plant's), the reference,
    and the command."""
    from furuta_cosim.fmu.exporter import declaration
    from furuta_cosim.fmu.plants import load_plant

    source = (getattr(linear, "provenance", None) or {}).get("plant_file")
    try:
        model = declaration(load_plant(source) if source else load_plant())
    except ConfigError:
        model = declaration(load_plant())
    declared = {v.name: v for v in model.reals}
    found = []
    for name in linear.states:
        v = declared.get(name)
        if v is None:
            found.append((name, "", f"fed back: the plant's {name}, in the model's units"))
            continue
        text = f"fed back: {v.description} ({v.unit or 'no unit'})"
        if name in model.upright:
            text += "; a rig whose encoder reads 0 hanging feeds its reading minus pi"
        found.append((name, v.unit, text))
    if tracked:
        v = declared.get(tracked)
        found.append((REFERENCE_INPUT, v.unit if v else "",
                      f"reference for {tracked}" + (f" ({v.unit})" if v and v.unit else "")
                      + f", through the prefilter F = {F:.6g}"))
    else:
        found.append((REFERENCE_INPUT, "", "reference (the controller file names no tracked output: F = 0)"))
    for name in noise:
        v = declared.get(name)
        found.append((noise_input(name), v.unit if v else "", f"measurement noise added to {name} before the law"))
    command = linear.inputs[0]
    v = declared.get(command)
    found.append((command, v.unit if v else "",
                  f"command: {v.description if v else command}, u = F r - Cc xc - Dc x"
                  + ("; held one sample" if delay else "") + "; clip it to the amplifier's limit"))
    return found


def controller_plant(name: str | Path, *, period: float | None = None, model: str | None = None,
                     delay: int = 0, noise: tuple = ()) -> PlantSet:
    """The linear 'plant' of a controller file: what the exporter builds into its FMU. With
    ``noise`` (fed-back signals), one more input per signal, added to it before the law
    (``n_<signal>``, fed by a scenario's source: furuta_cosim/scenario_source.py)."""
    from furuta_cosim.models import load_model

    cfile = load_controller(name)
    if cfile.swingup is not None:
        raise ConfigError([_NOT_LINEAR.format(source=cfile.source, balance=Path(cfile.balance).stem if cfile.balance else "its balance controller")])
    model_name = model or cfile.model
    if not model_name:
        raise ConfigError([f"{cfile.source}: model: missing; name the model the controller "
                           "runs on (its states name the FMU's inputs), or give `model`"])
    try:
        linear = load_model(model_name, None if model or not cfile.path else cfile.path.parent)
    except ConfigError as error:
        raise error.within(f"{cfile.source}: model") from None
    cfile = check_fits(cfile, linear)
    if period is not None:
        from furuta_cosim.config import Checker

        check = Checker("period")
        period = check.period(period, "")
        check.done()
    period = period or cfile.period or linear.period
    if not period:
        raise ConfigError([f"{cfile.source}: period: missing; a continuous controller needs the "
                           "period it is sampled at (`period`)"])
    c = discretize_controller(cfile.controller, period)
    for key in ("Ac", "Bc", "Cc", "Dc"):  # a continuous controller sampled at its period
        matrix = getattr(c, key)
        if matrix.size and not np.all(np.abs(matrix) <= MAX_MAGNITUDE):
            raise ConfigError([f"{cfile.source}: {key} sampled at {period:g}: entries beyond "
                               f"+-{MAX_MAGNITUDE:g} (or not finite): the FMU's output would be too"])
    F = cfile.F if cfile.F is not None else 0.0
    n, m = c.Dc.shape[1], c.n_xc
    unknown = [s for s in noise if s not in linear.states]
    if unknown:
        raise ConfigError([f"{cfile.source}: noise on {unknown[0]}, which the controller does not feed back "
                           f"({', '.join(linear.states)})"])
    picked = [list(linear.states).index(s) for s in noise]
    A, B = c.Ac, np.hstack([c.Bc, np.zeros((m, 1)), c.Bc[:, picked]])     # xc[k+1] from [x; r; n]
    C, D = -c.Cc, np.hstack([-c.Dc, [[F]], -c.Dc[:, picked]])              # u from xc and [x; r; n]
    states = [controller_state(k + 1) for k in range(m)]
    if delay:  # z[k+1] = u[k]; the output is z
        A = np.block([[A, np.zeros((m, 1))], [C, np.zeros((1, 1))]])
        B = np.vstack([B, D])
        C, D = np.hstack([np.zeros((1, m)), [[1.0]]]), np.zeros_like(D)
        states.append("u_held")
    elif not m:  # one inert state: C has no zero-size arrays
        A, B, C, states = np.zeros((1, 1)), np.zeros((1, B.shape[1])), np.zeros((1, 1)), [controller_state(1)]
    # a C identifier from the name: its alphanumeric parts, capitalized (lqr-paper: LqrPaper)
    identifier = "".join(part.capitalize() for part in re.split(r"[^0-9A-Za-z]+", cfile.name) if part)
    if not identifier[:1].isalpha():
        identifier = f"C{identifier}"
    spec = LinearSpec(f"{identifier}Controller{'Delayed' if delay else ''}",
                      f"controller {cfile.name} at {period:g} s (u = F r - Cc xc - Dc x"
                      + (", applied one sample late)" if delay else ")"),
                      True, float(period), 1, A.tolist(), B.tolist(), C.tolist(), D.tolist(),
                      [*linear.states, REFERENCE_INPUT, *[noise_input(s) for s in noise]],
                      list(linear.inputs[:1]), states, [0.0] * len(states),
                      signals=tuple(_signals(linear, cfile.tracked_output, F, bool(delay), noise)))
    return PlantSet(cfile.name, cfile.path or Path(cfile.name), "linear",
                    spec.description, linear=spec)


def export_controller(name: str | Path, output: str | Path | None = None, *,
                      period: float | None = None, model: str | None = None, delay: int = 0,
                      log=None, fmi_version: str = "2.0") -> Path:
    """Build the controller FMU (cached like the plants'); copy it to ``output`` when given."""
    from furuta_cosim.fmu.exporter import build_fmu

    if delay not in (0, 1):
        raise ConfigError([f"delay: expected 0 or 1 control samples, got {delay}"])
    return build_fmu(controller_plant(name, period=period, model=model, delay=delay),
                     output=output, log=log, fmi_version=fmi_version)


def ecos_closed_loop(scenario, controller: str | Path, *, delay: int = 1):
    """The scenario's plant FMU and the controller's FMU connected in Ecos, no Python in the
    loop: ``(t, {signal: values})`` at the control instants, the fed-back states and the
    applied input (``u``). The scenario's reference must be constant (it is the FMU's ``r``),
    and it needs no noise, disturbances, estimator or actuator limit of the master's: those
    are the Python master's.

    Parameters
    ----------
    scenario : Scenario, str or path
        A scenario name, file or loaded scenario.
    controller : str or path
        The controller's FMU (from ``export-controller``).
    delay : int, optional
        Control periods between a measurement and the input it causes (1, the default, is
        the master's one-step delay).

    Returns
    -------
    tuple of (ndarray, dict)

    Raises
    ------
    ConfigError
        When Ecos is not installed (the ``ecos`` extra) or the scenario needs the master.
    """
    from furuta_cosim.cosim.master import prepare
    from furuta_cosim.fmu.check import ecos_available, run_ecos_connected
    from furuta_cosim.fmu.contained import contained

    missing = ecos_available()
    if missing:
        raise ConfigError([f"ecos_closed_loop runs the Ecos engine: {missing}"])

    prepared = prepare(scenario)
    loop_only(prepared, "the Ecos loop")
    from furuta_cosim.fmu.session import model_description

    from furuta_cosim.fmu.exporter import build_fmu

    made = controller_plant(controller, period=prepared.control_period, delay=delay)
    fmu = build_fmu(made)
    outputs = dict(zip(prepared.states, prepared.outputs))
    connections = [(f"plant::{outputs[s]}", f"controller::{s}") for s in prepared.states]
    connections.append((f"controller::{made.linear.outputs[0]}", f"plant::{prepared.control_input}"))
    reals = {v.name for v in model_description(prepared.fmu).modelVariables if v.type == "Real"}
    start = {f"plant::{k}": float(v) for k, v in prepared.start.items() if k in reals}
    start[f"controller::{REFERENCE_INPUT}"] = float(prepared.rbar[0]) if len(prepared.rbar) else 0.0
    names = [f"plant::{outputs[s]}" for s in prepared.states] + [f"plant::{prepared.control_input}"]
    # in a child process: an engine crash is Ecos's verdict (EngineFailed), not ours
    rows = contained(run_ecos_connected, {"plant": prepared.fmu, "controller": fmu}, connections,
                     start, names, prepared.steps, prepared.control_period, engine="Ecos", timeout=600)
    signals = {s: rows[:, k] for k, s in enumerate(prepared.states)}
    signals["u"] = rows[:, -1]
    return prepared.t[:len(rows)], signals


def loop_only(prepared, what: str, allowed=()) -> None:
    """Refuse a scenario that needs more than a plant FMU and a controller FMU connected: a
    reference that changes, noise, disturbances, an estimator, an actuator limit, or a
    communication step finer than the control period are the Python master's (``allowed``:
    the keys among ``reference``, ``actuator limit``, ``noise``, ``disturbances`` the caller
    carries otherwise)."""
    scenario = prepared.scenario
    unsupported = [key for key, present in (
        ("reference (not constant)", not constant(prepared.rbar) and "reference" not in allowed),
        ("noise", scenario.noise and "noise" not in allowed),
        ("disturbances", scenario.disturbances and "disturbances" not in allowed),
        ("estimator", scenario.estimator),
        ("actuator limit", prepared.limit and "actuator limit" not in allowed),
        ("timing.communication_step", prepared.substeps != 1))
        if present]
    if unsupported:
        parts = "plant and controller" + (" and the scenario's source" if "noise" in allowed else "")
        raise ConfigError([f"{scenario.source}: {what} has only {parts}; "
                           f"this scenario needs the master for: {', '.join(unsupported)}"])


def constant(values) -> bool:
    return len(values) == 0 or bool(np.all(values == values[0]))
