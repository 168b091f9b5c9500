"""Lines of sight of a DigitalGlobe level-1B product, and their folding into a push-broom model.

The physical line of sight of detector ``s`` (0-based, DigitalGlobe sample ``s``, our column
``s + 0.5``) at time ``t`` is

.. math::

    \\mathbf{d}_{app}(t, s) = R^{itrf}_{body}(t)\\, R^{body}_{cam}
        \\,(x_0,\\; y_0 - s\\,p,\\; f)^T / |\\cdot|

with ``(x_0, y_0)`` = ``(DETORIGINX, DETORIGINY)``, ``p`` = ``DETPITCH`` and ``f`` = ``PD``
(all mm). That is the *apparent* direction the camera sees. Two corrections give the true
straight-line direction to the ground point the ray reaches at height ``h``:

1. Velocity aberration (first order in ``beta = v / c``): the apparent direction of a source is
   displaced towards the observer's velocity relative to it, so
   ``d = normalize(d_app - beta + (beta . d_app) d_app)`` with
   ``v = V_itrf + omega x (P - X)`` (the satellite's Earth-relative velocity plus the
   motion of the ground point during the light time, written in ITRF). About 20 m on the
   ground for WorldView.
2. Atmospheric refraction: a ray through a stratified atmosphere reaches the ground closer to
   the nadir than its straight extension. To first order in the refractivity ``N`` the
   horizontal displacement is ``D = tan(z) / cos^2(z) * integral N dh`` where ``z`` is the
   zenith angle of the ray at the ground and the integral is the zenith hydrostatic delay,
   computed with Saastamoinen's formula [1]_ from the standard-atmosphere pressure [2]_ at the
   height. About 1 to 2 m at 25 to 30 degrees off nadir.

``PushbroomModel`` has straight rays, a body -> ITRF attitude and per-detector directional
angles. :func:`build_model` folds the corrections into it at one height ``h_ref``: at every
attitude sample the rotation taking the apparent centre ray onto the corrected one is
composed with the attitude, and the remaining per-detector differences (averaged over the
image's time span) go into the ``tan psi`` polynomials. The refraction's dependence on height
cannot be represented by straight rays: away from ``h_ref`` the model errs by
``dD/dh * (h - h_ref)`` (about 0.2 m per km at 30 degrees).

References
----------
.. [1] J. Saastamoinen, "Atmospheric correction for the troposphere and stratosphere in radio
   ranging of satellites", in The Use of Artificial Satellites for Geodesy, Geophysical
   Monograph 15, AGU (1972), 247-251.
.. [2] U.S. Standard Atmosphere, 1976 (NOAA/NASA/USAF), troposphere pressure law.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from sensor_models.errors import InputError, OutOfRangeError

__all__ = [
    "SPEED_OF_LIGHT_M_S",
    "aberration_correct",
    "build_model",
    "camera_tangents",
    "refraction_displacement_m",
    "zenith_hydrostatic_delay_m",
]

SPEED_OF_LIGHT_M_S = 299_792_458.0
#: WGS84 nominal mean angular velocity of the Earth (rad/s)
EARTH_ROTATION_RAD_S = 7.292115e-5
#: detectors sampled across each array to fold the corrections into the polynomials
FOLD_DETECTORS = 33
#: degree of the ``tan psi`` polynomials (seed 003's cubic)
LOOK_DEGREE = 3
#: attitude samples kept beyond the image's time span (s)
TIME_MARGIN_S = 1.0


def camera_tangents(band, principal_distance_mm: float, s):
    """Directional-angle tangents of detectors in the camera frame (no correction).

    Parameters
    ----------
    band : WorldViewBand
        Detector origin and pitch (mm).
    principal_distance_mm : float
        ``PD``.
    s : array_like
        0-based detector indices (DigitalGlobe samples; our column ``s + 0.5``).

    Returns
    -------
    tan_psi_x, tan_psi_y : ndarray, shape of ``s``
        ``DETORIGINX / PD`` and ``(DETORIGINY - s * DETPITCH) / PD``.
    """
    s = np.asarray(s, dtype=np.float64)
    tx = np.full_like(s, band.det_origin_x_mm / principal_distance_mm)
    ty = (band.det_origin_y_mm - s * band.det_pitch_mm) / principal_distance_mm
    return tx, ty


def aberration_correct(direction, position_m, velocity_m_s, ground_m):
    """Remove the velocity aberration from apparent lines of sight (first order in v/c).

    Parameters
    ----------
    direction : ndarray, shape (N, 3)
        Apparent unit directions, ITRF.
    position_m, velocity_m_s : ndarray, shape (N, 3)
        Satellite ITRF position and Earth-relative velocity.
    ground_m : ndarray, shape (N, 3)
        The ground points the rays reach (ITRF), for the ``omega x (P - X)`` term.

    Returns
    -------
    ndarray, shape (N, 3)
        True unit directions: ``normalize(d - beta + (beta . d) d)``,
        ``beta = (V + omega x (P - X)) / c``.
    """
    omega = np.array([0.0, 0.0, EARTH_ROTATION_RAD_S])
    beta = (velocity_m_s + np.cross(omega, position_m - ground_m)) / SPEED_OF_LIGHT_M_S
    d = direction - beta + np.sum(beta * direction, axis=-1, keepdims=True) * direction
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def zenith_hydrostatic_delay_m(h_m, lat_deg):
    """Zenith hydrostatic delay (the height integral of the refractivity), metres.

    Parameters
    ----------
    h_m : array_like
        Ellipsoidal height of the ground, metres (used as the height in the standard
        atmosphere; the geoid's 30 m change the result by 0.3 %).
    lat_deg : array_like
        Geodetic latitude, degrees.

    Returns
    -------
    ndarray
        ``0.0022768 * P / (1 - 0.00266 cos 2 phi - 0.28e-6 h)`` with the standard-atmosphere
        pressure ``P = 1013.25 (1 - 2.25577e-5 h)^5.25588`` hPa (Saastamoinen; 2.3 m at sea
        level).
    """
    h = np.asarray(h_m, dtype=np.float64)
    phi = np.radians(np.asarray(lat_deg, dtype=np.float64))
    pressure_hpa = 1013.25 * (1.0 - 2.25577e-5 * h) ** 5.25588
    return 0.0022768 * pressure_hpa / (1.0 - 0.00266 * np.cos(2.0 * phi) - 0.28e-6 * h)


def refraction_displacement_m(zenith_rad, h_m, lat_deg):
    """Horizontal displacement of a ground point by refraction, towards the nadir.

    Parameters
    ----------
    zenith_rad : array_like
        Zenith angle of the line of sight at the ground point (radians).
    h_m, lat_deg : array_like
        Height (m) and latitude (degrees) of the ground point.

    Returns
    -------
    ndarray
        ``ZHD * tan z / cos^2 z`` (metres): how far the straight extension of the ray from
        the satellite lands beyond the point the refracted ray reaches.
    """
    z = np.asarray(zenith_rad, dtype=np.float64)
    return zenith_hydrostatic_delay_m(h_m, lat_deg) * np.tan(z) / np.cos(z) ** 2


def _refract(position_m, direction, h_ref):
    """Straight directions from the satellite to the refraction-displaced ground points."""
    from sensor_models.geometry.geodesy import ecef_to_geodetic
    from sensor_models.terrain.ellipsoid import intersect_ellipsoid

    x = intersect_ellipsoid(position_m, direction, np.full(direction.shape[0], h_ref))
    lon, lat, _ = ecef_to_geodetic(x)
    lam, phi = np.radians(lon), np.radians(lat)
    up = np.stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)], axis=-1)
    to_sat = position_m - x
    to_sat /= np.linalg.norm(to_sat, axis=-1, keepdims=True)
    cos_z = np.sum(to_sat * up, axis=-1)
    horizontal = to_sat - cos_z[:, None] * up
    horizontal /= np.linalg.norm(horizontal, axis=-1, keepdims=True)
    shift = refraction_displacement_m(np.arccos(np.clip(cos_z, -1.0, 1.0)), h_ref, lat)
    d = x + shift[:, None] * horizontal - position_m
    return d / np.linalg.norm(d, axis=-1, keepdims=True), shift


def _true_directions(pos, vel, d_app, h_ref, *, aberration, refraction):
    """Corrected unit directions (N, 3) and the refraction shifts (N,) (zeros if off)."""
    from sensor_models.terrain.ellipsoid import intersect_ellipsoid

    d = d_app
    if aberration:
        x0 = intersect_ellipsoid(pos, d_app, np.full(d_app.shape[0], h_ref))
        d = aberration_correct(d_app, pos, vel, x0)
    shift = np.zeros(d.shape[0])
    if refraction:
        d, shift = _refract(pos, d, h_ref)
    if not np.all(np.isfinite(d)):
        raise OutOfRangeError(f"some lines of sight miss the ellipsoid at height {h_ref:.1f} m")
    return d, shift


def _minimal_rotation(a, b) -> Rotation:
    """Rotations taking unit vectors ``a`` (N, 3) onto ``b`` (N, 3) about ``a x b``."""
    axis = np.cross(a, b)
    sin = np.linalg.norm(axis, axis=-1)
    angle = np.arctan2(sin, np.sum(a * b, axis=-1))
    unit = np.where(sin[:, None] > 0, axis / np.where(sin > 0, sin, 1.0)[:, None], 0.0)
    return Rotation.from_rotvec(unit * angle[:, None])


def _sample_times(meta, attitude_seconds):
    """Attitude samples over the image span plus ``TIME_MARGIN_S`` (indices) and the span."""
    t_img = np.sort(meta.seconds(np.array([0.0, float(meta.n_rows)])))
    keep = (attitude_seconds >= t_img[0] - TIME_MARGIN_S) & (attitude_seconds <= t_img[1] + TIME_MARGIN_S)
    idx = np.nonzero(keep)[0]
    if idx.size < 4:
        raise OutOfRangeError(f"the attitude data do not cover the image lines [{t_img[0]:.3f}, "
                              f"{t_img[1]:.3f}] s from FIRSTLINETIME")
    return idx, t_img


def _fold(meta, bands, orbit, attitude, h_ref, *, aberration, refraction):
    """Effective body -> ITRF quaternions and per-band corrected tangents.

    Returns ``(seconds (K,), quats (K, 4), {band_id: (s (J,), tan_x (J,), tan_y (J,),
    time_residual_px)}, stats)``.
    """
    idx, t_img = _sample_times(meta, attitude.seconds)
    t = attitude.seconds[idx]
    pos, vel = orbit.state(t)
    r_cam = attitude.rotation(t) * Rotation.from_quat(meta.camera_to_body_xyzw)
    ref = bands[0]
    s_mid = 0.5 * (meta.n_cols - 1)
    tx, ty = camera_tangents(ref, meta.principal_distance_mm, np.array([s_mid]))
    u_mid = np.array([tx[0], ty[0], 1.0]) / np.linalg.norm([tx[0], ty[0], 1.0])
    a = r_cam.apply(u_mid)
    b, _ = _true_directions(pos, vel, a, h_ref, aberration=aberration, refraction=refraction)
    r_eff = _minimal_rotation(a, b) * r_cam
    in_image = (t >= t_img[0]) & (t <= t_img[1])
    looks, stats = {}, {"central_correction_urad": float(np.max(np.linalg.norm(b - a, axis=-1)) * 1e6)}
    s = np.linspace(0.0, meta.n_cols - 1.0, FOLD_DETECTORS)
    for band in bands:
        bx, by = camera_tangents(band, meta.principal_distance_mm, s)
        u = np.stack([bx, by, np.ones_like(bx)], axis=-1)
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        k = t.size
        d_app = np.einsum("kij,sj->ksi", r_cam.as_matrix(), u).reshape(-1, 3)
        d_true, shift = _true_directions(np.repeat(pos, s.size, axis=0), np.repeat(vel, s.size, axis=0), d_app,
                                         h_ref, aberration=aberration, refraction=refraction)
        # camera-frame vectors of the corrected rays: R_eff^T d (R_eff^T = transpose)
        u_eff = np.einsum("kji,ksj->ksi", r_eff.as_matrix(), d_true.reshape(k, s.size, 3))
        tan_x, tan_y = u_eff[..., 0] / u_eff[..., 2], u_eff[..., 1] / u_eff[..., 2]
        mx, my = tan_x[in_image].mean(axis=0), tan_y[in_image].mean(axis=0)
        ifov = band.det_pitch_mm / meta.principal_distance_mm
        dev = np.maximum(np.abs(tan_x[in_image] - mx), np.abs(tan_y[in_image] - my)) / ifov
        looks[band.band_id] = (s, mx, my, float(dev.max()))
        if band is ref:
            stats["refraction_shift_m"] = (float(shift.min()), float(shift.max()))
    return t, r_eff.as_quat(), looks, stats


def _fit_look(s, tan_x, tan_y, n_cols, ifov):
    """Cubic ``tan psi(s)`` coefficients (powers of ``s``) and the fit residual (px)."""
    half = max(0.5 * (n_cols - 1.0), 1.0)
    u = (s - half) / half
    cx = np.polynomial.polynomial.polyfit(u, tan_x, LOOK_DEGREE)
    cy = np.polynomial.polynomial.polyfit(u, tan_y, LOOK_DEGREE)
    res = np.maximum(np.abs(tan_x - np.polynomial.polynomial.polyval(u, cx)),
                     np.abs(tan_y - np.polynomial.polynomial.polyval(u, cy))) / ifov
    shift = np.polynomial.Polynomial([-1.0, 1.0 / half])
    return np.polynomial.Polynomial(cx)(shift).coef, np.polynomial.Polynomial(cy)(shift).coef, float(res.max())


def build_model(meta, bands, *, aberration: bool = True, refraction: bool = True,
                refraction_height_m: float | None = None):
    """A :class:`~sensor_models.models.pushbroom.PushbroomModel` from parsed WorldView metadata.

    Parameters
    ----------
    meta : WorldViewMetadata
        The parsed XML.
    bands : sequence of WorldViewBand
        Bands to model (the first is the reference band and defines the folded attitude).
    aberration, refraction : bool
        Apply the corrections of the module docstring.
    refraction_height_m : float, optional
        Ellipsoidal height of the fold (default: mean corner ``HAE`` of the first band).

    Returns
    -------
    model : PushbroomModel
        See :func:`~sensor_models.readers.worldview.read_worldview`.
    fold : dict
        The fold's statistics: ``refraction_height_m``, ``central_correction_urad``,
        ``refraction_shift_m`` (min, max), and per band ``time_residual_px`` (how far the
        per-detector correction moves over the image span from its mean) and
        ``polynomial_residual_px`` (cubic fit), both in pixels (the ``fold`` of
        :class:`~sensor_models.readers.scene_value.ProductMetadata`).
    """
    from sensor_models.geometry.ephemeris import Attitude, Orbit
    from sensor_models.models.pushbroom import PushbroomModel
    from sensor_models.models.pushbroom_types import CcdLook, LineTiming

    if refraction_height_m is None:
        refraction_height_m = float(np.mean(bands[0].corner_hae_m))
    h_ref = float(refraction_height_m)
    if not np.isfinite(h_ref) or abs(h_ref) > 1.0e4:
        raise InputError(f"must be a height within +-10 km, got {refraction_height_m!r}", field="refraction_height_m")
    orbit = Orbit(meta.epoch, meta.ephemeris_seconds, meta.position_m, meta.velocity_m_s, frame="itrf")
    raw = Attitude(meta.attitude_seconds, meta.quaternions_xyzw, frame="itrf")
    t, quats, looks, stats = _fold(meta, bands, orbit, raw, h_ref, aberration=aberration, refraction=refraction)
    stats["refraction_height_m"] = h_ref
    ccds = {}
    for band in bands:
        s, mx, my, time_res = looks[band.band_id]
        ifov = band.det_pitch_mm / meta.principal_distance_mm
        cx, cy, fit_res = _fit_look(s, mx, my, meta.n_cols, ifov)
        stats[band.band_id] = {"time_residual_px": time_res, "polynomial_residual_px": fit_res}
        ccds[band.band_id] = [CcdLook("array1", 0, meta.n_cols, cx, cy)]
    model = PushbroomModel(
        orbit=orbit,
        attitude=Attitude(t, quats, frame="itrf"),
        line_timing=LineTiming(0.5, meta.first_line_seconds, meta.line_period_s),
        bands=ccds,
        n_rows=meta.n_rows,
        name=f"{meta.satellite} {meta.image_descriptor} {meta.epoch}",
    )
    return model, stats
