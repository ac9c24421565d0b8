"""State estimators designed on linear models (python-control keeps ``dlqe`` among its
stochastic-system functions; so do we, beside the controllers)."""

from __future__ import annotations

import control
import numpy as np

from furuta_cosim.errors import DesignError

# keeps the Riccati equation well posed when a noise channel is zero
_PROCESS_FLOOR = 1e-10
_MEASUREMENT_FLOOR = 1e-12


def kalman_gain(Ad, G, C, process_sigma, measurement_sigma) -> np.ndarray:
    """Steady-state Kalman gain M of the predictor-corrector filter

        xhat[k|k] = xpred + M (y[k] - C xpred),    xpred = Ad xhat + Bd u

    for x[k+1] = Ad x[k] + Bd u[k] + G w[k], y[k] = C x[k] + v[k], with independent white
    w (standard deviations ``process_sigma``) and v (``measurement_sigma``).
    """
    Ad, G, C = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (Ad, G, C))
    n = Ad.shape[0]
    process = np.atleast_1d(np.asarray(process_sigma, dtype=float))
    QN = G @ np.diag(process ** 2) @ G.T + _PROCESS_FLOOR * np.eye(n) if G.size else \
        _PROCESS_FLOOR * np.eye(n)
    RN = np.diag(np.maximum(np.asarray(measurement_sigma, dtype=float) ** 2, _MEASUREMENT_FLOOR))
    try:
        _, P, _ = control.dlqe(Ad, np.eye(n), C, QN, RN)
    except (ValueError, np.linalg.LinAlgError, control.ControlArgument) as error:
        raise DesignError(f"no steady-state Kalman filter: {error}") from None
    return P @ C.T @ np.linalg.inv(C @ P @ C.T + RN)
