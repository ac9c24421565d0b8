"""furuta-cosim: co-simulation toolchain for control design of underactuated plants."""

__version__ = "0.1.0"
