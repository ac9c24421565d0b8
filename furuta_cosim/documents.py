"""JSON documents: the one converter from the project's values to strict JSON.

JSON has no infinity and no NaN (Python writes ``Infinity`` and ``NaN``, which other tools
refuse): a non-finite number is ``null`` (a metric that never settles, a mode at z = 0 read as
log 0), numpy scalars and arrays become plain numbers and lists, tuples lists.
"""

from __future__ import annotations

import json
import math
from typing import Any


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite number replaced by None, numpy values made plain."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return json_safe(value.tolist())  # numpy arrays and scalars (numpy is not imported here)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps(value: Any, **options) -> str:
    """Strict JSON text of ``value`` (see :func:`json_safe`)."""
    return json.dumps(json_safe(value), allow_nan=False, **options)
