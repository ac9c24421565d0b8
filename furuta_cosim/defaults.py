"""Defaults that several layers share, each stated once (and cheap to import: the CLI reads
them while building its parser)."""

# The paper's control period: its printed K is a discrete LQR at 2 ms
# (docs/paper-readings.md §2).
PAPER_PERIOD = 2e-3
# The pendulum's conventional tracked output, when a plant has it.
TRACKED_OUTPUT = "theta0"
