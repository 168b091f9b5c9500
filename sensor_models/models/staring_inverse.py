"""Inverse localization kernels of the geostationary staring model, and their Jacobian.

Functions of a :class:`~sensor_models.models.geo_staring.GeoStaringModel` (module docstring
there): the object direction ``w`` of a ground point rotated into the camera frame
(:func:`ground_to_camera`), the two equations ``F(u, v) = (x/z - tan psi_x(u, v),
y/z - tan psi_y(u, v)) = 0`` of seed 000 eq. 11 solved for the frame coordinates
(:func:`camera_to_frame`), and the analytic image-space Jacobian at the solutions
(:func:`frame_jacobian`).
"""

from __future__ import annotations

import numpy as np

from sensor_models.geometry.geodesy import geodetic_to_ecef
from sensor_models.models.staring_camera import cubic_monomials

__all__ = ["camera_to_frame", "frame_jacobian", "ground_to_camera"]


def ground_to_camera(model, lon, lat, h):
    """Vectors from the satellite to ground points in the camera and body frames, and visibility.

    Parameters
    ----------
    model : GeoStaringModel
    lon, lat, h : ndarray, shape (N,)
        Ground points: degrees, degrees, metres above the ellipsoid.

    Returns
    -------
    cam, body : ndarray, shape (N, 3)
        ``(R^itrf_body R_inst R_ref)^T w`` and ``(R^itrf_body)^T w`` for ``w = G - P``, metres.
    visible : ndarray of bool, shape (N,)
        The satellite is above the point's local horizon.
    """
    ground = geodetic_to_ecef(lon, lat, h)
    w = ground - model.position_itrf_m
    body = w @ model.body_to_itrf  # R_b2i^T w, row-vector form
    cam = body @ model.generalized_installation
    lam, phi = np.radians(lon), np.radians(lat)
    up = np.stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)], axis=-1)
    # the satellite must be above the point's local horizon (Earth's limb)
    visible = np.einsum("ij,ij->i", up, -w) > 0.0
    return cam, body, visible


def camera_to_frame(model, cam, usable):
    """Normalized frame coordinates of camera-frame vectors: the cubic solved (seed 000 eq. 11).

    Parameters
    ----------
    model : GeoStaringModel
    cam : ndarray, shape (N, 3)
        Camera-frame directions.
    usable : ndarray of bool, shape (N,)
        Points to solve.

    Returns
    -------
    u, v : ndarray, shape (N,)
        NaN where not usable, behind the camera, or not solved.
    """
    n = cam.shape[0]
    u = np.full(n, np.nan)
    v = np.full(n, np.nan)
    front = usable & (cam[:, 2] > 0.0)
    idx = np.nonzero(front)[0]
    if idx.size:
        z = cam[idx, 2]
        u[idx], v[idx] = model.interior.solve(cam[idx, 0] / z, cam[idx, 1] / z)
    return u, v


def frame_jacobian(model, cam, body, u, v, positions):
    """``d(row, col)/dp`` at solutions ``(u, v)`` by the implicit-function theorem.

    ``d(u, v)/dp = T'^{-1} dF/dp`` with ``T'`` the 2x2 derivative of ``(tan psi_x, tan psi_y)``
    in ``(u, v)``, then ``d(row, col)/dp`` by the scales ``n/2``.

    Parameters
    ----------
    model : GeoStaringModel
    cam, body : ndarray, shape (N, 3)
        The points' camera- and body-frame vectors (:func:`ground_to_camera`).
    u, v : ndarray, shape (N,)
        Their solutions (:func:`camera_to_frame`), finite.
    positions : sequence of int
        Indices of the parameters in :meth:`GeoStaringModel.parameter_names`.

    Returns
    -------
    ndarray, shape (N, 2, P)
    """
    n = u.size
    xu, xv, yu, yv = model.interior.derivatives(u, v)
    det = xu * yv - xv * yu
    # T'^-1 = [[yv, -xv], [-yu, xu]] / det
    inv = np.stack([np.stack([yv, -xv], -1), np.stack([-yu, xu], -1)], 1) / det[:, None, None]
    dfdp = np.zeros((n, 2, len(positions)))
    x, y, z = cam[:, 0], cam[:, 1], cam[:, 2]
    d_inst = model.installation.matrix_derivatives()
    mono = None
    for j, k in enumerate(positions):
        if k < 3:
            dcam = body @ (d_inst[k] @ model.mirror_reflection)  # d(M^T body) as a row vector
            dfdp[:, 0, j] = (dcam[:, 0] * z - x * dcam[:, 2]) / (z * z)
            dfdp[:, 1, j] = (dcam[:, 1] * z - y * dcam[:, 2]) / (z * z)
        else:
            if mono is None:
                mono = cubic_monomials(u, v)
            comp, m = divmod(k - 3, 10)
            dfdp[:, comp, j] = -mono[:, m]
    duv = np.einsum("nij,njp->nip", inv, dfdp)  # rows: (du, dv)
    jac = np.empty_like(duv)
    jac[:, 0] = 0.5 * model.n_rows * duv[:, 1]
    jac[:, 1] = 0.5 * model.n_cols * duv[:, 0]
    return jac
