"""The project's exceptions; each subclasses the built-in a caller would expect."""

from __future__ import annotations


class ConfigError(ValueError):
    """A YAML file (plant, scenario, controller, tuning spec) that cannot be used.

    ``problems`` holds one line per problem, each naming the file and the key, so that a user
    fixes them all in one go.
    """

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


class FmuError(RuntimeError):
    """An FMU that failed to build, load, or reported an error while running."""


class DesignError(ValueError):
    """A control design problem that has no valid answer (unstabilizable, singular, ...)."""
