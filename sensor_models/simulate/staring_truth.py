"""TRUE staring-camera interiors outside the estimator's family: the physical lens itself.

The LAB and compensated models of a staring camera hold the 20-coefficient cubic of seed 000
eq. 4-5 (:class:`~sensor_models.models.staring_camera.StaringInterior`). When the TRUE model is that
same cubic fitted to the physical lens (the ``ideal`` path, ``GeoStaringModel.from_lab``),
every scheme that frees the interior reaches 1e-7 px: the estimator fits its own family.

Here the TRUE interior is the physical (laboratory) lens evaluated at every pixel: principal
point, focal length, array tilt and rotation (seed 002 table 1, through
:meth:`StaringLab.tangents` with its distortion switched off) and a Brown-Conrady distortion
with three radial terms::

    dx = x (k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 x^2) + 2 p2 x y
    dy = y (k1 r^2 + k2 r^4 + k3 r^6) + p2 (r^2 + 2 y^2) + 2 p1 x y

(pixels from the principal point), ``tan psi = (x - dx, y - dy) / F`` with ``F = f / pitch``.
The tilt's central projection and the ``k2``, ``k3`` terms lie outside the cubic; the residual of
the cubic's best fit is in ``model.lab_fit_residual`` (``physical_fit_residual_px``).

The inverse (ground -> image) is the base model's Newton solve on these tangents, started from
the cubic's linear terms, with derivatives by central differences.

References
----------
.. [1] Seed 002: Xiao et al., Appl. Sci. 2023, 13, 9688, table 1 (lens terms of the staring camera).
.. [2] Brown, D. C. 1971, Close-range camera calibration, Photogramm. Eng. 37(8):855-866
   (radial series k1, k2, k3 and decentering p1, p2).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sensor_models.models.geo_staring import GeoStaringModel
from sensor_models.models.staring_camera import StaringInterior, StaringLab

__all__ = ["PhysicalLensInterior", "PhysicalLensStaringModel", "physical_truth", "radial_from_corner_px"]

#: step of the central differences, normalized units (about 5e-4 px on a 10240 array)
_DIFF_STEP = 1e-7


def radial_from_corner_px(corner_px: float, power: int, image_shape) -> float:
    """The radial coefficient giving ``corner_px`` pixels of displacement at the frame corner.

    Parameters
    ----------
    corner_px : float
        Displacement ``k r^(power + 1)`` at ``r`` = half the frame diagonal, pixels.
    power : int
        Power of ``r`` multiplying ``x`` (4 for ``k2``, 6 for ``k3``).
    image_shape : (int, int)
        ``(n_rows, n_cols)``.

    Returns
    -------
    float
        The coefficient, pixels^-power.
    """
    r_corner = 0.5 * float(np.hypot(*image_shape))
    return float(corner_px) / r_corner ** (int(power) + 1)


@dataclass(frozen=True)
class PhysicalLensInterior(StaringInterior):
    """A staring interior whose directions are the physical lens's, not the cubic's.

    ``tan_psi_x``, ``tan_psi_y`` hold the cubic fitted to the lens (what a LAB file would carry);
    :meth:`tangents` and :meth:`derivatives` evaluate the lens itself.

    Attributes
    ----------
    lens : StaringLab
        Geometry (focal length, pitch, principal point, tilt, rotation) and ``k1``, ``k2``,
        ``p1``, ``p2``.
    radial_k3 : float
        ``k3``, pixels^-6.
    image_shape : (int, int)
        ``(n_rows, n_cols)``.
    """

    lens: StaringLab = None
    radial_k3: float = 0.0
    image_shape: tuple = (0, 0)

    def tangents(self, u, v):
        """Directional angles of the physical lens at normalized coordinates (module docstring).

        Parameters
        ----------
        u, v : ndarray
            Normalized frame coordinates (``u`` from the columns, ``v`` from the rows), one shape.

        Returns
        -------
        tan_psi_x, tan_psi_y : ndarray, shape of ``u``
        """
        n_rows, n_cols = self.image_shape
        u, v = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
        row, col = 0.5 * n_rows * (1.0 + v), 0.5 * n_cols * (1.0 + u)
        geometry = replace(self.lens, radial_k=(0.0, 0.0), decentering_p=(0.0, 0.0))
        f_px = self.lens.focal_length_mm / self.lens.pixel_size_mm
        tx0, ty0 = geometry.tangents(row, col, self.image_shape)
        x, y = tx0 * f_px, ty0 * f_px
        r2 = x * x + y * y
        k1, k2 = self.lens.radial_k
        p1, p2 = self.lens.decentering_p
        radial = r2 * (k1 + r2 * (k2 + r2 * self.radial_k3))
        dx = x * radial + p1 * (r2 + 2.0 * x * x) + 2.0 * p2 * x * y
        dy = y * radial + p2 * (r2 + 2.0 * y * y) + 2.0 * p1 * x * y
        return (x - dx) / f_px, (y - dy) / f_px

    def derivatives(self, u, v):
        """Partial derivatives of :meth:`tangents` by central differences.

        Parameters
        ----------
        u, v : ndarray
            Normalized frame coordinates, one shape.

        Returns
        -------
        dx_du, dx_dv, dy_du, dy_dv : ndarray, shape of ``u``
        """
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        h = _DIFF_STEP
        xp, yp = self.tangents(u + h, v)
        xm, ym = self.tangents(u - h, v)
        xq, yq = self.tangents(u, v + h)
        xn, yn = self.tangents(u, v - h)
        return (xp - xm) / (2 * h), (xq - xn) / (2 * h), (yp - ym) / (2 * h), (yq - yn) / (2 * h)


class PhysicalLensStaringModel(GeoStaringModel):
    """A :class:`GeoStaringModel` whose interior is a :class:`PhysicalLensInterior`.

    :meth:`with_parameters` keeps the physical lens when the 20 interior values are the fit's
    (e.g. only the installation changed: thermal series, figure-4 cases); otherwise the new
    values are a cubic and the model becomes an ordinary cubic one.
    """

    def with_parameters(self, values) -> GeoStaringModel:
        """A copy with new parameter values (see :meth:`GeoStaringModel.with_parameters`).

        Parameters
        ----------
        values : array_like, shape (23,)
            Installation roll, pitch, yaw (radians) and the 20 interior coefficients.

        Returns
        -------
        GeoStaringModel
            A :class:`PhysicalLensStaringModel` when the interior values are unchanged.
        """
        new = super().with_parameters(values)
        old = np.concatenate([self.interior.tan_psi_x, self.interior.tan_psi_y])
        if np.array_equal(np.asarray(values, dtype=np.float64).reshape(-1)[3:], old):
            new.interior = self.interior
        return new


def physical_truth(model: GeoStaringModel, lens: StaringLab, *, radial_k3: float = 0.0) -> PhysicalLensStaringModel:
    """The TRUE model: ``model`` (exterior, frame) with the physical ``lens`` as its interior.

    Parameters
    ----------
    model : GeoStaringModel
        A model of the camera (e.g. ``GeoStaringModel.from_lab(lens, ...)``), whose cubic is kept
        as the interior's coefficients.
    lens : StaringLab
        The TRUE laboratory lens.
    radial_k3 : float
        Its ``k3``, pixels^-6.

    Returns
    -------
    PhysicalLensStaringModel
        ``lab`` is ``lens``; ``lab_fit_residual`` gains ``physical_fit_residual_px``: the largest
        difference, pixels, between the lens and the model's cubic over a 101 x 101 grid.
    """
    interior = PhysicalLensInterior(model.interior.tan_psi_x, model.interior.tan_psi_y, lens=lens,
                                    radial_k3=float(radial_k3), image_shape=tuple(model.image_shape))
    new = PhysicalLensStaringModel.__new__(PhysicalLensStaringModel)
    new.__dict__.update(model.__dict__)
    new.interior = interior
    new.lab = lens
    t = np.linspace(-1.0, 1.0, 101)
    u, v = (a.reshape(-1) for a in np.meshgrid(t, t))
    tx, ty = interior.tangents(u, v)
    cx, cy = model.interior.tangents(u, v)
    resid = float(np.hypot(tx - cx, ty - cy).max() / lens.ifov_rad)
    new.lab_fit_residual = {**(model.lab_fit_residual or {}), "physical_fit_residual_px": resid}
    return new
