"""Defaults that several layers share, each stated once (and cheap to import: the CLI reads
them while building its parser)."""

# The paper's control period: its printed K is a discrete LQR at 2 ms
# (docs/pages/paper-readings.md §2).
PAPER_PERIOD = 2e-3

# What a period (control, sample, communication) and a matrix entry may be: beyond these a
# build or a run is numerically meaningless (a period of 1e-300 s, a gain of 1e308 that turns
# the output into -inf); each file key and option is refused with one line outside them.
MIN_PERIOD = 1e-9
MAX_PERIOD = 1e6
MAX_MAGNITUDE = 1e12
