"""Gauge pseudo-observations that fix the camera frame in the joint calibration scheme.

In the joint scheme the installation angles and the c0/c1 terms of every CCD's interior are
nearly dependent (a rotation of the camera is a shift of every detector's look).
:func:`gauge_prior` holds the reference CCD's mean look and along-track tilt of a push-broom
camera at their initial values; :func:`staring_gauge_prior` holds an area-array camera's mean
look and in-plane rotation. Both are :class:`~calibrate.lsq_inputs.Prior` pseudo-observations
with standard deviations of ``gauge_sigma_px`` pixels.
"""

from __future__ import annotations

import numpy as np

from calibrate.calibration_problem import EXTERIOR
from calibrate.lsq_inputs import Prior
from sensor_models.errors import InputError

__all__ = ["gauge_prior", "staring_gauge_prior"]


def staring_gauge_prior(model, free, gauge_sigma_px):
    """Joint scheme of a staring camera: hold its mean look and in-plane rotation (the gauge).

    Parameters
    ----------
    model : SensorModel
        Area-array staring camera (its ``gauge_rows``).
    free : sequence of str
        Names estimated by the joint step.
    gauge_sigma_px : float
        Standard deviation of the pseudo-observations, px.

    Returns
    -------
    Prior or None
        None when no free parameter enters the gauge.
    """
    rows, scale = model.gauge_rows()
    names = list(model.parameter_names())
    idx = [names.index(n) for n in free]
    matrix = np.asarray(rows)[:, idx]
    keep = np.any(matrix != 0.0, axis=1)
    if not keep.any():
        return None
    x0 = model.parameters().values[idx]
    return Prior(matrix[keep], matrix[keep] @ x0, gauge_sigma_px * np.asarray(scale)[keep])


def gauge_prior(model, groups, free, reference_ccd, gauge_sigma_px):
    """Pseudo-observations fixing the camera frame in the joint scheme.

    A rotation of the camera shifts every detector's look: roll moves ``tan psi_y``, pitch
    ``tan psi_x``, and yaw tilts ``tan psi_x`` along the CCD. Three linear functionals of the
    reference CCD's polynomials, taken over its detectors ``s = 0 .. n-1``, are held at their
    initial values: the mean of ``tan psi_x(s)``, its least-squares slope in ``s``, and the
    mean of ``tan psi_y(s)``. (Holding single coefficients is not enough: the cubic's higher
    terms can mimic a tilt.) No gauge is added when a CCD with GCPs keeps its interior: its
    points already fix the frame.

    Parameters
    ----------
    model : PushbroomModel
        The model calibrated (initial values).
    groups : list
        Point groups (:func:`calibrate.gcp_groups.group_points`) with their ``estimable`` flags.
    free : sequence of str
        Names estimated by the joint step.
    reference_ccd : (str, str) or None
        ``(band, ccd name)`` holding the gauge; default: the estimable CCD with the most points
        in the reference band.
    gauge_sigma_px : float
        Standard deviation of the pseudo-observations, px (converted with the CCD's IFOV).

    Returns
    -------
    Prior or None
        None when no gauge is needed or possible.

    Raises
    ------
    InputError
        ``reference_ccd`` has no estimable interior.
    """
    if not any(n in free for n in EXTERIOR):
        return None
    if any(not any(n in free for n in g.interior) for g in groups):
        return None  # a CCD whose interior is held already anchors the frame
    candidates = [g for g in groups if g.estimable and any(n in free for n in g.interior)]
    if not candidates:
        return None
    if reference_ccd is not None:
        band, name = reference_ccd
        chosen = [g for g in candidates if g.band == band and g.ccd_name == name]
        if not chosen:
            raise InputError(f"reference CCD {band}.{name} has no estimable interior", field="reference_ccd")
        ref = chosen[0]
    else:
        in_ref = [g for g in candidates if g.band == model.reference_band] or candidates
        ref = max(in_ref, key=lambda g: g.idx.size)
    look = model.detector_arrays(ref.band)[ref.ccd]
    ifov = abs(float(look.tan_psi_y[1])) if look.tan_psi_y.size > 1 else 0.0
    if not ifov > 0.0:
        ifov = 1e-5
    s = np.arange(look.n_detectors, dtype=np.float64)
    sc = s - s.mean()
    position = {n: j for j, n in enumerate(free)}
    rows, sigmas = [], []
    for axis, kind, sigma in (
        ("tan_psi_x", "mean", gauge_sigma_px * ifov),
        ("tan_psi_x", "slope", gauge_sigma_px * ifov / max(look.n_detectors / 2.0, 1.0)),
        ("tan_psi_y", "mean", gauge_sigma_px * ifov),
    ):
        row = np.zeros(len(free))
        for k in range(getattr(look, axis).size):
            j = position.get(f"{ref.band}.{look.name}.{axis}.c{k}")
            if j is None:
                continue
            row[j] = np.mean(s**k) if kind == "mean" else np.sum(sc * s**k) / np.sum(sc * sc)
        if np.any(row):
            rows.append(row)
            sigmas.append(sigma)
    if not rows:
        return None
    matrix = np.array(rows)
    lookup = {n: i for i, n in enumerate(model.parameters().names)}
    x0 = model.parameters().values[[lookup[n] for n in free]]
    return Prior(matrix, matrix @ x0, np.array(sigmas))
