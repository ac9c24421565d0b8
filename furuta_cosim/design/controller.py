"""The paper's generalized (dynamic) state feedback and its closed loop.

    x_c' = Ac x_c + Bc x          (x_c[k+1] = ... in discrete time)
    u    = r - (Cc x_c + Dc x)

n_xc = 0 is static state feedback u = r - K x with Dc = K. The augmented closed loop of
plant and controller is  xbar' = Abar xbar + Bbar r  with

    Abar = [[A - B Dc, -B Cc],        Bbar = [[B],
            [Bc,        Ac  ]]                [0]]
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from furuta_cosim.design.linear import LinearModel, discretize
from furuta_cosim.errors import DesignError


@dataclass(frozen=True)
class GeneralizedController:
    """The paper's generalized dynamic state feedback ``xc' = Ac xc + Bc x``, ``u = Cc xc + Dc x``
    (a difference equation when ``period`` > 0). Matrices are checked for shape and finiteness
    and frozen.

    Parameters
    ----------
    Ac : array_like, n_xc x n_xc
        Controller state matrix; empty for a static gain.
    Bc : array_like, n_xc x n_x
        Plant state to controller state.
    Cc : array_like, n_u x n_xc
        Controller state to input.
    Dc : array_like, n_u x n_x
        Direct feedback (``-K`` for a static gain).
    period : float, optional
        Sampling period in seconds; 0 (the default) is continuous time.
    name : str, optional
        Used in messages and reports.
    provenance : dict, optional
        Where the controller came from (a design, a tuning run); not compared.

    Raises
    ------
    DesignError
        Naming the controller and the matrix that does not fit.
    """

    Ac: np.ndarray
    Bc: np.ndarray
    Cc: np.ndarray
    Dc: np.ndarray
    period: float = 0.0
    name: str = ""
    provenance: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        Dc = np.atleast_2d(np.asarray(self.Dc, dtype=float))
        n_u, n_x = Dc.shape
        Ac = np.asarray(self.Ac, dtype=float)
        Ac = np.atleast_2d(Ac) if Ac.size else np.zeros((0, 0))
        n_xc = Ac.shape[0]
        if Ac.shape != (n_xc, n_xc):
            raise DesignError(f"controller {self.name or '?'}: Ac must be square, got "
                              f"{Ac.shape[0]}x{Ac.shape[1]}")
        shapes = {"Ac": (n_xc, n_xc), "Bc": (n_xc, n_x), "Cc": (n_u, n_xc)}
        arrays = {"Ac": Ac}
        problems = []
        for key in ("Bc", "Cc"):
            value = np.asarray(getattr(self, key), dtype=float)
            if value.size != shapes[key][0] * shapes[key][1]:
                problems.append(f"{key} must be {shapes[key][0]}x{shapes[key][1]}, got "
                                f"{value.size} value(s)")
                continue
            arrays[key] = value.reshape(shapes[key])
        if problems:
            raise DesignError(f"controller {self.name or '?'}: " + "; ".join(problems))
        arrays["Dc"] = Dc
        for key, value in arrays.items():
            if not np.all(np.isfinite(value)):
                raise DesignError(f"controller {self.name or '?'}: {key} has non-finite entries")
            value.setflags(write=False)
            object.__setattr__(self, key, value)
        if not (self.period >= 0 and np.isfinite(self.period)):
            raise DesignError(f"controller {self.name or '?'}: period must be >= 0, got {self.period}")

    @classmethod
    def static(cls, K, period: float = 0.0, name: str = "", provenance: dict | None = None):
        """Static state feedback ``u = r - K x``.

        Parameters
        ----------
        K : array_like, n_u x n_x
            The gain.
        period : float, optional
            Sampling period in seconds; 0 is continuous time.
        name : str, optional
            Used in messages and reports.
        provenance : dict, optional
            Where the gain came from.

        Returns
        -------
        GeneralizedController
        """
        K = np.atleast_2d(np.asarray(K, dtype=float))
        return cls(np.zeros((0, 0)), np.zeros((0, K.shape[1])), np.zeros((K.shape[0], 0)), K,
                   period, name, provenance or {})

    @property
    def n_xc(self) -> int:
        return self.Ac.shape[0]

    @property
    def discrete(self) -> bool:
        return self.period > 0

    @property
    def K(self) -> np.ndarray:
        """Dc: the static gain (meaningful alone when n_xc = 0 or Bc = 0)."""
        return self.Dc

    def check_fits(self, model: LinearModel) -> None:
        """Refuse a controller whose state and input counts are not the model's.

        Parameters
        ----------
        model : LinearModel
            The plant the controller is to close the loop on.

        Raises
        ------
        DesignError
        """
        if self.Dc.shape != (model.B.shape[1], model.n):
            raise DesignError(f"controller {self.name or '?'} is for {self.Dc.shape[1]} states and "
                              f"{self.Dc.shape[0]} input(s); model {model.name} has {model.n} "
                              f"states and {model.B.shape[1]} input(s)")


def discretize_controller(controller: GeneralizedController, period: float) -> GeneralizedController:
    """Zero-order-hold discretization of a continuous controller (its input x held over a period)."""
    if controller.discrete:
        return controller
    if not period > 0:
        raise DesignError(f"the sampling period must be > 0, got {period}")
    provenance = {**controller.provenance, "discretized": f"zoh, {period:g} s"}
    if controller.n_xc == 0:
        return GeneralizedController(controller.Ac, controller.Bc, controller.Cc, controller.Dc,
                                     period, controller.name, provenance)
    import control  # here: python-control takes a second to import, and runs rarely need it

    sampled = control.c2d(control.ss(controller.Ac, controller.Bc, controller.Cc, controller.Dc),
                          period, method="zoh")
    return GeneralizedController(sampled.A, sampled.B, controller.Cc, controller.Dc, period,
                                 controller.name, provenance)


def augmented(model: LinearModel, controller: GeneralizedController) -> tuple[np.ndarray, np.ndarray]:
    """(Abar, Bbar) of plant and controller in the controller's time domain.

    A discrete controller on a continuous model closes the exact sampled-data loop: the
    plant is discretized with zero-order hold at the controller's period.
    """
    controller.check_fits(model)
    if controller.discrete:
        model = discretize(model, controller.period)
    elif model.discrete:
        raise DesignError(f"controller {controller.name or '?'} is continuous but model "
                          f"{model.name} is discrete: discretize the controller first")
    A, B = model.A, model.B
    top = np.hstack([A - B @ controller.Dc, -B @ controller.Cc])
    bottom = np.hstack([controller.Bc, controller.Ac])
    Abar = np.vstack([top, bottom])
    Bbar = np.vstack([B, np.zeros((controller.n_xc, B.shape[1]))])
    return Abar, Bbar
