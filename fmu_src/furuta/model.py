"""Declaration of the Furuta pendulum FMU: variables here, equations in model.c.

The start values of the physical parameters come from the plant's default parameter set
(``scenarios/plants/paper-calibrated.yaml``), so each number lives in one place.
"""

from furuta_cosim.fmu.declaration import MAX_SUBSTEPS, Integer, Model, Real

DEFAULT_PARAMETER_SET = "paper-calibrated"

# name, unit, description, its physical range: True must be > 0, 0.0 must be >= 0
PHYSICAL_PARAMETERS = [
    ("m_p", "kg", "pendulum mass", True),
    ("m_c", "kg", "counterweight mass", True),
    ("I_p", "kg.m2", "pendulum moment of inertia", True),
    ("I_a", "kg.m2", "arm moment of inertia", True),
    ("r", "m", "arm radius", True),
    ("l_p", "m", "distance from the pendulum axis to its centre of mass", True),
    ("h", "m", "height of the arm's centre of mass (enters only a constant potential)", True),
    ("C0", "N.m.s/rad", "arm viscous friction", 0.0),
    ("C1", "N.m.s/rad", "pendulum viscous friction", 0.0),
    ("R_a", "Ohm", "armature resistance", True),
    ("L_a", "H", "armature inductance", True),
    ("I_m", "kg.m2", "motor rotor inertia", True),
    ("M_f", "N.m/A", "motor torque constant (mutual inductance)", True),
    ("g", "m/s2", "gravitational acceleration", True),
    ("N", "", "effective gear ratio in torque, back-EMF and reflected inertia", True),
]

# what a real rig adds (model.c): each is absent at its default, so a parameter set that does
# not name them (the paper's) runs the same numbers to the bit.
# name, unit, description, default, physical range (as above; None: any value)
RIG_PARAMETERS = [
    ("Tc0", "N.m", "Coulomb friction torque on the arm (0: none)", 0.0, 0.0),
    ("Tc1", "N.m", "Coulomb friction torque on the pendulum (0: none)", 0.0, 0.0),
    ("w_c", "rad/s", "speed below which Coulomb friction is smoothed: Tc tanh(speed / w_c)", 0.01, True),
    ("K_c", "N.m/rad", "stiffness on the arm, the encoder cable (0: none)", 0.0, 0.0),
    ("theta0_rest", "rad", "arm angle at which the cable exerts no torque", 0.0, None),
    ("theta0_min", "rad", "arm angle of the lower end stop", -3.0, None),
    ("theta0_max", "rad", "arm angle of the upper end stop", 3.0, None),
    ("K_stop", "N.m/rad", "stiffness of the end stops (0 with D_stop 0: no stops)", 0.0, 0.0),
    ("D_stop", "N.m.s/rad", "damping of the end stops, while in contact", 0.0, 0.0),
]

# Coulomb friction has no linearization at zero speed (its smoothed slope Tc / w_c is an
# artefact of the smoothing, not a damping): linear models of this plant leave it out
NONSMOOTH = ["Tc0", "Tc1"]

STATES = [
    ("theta0", "rad", "arm angle"),
    ("dtheta0", "rad/s", "arm angular velocity"),
    ("theta1", "rad", "pendulum angle, 0 = upright"),
    ("dtheta1", "rad/s", "pendulum angular velocity"),
    ("i", "A", "armature current"),
]


# the outputs a design model of this plant measures: the paper's C (arm angle, pendulum angle,
# current); the ``derived`` models linearize to them
MEASURED = ["theta0", "theta1", "i"]


def declare(parameters):
    """Return the declaration; ``parameters`` maps each physical parameter to its start."""
    model = Model("Furuta", "Rotary inverted (Furuta) pendulum with DC motor, "
                  "Solis & Thomas (2021), readings of docs/paper-readings.md")
    model.register_variable(Real("V", "input", start=0.0, unit="V",
                                 description="armature voltage"))
    model.register_variable(Real("tau0", "input", start=0.0, unit="N.m",
                                 description="disturbance torque on the arm"))
    model.register_variable(Real("tau1", "input", start=0.0, unit="N.m",
                                 description="disturbance torque on the pendulum"))
    for name, unit, description in STATES:
        model.register_state(name, 0.0, unit, description)
    for name, unit, description, low in PHYSICAL_PARAMETERS:
        model.register_variable(Real(name, "parameter", start=float(parameters[name]), unit=unit,
                                     description=description, positive=low is True,
                                     minimum=None if low is True else low))
    for name, unit, description, default, low in RIG_PARAMETERS:
        model.register_variable(Real(name, "parameter", start=float(parameters.get(name, default)),
                                     unit=unit, description=description, positive=low is True,
                                     minimum=None if low is True or low is None else low))
    model.register_variable(Real("V_max", "parameter", start=float(parameters["V_max"]),
                                 unit="V", description="voltage limit |V| <= V_max; 0 = no limit",
                                 minimum=0.0))
    model.register_variable(Integer("n_substeps", int(parameters["n_substeps"]), minimum=1,
                                    maximum=MAX_SUBSTEPS,
                                    description="RK4 substeps per communication step"))
    model.substeps = "n_substeps"
    model.measured = list(MEASURED)
    model.nonsmooth = list(NONSMOOTH)
    model.upright = ["theta1"]
    return model
