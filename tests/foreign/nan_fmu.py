"""A plant FMU whose outputs turn NaN: a pythonfmu slave with the foreign pendulum's names, a
stable first-order response in each state until ``nan_after`` seconds, NaN from then on.
Another tool's FMU may do this without an error status; a run on it must fail, not pass.
Built with pendulum_physics.py as a project file (the names)."""

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

from pendulum_physics import INPUTS, STATES


class NanPlant(Fmi2Slave):
    author = "tests"
    description = "outputs NaN after nan_after seconds"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.nan_after = 0.014
        self.register_variable(Real("nan_after", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable))
        for name in STATES:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.output))
            setattr(self, f"{name}_0", 0.0)
            self.register_variable(Real(f"{name}_0", causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable))
        for name in INPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input))

    def exit_initialization_mode(self):
        for name in STATES:
            setattr(self, name, getattr(self, f"{name}_0"))

    def do_step(self, current_time, step_size):
        end = current_time + step_size
        for name in STATES:
            value = getattr(self, name)
            setattr(self, name, float("nan") if end > self.nan_after + 1e-12 else 0.9 * value)
        return True
