"""Regenerate the designed controller files shipped in scenarios/controllers/.

    python tools/regenerate_controllers.py

Only lqr-paper.yaml is designed by the project (dlqr on the printed model at 2 ms, the
paper's Q and R); the other files hold the paper's published matrices and are written by
hand. tests/test_design.py checks that the shipped file equals a fresh design.
"""

from furuta_cosim import paths
from furuta_cosim.defaults import PAPER_PERIOD
from furuta_cosim.lqr_file import design_lqr_file

DESCRIPTION = ("the paper's LQR: dlqr on the printed model at 2 ms, Q = diag(1, 10, 100, 10, 1), "
               "R = 10; its K truncates to the printed [-0.31 -5.26 70.74 8.92 0.17]")

if __name__ == "__main__":
    design = design_lqr_file("paper-printed", period=PAPER_PERIOD, name="lqr-paper",
                             description=DESCRIPTION,
                             output=paths.scenarios() / "controllers" / "lqr-paper.yaml")
    print(f"wrote {design.path}")
