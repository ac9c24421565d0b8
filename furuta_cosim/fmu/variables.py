"""What an importer reads off an FMU's variables, for FMI 2.0 and 3.0 alike: which are
floating-point scalars, which take a start value from the importer, and how a declared unit
converts to its SI base unit.

A declared unit is input like any other: :func:`unit_problems` refuses a unit defined twice,
a factor that is not finite, zero or outside [:data:`MIN_FACTOR`, :data:`MAX_FACTOR`] in
magnitude, and an offset that is not finite or above :data:`MAX_OFFSET` in magnitude;
:func:`dimension_problem` refuses a unit whose base unit is not the dimension the view expects
(``mm`` on an angle). Radians count as dimensionless, as in SI (``deg`` on an angle is fine).
"""

from __future__ import annotations

import math

MIN_FACTOR, MAX_FACTOR = 1e-12, 1e12
MAX_OFFSET = 1e6
BASE = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
# the dimension of each unit this project's plants declare, as base-unit exponents
DIMENSIONS = {"rad": {}, "rad/s": {"s": -1}, "rad/s2": {"s": -2}, "1/s": {"s": -1}, "A": {"A": 1},
              "V": {"kg": 1, "m": 2, "s": -3, "A": -1}, "s": {"s": 1}, "m": {"m": 1}, "Nm": {"kg": 1, "m": 2, "s": -2}}


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


def unit_problems(description) -> list[str]:
    """One line per unit definition an importer must refuse (see the module docstring)."""
    problems, seen = [], set()
    for unit in description.unitDefinitions:
        if unit.name in seen:
            problems.append(f"unit {unit.name!r} is defined twice")
            continue
        seen.add(unit.name)
        base = unit.baseUnit
        if base is None:
            continue
        try:
            factor, offset = float(base.factor), float(base.offset)
        except (TypeError, ValueError):
            problems.append(f"unit {unit.name!r}: factor and offset must be numbers")
            continue
        if not (math.isfinite(factor) and MIN_FACTOR <= abs(factor) <= MAX_FACTOR):
            problems.append(f"unit {unit.name!r}: factor {factor!r} is not a finite number with "
                            f"magnitude in [{MIN_FACTOR:g}, {MAX_FACTOR:g}]")
        if not (math.isfinite(offset) and abs(offset) <= MAX_OFFSET):
            problems.append(f"unit {unit.name!r}: offset {offset!r} is not a finite number with "
                            f"magnitude at most {MAX_OFFSET:g}")
    return problems


def dimension_problem(description, variable, expected: str | None) -> str | None:
    """Why ``variable``'s declared unit cannot stand for a quantity in ``expected`` (a unit of
    :data:`DIMENSIONS`), or None when it can or nothing can be told (no base unit declared)."""
    want = DIMENSIONS.get(expected or "")
    declared = getattr(variable, "declaredType", None)
    name = variable.unit or (declared.unit if declared is not None else None)
    if want is None or not name:
        return None
    for unit in description.unitDefinitions:
        if unit.name == name and unit.baseUnit is not None:
            have = {s: int(getattr(unit.baseUnit, s, 0) or 0) for s in BASE if s != "rad"}
            if {s: p for s, p in have.items() if p} != want:
                return (f"{variable.name} is in {name!r}, not a unit of {expected} (its base unit's "
                        f"exponents: {', '.join(f'{s}^{p}' for s, p in have.items() if p) or 'none'})")
    return None
