"""A cart on a track, driven by a DC motor through a pinion, with a free pendulum on it:
Quanser's IP02 linear servo with its single inverted pendulum (SIP). Declaration here,
equations in model.c.

Defaults: the IP02 cart and motor from Quanser's "IP01 and IP02 User Manual" (system
parameters table) and the long (24 inch) pendulum from "IP01 and IP02 - Single Inverted
Pendulum (SIP): User Manual" (document 511, revision 03, table 6). The amplifier limit V_max
is this example's choice (0: none), not the manual's.
"""

from furuta_cosim.fmu.declaration import MAX_SUBSTEPS, Integer, Model, Real


def declare(parameters):
    model = Model("CartPole", "Cart on a track driven by a DC motor through a pinion, with a "
                  "pendulum (Quanser IP02 + SIP)")
    model.register_variable(Real("V", "input", start=0.0, unit="V", description="motor voltage"))
    model.register_variable(Real("F_d", "input", start=0.0, unit="N",
                                 description="disturbance force on the cart"))
    model.register_variable(Real("tau_d", "input", start=0.0, unit="N.m",
                                 description="disturbance torque on the pendulum"))
    model.register_state("x_c", 0.0, "m", "cart position on the track")
    model.register_state("dx_c", 0.0, "m/s", "cart velocity")
    model.register_state("alpha", 0.0, "rad", "pendulum angle, 0 = upright, positive leaning to +x_c")
    model.register_state("dalpha", 0.0, "rad/s", "pendulum angular velocity")
    p = parameters
    model.parameter(p, "M_c", 0.57, "kg", "cart mass (IP02, without its extra weight)", positive=True)
    model.parameter(p, "J_m", 3.9e-7, "kg.m2", "motor rotor inertia", positive=True)
    model.parameter(p, "K_g", 3.71, "1", "planetary gearbox ratio", positive=True)
    model.parameter(p, "eta_g", 1.0, "1", "gearbox efficiency", positive=True, maximum=1.0)
    model.parameter(p, "eta_m", 1.0, "1", "motor efficiency", positive=True, maximum=1.0)
    model.parameter(p, "K_t", 7.67e-3, "N.m/A", "motor torque constant", positive=True)
    model.parameter(p, "K_m", 7.67e-3, "V.s/rad", "motor back-EMF constant", positive=True)
    model.parameter(p, "R_m", 2.6, "Ohm", "motor armature resistance", positive=True)
    model.parameter(p, "r_mp", 6.35e-3, "m", "motor pinion radius", positive=True)
    model.parameter(p, "B_eq", 4.3, "N.s/m", "viscous damping seen at the motor pinion", minimum=0.0)
    model.parameter(p, "M_p", 0.230, "kg", "pendulum mass (long pendulum, with T-fitting)", positive=True)
    model.parameter(p, "l_p", 0.3302, "m", "pivot to the pendulum's centre of mass", positive=True)
    model.parameter(p, "J_p", 7.88e-3, "kg.m2", "pendulum inertia about its centre of mass", positive=True)
    model.parameter(p, "B_p", 0.0024, "N.m.s/rad", "viscous damping at the pendulum axis", minimum=0.0)
    model.parameter(p, "g", 9.81, "m/s2", "gravitational acceleration", positive=True)
    model.parameter(p, "V_max", 0.0, "V", "voltage limit |V| <= V_max; 0 = no limit", minimum=0.0)
    model.register_variable(Integer("n_substeps", int(p.get("n_substeps", 4)), minimum=1,
                                    maximum=MAX_SUBSTEPS, description="RK4 substeps per communication step"))
    model.substeps = "n_substeps"
    model.measured = ["x_c", "alpha"]     # the two encoders; the first is the tracked output
    model.upright = ["alpha"]             # a run that lets it fall beyond pi/2 diverged
    return model
