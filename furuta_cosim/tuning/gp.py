"""The Gaussian processes of ``bo`` (tuning/bayesopt.py, tuning/mobo.py): scikit-learn's
GaussianProcessRegressor with a Matern 5/2 kernel, a length scale per parameter, on the unit
cube, its observations normalized (``normalize_y``).

scikit-learn keeps the model: the kernel, the conditioning on the data, the hyperparameters
it reports. Two of its steps are computed here instead, because the optimizer asks them
hundreds of times a run and scikit-learn's general kernel objects spend most of their time
outside the arithmetic (profile of ``tune effort --plant qube-servo-3``: the hyperparameter
fits were 11 s of the optimizer's 17 s):

- the log marginal likelihood and its gradient in the log hyperparameters, which the fit
  climbs (:func:`negative_log_likelihood`: the same function as scikit-learn's
  ``log_marginal_likelihood(theta, eval_gradient=True)``, tests/test_gp.py compares them);
- the posterior mean and standard deviation at the acquisition's candidates
  (:meth:`Surrogate.predict`).
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np

# the bounds of each hyperparameter: the kernel's constant, its length scales, the noise
CONSTANT_BOUNDS, LENGTH_BOUNDS, NOISE_BOUNDS = (1e-3, 1e3), (1e-2, 1e2), (1e-8, 1e-1)
# what scikit-learn adds to the kernel's diagonal (GaussianProcessRegressor's alpha)
JITTER = 1e-10


def kernel(d: int, theta=None):
    """constant x Matern 5/2 (a length scale per parameter) + white noise."""
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    k = ConstantKernel(1.0, CONSTANT_BOUNDS) * Matern(np.full(d, 0.5), LENGTH_BOUNDS, nu=2.5) \
        + WhiteKernel(1e-4, NOISE_BOUNDS)
    if theta is not None:
        k = k.clone_with_theta(np.asarray(theta, dtype=float))
    return k


def _scale(y: np.ndarray) -> float:
    """scikit-learn's ``normalize_y`` scale: the deviation of ``y``, 1 for a constant ``y``."""
    scale = float(np.std(y))
    return scale if scale >= 10 * np.finfo(float).eps else 1.0


def normalized(y: np.ndarray) -> np.ndarray:
    """``y`` as scikit-learn's ``normalize_y`` trains on it: zero mean, unit deviation."""
    return (y - np.mean(y)) / _scale(y)


def negative_log_likelihood(theta, X: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    """-log p(y | X) and its gradient in ``theta`` = log of (constant, length scales...,
    noise), for the observations ``y`` as trained on (:func:`normalized`). Where the kernel
    matrix is not positive definite: +inf and a zero gradient, as scikit-learn's."""
    from scipy.linalg import cho_solve, cholesky

    theta = np.asarray(theta, dtype=float)
    constant, lengths, noise = math.exp(theta[0]), np.exp(theta[1:-1]), math.exp(theta[-1])
    Z = X / lengths
    # squared scaled distances by one matrix product, |z_i|^2 + |z_j|^2 - 2 z_i.z_j
    squares = np.einsum("ij,ij->i", Z, Z)
    r = squares[:, None] + squares[None, :] - 2.0 * (Z @ Z.T)
    np.fill_diagonal(r, 0.0)
    np.maximum(r, 0.0, out=r)
    r = np.sqrt(5.0 * r)
    E = np.exp(-r)
    M = (1.0 + r + r * r / 3.0) * E                   # Matern 5/2, 1 on the diagonal
    K = constant * M
    K[np.diag_indices_from(K)] += noise + JITTER
    try:
        L = cholesky(K, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return math.inf, np.zeros_like(theta)
    alpha = cho_solve((L, True), y, check_finite=False)
    value = 0.5 * float(y @ alpha) + float(np.log(np.diag(L)).sum()) + 0.5 * len(y) * math.log(2 * math.pi)
    # d log p / d theta_k = 0.5 trace((alpha alpha^T - K^-1) dK/dtheta_k)
    W = np.outer(alpha, alpha) - cho_solve((L, True), np.eye(len(y)), check_finite=False)
    gradient = np.empty_like(theta)
    gradient[0] = 0.5 * constant * float(np.sum(W * M))
    # d K_ij / d log l_k = constant 5/3 (1 + r_ij) exp(-r_ij) (z_ik - z_jk)^2, and for a
    # symmetric G: sum_ij G_ij (z_ik - z_jk)^2 = 2 sum_i z_ik (z_ik g_i - (G Z)_ik)
    G = W * (constant * 5.0 / 3.0 * (1.0 + r) * E)
    gradient[1:-1] = np.einsum("ik,ik->k", Z, Z * G.sum(axis=1)[:, None] - G @ Z)
    gradient[-1] = 0.5 * noise * float(np.trace(W))
    return value, -gradient


def _climb(X, y, _objective, theta, bounds):
    """scikit-learn's ``optimizer`` hook: L-BFGS-B to convergence on
    :func:`negative_log_likelihood` (the objective scikit-learn passes computes the same,
    slower) from two starts, the hyperparameters the batch before used and the kernel's
    defaults, keeping the likelier. From the batch before's alone, a fit that once fell into
    the optimum where every length scale sits at its lower bound (a GP that predicts its
    mean everywhere but at its data) stayed there for the rest of the run: at those lengths
    the likelihood's gradient vanishes. Capped at 30 iterations (as at 0e89d82, when the
    likelihood cost 9 times as much) the fits left the QUBE plant's median 1 % higher over
    10 seeds (docs: Performance)."""
    from scipy.optimize import minimize

    best = None
    for start in _starts(theta, X.shape[1]):
        found = minimize(negative_log_likelihood, start, args=(X, y), method="L-BFGS-B", jac=True,
                         bounds=bounds)
        if best is None or found.fun < best.fun:
            best = found
    return best.x, best.fun


def _starts(theta, d: int) -> list[np.ndarray]:
    """Where a fit climbs from: ``theta``, and the kernel's defaults when they differ."""
    default = kernel(d).theta
    theta = np.asarray(theta, dtype=float)
    return [theta] if np.allclose(theta, default) else [theta, default]


class Surrogate:
    """One GP on the unit cube: fitted (or only conditioned, with given hyperparameters),
    then conditioned on made-up observations of a batch."""

    def __init__(self, X, y, theta, refit: bool, restarts: int, seed: int):
        from sklearn.gaussian_process import GaussianProcessRegressor

        self.X, self.y = np.asarray(X, dtype=float), np.asarray(y, dtype=float)
        climb = functools.partial(_climb, self.X, normalized(self.y))
        self.gp = GaussianProcessRegressor(kernel(self.X.shape[1], theta), normalize_y=True,
                                           alpha=JITTER, random_state=seed,
                                           n_restarts_optimizer=restarts if refit else 0,
                                           optimizer=climb if refit else None)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # hyperparameters at their bounds: expected here
            self.gp.fit(self.X, self.y)
        self.theta = [float(v) for v in self.gp.kernel_.theta]
        self._predictor = None

    def believe(self, x: np.ndarray) -> None:
        """Condition on the prediction at ``x`` (the kriging believer), hyperparameters kept."""
        from sklearn.gaussian_process import GaussianProcessRegressor

        mean = float(self.predict(x[None, :])[0][0])
        self.X, self.y = np.vstack([self.X, x]), np.append(self.y, mean)
        self.gp = GaussianProcessRegressor(self.gp.kernel_, normalize_y=True, alpha=JITTER, optimizer=None)
        self.gp.fit(self.X, self.y)
        self._predictor = None

    def predict(self, X):
        """Mean and standard deviation at the points ``X``: scikit-learn's predict(X,
        return_std=True), computed without its input checks and kernel objects (the
        acquisition asks this of thousands of candidates per point)."""
        from scipy.linalg import solve_triangular

        if self._predictor is None:
            k = self.gp.kernel_
            lengths = self.length_scales()
            train = self.gp.X_train_ / lengths
            self._predictor = (float(k.k1.k1.constant_value), lengths, float(k.k2.noise_level),
                               float(np.mean(self.y)), _scale(self.y),
                               train, np.einsum("ij,ij->i", train, train))
        constant, lengths, noise, mean_y, scale, train, train_sq = self._predictor
        Z = np.asarray(X, dtype=float) / lengths
        # squared distances by one matrix product (|z|^2 + |t|^2 - 2 z.t), never below 0
        r = np.einsum("ij,ij->i", Z, Z)[:, None] + train_sq[None, :]
        r -= 2.0 * (Z @ train.T)
        np.maximum(r, 0.0, out=r)
        r *= 5.0
        np.sqrt(r, out=r)
        K = r * r
        K *= 1.0 / 3.0
        K += r
        K += 1.0
        np.negative(r, out=r)
        np.exp(r, out=r)
        K *= r
        K *= constant                                  # Matern 5/2
        mean = mean_y + scale * (K @ self.gp.alpha_)
        V = solve_triangular(self.gp.L_, K.T, lower=True, check_finite=False)
        variance = np.maximum(constant + noise - np.einsum("ij,ij->j", V, V), 0.0)
        return mean, scale * np.sqrt(variance)

    def length_scales(self) -> np.ndarray:
        return np.asarray(self.gp.kernel_.k1.k2.length_scale, dtype=float).reshape(-1)
