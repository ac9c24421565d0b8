"""A Gaussian process that refits its kernel hyperparameters only every few tells.

scikit-optimize refits the GP's hyperparameters (with restarts) at every tell, which is most
of a run's time at 12 dimensions and 150 calls. Between full refits this GP keeps the last
fitted kernel and only conditions on the new data (a Cholesky factorization); each refit
starts from the last kernel. The optimizer clones its estimator at every tell, so the memory
of the last kernel is shared between clones on purpose.
"""

from __future__ import annotations

from sklearn.base import clone
from skopt.learning import GaussianProcessRegressor
from skopt.learning.gaussian_process.gpr import _param_for_white_kernel_in_Sum
from skopt.learning.gaussian_process.kernels import WhiteKernel


class Memory:
    """Shared by every clone of one estimator (a deep copy returns the same object)."""

    def __init__(self):
        self.kernel, self.noise, self.fits = None, None, 0

    def __deepcopy__(self, memo):
        return self


class WarmGaussianProcess(GaussianProcessRegressor):
    def __init__(self, kernel=None, *, alpha=0.0, optimizer="fmin_l_bfgs_b", n_restarts_optimizer=0,
                 normalize_y=True, copy_X_train=True, random_state=None, noise=1e-10,
                 refit_every=5, memory=None):
        super().__init__(kernel=kernel, alpha=alpha, optimizer=optimizer,
                         n_restarts_optimizer=n_restarts_optimizer, normalize_y=normalize_y,
                         copy_X_train=copy_X_train, random_state=random_state, noise=noise)
        self.refit_every = refit_every
        self.memory = memory

    def fit(self, X, y):
        memory = self.memory if self.memory is not None else Memory()
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
            if memory.fits % self.refit_every:
                self.optimizer = None
        super().fit(X, y)
        memory.kernel, memory.noise = self.kernel_, self.noise_
        return self
