"""The Furuta pendulum as another exporter would ship it: a pythonfmu slave with its own
variable names, written from the paper's equations (Solis & Thomas 2021, Sec. III, with the
project's readings in docs/paper-readings.md) and sharing no code with fmu_src/furuta.

    M1(q) q'' + M2(q, q') q' + M3(q) = T,   L_a i' = V - R_a i - M_f N theta0'

with q = (arm angle, pendulum angle), T = (M_f N i + arm torque, pendulum torque), the
pendulum angle 0 upright. Integrated by classical RK4 with 20 substeps per doStep.
"""

import math

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real

PHYSICS = {  # paper-calibrated
    "pendulum_mass": 0.1, "cart_mass": 0.01, "pendulum_inertia": 5.1e-4, "arm_inertia": 3.1e-3,
    "arm_length": 0.13, "pendulum_com": 0.125, "arm_friction": 1.0e-3,
    "pendulum_friction": 1.0e-3, "resistance": 8.0, "inductance": 0.010,
    "rotor_inertia": 1.9e-6, "motor_constant": 0.0214, "gravity": 9.806, "gear_ratio": 122.40,
}
STATES = ("arm_angle", "arm_rate", "pend_angle", "pend_rate", "current")
INPUTS = ("voltage", "arm_torque", "pend_torque")


class ForeignPendulum(Fmi2Slave):
    author = "tests"
    description = "Furuta pendulum, independent pythonfmu implementation"
    # a variant (tests/test_units.py) gives angles in degrees and takes the start of a
    # state on the state itself, as many exporters do, instead of on a <state>_0 parameter
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

    def exit_initialization_mode(self):
        if not self.START_PARAMETERS:
            return
        for name in STATES:
            setattr(self, name, getattr(self, f"{name}_0"))

    def _rates(self, x):
        th0, w0, th1, w1, i = x
        mp, lp, r = self.pendulum_mass, self.pendulum_com, self.arm_length
        J0 = self.arm_inertia + r * r * (mp + self.cart_mass) + self.gear_ratio ** 2 * self.rotor_inertia
        J1 = self.pendulum_inertia + mp * lp * lp
        s, c = math.sin(th1), math.cos(th1)
        s2 = math.sin(2.0 * th1)
        # M1 q'' = T - M2 q' - M3
        a, b, d = J0 + mp * lp * lp * s * s, -mp * r * lp * c, J1
        f0 = (self.motor_constant * self.gear_ratio * i + self.arm_torque
              - (mp * lp * lp * w1 * s2 + self.arm_friction) * w0 - mp * r * lp * w1 * s * w1)
        f1 = (self.pend_torque + 0.5 * mp * lp * lp * w0 * s2 * w0 - self.pendulum_friction * w1
              + mp * self.gravity * lp * s)
        det = a * d - b * b
        di = (self.voltage - self.resistance * i - self.motor_constant * self.gear_ratio * w0) / self.inductance
        return (w0, (d * f0 - b * f1) / det, w1, (a * f1 - b * f0) / det, di)

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
