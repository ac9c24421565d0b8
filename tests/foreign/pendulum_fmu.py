"""The Furuta pendulum as another exporter would ship it: a pythonfmu slave with its own
variable names, on the physics of pendulum_physics.py (built with it as a project file).
Integrated by classical RK4 with 20 substeps per doStep.
"""

import math

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real

from pendulum_physics import INPUTS, PHYSICS, STATES, rates


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

    def _rates(self, x):
        return rates(self, x, (self.voltage, self.arm_torque, self.pend_torque))

    def do_step(self, current_time, step_size):
        scale = math.pi / 180.0 if self.DEGREES else 1.0
        x = tuple(getattr(self, n) * (1.0 if n == "current" else scale) for n in STATES)
        h = step_size / 20
        for _ in range(20):
            k1 = self._rates(x)
            k2 = self._rates(tuple(v + 0.5 * h * k for v, k in zip(x, k1)))
            k3 = self._rates(tuple(v + 0.5 * h * k for v, k in zip(x, k2)))
            k4 = self._rates(tuple(v + h * k for v, k in zip(x, k3)))
            x = tuple(v + h / 6 * (p + 2 * q + 2 * s + t) for v, p, q, s, t in zip(x, k1, k2, k3, k4))
        for name, value in zip(STATES, x):
            setattr(self, name, value / (1.0 if name == "current" else scale))
        return True
