r"""Temperature- and time-driven installation angles of a geostationary staring camera.

Seed 002 section 3.3 (figure 11): a geostationary camera's relative installation angles
``(alpha, beta, theta)`` (here ``installation.roll, pitch, yaw``) move with the temperature of
the bracket, which follows the Sun with a daily period (seed 000 section 4: "periodic, with a
cycle of one day approximately"; seed 002 introduction: annual and diurnal periodicities). The
seed calibrates the exterior at many epochs, builds the curve of the installation angles
against time and compensates the exterior with it. The study takes three steps:

1. **Per-epoch exterior** (:func:`fit_installation`, this module): the three installation
   angles from control points by Gauss-Newton on the image residuals with the model's analytic
   Jacobian ``d(row, col)/d(roll, pitch, yaw)``, with their covariance
   ``sigma_px^2 (J^T J)^{-1}`` (the same estimate as
   ``calibrate_model(model, ..., scheme="exterior")`` of :mod:`calibrate.absolute`, without its
   robust weighting, at a fraction of its cost).
2. **A model of the angles against time** (:class:`calibrate.schemes.thermal_model.ThermalModel`):
   per angle, harmonics of the time of day, a trend and optional temperature telemetry, the
   harmonic order chosen by cross-validation.
3. **Compensation** (:func:`evaluate_positioning`, this module): at unseen epochs the
   predicted angles are put into the model (``model.with_parameters``) and the positioning
   error over the frame, in pixels, is compared with that of a constant installation (the mean
   of the per-epoch solutions).

:mod:`calibrate.schemes.thermal_simulation` builds the test bed (a drifting installation and
its per-epoch exterior) and :mod:`calibrate.schemes.thermal_figures` draws the figures. This
module also holds what they share: the angle units (:data:`ARCSEC`, :data:`DAY_S`), the
installation's parameter names and the checks of epochs and telemetry.

References
----------
.. [1] Seed 002: Xiao et al., image point positioning compensation of a high-orbit thermal
   infrared staring camera, Appl. Sci. 2023, 13, 9688: section 2.3 (virtual control points),
   section 3.3 and figure 11 (installation angles against time under temperature changes).
.. [2] Seed 000: on-orbit calibration of a geostationary camera from the relative motion of
   stars, Sensors 2021, section 4 (daily period of the thermal positioning error).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sensor_models.errors import InputError

__all__ = [
    "ARCSEC",
    "AXES",
    "DAY_S",
    "INSTALLATION_NAMES",
    "EpochFit",
    "as_seconds",
    "as_temperatures",
    "check_increasing",
    "evaluate_positioning",
    "fit_installation",
    "frame_grid",
    "with_installation",
]

#: one arcsecond in radians
ARCSEC = math.pi / 180.0 / 3600.0
#: one mean solar day, seconds
DAY_S = 86_400.0
#: the model parameters of the installation angles, in the order of :data:`AXES`
INSTALLATION_NAMES = ("installation.roll", "installation.pitch", "installation.yaw")
#: the installation angles, in the order of every ``(..., 3)`` angle array
AXES = ("roll", "pitch", "yaw")


# --------------------------------------------------------------------------- helpers
def as_seconds(times, field_name="times"):
    """Float seconds, shape (N,): float input as is, datetime64 as seconds since 1970-01-01 (UTC).

    Parameters
    ----------
    times : array_like
        Numbers (seconds) or datetime64 values.
    field_name : str
        Field named in the error.

    Returns
    -------
    ndarray of float64, shape (N,)
        Seconds.

    Raises
    ------
    InputError
        Values that are not numbers or datetime64, or NaN or infinite ones.
    """
    arr = np.asarray(times)
    if np.issubdtype(arr.dtype, np.datetime64):
        sec = (arr - np.datetime64("1970-01-01T00:00:00", "ns")) / np.timedelta64(1, "ns") * 1e-9
        sec = np.asarray(sec, dtype=np.float64)
    else:
        try:
            sec = np.asarray(arr, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError("must be numbers (seconds) or datetime64", field=field_name) from None
    sec = sec.reshape(-1)
    if not np.all(np.isfinite(sec)):
        raise InputError("holds NaN or infinite values", field=field_name)
    return sec


def check_increasing(t, field_name="times"):
    """Refuse epochs that are not strictly increasing.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Epochs, seconds (:func:`as_seconds`).
    field_name : str
        Field named in the error.

    Returns
    -------
    None

    Raises
    ------
    InputError
        Naming the first entry that is not after its predecessor.
    """
    if t.size > 1 and not np.all(np.diff(t) > 0.0):
        k = int(np.argmin(np.diff(t)))
        raise InputError(f"must be strictly increasing (entry {k + 1} is not after entry {k})", field=field_name)


def as_temperatures(values, n, field_name="temperatures"):
    """Temperature telemetry of ``n`` epochs as an array of shape (n, M), checked.

    Parameters
    ----------
    values : array_like, shape (n,) or (n, M)
        One or ``M`` temperature series, degrees Celsius.
    n : int
        Number of epochs.
    field_name : str
        Field named in the error.

    Returns
    -------
    ndarray of float64, shape (n, M)
        The series, one column each.

    Raises
    ------
    InputError
        Another shape, or NaN or infinite values.
    """
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr.reshape(-1, 1)
    if arr.ndim != 2 or arr.shape[0] != n:
        raise InputError(f"must have shape ({n},) or ({n}, M), got {np.shape(values)}", field=field_name)
    if not np.all(np.isfinite(arr)):
        raise InputError("holds NaN or infinite values", field=field_name)
    return arr


def _installation_positions(model):
    names = tuple(model.parameters().names)
    try:
        return [names.index(n) for n in INSTALLATION_NAMES]
    except ValueError:
        raise InputError("the model has no installation.roll/pitch/yaw parameters", field="model") from None


def with_installation(model, angles_rad):
    """A copy of ``model`` with installation angles ``(roll, pitch, yaw)`` (radians, shape (3,)).

    Parameters
    ----------
    model : GeoStaringModel
        Model to copy.
    angles_rad : array_like, shape (3,)
        Installation roll, pitch, yaw, radians.

    Returns
    -------
    GeoStaringModel
        The copy.
    """
    angles = np.asarray(angles_rad, dtype=np.float64).reshape(-1)
    if angles.size != 3 or not np.all(np.isfinite(angles)):
        raise InputError("needs 3 finite angles (radians)", field="installation")
    values = np.array(model.parameters().values, dtype=np.float64)
    values[_installation_positions(model)] = angles
    return model.with_parameters(values)


def frame_grid(image_shape, n: int = 21, margin_px: float = 4.0):
    """Pixel grid over the frame, ``row, col`` each shape (n*n,), pixel centres convention.

    Parameters
    ----------
    image_shape : (int, int)
        Frame shape (rows, cols).
    n : int
        Points per axis.
    margin_px : float
        Distance of the outer points from the frame edges, pixels.

    Returns
    -------
    row, col : ndarray, shape (n * n,)
        Pixel coordinates.
    """
    n_rows, n_cols = image_shape
    r = np.linspace(margin_px, n_rows - margin_px, n)
    c = np.linspace(margin_px, n_cols - margin_px, n)
    gr, gc = np.meshgrid(r, c, indexing="ij")
    return gr.ravel(), gc.ravel()


# --------------------------------------------------------------------------- per-epoch exterior
@dataclass
class EpochFit:
    """Exterior solution of one epoch (:func:`fit_installation`).

    Attributes
    ----------
    angles, sigma : ndarray, shape (3,)
        Installation ``roll, pitch, yaw`` and their standard deviations, radians.
    covariance : ndarray, shape (3, 3)
    rms_px : float
        RMS of the image residuals after the fit (row and column together).
    n_points, iterations : int
    success : bool
    message : str
    """

    angles: np.ndarray
    sigma: np.ndarray
    covariance: np.ndarray
    rms_px: float
    n_points: int
    iterations: int
    success: bool
    message: str


def fit_installation(model, row, col, lon, lat, h, *, sigma_px: float = 0.1, max_iter: int = 10,
                     tol_rad: float = 1e-4 * ARCSEC) -> EpochFit:
    """Installation angles of a staring camera from control points (Gauss-Newton, 3 unknowns).

    Minimizes ``sum |(row, col)_obs - ground_to_image(model(theta), lon, lat, h)|^2`` over
    ``theta = (roll, pitch, yaw)``, starting from the model's angles; the normal equations
    use the analytic Jacobian of :meth:`GeoStaringModel.image_jacobian`. The covariance is
    ``sigma^2 (J^T J)^{-1}`` with ``sigma`` the larger of ``sigma_px`` and the a-posteriori
    residual standard deviation.

    Parameters
    ----------
    model : GeoStaringModel
        Initial model (e.g. the laboratory one, or the previous epoch's solution).
    row, col : array_like, shape (N,)
        Observed image coordinates, pixels (first pixel centre at 0.5).
    lon, lat, h : array_like, shape (N,)
        Control points, WGS84 degrees and metres.
    sigma_px : float
        Prior standard deviation of the image coordinates, pixels.

    Returns
    -------
    EpochFit
        ``success=False`` with a message when fewer than 3 points project or the system is
        singular (never raises for a failed estimation).
    """
    row = np.asarray(row, dtype=np.float64).reshape(-1)
    col = np.asarray(col, dtype=np.float64).reshape(-1)
    lon, lat, h = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (lon, lat, h))
    if not (row.size == col.size == lon.size == lat.size == h.size):
        raise InputError("row, col, lon, lat, h must have the same length", field="points")
    theta = np.array(model.parameters().values, dtype=np.float64)[_installation_positions(model)]
    nan3 = np.full(3, np.nan)
    current = model
    it = 0
    for it in range(1, max_iter + 1):
        r, c, jac = current.image_jacobian(lon, lat, h, names=INSTALLATION_NAMES)
        ok = np.isfinite(r) & np.isfinite(c)
        if ok.sum() < 3:
            return EpochFit(nan3, nan3, np.full((3, 3), np.nan), float("nan"), int(ok.sum()), it, False,
                            f"only {int(ok.sum())} control points project into the image")
        res = np.concatenate([row[ok] - r[ok], col[ok] - c[ok]])
        a = np.concatenate([jac[ok, 0, :], jac[ok, 1, :]])
        try:
            step, *_ = np.linalg.lstsq(a, res, rcond=None)
            normal_inv = np.linalg.inv(a.T @ a)
        except np.linalg.LinAlgError:
            return EpochFit(nan3, nan3, np.full((3, 3), np.nan), float("nan"), int(ok.sum()), it, False,
                            "singular normal equations")
        theta = theta + step
        current = with_installation(model, theta)
        if np.max(np.abs(step)) < tol_rad:
            break
    r, c = current.ground_to_image(lon, lat, h)
    ok = np.isfinite(r) & np.isfinite(c)
    res = np.concatenate([row[ok] - r[ok], col[ok] - c[ok]])
    dof = max(res.size - 3, 1)
    s0 = math.sqrt(float(res @ res) / dof)
    cov = max(s0, float(sigma_px)) ** 2 * normal_inv
    converged = np.max(np.abs(step)) < tol_rad or it < max_iter
    return EpochFit(theta, np.sqrt(np.diag(cov)), cov, float(np.sqrt(np.mean(res * res) * 2.0)), int(ok.sum()), it,
                    bool(converged), "converged" if converged else f"not converged in {max_iter} iterations")


# --------------------------------------------------------------------------- compensation
def evaluate_positioning(lab, true_angles, candidates: dict, *, grid_n: int = 15, height_m: float = 0.0) -> dict:
    """Positioning error over the frame of models with given installations, per epoch.

    For every epoch, ground points of a ``grid_n x grid_n`` pixel grid are located through
    the TRUE model (``lab`` with ``true_angles[i]``) and projected back through ``lab`` with
    each candidate's installation; the error is the RMS image distance, pixels.

    Parameters
    ----------
    lab : GeoStaringModel
    true_angles : array_like, shape (N, 3)
        Radians.
    candidates : dict of str to array_like of shape (N, 3) or (3,)
        E.g. ``{"constant": mean_angles, "predicted": model.predict(times)}``.

    Returns
    -------
    dict
        ``{name: ndarray (N,)}`` RMS pixels per epoch, plus ``"<name>_rms_px"`` over all epochs.
    """
    true = np.asarray(true_angles, dtype=np.float64).reshape(-1, 3)
    n = true.shape[0]
    gr, gc = frame_grid(lab.image_shape, grid_n)
    cands = {}
    for name, value in candidates.items():
        arr = np.asarray(value, dtype=np.float64)
        cands[name] = np.broadcast_to(arr.reshape(-1, 3) if arr.size != 3 else arr.reshape(1, 3), (n, 3))
    out = {name: np.full(n, np.nan) for name in cands}
    for i in range(n):
        lon, lat, h = with_installation(lab, true[i]).image_to_ground(gr, gc, height=height_m)
        for name, arr in cands.items():
            r, c = with_installation(lab, arr[i]).ground_to_image(lon, lat, h)
            out[name][i] = np.sqrt(np.nanmean((r - gr) ** 2 + (c - gc) ** 2))
    for name in cands:
        out[f"{name}_rms_px"] = float(np.sqrt(np.mean(out[name] ** 2)))
    return out


