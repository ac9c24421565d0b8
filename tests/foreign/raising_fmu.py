"""A plant another exporter built that gives up: its doStep raises after 10 ms (pythonfmu
answers with fmi2Fatal, after which FMI 2.0 allows no further call on the instance)."""

from pythonfmu import Fmi2Causality, Fmi2Slave, Real


class RaisingPlant(Fmi2Slave):
    author = "tests"
    description = "an integrator whose doStep raises after 10 ms"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.x = 0.0
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("x", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        if current_time >= 0.01:
            raise RuntimeError("the plant gave up")
        self.x += self.u * step_size
        return True
