"""Control design on linear models: LQR, the generalized controller, analysis, prefilters.

Knows nothing of FMUs or files: callers hand it matrices (``LinearModel``).
"""

from furuta_cosim.design.analysis import Analysis, analyze
from furuta_cosim.design.controller import GeneralizedController, augmented, discretize_controller
from furuta_cosim.design.linear import LinearModel, discretize
from furuta_cosim.design.lqr import PAPER_Q, PAPER_R, lqr
from furuta_cosim.design.prefilter import prefilter

__all__ = ["Analysis", "GeneralizedController", "LinearModel", "PAPER_Q", "PAPER_R", "analyze",
           "augmented", "discretize", "discretize_controller", "lqr", "prefilter"]
