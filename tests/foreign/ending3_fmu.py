"""An FMI 3.0 plant another exporter built that asks to end the simulation: from 10 ms on,
its doStep answers fmi3OK with terminateSimulation set (pythonfmu3 passes that flag on)."""

from pythonfmu3 import Fmi3Causality, Fmi3Slave, Fmi3StepResult, Fmi3Variability, Float64


class EndingPlant3(Fmi3Slave):
    author = "tests"
    description = "an integrator that asks to end the simulation after 10 ms"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.time, self.u, self.x = 0.0, 0.0, 0.0
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))
        self.register_variable(Float64("u", causality=Fmi3Causality.input, start=0.0,
                                       variability=Fmi3Variability.continuous))
        self.register_variable(Float64("x", causality=Fmi3Causality.output,
                                       variability=Fmi3Variability.continuous))

    def do_step(self, current_time, step_size):
        self.x += self.u * step_size
        self.time = current_time + step_size
        return Fmi3StepResult(terminateSimulation=current_time >= 0.01)
