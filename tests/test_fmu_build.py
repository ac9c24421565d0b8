"""The exporter: valid FMUs, every fmi2 symbol, hidden internals, complete sources, cache."""

import ctypes
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy.validation import validate_fmu

from furuta_cosim.fmu.exporter import build_fmu
from furuta_cosim.fmu.session import FmuBinary, PlantSession

from helpers import STATES

FMI2_FUNCTIONS = """fmi2GetTypesPlatform fmi2GetVersion fmi2SetDebugLogging fmi2Instantiate
fmi2FreeInstance fmi2SetupExperiment fmi2EnterInitializationMode fmi2ExitInitializationMode
fmi2Terminate fmi2Reset fmi2GetReal fmi2GetInteger fmi2GetBoolean fmi2GetString fmi2SetReal
fmi2SetInteger fmi2SetBoolean fmi2SetString fmi2GetFMUstate fmi2SetFMUstate fmi2FreeFMUstate
fmi2SerializedFMUstateSize fmi2SerializeFMUstate fmi2DeSerializeFMUstate
fmi2GetDirectionalDerivative fmi2EnterEventMode fmi2NewDiscreteStates
fmi2EnterContinuousTimeMode fmi2CompletedIntegratorStep fmi2SetTime fmi2SetContinuousStates
fmi2GetDerivatives fmi2GetEventIndicators fmi2GetContinuousStates
fmi2GetNominalsOfContinuousStates fmi2SetRealInputDerivatives fmi2GetRealOutputDerivatives
fmi2DoStep fmi2CancelStep fmi2GetStatus fmi2GetRealStatus fmi2GetIntegerStatus
fmi2GetBooleanStatus fmi2GetStringStatus""".split()


@pytest.mark.parametrize("plant", ["furuta", "toy"])
def test_fmpy_validate_finds_no_problem(plant):
    assert validate_fmu(str(build_fmu(plant))) == []


@pytest.mark.parametrize("plant, identifier", [("furuta", "Furuta"), ("toy", "Toy")])
def test_archive_layout_and_exports(plant, identifier):
    fmu = build_fmu(plant)
    names = set(zipfile.ZipFile(fmu).namelist())
    assert {"modelDescription.xml", f"binaries/linux64/{identifier}.so", "sources/fmi2_glue.c",
            "sources/model.c", "sources/model_api.h", "sources/model_vars.h"} <= names
    with FmuBinary(fmu) as binary:
        library = ctypes.CDLL(str(binary.directory / "binaries/linux64" / f"{identifier}.so"))
        missing = [name for name in FMI2_FUNCTIONS if not hasattr(library, name)]
        assert missing == []
        # everything but the fmi2 API is hidden
        for internal in ("model_outputs", "model_check", "apply_start_values"):
            assert not hasattr(library, internal)


def test_cache_reuses_and_separates_builds(furuta_fmu):
    stamp = furuta_fmu.stat().st_mtime_ns
    assert build_fmu("furuta") == furuta_fmu
    assert furuta_fmu.stat().st_mtime_ns == stamp
    literal = build_fmu("table-literal")
    assert literal != furuta_fmu and literal.name.startswith("Furuta-")


def test_output_copy(tmp_path):
    copy = build_fmu("toy", output=tmp_path)
    assert copy == tmp_path / "Toy.fmu"
    assert copy.read_bytes() == build_fmu("toy").read_bytes()


def _run(fmu, steps=500):
    with PlantSession.open(fmu) as plant:
        plant.reset({"theta1_start": 0.1})
        plant.set_io(["V"], STATES)
        return np.array([plant.step([0.5], 1e-3) for _ in range(steps)])


def test_fmpy_compile_rebuilds_from_sources(tmp_path, furuta_fmu):
    stripped = tmp_path / "Furuta.fmu"
    with zipfile.ZipFile(furuta_fmu) as source, zipfile.ZipFile(stripped, "w") as target:
        for item in source.infolist():
            if not item.filename.startswith("binaries/"):
                target.writestr(item, source.read(item))
    # fmpy compile calls cmake: the one the test extra installs beside this Python comes first
    env = {**os.environ, "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ["PATH"]])}
    result = subprocess.run([sys.executable, "-m", "fmpy", "compile", str(stripped),
                             "--all-warnings", "--warning-as-error"], capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "binaries/linux64/Furuta.so" in zipfile.ZipFile(stripped).namelist()
    assert validate_fmu(str(stripped)) == []
    np.testing.assert_allclose(_run(stripped), _run(furuta_fmu), rtol=1e-12, atol=1e-15)
