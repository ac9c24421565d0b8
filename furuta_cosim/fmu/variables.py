"""What an importer reads off an FMU's variables, for FMI 2.0 and 3.0 alike: which are
floating-point scalars, which take a start value from the importer, and how a declared unit
converts to its SI base unit."""

from __future__ import annotations


def is_real(variable) -> bool:
    """A scalar floating-point variable: FMI 2.0's Real, FMI 3.0's Float64 (not an array)."""
    return variable.type in ("Real", "Float64") and not getattr(variable, "dimensions", None)


def settable_start(variable) -> bool:
    """Whether an importer may set the variable's start value before initialization (FMI 2.0
    and 3.0: ``initial`` exact or approx on a variable that is not a constant)."""
    return variable.initial in ("exact", "approx") and variable.variability != "constant"


def declared_conversion(description, variable) -> tuple[float, float] | None:
    """(factor, offset) from the unit the variable declares to its SI base unit, when that
    differs from 1 and 0 (``deg``: factor pi/180); None otherwise."""
    declared = getattr(variable, "declaredType", None)
    name = variable.unit or (declared.unit if declared is not None else None)
    if not name:
        return None
    for unit in description.unitDefinitions:
        if unit.name == name and unit.baseUnit is not None:
            factor, offset = float(unit.baseUnit.factor), float(unit.baseUnit.offset)
            if (factor, offset) != (1.0, 0.0):
                return factor, offset
    return None
