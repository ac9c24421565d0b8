"""The Furuta pendulum as another exporter would ship it: a pythonfmu slave with its own
variable names, on the physics of pendulum_physics.py (built with it as a project file).
Integrated by classical RK4 with 20 substeps per doStep.
"""

import math

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real

from pendulum_physics import INPUTS, PHYSICS, STATES, rk4


class ForeignPendulum(Fmi2Slave):
    author = "tests"
    description = "Furuta pendulum, independent pythonfmu implementation"
    # a variant (tests/test_units.py) gives angles in degrees, an output that is not a state
    # (arm_turns), and takes the start of a state on the state itself, as many exporters do,
    # instead of on a <state>_0 parameter
    DEGREES = False
    START_PARAMETERS = True

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        for name, value in PHYSICS.items():
            setattr(self, name, value)
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable))
        for name in STATES:
            setattr(self, name, 0.0)
            if not self.START_PARAMETERS:
                self.register_variable(Real(name, causality=Fmi2Causality.output,
                                            initial=Fmi2Initial.exact, start=0.0))
                continue
            self.register_variable(Real(name, causality=Fmi2Causality.output))
            setattr(self, f"{name}_0", 0.0)
            self.register_variable(Real(f"{name}_0", causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable))
        for name in INPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        if self.DEGREES:
            # an output that is not a state, as exporters often add
            self.register_variable(Real("arm_turns", causality=Fmi2Causality.output,
                                        getter=lambda: self.arm_angle / 360.0))

    def exit_initialization_mode(self):
        if not self.START_PARAMETERS:
            return
        for name in STATES:
            setattr(self, name, getattr(self, f"{name}_0"))

    def do_step(self, current_time, step_size):
        scale = math.pi / 180.0 if self.DEGREES else 1.0
        x = tuple(getattr(self, n) * (1.0 if n == "current" else scale) for n in STATES)
        x = rk4(self, x, tuple(getattr(self, n) for n in INPUTS), step_size)
        for name, value in zip(STATES, x):
            setattr(self, name, value / (1.0 if name == "current" else scale))
        return True
