"""The foreign pendulum exported for FMI 3.0 by pythonfmu3, with co-simulation and model
exchange, on the physics of pendulum_physics.py (built with it as a project file).

As the Modelica Association's Reference FMUs do it: a state takes its start value on the
variable itself (``initial="exact"``), its derivative is a variable of its own that names it
(``derivative``), the angles declare their unit. Co-simulation steps by classical RK4 with 20
substeps per doStep.
"""

from pythonfmu3 import Fmi3Causality, Fmi3Initial, Fmi3Slave, Fmi3Variability, Float64, ModelExchange, Unit

from pendulum_physics import INPUTS, PHYSICS, STATES, rates, rk4

UNITS = {"arm_angle": "rad", "arm_rate": "rad/s", "pend_angle": "rad", "pend_rate": "rad/s",
         "current": "A", "voltage": "V", "arm_torque": "N.m", "pend_torque": "N.m"}


class ForeignPendulum3(Fmi3Slave, ModelExchange):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.author = "tests"
        self.description = "Furuta pendulum, independent pythonfmu3 implementation"
        self.time = 0.0
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))
        self.register_units([Unit("rad", rad=1), Unit("rad/s", rad=1, s=-1), Unit("A", A=1),
                             Unit("V", kg=1, m=2, s=-3, A=-1), Unit("N.m", kg=1, m=2, s=-2)])
        for name, value in PHYSICS.items():
            setattr(self, name, value)
            self.register_variable(Float64(name, causality=Fmi3Causality.parameter,
                                           variability=Fmi3Variability.tunable, start=value))
        for name in INPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Float64(name, causality=Fmi3Causality.input, start=0.0,
                                           variability=Fmi3Variability.continuous, unit=UNITS[name]))
        for k, name in enumerate(STATES):
            setattr(self, name, 0.0)
            state = Float64(name, causality=Fmi3Causality.output, variability=Fmi3Variability.continuous,
                            initial=Fmi3Initial.exact, start=0.0, unit=UNITS[name])
            self.register_variable(state)
            self.register_variable(Float64(f"der({name})", causality=Fmi3Causality.local,
                                           variability=Fmi3Variability.continuous,
                                           derivative=state.value_reference,
                                           getter=lambda k=k: self._rates(self._state())[k]))

    def _state(self):
        return tuple(getattr(self, n) for n in STATES)

    def _rates(self, x):
        return rates(self, x, tuple(getattr(self, n) for n in INPUTS))

    def get_continuous_state_derivatives(self):
        return list(self._rates(self._state()))

    def do_step(self, current_time, step_size):
        x = self._state()
        x = rk4(self, x, tuple(getattr(self, n) for n in INPUTS), step_size)
        for name, value in zip(STATES, x):
            setattr(self, name, value)
        self.time = current_time + step_size
        return True
