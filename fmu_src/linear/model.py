"""Declaration of a linear state-space plant FMU, sized by the plant file.

    continuous:  x' = A x + B u + v        discrete:  x[k+1] = A x[k] + B u[k] + v[k]
                 y  = C x + D u                       y[k]   = C x[k] + D u[k]

The matrices are parameters (``A[i,j]`` ...) whose start values are the file's matrices,
so one binary serves every plant of the same dimensions; ``v`` is a process-noise input per
state, and the full state is an output besides ``y``.
"""

from furuta_cosim.fmu.declaration import MAX_SUBSTEPS, Integer, Model, Real


def _matrix(model, name, rows, description):
    first = len(model.reals)
    for i, row in enumerate(rows, start=1):
        for j, value in enumerate(row, start=1):
            model.register_variable(Real(f"{name}[{i},{j}]", "parameter", start=float(value),
                                         description=f"{description} ({i},{j})"))
    return first


def declare(spec):
    """Return the declaration for ``spec``: a validated linear plant (see plants.py)."""
    model = Model(spec.identifier, spec.description, discrete=spec.discrete)
    constants = {"LIN_NU": len(spec.inputs), "LIN_NY": len(spec.outputs)}
    constants["LIN_U0"] = len(model.reals)
    said = {name: (unit, text) for name, unit, text in getattr(spec, "signals", ())}
    for name in spec.inputs:
        unit, text = said.get(name, ("", "control input"))
        model.register_variable(Real(name, "input", start=0.0, unit=unit, description=text))
    constants["LIN_V0"] = len(model.reals)
    for name in spec.states:
        model.register_variable(Real(f"v_{name}", "input", start=0.0,
                                     description=f"process noise on {name}"))
    constants["LIN_Y0"] = len(model.reals)
    for name in spec.outputs:
        unit, text = said.get(name, ("", "measured output"))
        model.register_variable(Real(name, "output", unit=unit, description=text))
    for name, start in zip(spec.states, spec.x0):
        model.register_state(name, start, "", "state")
    constants["LIN_A0"] = _matrix(model, "A", spec.A, "state matrix")
    constants["LIN_B0"] = _matrix(model, "B", spec.B, "input matrix")
    constants["LIN_C0"] = _matrix(model, "C", spec.C, "output matrix")
    constants["LIN_D0"] = _matrix(model, "D", spec.D, "feedthrough matrix")
    if spec.discrete:
        model.register_variable(Real("Ts", "parameter", start=spec.period, unit="s",
                                     description="sample period", positive=True))
        model.sample_period = "Ts"
    else:
        model.register_variable(Integer("n_substeps", spec.substeps, minimum=1,
                                        maximum=MAX_SUBSTEPS, description="RK4 substeps per communication step"))
        model.substeps = "n_substeps"
    model.constants = constants
    return model
