"""IDENTIFIER: a mass on a spring with a damper, pushed by a force. Declaration here (its
variables, with their units, defaults and ranges), equations in model.c.

Replace it with your plant: declare each state (register_state, with its unit), each input,
each parameter (model.parameter: the plant file's value, else the default given here), the
outputs a sensor measures (model.measured: the first is the output a reference tracks), and
write the derivatives in model.c in the order the states are declared here.
"""

from furuta_cosim.fmu.declaration import MAX_SUBSTEPS, Integer, Model, Real


def declare(parameters):
    model = Model("IDENTIFIER", "a mass on a spring with a damper, pushed by a force")
    model.register_variable(Real("F", "input", start=0.0, unit="N", description="force on the mass"))
    model.register_state("x", 0.0, "m", "position of the mass")
    model.register_state("v", 0.0, "m/s", "velocity of the mass")
    model.parameter(parameters, "m", 1.0, "kg", "mass", positive=True)
    model.parameter(parameters, "k", 4.0, "N/m", "spring stiffness", minimum=0.0)
    model.parameter(parameters, "c", 0.5, "N.s/m", "damping", minimum=0.0)
    model.register_variable(Integer("n_substeps", int(parameters.get("n_substeps", 4)), minimum=1,
                                    maximum=MAX_SUBSTEPS, description="RK4 substeps per communication step"))
    model.substeps = "n_substeps"
    model.measured = ["x"]
    return model
