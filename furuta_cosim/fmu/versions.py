"""FMI versions: one class per version the exporter writes and the sessions import,
registered once in :data:`VERSIONS`. The exporter, the CLI's ``--fmi-version`` choices and the
error messages read the registry; the session class of each version is
:data:`furuta_cosim.fmu.session.SESSIONS`.

A version says where its binaries go in the zip (``platform``), which C glue of
``fmu_src/common`` it compiles, how the cache names its FMUs, and how its
modelDescription.xml (and any further file of ``sources/``) is written.
"""

from __future__ import annotations

from typing import ClassVar

from furuta_cosim.errors import ConfigError

VERSIONS: dict[str, type[FmiVersion]] = {}


class FmiVersion:
    name: ClassVar[str]
    platform: ClassVar[str]                 # binaries/<platform>/ in the zip
    glue: ClassVar[tuple[str, ...]]         # sources of fmu_src/common compiled in
    cache_tag: ClassVar[str]                # in the cache's file name: <Identifier><tag>-<key>.fmu

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.name in VERSIONS:
            raise ValueError(f"FMI version {cls.name!r} registered twice")
        VERSIONS[cls.name] = cls

    @staticmethod
    def model_description(model, guid: str, sources: list[str]) -> str:
        raise NotImplementedError

    @staticmethod
    def extra_sources(model, sources: list[str]) -> dict[str, bytes]:
        """Files of ``sources/`` besides the C sources (none by default)."""
        return {}


class Fmi2(FmiVersion):
    name = "2.0"
    platform = "linux64"
    glue = ("fmi2_glue.c", "model_api.h")
    cache_tag = ""  # as before FMI 3.0: caches and files made then remain valid

    @staticmethod
    def model_description(model, guid, sources):
        from furuta_cosim.fmu.exporter import generate_model_description

        return generate_model_description(model, guid, sources)


class Fmi3(FmiVersion):
    name = "3.0"
    platform = "x86_64-linux"
    glue = ("fmi2_glue.c", "model_api.h", "fmi3_glue.c")
    cache_tag = "-fmi3"

    @staticmethod
    def model_description(model, guid, _sources):  # FMI 3.0 lists its sources in buildDescription.xml
        from furuta_cosim.fmu.exporter import generate_model_description_3

        return generate_model_description_3(model, guid)

    @staticmethod
    def extra_sources(model, sources):
        from furuta_cosim.fmu.exporter import generate_build_description

        return {"buildDescription.xml": generate_build_description(model, sources).encode()}


def fmi_version(name: str) -> type[FmiVersion]:
    """The registered version ``name``; ConfigError naming the parameter otherwise."""
    if name not in VERSIONS:
        raise ConfigError([f"fmi_version: expected one of {', '.join(VERSIONS)}, got {name!r}"])
    return VERSIONS[name]
