"""What reading and writing an SSP share: the standard's namespaces, the entry of the system
description, the SI exponents of the unit symbols the models use, an FMU's variables by name
and their unit and type, and validation against the SSP 1.0 schemas."""

from __future__ import annotations

import io
import re
from pathlib import Path, PurePosixPath
from xml.etree import ElementTree as ET

import numpy as np

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"


SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"


SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"


OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"


OURS = "org.furuta-cosim"


ENTRY = "SystemStructure.ssd"


SET_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


# SI exponents (kg, m, s, A, K, mol, cd, rad) of the unit symbols the models use
BASE = {"kg": (1, 0, 0, 0, 0, 0, 0, 0), "m": (0, 1, 0, 0, 0, 0, 0, 0), "s": (0, 0, 1, 0, 0, 0, 0, 0),
        "A": (0, 0, 0, 1, 0, 0, 0, 0), "K": (0, 0, 0, 0, 1, 0, 0, 0), "rad": (0, 0, 0, 0, 0, 0, 0, 1),
        "N": (1, 1, -2, 0, 0, 0, 0, 0), "V": (1, 2, -3, -1, 0, 0, 0, 0), "Ohm": (1, 2, -3, -2, 0, 0, 0, 0),
        "H": (1, 2, -2, -2, 0, 0, 0, 0), "W": (1, 2, -3, 0, 0, 0, 0, 0), "J": (1, 2, -2, 0, 0, 0, 0, 0),
        "g": (1, 0, 0, 0, 0, 0, 0, 0)}


EXPONENTS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


for prefix, uri in (("ssd", SSD), ("ssc", SSC), ("ssv", SSV), ("osp", OSP)):
    ET.register_namespace(prefix, uri)


def base_unit(unit: str) -> dict[str, int] | None:
    """The SI exponents of a unit as the models write it (``N.m.s/rad``, ``kg.m2``, ``rad/s/s``),
    or None when a symbol is not one of :data:`BASE`'s. ``g`` is grams only in ``kg``."""
    total = np.zeros(8, dtype=int)
    for k, part in enumerate(unit.split("/")):
        for token in part.split("."):
            found = re.fullmatch(r"([A-Za-z]+)(-?\d*)", token)
            if not found or found.group(1) not in BASE or found.group(1) == "g":
                return None
            power = int(found.group(2) or 1)
            total += (1 if k == 0 else -1) * power * np.array(BASE[found.group(1)])
    return {name: int(e) for name, e in zip(EXPONENTS, total) if e}


def schema_problems(files: dict) -> list[str] | None:
    """Each ``.ssd`` and ``.ssv`` of ``files`` (entry -> bytes) against the SSP 1.0 XML schemas
    the standard publishes, as the ``pyssp-standard`` package carries them (read with
    ``xmlschema``): the problems, [] when valid, None when those packages are not installed
    (not validated, said as such)."""
    try:
        import pyssp_standard
        import xmlschema
    except ImportError:
        return None
    folder = Path(pyssp_standard.__file__).parent / "resources"
    schemas = {".ssd": "SystemStructureDescription.xsd", ".ssv": "SystemStructureParameterValues.xsd"}
    problems = []
    for name, data in files.items():
        schema = schemas.get(PurePosixPath(name).suffix)
        if schema is None:
            continue
        for error in xmlschema.XMLSchema(str(folder / schema)).iter_errors(io.BytesIO(data)):
            problems.append(f"{name}: {error.reason} (at {error.path})")
    return problems


def variables_of(md) -> dict:
    return {v.name: v for v in md.modelVariables}


def unit_of(variable) -> str | None:
    unit = variable.declaredType.unit if variable.declaredType is not None and variable.declaredType.unit \
        else getattr(variable, "unit", None)
    return unit or None


def is_real(variable) -> bool:
    return variable.type in ("Real", "Float64", "Float32")
