"""In-orbit measurement sensitivity of the OALR (seed 004 table 4) from measured mark noise.

Seed 004 section 4 propagates the mark location error ``sigma_k`` through its table 2 (eq. 2-5
linearized, :func:`calibrate.schemes.autocollimation.measurement_sigmas`) into table 3, then
states: "the in-orbit measurement sensitivity can be determined by correcting the random
components using the data from multiple readings (9)", and gives table 4 (3 sigma): 0.0015 mm
(focal length), 0.0022 / 0.0022 / 0.0936 arcsec (rotations about X / Y / Z).

We read it as table 2 applied to the error of a mark position averaged over ``N`` readings:

.. math::

    \\sigma_{k,\\mathrm{sens}} = c\\, \\sigma_1 / \\sqrt{N},

with ``sigma_1`` the 1-sigma scatter of one reading of a static mark per coordinate, *measured*
here by rendering repeated SMCCD frames of the mark
(:func:`calibrate.schemes.autocollimation.render_cross`: the profile's signal, background, read
noise, PSF and PRNU) and locating each (:func:`~calibrate.schemes.autocollimation.locate_cross`);
``c = 3`` (the table's level) and ``N = 9`` (the "(9)" of the text; the paper's own lab-to-flight
``sigma_k`` ratio, 0.430 / 0.144 = 2.99, is the same ``sqrt(9)``). The nominal mark positions
are taken as known (table 2 counts one ``sigma_k`` per displacement coordinate).

Table 2 is linear in ``sigma_k``, so each paper row also gives the mark-level sensitivity it
implies; :func:`sensitivity_table4` lists it beside ours. :func:`monte_carlo_table4` checks the
propagation independently: true changes, marks rendered ``N`` times at the displaced positions,
located, averaged and turned back into changes by eq. 2-5; ``c`` times the standard deviation of
recovered minus true, with its 95 % interval.
"""

from __future__ import annotations

import numpy as np

from calibrate.schemes.autocollimation import (ARCSEC, OalrChanges, OalrGeometry, changes_from_displacements,
                                               displacements_from_changes, locate_cross, measurement_sigmas,
                                               render_cross)
from sensor_models.errors import InputError

__all__ = ["LEVEL", "PAPER_READINGS", "PAPER_TABLE4", "TABLE4_ROWS", "monte_carlo_table4", "reading_noise",
           "sensitivity_table4"]

#: seed 004 table 4, in-orbit measurement sensitivity (3 sigma)
PAPER_TABLE4 = {"sigma_f_mm": 0.0015, "sigma_rot_x_arcsec": 0.0022, "sigma_rot_y_arcsec": 0.0022,
                "sigma_rot_z_arcsec": 0.0936}
#: the four rows, in the table's order
TABLE4_ROWS = tuple(PAPER_TABLE4)
#: readings averaged per in-orbit measurement (seed 004 section 4: "multiple readings (9)")
PAPER_READINGS = 9
#: confidence level of table 4 (its caption: 3 sigma)
LEVEL = 3.0


def _reading(frame, centre, rng, render_kw: dict, gain) -> np.ndarray:
    """One located (row, col) of a mark rendered at ``centre`` (PRNU ``gain`` applied when given)."""
    img = render_cross(frame, centre, rng=rng, **render_kw)
    if gain is not None:
        img = render_kw["background_e"] + (img - render_kw["background_e"]) * gain
    return np.array(locate_cross(img))


def reading_noise(render_kw: dict, *, frame=(41, 41), centres: int = 12, readings: int = 12, gain=None,
                  seed: int = 0) -> dict:
    """Measured 1-sigma scatter of one mark reading, per coordinate.

    ``centres`` static marks at random sub-pixel phases near the frame centre, each rendered and
    located ``readings`` times with fresh noise; the scatter is the pooled within-mark standard
    deviation (the mean of each mark's readings removed, ``centres * (readings - 1)`` degrees of
    freedom), rows and columns together.

    Parameters
    ----------
    render_kw : dict
        ``psf_sigma_px``, ``amplitude_e``, ``background_e``, ``read_noise_e`` of
        :func:`~calibrate.schemes.autocollimation.render_cross`.
    frame : (int, int)
        SMCCD frame, pixels.
    centres, readings : int
        Static marks, and readings of each (both >= 2).
    gain : ndarray, shape ``frame``, optional
        Per-pixel gain (PRNU), fixed over the readings.
    seed : int

    Returns
    -------
    dict
        ``sigma_px`` (pooled), ``sigma_row_px``, ``sigma_col_px``, ``dof`` (per coordinate),
        ``bias_px`` (mean located minus true, over every reading: row, col).
    """
    if centres < 2 or readings < 2:
        raise InputError("needs at least 2 marks and 2 readings of each", field="readings")
    rng = np.random.default_rng(seed)
    mid = 0.5 * np.asarray(frame, dtype=np.float64)
    res = np.empty((centres, readings, 2))
    truth = np.empty((centres, 2))
    for i in range(centres):
        truth[i] = mid + rng.uniform(-0.5, 0.5, 2)
        for j in range(readings):
            res[i, j] = _reading(frame, truth[i], rng, render_kw, gain)
    dev = res - res.mean(axis=1, keepdims=True)
    dof = centres * (readings - 1)
    var = (dev ** 2).sum(axis=(0, 1)) / dof
    return {"sigma_px": float(np.sqrt(var.mean())), "sigma_row_px": float(np.sqrt(var[0])),
            "sigma_col_px": float(np.sqrt(var[1])), "dof": int(dof),
            "bias_px": (res - truth[:, None, :]).mean(axis=(0, 1)).tolist()}


def _rows(sigma_k_px: float, geometry: OalrGeometry) -> dict:
    s = measurement_sigmas(sigma_k_px, geometry)
    return {"sigma_f_mm": s["sigma_f_mm"], "sigma_rot_x_arcsec": s["sigma_rot_x_rad"] / ARCSEC,
            "sigma_rot_y_arcsec": s["sigma_rot_y_rad"] / ARCSEC, "sigma_rot_z_arcsec": s["sigma_rot_z_rad"] / ARCSEC}


def sensitivity_table4(sigma_reading_px: float, *, readings: int = PAPER_READINGS, level: float = LEVEL,
                       geometry: OalrGeometry = OalrGeometry()) -> dict:
    """Seed 004 table 4 from a measured single-reading mark noise (module docstring).

    Parameters
    ----------
    sigma_reading_px : float
        1-sigma error of one mark reading per coordinate, pixels (:func:`reading_noise`).
    readings : int
        Readings averaged per measurement ``N``.
    level : float
        Confidence level ``c`` (3: table 4's).
    geometry : OalrGeometry

    Returns
    -------
    dict
        ``sigma_k_px`` (``c sigma_1 / sqrt(N)``), ``readings``, ``level``, ``rows``: name ->
        ``{"ours", "paper", "ratio"}``, ``paper_sigma_k_px``: name -> the mark-level sensitivity
        each paper row implies through table 2, and ``readings_for_paper``: the ``N`` that would
        bring ours to the paper's (mean over the rows).
    """
    s1 = float(sigma_reading_px)
    if not (np.isfinite(s1) and s1 >= 0.0) or int(readings) < 1:
        raise InputError(f"needs a non-negative noise and >= 1 reading, got {sigma_reading_px}, {readings}",
                         field="readings")
    sigma_k = float(level) * s1 / np.sqrt(int(readings))
    ours = _rows(sigma_k, geometry)
    unit = _rows(1.0, geometry)
    rows = {k: {"ours": ours[k], "paper": PAPER_TABLE4[k], "ratio": ours[k] / PAPER_TABLE4[k]} for k in TABLE4_ROWS}
    implied = {k: PAPER_TABLE4[k] / unit[k] for k in TABLE4_ROWS}
    n_paper = float(np.mean([int(readings) * rows[k]["ratio"] ** 2 for k in TABLE4_ROWS]))
    return {"sigma_reading_px": s1, "readings": int(readings), "level": float(level), "sigma_k_px": sigma_k,
            "rows": rows, "paper_sigma_k_px": implied, "readings_for_paper": n_paper}


def monte_carlo_table4(render_kw: dict, *, readings: int = PAPER_READINGS, trials: int = 60, spread: dict,
                       level: float = LEVEL, frame=(41, 41), gains=(None, None),
                       geometry: OalrGeometry = OalrGeometry(), seed: int = 1) -> dict:
    """Table 4 by simulation: rendered, located and averaged marks through eq. 2-5.

    Each trial draws true changes (normal, standard deviations ``spread``), turns them into mark
    displacements (:func:`~calibrate.schemes.autocollimation.displacements_from_changes`), renders
    each channel's mark ``readings`` times at its nominal position (random sub-pixel phase) plus
    the displacement, locates and averages them, subtracts the nominal position and recovers the
    changes (:func:`~calibrate.schemes.autocollimation.changes_from_displacements`).

    Parameters
    ----------
    render_kw : dict
        As :func:`reading_noise`.
    readings : int
        Readings averaged per measurement.
    trials : int
        Simulated measurements (>= 3).
    spread : dict
        ``delta_f_mm``, ``rot_x_arcsec``, ``rot_y_arcsec``, ``rot_z_arcsec``: 1-sigma true changes.
    level : float
        Confidence level of the result (3: table 4's).
    frame : (int, int)
    gains : (ndarray or None, ndarray or None)
        Per-pixel gain of each channel's SMCCD.
    geometry : OalrGeometry
    seed : int

    Returns
    -------
    dict
        name -> ``{"value", "low", "high"}``: ``level`` times the standard deviation of recovered
        minus true, and its 95 % interval (chi-square, ``trials - 1`` degrees of freedom).
    """
    from scipy.stats import chi2

    if trials < 3:
        raise InputError("needs at least 3 trials", field="trials")
    rng = np.random.default_rng(seed)
    true = OalrChanges(rng.normal(0, spread["delta_f_mm"], trials), rng.normal(0, spread["rot_x_arcsec"], trials) * ARCSEC,
                       rng.normal(0, spread["rot_y_arcsec"], trials) * ARCSEC,
                       rng.normal(0, spread["rot_z_arcsec"], trials) * ARCSEC)
    d_true = np.stack(displacements_from_changes(true, geometry), 1)  # (N, 4): dx1, dy1, dx2, dy2
    mid = 0.5 * np.asarray(frame, dtype=np.float64)
    d_meas = np.empty_like(d_true)
    for i in range(trials):
        for ch in range(2):
            nominal = mid + rng.uniform(-0.5, 0.5, 2)
            at = nominal + np.array([d_true[i, 2 * ch + 1], d_true[i, 2 * ch]])  # (row = y, col = x)
            mean = np.mean([_reading(frame, at, rng, render_kw, gains[ch]) for _ in range(int(readings))], axis=0)
            d_meas[i, 2 * ch], d_meas[i, 2 * ch + 1] = mean[1] - nominal[1], mean[0] - nominal[0]
    est = changes_from_displacements(*d_meas.T, geometry)
    err = {"sigma_f_mm": est.delta_f_mm - true.delta_f_mm,
           "sigma_rot_x_arcsec": (est.rot_x_rad - true.rot_x_rad) / ARCSEC,
           "sigma_rot_y_arcsec": (est.rot_y_rad - true.rot_y_rad) / ARCSEC,
           "sigma_rot_z_arcsec": (est.rot_z_rad - true.rot_z_rad) / ARCSEC}
    dof = trials - 1
    lo_f, hi_f = np.sqrt(dof / chi2.ppf(0.975, dof)), np.sqrt(dof / chi2.ppf(0.025, dof))
    out = {}
    for k, e in err.items():
        s = float(level) * float(np.std(e, ddof=1))
        out[k] = {"value": s, "low": s * lo_f, "high": s * hi_f}
    return out
