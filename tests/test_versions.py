"""FMI versions: a registry the exporter, the sessions and the CLI read."""

import zipfile

import pytest

from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu import versions
from furuta_cosim.fmu.exporter import build_fmu
from furuta_cosim.fmu.session import SESSIONS, FmuBinary, PlantSession, PlantSession3
from furuta_cosim.fmu.versions import VERSIONS, FmiVersion


def test_every_exported_version_has_a_session_and_lays_out_its_zip(tmp_path):
    assert set(VERSIONS) == set(SESSIONS) == {"2.0", "3.0"}
    for name, version in VERSIONS.items():
        fmu = build_fmu("toy", fmi_version=name)
        names = zipfile.ZipFile(fmu).namelist()
        assert any(n.startswith(f"binaries/{version.platform}/") for n in names), names
        assert all(f"sources/{g}" in names for g in version.glue)
        assert ("sources/buildDescription.xml" in names) == (name == "3.0")
        binary = FmuBinary(fmu)
        try:
            with PlantSession.for_binary(binary) as session:
                assert type(session) is SESSIONS[name] and session.VERSION == name
        finally:
            binary.close()


def test_a_session_class_refuses_a_binary_of_another_version():
    binary = FmuBinary(build_fmu("toy", fmi_version="3.0"))
    try:
        with pytest.raises(Exception, match="an FMI 3.0 FMU, not 2.0: open it with PlantSession.for_binary"):
            PlantSession(binary)
        with PlantSession.for_binary(binary) as session:
            assert isinstance(session, PlantSession3)
    finally:
        binary.close()


def test_an_unknown_version_names_the_parameter_and_the_registry():
    with pytest.raises(ConfigError, match=r"fmi_version: expected one of 2\.0, 3\.0, got '1\.0'"):
        build_fmu("toy", fmi_version="1.0")


def test_a_version_registered_twice_is_refused(monkeypatch):
    monkeypatch.setattr(versions, "VERSIONS", dict(VERSIONS))
    with pytest.raises(ValueError, match="registered twice"):
        class Again(FmiVersion):
            name = "2.0"
