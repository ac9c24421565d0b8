"""Declaration of a scenario's source: the signals a scenario feeds its loop, sample by sample,
as a discrete FMU that an SSP wires to the controller and the plant.

    sample[k+1] = sample[k] + 1        y_j = TABLE[min(sample, rows - 1)][j]

The table (the reference the controller sees, the measurement noise added to each fed-back
signal, the disturbances at the plant's inputs, one row per control sample) is the master's
own (furuta_cosim/cosim/master.py prepare: the same draws of the same seed), written into the
C source as exact decimal literals (17 significant digits), so every engine reads the numbers
the master used. After the last row the source holds it.

It is built by ``export-ssp`` from a scenario (furuta_cosim/scenario_source.py); a plant file
cannot name it.
"""

from furuta_cosim.fmu.declaration import DeclarationError, Model, Real


def declare(spec):
    """The declaration of ``spec`` (a SourceSpec); refused for a plant file's parameters."""
    if isinstance(spec, dict):
        raise DeclarationError("model source: built by export-ssp from a scenario, not by a plant file")
    model = Model(spec.identifier, spec.description, discrete=True)
    constants = {"SRC_ROWS": len(spec.rows), "SRC_COLS": len(spec.outputs)}
    constants["SRC_Y0"] = len(model.reals)
    for name, unit, text in spec.outputs:
        model.register_variable(Real(name, "output", unit=unit, description=text))
    model.register_state("sample", 0.0, "", "samples since the start (the table's row)")
    model.register_variable(Real("Ts", "parameter", start=spec.period, unit="s",
                                 description="sample period: one row of the table each", positive=True))
    model.sample_period = "Ts"
    values = ", ".join(repr(float(v)) for row in spec.rows for v in row)
    constants["SRC_TABLE"] = "{" + values + "}"
    model.constants = constants
    return model
