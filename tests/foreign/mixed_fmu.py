"""A valid FMU with every FMI 2.0 variable type: a first-order lag (Real), a step counter
(Integer), a saturation flag (Boolean) and a label (String). validate-fmu must call it valid."""

from pythonfmu import Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real, String


class MixedTypes(Fmi2Slave):
    author = "tests"
    description = "one variable of each FMI 2.0 type"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u, self.y, self.tau = 1.0, 0.0, 0.5
        self.steps, self.saturated, self.label = 0, False, "lag"
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("tau", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        # outputs with an exact start: fmpy then expects none of them among the initial unknowns
        exact = {"causality": Fmi2Causality.output, "initial": Fmi2Initial.exact}
        self.register_variable(Real("y", **exact))
        self.register_variable(Integer("steps", variability=Fmi2Variability.discrete, **exact))
        self.register_variable(Boolean("saturated", variability=Fmi2Variability.discrete, **exact))
        self.register_variable(String("label", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed))

    def do_step(self, current_time, step_size):
        self.y += step_size / self.tau * (self.u - self.y)
        self.steps += 1
        self.saturated = self.y > 0.9
        return True
