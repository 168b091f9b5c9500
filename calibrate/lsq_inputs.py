"""What the caller hands the least-squares solver (:func:`calibrate.lsq.solve`).

:class:`Chunk` is one block of points: residuals ``observed - modelled``, the model's Jacobian
for some of the parameters and the points' prior weights. :class:`Prior` holds linear
pseudo-observations ``G x = v +- sigma`` on the parameters (e.g. gauge constraints). The
problem they state is in the docstring of :mod:`calibrate.lsq`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from sensor_models.errors import InputError

__all__ = ["Chunk", "Prior"]


class Chunk(NamedTuple):
    """One block of points handed to :func:`calibrate.lsq.solve`.

    Attributes
    ----------
    residual : ndarray, shape (n, k) or (n,)
        Observed minus modelled values.
    jacobian : ndarray, shape (n, k, p) or (n, p)
        Derivatives of the modelled values with respect to the parameters ``columns``.
    weight : ndarray, shape (n,), optional
        Prior weights (``1 / sigma^2``); default 1. Zero removes a point from the fit.
    columns : array_like of int, shape (p,), optional
        Positions in ``x`` of the Jacobian's columns; default: all ``P`` parameters.
    """

    residual: np.ndarray
    jacobian: np.ndarray
    weight: np.ndarray | None = None
    columns: Sequence[int] | None = None


@dataclass(frozen=True)
class Prior:
    """Linear pseudo-observations ``matrix @ x = value +- sigma`` (e.g. gauge constraints).

    Attributes
    ----------
    matrix : ndarray, shape (m, P)
    value, sigma : ndarray, shape (m,)

    Their weights ``1 / sigma^2`` are in the units of the prior point weights; they are not
    robustly reweighted. :meth:`fixed` builds ``x[index] = value +- sigma``.
    """

    matrix: np.ndarray
    value: np.ndarray
    sigma: np.ndarray

    def __post_init__(self):
        matrix = np.atleast_2d(np.asarray(self.matrix, dtype=np.float64))
        value = np.asarray(self.value, dtype=np.float64).reshape(-1)
        sigma = np.asarray(self.sigma, dtype=np.float64).reshape(-1)
        if not (matrix.shape[0] == value.size == sigma.size):
            raise InputError("prior matrix rows, values and sigmas must have one length")
        if not np.all(np.isfinite(matrix)) or not np.all(np.isfinite(value)):
            raise InputError("prior matrix and values must be finite")
        if np.any(~(sigma > 0.0)) or np.any(~np.isfinite(sigma)):
            raise InputError("prior sigmas must be positive and finite")
        object.__setattr__(self, "matrix", matrix)
        object.__setattr__(self, "value", value)
        object.__setattr__(self, "sigma", sigma)

    @classmethod
    def fixed(cls, index, value, sigma, n_par: int) -> "Prior":
        """Pseudo-observations of single parameters: ``x[index] = value +- sigma``.

        Parameters
        ----------
        index : int or array_like of int, shape (M,)
            Positions of the held parameters in the parameter vector.
        value, sigma : float or array_like, shape (M,)
            Held values and their standard deviations (parameter units).
        n_par : int
            Number of parameters P.

        Returns
        -------
        Prior
            ``M`` pseudo-observations with a (M, P) selection matrix.
        """
        index = np.asarray(index, dtype=np.intp).reshape(-1)
        if np.any((index < 0) | (index >= n_par)):
            raise InputError("prior index outside the parameter vector")
        matrix = np.zeros((index.size, n_par))
        matrix[np.arange(index.size), index] = 1.0
        return cls(matrix, value, sigma)

    def __len__(self) -> int:
        return self.value.size
