"""Plant variables declared in Python, pythonfmu style; equations stay in C.

A plant's ``fmu_src/<model>/model.py`` defines ``declare(options)`` that returns a
:class:`Model` whose variables were registered in order. The order gives the value
references; the exporter turns the declaration into ``modelDescription.xml`` and the C
header ``model_vars.h``.
"""

from __future__ import annotations

import math
import re
import sys
from dataclasses import dataclass, field

from furuta_cosim.errors import FmuError
from furuta_cosim.signals import start_parameter

CAUSALITIES = ("parameter", "input", "output", "local")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\[[0-9]+(,[0-9]+)*\])?$|^der\([A-Za-z_][A-Za-z0-9_]*\)$")


class DeclarationError(FmuError):
    """A plant declaration (``fmu_src/<model>/model.py``) that cannot become an FMU.

    ``variable`` names the variable at fault when one is, and ``reason`` says why, so that a
    caller can point at the parameter file's key instead."""

    def __init__(self, message: str, variable: str | None = None, reason: str = "",
                 where: tuple[str, int] | None = None):
        super().__init__(message)
        self.variable, self.reason = variable, reason or message
        # (file, line) of the declaration's call that registered the variable at fault, when
        # that call is outside this package (a user's plant folder)
        self.where = where


def _caller() -> tuple[str, int] | None:
    """The file and line of the first caller outside this module: where a plant's
    ``declare()`` registered the variable (a user's ``model.py`` line, for its messages)."""
    frame = sys._getframe(1)
    while frame is not None and frame.f_code.co_filename == __file__:
        frame = frame.f_back
    return (frame.f_code.co_filename, frame.f_lineno) if frame is not None else None


@dataclass(frozen=True)
class Real:
    """A Real variable.

    Parameters
    ----------
    name : str
        FMI name; ``A[1,2]`` style structured names are allowed.
    causality : {"parameter", "input", "output", "local"}
    start : float, optional
        Required for parameters and inputs.
    unit : str
        Its unit (``"1"`` for a pure number; a plant folder's states, inputs and parameters
        must give one).
    description : str
        One line saying what it is.
    positive : bool
        The FMU rejects values <= 0 (masses, lengths, inertias).
    minimum : float, optional
        The smallest physical value (a friction or a stiffness is >= 0): the model
        description's ``min``, which importers check before they set a value.
    maximum : float, optional
        The largest physical value (an efficiency is <= 1): the model description's ``max``.
    """

    name: str
    causality: str
    start: float | None = None
    unit: str = ""
    description: str = ""
    positive: bool = False
    minimum: float | None = None
    maximum: float | None = None


# RK4 substeps per communication step, at most: beyond it one step costs more than a
# millisecond of wall time for no accuracy anyone needs (10 give about 1e-12 rad at 1 ms)
MAX_SUBSTEPS = 1000


@dataclass(frozen=True)
class Integer:
    """An Integer parameter (for example the RK4 substep count).

    Parameters
    ----------
    name : str
        FMI name.
    start : int
        Its value unless set.
    minimum : int
        Its smallest value, checked by the FMU.
    maximum : int
        Its largest value, checked by the FMU.
    description : str
    causality : str
        Always ``"parameter"``.
    """

    name: str
    start: int
    minimum: int = -(2**31)
    description: str = ""
    causality: str = "parameter"
    maximum: int = 2**31 - 1


@dataclass(frozen=True)
class State:
    """A state: an output ``name``, its start parameter ``name_start`` and ``der(name)``."""

    name: str
    start_parameter: str
    derivative: str | None


@dataclass
class Model:
    """A plant declaration: identifier, time domain and ordered variables.

    A plant's ``declare(parameters)`` builds one and registers its variables in order
    (:meth:`register_variable`, :meth:`register_state`, :meth:`parameter`); the exporter
    turns it into the FMU's model description and the C header of its equations.

    Parameters
    ----------
    identifier : str
        The FMU's model identifier: a C name (it names the binary and the C functions).
    description : str
        One line saying what the plant is.
    discrete : bool
        A plant that advances once per sample period (``sample_period``) instead of a
        continuous one integrated by RK4 (``substeps``).
    reals : list of Real
        The registered Real variables, in order (filled by the register methods).
    integers : list of Integer
        The registered Integer parameters, in order.
    states : list of State
        The registered states, in order.
    substeps : str, optional
        The Integer parameter that counts RK4 substeps per communication step (continuous).
    sample_period : str, optional
        The Real parameter that is the sample period (discrete).
    constants : dict
        Extra ``#define`` lines of the C header (name -> integer).
    measured : list of str
        The outputs a sensor measures (a design model's outputs); the first is the output a
        reference tracks when a scenario names none. Empty: every state.
    nonsmooth : list of str
        Parameters a linear model leaves out (set to 0 for linearization: Coulomb friction).
    upright : list of str
        States whose 0 is a pendulum upright: a run that lets one fall beyond pi/2 diverged.
    """

    identifier: str
    description: str
    discrete: bool = False
    reals: list[Real] = field(default_factory=list)
    integers: list[Integer] = field(default_factory=list)
    states: list[State] = field(default_factory=list)
    substeps: str | None = None
    sample_period: str | None = None
    constants: dict[str, int] = field(default_factory=dict)
    measured: list[str] = field(default_factory=list)  # outputs a design model measures (all: empty)
    nonsmooth: list[str] = field(default_factory=list)  # parameters a linear model leaves out (set to 0)
    # states whose 0 is a pendulum upright: a run that lets one fall beyond pi/2 diverged
    upright: list[str] = field(default_factory=list)
    # name -> value reference, kept as variables are registered (a linear plant or a controller
    # declares tens of thousands: a scan per registration made declaring quadratic)
    _references: dict[str, tuple[str, int]] = field(default_factory=dict, repr=False, compare=False,
                                                     init=False)
    # name -> (file, line) of the call that registered it (see _caller)
    where: dict[str, tuple[str, int] | None] = field(default_factory=dict, repr=False, compare=False,
                                                     init=False)

    def parameter(self, values, name: str, default: float, unit: str, description: str, *,
                  positive: bool = False, minimum: float | None = None,
                  maximum: float | None = None) -> None:
        """Register the Real parameter ``name``: its start is ``values[name]`` (the plant
        file's), else ``default``.

        Parameters
        ----------
        values : mapping
            The plant file's parameters (``declare``'s argument).
        name : str
            The parameter's FMI name (and C name: ``R(name)`` in model.c).
        default : float
            Its value when the plant file gives none.
        unit : str
            Its unit (``"1"`` for a pure number).
        description : str
            One line saying what it is.
        positive : bool
            It must be > 0 (a mass, a length).
        minimum : float, optional
            The smallest physical value (a damping >= 0), which every value of it must
            respect: a plant file's, an importer's (the model description's min).
        maximum : float, optional
            The largest physical value (an efficiency <= 1): the model description's max.
        """
        start = values.get(name, default) if values is not None else default
        try:
            start = float(start)
        except (TypeError, ValueError):
            raise DeclarationError(f"{self.identifier}.{name}: expected a number, got {start!r}",
                                   name, f"expected a number, got {start!r}", _caller()) from None
        self.register_variable(Real(name, "parameter", start=start, unit=unit, description=description,
                                    positive=positive, minimum=minimum, maximum=maximum))

    def register_variable(self, variable: Real | Integer) -> None:
        """Add a variable; its value reference is its position of registration.

        Parameters
        ----------
        variable : Real or Integer
            An input, output, parameter or local; the first input is the control input,
            the others disturbance inputs.
        """
        try:
            self._register(variable)
        except DeclarationError as error:
            error.where = error.where or _caller()
            raise
        self.where[variable.name] = _caller()

    def _register(self, variable: Real | Integer) -> None:
        if not _NAME.match(variable.name):
            raise DeclarationError(f"{self.identifier}: invalid variable name {variable.name!r}")
        if variable.name in self._references:
            raise DeclarationError(f"{self.identifier}: variable {variable.name!r} declared twice")
        if variable.causality not in CAUSALITIES:
            raise DeclarationError(
                f"{self.identifier}.{variable.name}: causality must be one of {CAUSALITIES}")
        if isinstance(variable, Integer):
            if not variable.minimum <= variable.start <= variable.maximum:
                reason = f"must be a whole number in [{variable.minimum}, {variable.maximum}], got {variable.start}"
                raise DeclarationError(f"{self.identifier}.{variable.name}: start {reason}",
                                       variable.name, reason)
            self._references[variable.name] = ("integer", len(self.integers))
            self.integers.append(variable)
            return
        if variable.causality in ("parameter", "input"):
            if variable.start is None or not math.isfinite(variable.start):
                raise DeclarationError(
                    f"{self.identifier}.{variable.name}: a {variable.causality} needs a finite start",
                    variable.name, "must be finite")
            if variable.positive and variable.start <= 0:
                raise DeclarationError(
                    f"{self.identifier}.{variable.name}: start {variable.start} must be > 0",
                    variable.name, f"must be > 0, got {variable.start:g}")
            if variable.minimum is not None and variable.start < variable.minimum:
                raise DeclarationError(
                    f"{self.identifier}.{variable.name}: start {variable.start} must be >= {variable.minimum:g}",
                    variable.name, f"must be >= {variable.minimum:g}, got {variable.start:g}")
            if variable.maximum is not None and variable.start > variable.maximum:
                raise DeclarationError(
                    f"{self.identifier}.{variable.name}: start {variable.start} must be <= {variable.maximum:g}",
                    variable.name, f"must be <= {variable.maximum:g}, got {variable.start:g}")
        if variable.minimum is not None and variable.maximum is not None and variable.minimum > variable.maximum:
            raise DeclarationError(f"{self.identifier}.{variable.name}: minimum {variable.minimum:g} is "
                                   f"above maximum {variable.maximum:g}", variable.name)
        self._references[variable.name] = ("real", len(self.reals))
        self.reals.append(variable)

    def register_state(self, name: str, start: float, unit: str, description: str) -> None:
        """Add a state: an output, the parameter ``<name>_start`` and, if continuous, ``der(<name>)``.

        Parameters
        ----------
        name : str
            The state's name; the states' order of registration is the order of ``x`` and
            ``dx`` in model.c.
        start : float
            Its initial value (``<name>_start``: what a scenario's ``plant.initial`` sets).
        unit : str
            Its unit; a plant folder must give one (``"1"`` for a pure number).
        description : str
            One line saying what it is.
        """
        self.register_variable(Real(name, "output", unit=unit, description=description))
        start_name = start_parameter(name)
        self.register_variable(Real(start_name, "parameter", start=start, unit=unit,
                                    description=f"initial value of {name}"))
        derivative = None
        if not self.discrete:
            derivative = f"der({name})"
            rate_unit = f"{unit}/s" if unit else "1/s"
            self.register_variable(Real(derivative, "local", unit=rate_unit,
                                        description=f"time derivative of {name}"))
        self.states.append(State(name, start_name, derivative))

    def names(self) -> list[str]:
        """Every variable's name, in value reference order."""
        return [v.name for v in self.reals] + [v.name for v in self.integers]

    def value_reference(self, name: str) -> int:
        """Reals first, then integers: one value reference space for all types.

        Parameters
        ----------
        name : str
            A registered variable.
        """
        kind, k = self._references[name]
        return k if kind == "real" else len(self.reals) + k

    def check(self) -> None:
        """Everything the glue relies on is declared."""
        if not self.states:
            raise DeclarationError(f"{self.identifier}: declares no state")
        if self.discrete:
            if self.sample_period is None:
                raise DeclarationError(f"{self.identifier}: a discrete model needs sample_period")
        elif self.substeps is None:
            raise DeclarationError(f"{self.identifier}: a continuous model needs substeps")
        for name in (self.substeps, self.sample_period):
            if name is not None and name not in self._references:
                raise DeclarationError(f"{self.identifier}: {name!r} is not declared")
