"""The one interface every sensor model implements.

A :class:`SensorModel` maps image coordinates ``(row, col)`` to WGS84 ground coordinates
``(lon, lat, h)`` and back, and exposes its calibration parameters with analytic Jacobians.
Image coordinates follow GDAL/rasterio: the first pixel's centre is ``(0.5, 0.5)``; rows are
image lines (along track for a push-broom), columns are samples.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from sensor_models.errors import InputError

__all__ = ["ParameterVector", "SensorModel", "as_float_arrays"]


@dataclass(frozen=True)
class ParameterVector:
    """Named calibration parameters of a model.

    Attributes
    ----------
    names : tuple of str
        One name per parameter, e.g. ``"installation.yaw"`` or ``"B2.ccd1.tan_psi_y.c1"``.
        Names carry units when they are not radians, metres or dimensionless.
    values : ndarray, shape (P,)
    """

    names: tuple[str, ...]
    values: np.ndarray

    def __post_init__(self):
        values = np.asarray(self.values, dtype=np.float64).reshape(-1)
        if values.shape[0] != len(self.names):
            raise ValueError(f"{len(self.names)} names for {values.shape[0]} values")
        object.__setattr__(self, "values", values)

    def __len__(self) -> int:
        return len(self.names)

    def as_dict(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.values)}

    def index(self, names) -> np.ndarray:
        """Positions of ``names`` (an iterable of names) in this vector."""
        lookup = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in lookup]
        if missing:
            raise KeyError(f"unknown parameters: {', '.join(missing)}")
        return np.array([lookup[n] for n in names], dtype=np.intp)


def as_float_arrays(*arrays, names=None):
    """Broadcast inputs to float64 arrays of one shape; reject non-finite values.

    Raises
    ------
    InputError
        If an input holds NaN or infinity (naming it).
    """
    out = np.broadcast_arrays(*[np.asarray(a, dtype=np.float64) for a in arrays])
    for i, a in enumerate(out):
        if not np.all(np.isfinite(a)):
            label = names[i] if names else f"argument {i}"
            raise InputError(f"{label} holds NaN or infinite values")
    return [np.ascontiguousarray(a) for a in out]


class SensorModel(abc.ABC):
    """Abstract sensor model: ground <-> image mapping plus parameters and Jacobians."""

    #: short model kind, e.g. ``"pushbroom"``, ``"rpc"``, ``"geo_staring"``
    kind: str = "abstract"

    @property
    @abc.abstractmethod
    def image_shape(self) -> tuple[int, int]:
        """``(n_rows, n_cols)`` of the image this model describes."""

    @abc.abstractmethod
    def image_to_ground(self, row, col, *, height=None, dem=None, band=None):
        """Direct localization: image coordinates to ground coordinates.

        Parameters
        ----------
        row, col : array_like, shape (N,)
            Continuous image coordinates (first pixel centre at 0.5).
        height : float or array_like, optional
            Ellipsoidal height in metres of the ground surface (exclusive with ``dem``).
        dem : sensor_models.terrain.Dem, optional
            Terrain to intersect.
        band : str, optional
            Spectral band for multi-band models.

        Returns
        -------
        lon_deg, lat_deg, h_m : ndarray, shape (N,)
        """

    @abc.abstractmethod
    def ground_to_image(self, lon, lat, h, *, band=None):
        """Inverse localization: ground coordinates to continuous image coordinates.

        Returns
        -------
        row, col : ndarray, shape (N,)
        """

    @abc.abstractmethod
    def parameters(self) -> ParameterVector:
        """The calibration parameters and their current values."""

    @abc.abstractmethod
    def with_parameters(self, values) -> "SensorModel":
        """A copy of this model with new parameter values (same order as :meth:`parameters`)."""

    @abc.abstractmethod
    def image_jacobian(self, lon, lat, h, *, band=None, names=None):
        """Analytic partial derivatives of ``ground_to_image`` with respect to the parameters.

        Returns
        -------
        row, col : ndarray, shape (N,)
            The projections of the ground points.
        jac : ndarray, shape (N, 2, P)
            ``d(row, col) / d(parameter)`` for the parameters ``names`` (default: all).
        """
