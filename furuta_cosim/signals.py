"""The names of the signals a run derives from others, and the start-parameter convention:
each written here once, read by the master, the metrics, the exporters and linearization.

- ``u_command``: the controller's command before the actuator limit (``u`` is after it);
- ``xc1``, ``xc2``, ...: the controller's states;
- ``<state>_hat``: the estimator's estimate of a state;
- ``<state>_start``: the FMU parameter that sets a state's initial value (this project's
  plants; another tool's plant names its own through a mapping).
"""

from __future__ import annotations

import re

COMMAND = "u_command"
_CONTROLLER_STATE = re.compile(r"xc\d+")


def controller_state(k: int) -> str:
    """The name of the controller's k-th state (from 1)."""
    return f"xc{k}"


def is_controller_state(name: str) -> bool:
    return bool(_CONTROLLER_STATE.fullmatch(name))


def estimate(state: str) -> str:
    """The estimator's signal for ``state``."""
    return f"{state}_hat"


def is_estimate(name: str) -> bool:
    return name.endswith("_hat")


def start_parameter(state: str) -> str:
    """The parameter that sets ``state``'s initial value in this project's plants."""
    return f"{state}_start"
