"""Hostile calls into the plant FMU, through fmpy's plain bindings: corrupted serialized
states, non-finite times, calls in the wrong mode, parameters that make the model's
arithmetic overflow. Each is refused with fmi2Error and a message; none crashes, none
returns NaN with fmi2OK, and the instance stays usable."""

import ctypes
import math
import struct

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Model, FMU2Slave
from fmpy.fmi1 import FMICallException

from helpers import run_cli

CALIBRATED = {"theta1_start": 0.1}


@pytest.fixture(scope="module")
def unpacked(furuta_fmu, tmp_path_factory):
    description = read_model_description(furuta_fmu)
    folder = extract(furuta_fmu, str(tmp_path_factory.mktemp("furuta")))
    return description, folder


@pytest.fixture
def slave(unpacked):
    description, folder = unpacked
    fmu = FMU2Slave(guid=description.guid, unzipDirectory=folder,
                    modelIdentifier=description.coSimulation.modelIdentifier, instanceName="cs")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    yield fmu
    fmu.freeInstance()


@pytest.fixture
def model(unpacked):
    description, folder = unpacked
    fmu = FMU2Model(guid=description.guid, unzipDirectory=folder,
                    modelIdentifier=description.modelExchange.modelIdentifier, instanceName="me")
    fmu.instantiate()
    yield fmu
    fmu.freeInstance()


def doubles(*values):
    return (ctypes.c_double * len(values))(*values)


def derivatives(model):
    dx = doubles(*[0.0] * 5)
    model.getDerivatives(dx, 5)
    return list(dx)


def vr(unpacked, name):
    return next(v.valueReference for v in unpacked[0].modelVariables if v.name == name)


def serialized(slave):
    return slave.serializeFMUstate(slave.getFMUstate())


def still_works(slave, t=0.0):
    slave.doStep(t, 1e-3)
    assert all(math.isfinite(v) for v in slave.getReal(list(range(5))))


@pytest.mark.parametrize("corruption", ["mode 1000", "mode -1", "magic", "another model",
                                        "interface", "NaN real", "NaN time", "substeps 0",
                                        "substeps huge", "negative mass", "truncated", "longer"])
def test_a_corrupted_serialized_state_is_refused(slave, unpacked, corruption):
    data = bytearray(serialized(slave))
    size = len(data)
    header = struct.Struct("<4I")
    magic, version, model_hash, interface = header.unpack_from(data, 0)
    values_end = size - 24  # ... double time, double start_time, int mode (+ padding)
    if corruption.startswith("mode"):
        struct.pack_into("<i", data, size - 8, int(corruption.split()[1]))
    elif corruption == "magic":
        header.pack_into(data, 0, magic ^ 1, version, model_hash, interface)
    elif corruption == "another model":
        header.pack_into(data, 0, magic, version, model_hash ^ 0x5A5A, interface)
    elif corruption == "interface":
        header.pack_into(data, 0, magic, version, model_hash, 1 - interface)
    elif corruption == "NaN real":
        struct.pack_into("<d", data, header.size + 8 * vr(unpacked, "theta1"), math.nan)
    elif corruption == "NaN time":
        struct.pack_into("<d", data, values_end, math.nan)
    elif corruption.startswith("substeps"):
        count = 0 if corruption.endswith("0") else 2**31 - 1
        real_count = sum(1 for v in unpacked[0].modelVariables if v.type == "Real")
        struct.pack_into("<i", data, header.size + 8 * real_count, count)
    elif corruption == "negative mass":
        struct.pack_into("<d", data, header.size + 8 * vr(unpacked, "m_p"), -1.0)
    elif corruption == "truncated":
        data = data[:-8]
    elif corruption == "longer":
        data = data + b"\0" * 8
    with pytest.raises(FMICallException):
        slave.deSerializeFMUstate(bytes(data))
    # the instance goes on as before: the state was not applied
    slave.setReal([vr(unpacked, "V")], [0.0])
    still_works(slave)


def test_a_good_serialized_state_round_trips(slave, unpacked):
    data = serialized(slave)
    slave.doStep(0.0, 1e-3)
    state = slave.deSerializeFMUstate(data)
    slave.setFMUstate(state)
    still_works(slave, 0.0)  # back at t = 0


@pytest.mark.parametrize("point", [math.nan, math.inf, -math.inf])
def test_non_finite_communication_points_are_refused(slave, point):
    with pytest.raises(FMICallException):
        slave.doStep(point, 1e-3)
    still_works(slave)  # the time was not touched


@pytest.mark.parametrize("step", [math.nan, math.inf, 0.0, -1e-3])
def test_bad_step_sizes_are_refused(slave, step):
    with pytest.raises(FMICallException):
        slave.doStep(0.0, step)
    still_works(slave)


def test_calls_in_the_wrong_mode_are_refused(unpacked, model):
    with pytest.raises(FMICallException):
        model.terminate()                      # not yet initialized
    with pytest.raises(FMICallException):
        model.setTime(0.5)                     # only in event or continuous-time mode
    with pytest.raises(FMICallException):
        model.setContinuousStates(doubles(*[0.0] * 5), 5)
    model.setupExperiment(startTime=0.0)
    model.enterInitializationMode()
    model.exitInitializationMode()             # event mode
    with pytest.raises(FMICallException):
        model.setContinuousStates(doubles(*[0.0] * 5), 5)  # only in continuous-time mode
    model.enterContinuousTimeMode()
    with pytest.raises(FMICallException):
        model.setTime(math.nan)
    model.setTime(0.25)
    model.setContinuousStates(doubles(0.0, 0.0, 0.1, 0.0, 0.0), 5)
    assert all(math.isfinite(v) for v in derivatives(model))
    model.terminate()
    with pytest.raises(FMICallException):
        model.terminate()                      # twice


@pytest.mark.parametrize("case", ["tiny masses", "huge states"])
def test_non_finite_derivatives_are_an_error_not_nan(unpacked, model, case):
    model.setupExperiment(startTime=0.0)
    model.enterInitializationMode()
    if case == "tiny masses":
        names = ["m_p", "m_c", "I_p", "I_a", "I_m", "r", "l_p", "h", "L_a"]
        model.setReal([vr(unpacked, n) for n in names], [1e-200] * len(names))
    model.exitInitializationMode()
    model.enterContinuousTimeMode()
    if case == "huge states":
        model.setContinuousStates(doubles(1e300, 1e300, 1.0, 1e300, 1e300), 5)
    else:
        model.setContinuousStates(doubles(0.0, 1.0, 0.1, 1.0, 1.0), 5)
    with pytest.raises(FMICallException):
        derivatives(model)


def test_linearize_on_a_degenerate_parameter_set_is_an_input_error(tmp_path, capsys):
    plant = tmp_path / "tiny.yaml"
    tiny = ", ".join(f"{n}: 1.0e-200" for n in ["m_p", "m_c", "I_p", "I_a", "I_m", "r", "l_p", "h", "L_a"])
    plant.write_text(f"model: furuta\nextends: paper-calibrated\nparameters: {{{tiny}}}\n")
    code, out, err = run_cli(capsys, "linearize", "--params", str(plant), "--json")
    assert code == 2 and out == "" and "not finite" in err
    assert len(err.strip().splitlines()) == 1
