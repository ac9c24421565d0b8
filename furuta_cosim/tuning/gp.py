"""A Gaussian process that refits its kernel hyperparameters only every few tells.

scikit-optimize refits the GP's hyperparameters (with restarts) at every tell, which is most
of a run's time at 12 dimensions and 150 calls. Between full refits this GP keeps the last
fitted kernel and only conditions on the new data (a Cholesky factorization); each refit
starts from the last kernel. The optimizer clones its estimator at every tell, so the memory
of the last kernel is shared between clones on purpose.

Its ``predict`` computes what scikit-optimize's does, with less overhead: the predictive
variance through a matrix product (scikit-optimize uses a three-operand ``einsum`` that runs
without BLAS: 2,000 candidate points x 150 observations took most of the acquisition's time),
and no input validation of the arrays the acquisition hands it.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
from sklearn.base import clone
from skopt.learning import GaussianProcessRegressor
from skopt.learning.gaussian_process.gpr import _param_for_white_kernel_in_Sum
from skopt.learning.gaussian_process.kernels import WhiteKernel


class Memory:
    """Shared by every clone of one estimator (a deep copy returns the same object)."""

    def __init__(self):
        self.kernel, self.noise, self.fits = None, None, 0
        self.frozen = False

    def __deepcopy__(self, memo):
        return self

    @contextmanager
    def conditioning_only(self):
        """Fits inside only condition on their data with the last kernel: neither count
        towards the next hyperparameter refit nor change the kernel remembered (the fits of
        a batch's made-up observations)."""
        self.frozen = True
        try:
            yield
        finally:
            self.frozen = False


# the kernel hyperparameters are fitted at every this many tells (conditioning between), from
# the last kernel and a spec's ``optimizer.gp_restarts`` random starts besides
REFIT_EVERY = 5


class WarmGaussianProcess(GaussianProcessRegressor):
    def __init__(self, kernel=None, *, alpha=0.0, optimizer="fmin_l_bfgs_b", n_restarts_optimizer=0,
                 normalize_y=True, copy_X_train=True, random_state=None, noise=1e-10,
                 refit_every=REFIT_EVERY, memory=None):
        super().__init__(kernel=kernel, alpha=alpha, optimizer=optimizer,
                         n_restarts_optimizer=n_restarts_optimizer, normalize_y=normalize_y,
                         copy_X_train=copy_X_train, random_state=random_state, noise=noise)
        self.refit_every = refit_every
        self.memory = memory

    def fit(self, X, y):
        memory = self.memory if self.memory is not None else Memory()
        frozen = memory.frozen and memory.kernel is not None
        if not frozen:
            memory.fits += 1
        if memory.kernel is not None:
            kernel = clone(memory.kernel)
            present, name = _param_for_white_kernel_in_Sum(kernel)
            if present:  # the fitted kernel has its noise zeroed for prediction: restore it
                if self.noise == "gaussian":  # fitted: start from (or keep) the last fitted level
                    kernel.set_params(**{name: WhiteKernel(noise_level=memory.noise)})
                else:
                    kernel.set_params(**{name: WhiteKernel(noise_level=self.noise, noise_level_bounds="fixed")})
            self.kernel = kernel
            if frozen or memory.fits % self.refit_every:
                self.optimizer = None
        super().fit(X, y)
        if not frozen:
            memory.kernel, memory.noise = self.kernel_, self.noise_
        return self

    def predict(self, X, return_std=False, return_cov=False, return_mean_grad=False,
                return_std_grad=False):
        X = np.asarray(X, dtype=float)
        if return_cov or X.ndim != 2 or not hasattr(self, "X_train_") or \
                (return_std_grad and not return_std) or \
                (X.shape[0] != 1 and (return_mean_grad or return_std_grad)):
            # what this method does not cover (or scikit-optimize's own errors)
            return super().predict(X, return_std=return_std, return_cov=return_cov,
                                   return_mean_grad=return_mean_grad,
                                   return_std_grad=return_std_grad)
        scale, K_trans = self.y_train_std_, self.kernel_(X, self.X_train_)
        y_mean = scale * K_trans.dot(self.alpha_) + self.y_train_mean_
        if not (return_std or return_mean_grad):
            return y_mean
        weighted = K_trans.dot(self.K_inv_) if return_std else None
        if return_std:
            y_var = self.kernel_.diag(X) - np.einsum("ij,ij->i", weighted, K_trans)
            y_std = np.sqrt(np.maximum(y_var, 0.0) * scale**2)  # rounding can make it negative
        if not return_mean_grad:
            return y_mean, y_std
        grad = self.kernel_.gradient_x(X[0], self.X_train_)
        grad_mean = scale * grad.T.dot(self.alpha_)
        if not return_std_grad:
            return (y_mean, y_std, grad_mean) if return_std else (y_mean, grad_mean)
        grad_std = np.zeros(X.shape[1])
        if np.any(np.abs(y_std) > 1e-8):  # scikit-optimize: zero where the std is (all)close to 0
            grad_std = -weighted.dot(grad)[0] / y_std * scale**2
        return y_mean, y_std, grad_mean, grad_std
