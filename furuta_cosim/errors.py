"""The project's exceptions; each subclasses the built-in a caller would expect."""

from __future__ import annotations


MAX_LINE = 2000  # characters of one problem line: a 5000-character key is quoted, not echoed


def printable(line: str) -> str:
    """``line`` as one printable line: control characters (a newline or carriage return in a
    key read from a file) escaped, and no longer than :data:`MAX_LINE`."""
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in line)
    return shown if len(shown) <= MAX_LINE else shown[:MAX_LINE] + "..."


class ConfigError(ValueError):
    """A YAML file (plant, scenario, controller, tuning spec) that cannot be used.

    ``problems`` holds one line per problem, each naming the file and the key, so that a user
    fixes them all in one go.
    """

    def __init__(self, problems: list[str]):
        self.problems = [printable(str(problem)) for problem in problems]
        super().__init__("\n".join(self.problems))

    def within(self, prefix: str) -> "ConfigError":
        """The same problems, seen from the file that referred to this one (``scenario: key``)."""
        return ConfigError([f"{prefix}: {problem}" for problem in self.problems])


class PlantUnfit(ConfigError):
    """A scenario that the plant FMU it is given cannot run: the FMU lacks what the scenario
    needs (model exchange for a Kalman estimator's linearization). ``regress --fmu`` reports
    it for that scenario and goes on with the others."""


class NotApplicable(ConfigError):
    """A scenario asked to run on a plant of another model than its own (a toy scenario on a
    pendulum plant): ``regress`` lists it as not applicable and goes on with the others."""


class FmuError(RuntimeError):
    """An FMU that failed to build, load, or reported an error while running."""

    def __init__(self, message: str, multiline: bool = False):
        # ``multiline``: our own compiler's output, line by line; any other message is one line
        super().__init__("\n".join(printable(line) for line in str(message).splitlines())
                         if multiline else printable(str(message)))


class DesignError(ValueError):
    """A control design problem that has no valid answer (unstabilizable, singular, ...).

    ``key`` names the setting at fault when there is one (``Q``, ``R``, ``period``, or
    ``A, B`` for the model itself), so that a caller can point at its own flag or file.
    """

    def __init__(self, message: str, key: str | None = None):
        self.key = key
        super().__init__(message)


class Signalled(KeyboardInterrupt):
    """SIGTERM or SIGHUP (the terminal closed), stopping a command as Ctrl-C does: every partial
    file removed, the rig made safe, the log written. ``name`` is the signal's, ``code`` the exit
    code (128 + its number: 143, 129)."""

    def __init__(self, name: str, code: int):
        self.name, self.code = name, code
        super().__init__(name)


class RunStopped(RuntimeError):
    """A run that stopped before its end through no fault of its input (a lost Dask scheduler,
    no worker left): what it recorded is kept, and ``--resume`` continues it."""
