"""Co-simulation: Python controllers sampling a plant FMU, references, noise, traces.

The public operation, in three steps: :func:`prepare` a scenario, :func:`compile_controller`
against it (or let :func:`evaluate` do so), :func:`evaluate` on an open plant session ->
:class:`RunResult`. :func:`simulate` runs a scenario's controllers in turn.
"""

from furuta_cosim.cosim.evaluation import Compiled, compile_controller, evaluate, runs, simulate
from furuta_cosim.cosim.master import Prepared, prepare
from furuta_cosim.cosim.result import RunResult

__all__ = ["Compiled", "Prepared", "RunResult", "compile_controller", "evaluate", "prepare",
           "runs", "simulate"]
