"""The Furuta pendulum written from the paper's equations (Solis & Thomas 2021, Sec. III, with
the project's readings in docs/pages/paper-readings.md), sharing no code with fmu_src/furuta: the
physics of the foreign test FMUs (pendulum_fmu.py for pythonfmu, pendulum3_fmu.py for
pythonfmu3), which ship this file as a project file.

    M1(q) q'' + M2(q, q') q' + M3(q) = T,   L_a i' = V - R_a i - M_f N theta0'

with q = (arm angle, pendulum angle), T = (M_f N i + arm torque, pendulum torque), the
pendulum angle 0 upright; SI units throughout.
"""

import math

PHYSICS = {  # paper-calibrated
    "pendulum_mass": 0.1, "cart_mass": 0.01, "pendulum_inertia": 5.1e-4, "arm_inertia": 3.1e-3,
    "arm_length": 0.13, "pendulum_com": 0.125, "arm_friction": 1.0e-3,
    "pendulum_friction": 1.0e-3, "resistance": 8.0, "inductance": 0.010,
    "rotor_inertia": 1.9e-6, "motor_constant": 0.0214, "gravity": 9.806, "gear_ratio": 122.40,
}
STATES = ("arm_angle", "arm_rate", "pend_angle", "pend_rate", "current")
INPUTS = ("voltage", "arm_torque", "pend_torque")


def rates(p, x, u):
    """dx/dt at state x (STATES) and inputs u (INPUTS), parameters p (PHYSICS's keys)."""
    th0, w0, th1, w1, i = x
    voltage, arm_torque, pend_torque = u
    mp, lp, r = p.pendulum_mass, p.pendulum_com, p.arm_length
    J0 = p.arm_inertia + r * r * (mp + p.cart_mass) + p.gear_ratio ** 2 * p.rotor_inertia
    J1 = p.pendulum_inertia + mp * lp * lp
    s, c = math.sin(th1), math.cos(th1)
    s2 = math.sin(2.0 * th1)
    # M1 q'' = T - M2 q' - M3
    a, b, d = J0 + mp * lp * lp * s * s, -mp * r * lp * c, J1
    f0 = (p.motor_constant * p.gear_ratio * i + arm_torque
          - (mp * lp * lp * w1 * s2 + p.arm_friction) * w0 - mp * r * lp * w1 * s * w1)
    f1 = (pend_torque + 0.5 * mp * lp * lp * w0 * s2 * w0 - p.pendulum_friction * w1
          + mp * p.gravity * lp * s)
    det = a * d - b * b
    di = (voltage - p.resistance * i - p.motor_constant * p.gear_ratio * w0) / p.inductance
    return (w0, (d * f0 - b * f1) / det, w1, (a * f1 - b * f0) / det, di)


def rk4(p, x, u, step, substeps=20):
    """The state after ``step`` seconds of classical RK4 in ``substeps`` substeps, inputs held."""
    h = step / substeps
    for _ in range(substeps):
        k1 = rates(p, x, u)
        k2 = rates(p, tuple(v + 0.5 * h * k for v, k in zip(x, k1)), u)
        k3 = rates(p, tuple(v + 0.5 * h * k for v, k in zip(x, k2)), u)
        k4 = rates(p, tuple(v + h * k for v, k in zip(x, k3)), u)
        x = tuple(v + h / 6 * (a + 2 * b + 2 * c + d) for v, a, b, c, d in zip(x, k1, k2, k3, k4))
    return x
