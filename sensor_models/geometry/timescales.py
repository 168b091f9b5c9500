"""Time scales and Earth orientation parameters for a UTC scene epoch plus SI seconds.

Times in gcpcal are a UTC scene epoch (``numpy.datetime64[ns]``) plus float64 **elapsed SI
seconds** since that epoch. "Elapsed SI seconds" means seconds of atomic time: the epoch is
converted to TAI once and the seconds are added in TAI, so a leap second inside a scene is
counted like any other second (``t`` advances by 1 s across 23:59:60 UTC). From TAI:

* TT  = TAI + 32.184 s exactly [1]_;
* UTC = TAI - (TAI - UTC), with the leap-second table built into ERFA (``erfa.taiutc``), used
  only to look up the IERS tables, which are tabulated at 0h UTC;
* UT1 = UTC + (UT1 - UTC), the latter interpolated linearly in the IERS tables
  (``erfa.utcut1``).

Julian dates are kept in two parts ``(jd1, jd2)`` as ERFA does: ``jd1`` holds the day number
of the epoch's date (``xxxxxxx.5``) and ``jd2`` the fraction plus ``seconds / 86400``, so that a
date near 2020 keeps about 1e-11 s of resolution instead of the 40 µs of a single float64 JD.
UTC Julian dates are ERFA's quasi-JD: during a leap-second day the fraction advances by
1/86401 per second.

Earth orientation (polar motion ``xp, yp`` and ``UT1 - UTC``) comes from the IERS tables
shipped in the ``astropy-iers-data`` package and read offline by :class:`EarthOrientation`.
The celestial pole offsets ``dX, dY`` are not used, as in astropy: the IAU 2006/2000A
precession-nutation model alone is good to about 0.2 mas [1]_.

References
----------
.. [1] G. Petit and B. Luzum (eds.), *IERS Conventions (2010)*, IERS Technical Note 36,
   chapter 5 ("Transformation between the ITRS and the GCRS"), sections 5.4-5.5 and 5.9-5.10.
.. [2] IAU SOFA Board, *SOFA Time Scale and Calendar Tools* (the time-scale routines that ERFA
   reproduces: ``dtf2d``, ``utctai``, ``taiutc``, ``utcut1``).
"""

from __future__ import annotations

import datetime as _dt
import functools
import re
import warnings
from pathlib import Path

import erfa
import numpy as np

from sensor_models.errors import InputError, OutOfRangeError

__all__ = [
    "DAY_S",
    "MJD_ZERO_JD",
    "TT_MINUS_TAI_S",
    "EarthOrientation",
    "default_eop",
    "epoch_tai_jd",
    "parse_utc",
    "tai_jd",
    "tai_to_tt_jd",
    "tai_to_utc_jd",
    "tt_jd",
    "ut1_jd",
    "utc_jd",
    "utc_jd_to_day",
    "utc_jd_to_mjd",
    "utc_mjd",
    "utc_to_ut1_jd",
]

DAY_S = 86400.0
"""SI seconds in a day of TAI/TT (and of UTC without a leap second)."""
MJD_ZERO_JD = 2400000.5
"""Julian date of MJD 0 (1858-11-17 0h)."""
TT_MINUS_TAI_S = 32.184
"""TT - TAI in seconds, exact by definition (IAU 1991 Resolution A4, IERS Conventions 2010)."""

ARCSEC_TO_RAD = np.pi / (180.0 * 3600.0)


# --------------------------------------------------------------------------------------------
# ERFA boundary: ERFA reports problems as ErfaWarning ("dubious year": the leap-second table
# may be out of date for this date) or ErfaError; both become gcpcal errors here.
# --------------------------------------------------------------------------------------------
def call_erfa(func, *args, what: str):
    """Call an ERFA function, turning its warnings and errors into :class:`OutOfRangeError`."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", erfa.ErfaWarning)
        try:
            return func(*args)
        except erfa.ErfaWarning as err:
            raise OutOfRangeError(
                f"{what}: ERFA says '{err}'. The date lies before 1960 or beyond the leap-second "
                "table built into pyerfa; TAI-UTC is unknown there (update pyerfa for new leap "
                "seconds)"
            ) from None
        except erfa.ErfaError as err:
            raise OutOfRangeError(f"{what}: ERFA rejected the date: {err}") from None


# --------------------------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------------------------
_ISO_RE = re.compile(
    r"^\s*(?P<year>\d{4})-(?P<month>\d{2})-(?P<day>\d{2})"
    r"(?:[T ](?P<hour>\d{2}):(?P<minute>\d{2})"
    r"(?::(?P<second>\d{2})(?:[.,](?P<frac>\d{1,9})\d*)?)?)?"
    r"(?P<zone>Z|z|[+-]\d{2}(?::?\d{2})?)?\s*$"
)


def parse_utc(value) -> np.datetime64:
    """Parse a UTC instant into ``numpy.datetime64[ns]``.

    Parameters
    ----------
    value : str, datetime.datetime, datetime.date or numpy.datetime64
        * ISO-8601 text ``YYYY-MM-DD[Thh:mm[:ss[.fffffffff]]][Z|+00:00]``; a space may replace
          the ``T``; digits beyond nanoseconds are truncated. Text without a zone is UTC; a
          non-zero UTC offset is an error (times must be UTC at this boundary).
        * :class:`datetime.datetime`: naive values are taken as UTC; aware values must have a
          zero UTC offset.
        * :class:`numpy.datetime64` of any unit (taken as UTC).

    Returns
    -------
    numpy.datetime64
        The instant with nanosecond unit.

    Raises
    ------
    InputError
        Unparseable text, impossible dates (2021-02-30), a non-UTC offset, ``NaT``, a leap
        second (``23:59:60``, which ``datetime64`` cannot hold: choose an epoch next to it) or a
        date outside the ``datetime64[ns]`` range (1678-2261).
    """
    if isinstance(value, np.datetime64):
        if np.isnat(value):
            raise InputError("a UTC time is NaT (not a time)")
        return _to_ns(value, repr(value))
    if isinstance(value, _dt.datetime):
        offset = value.utcoffset()
        if offset is not None and offset != _dt.timedelta(0):
            raise InputError(
                f"time {value.isoformat()} has UTC offset {offset}; give times in UTC"
            )
        naive = value.replace(tzinfo=None)
        return _to_ns(np.datetime64(naive.isoformat(), "us"), value.isoformat())
    if isinstance(value, _dt.date):
        return _to_ns(np.datetime64(value.isoformat(), "D"), value.isoformat())
    if isinstance(value, bytes):
        value = value.decode("ascii", errors="replace")
    if not isinstance(value, str):
        raise InputError(
            f"cannot read a UTC time from {type(value).__name__} {value!r}; give ISO-8601 text "
            "such as '2021-03-04T05:06:07.123456Z', a datetime or a numpy.datetime64"
        )
    match = _ISO_RE.match(value)
    if match is None:
        raise InputError(
            f"cannot parse {value!r} as an ISO-8601 UTC time; expected e.g. "
            "'2021-03-04T05:06:07.123456Z'"
        )
    zone = match["zone"]
    if zone not in (None, "Z", "z"):
        digits = zone[1:].replace(":", "")
        if int(digits) != 0:
            raise InputError(f"time {value!r} has UTC offset {zone}; give times in UTC")
    second = int(match["second"] or 0)
    if second == 60:
        raise InputError(
            f"time {value!r} lies inside a leap second, which numpy.datetime64 cannot hold; "
            "use a scene epoch next to it (times inside the scene are counted in SI seconds "
            "and may cross the leap second)"
        )
    try:
        whole = _dt.datetime(
            int(match["year"]),
            int(match["month"]),
            int(match["day"]),
            int(match["hour"] or 0),
            int(match["minute"] or 0),
            second,
        )
    except ValueError as err:
        raise InputError(f"{value!r} is not a valid date and time: {err}") from None
    nanoseconds = int((match["frac"] or "").ljust(9, "0"))
    epoch = _to_ns(np.datetime64(whole.isoformat(), "s"), repr(value))
    return epoch + np.timedelta64(nanoseconds, "ns")


def _to_ns(value: np.datetime64, shown: str) -> np.datetime64:
    as_ns = value.astype("datetime64[ns]")
    # datetime64[ns] wraps silently outside ~1678-2261; check by a round trip
    if np.isnat(as_ns) or as_ns.astype(value.dtype) != value:
        raise InputError(f"time {shown} lies outside the datetime64[ns] range (1678-2261)")
    return as_ns


# --------------------------------------------------------------------------------------------
# Time scales
# --------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=64)
def _epoch_tai_jd_cached(epoch_ns: int) -> tuple[float, float]:
    epoch = np.datetime64(epoch_ns, "ns")
    day = epoch.astype("datetime64[D]")
    ns_of_day = int((epoch - day).astype("timedelta64[ns]").astype(np.int64))
    date = day.astype(_dt.date)
    hour, rest = divmod(ns_of_day, 3_600_000_000_000)
    minute, rest = divmod(rest, 60_000_000_000)
    second = rest / 1e9  # < 60 s, exact to ~1e-15 s
    # dtf2d takes a UTC calendar date and time ('UTC' scale: knows leap-second days)
    utc1, utc2 = call_erfa(
        erfa.dtf2d, "UTC", date.year, date.month, date.day, hour, minute, second,
        what=f"epoch {epoch}",
    )
    # utctai takes a UTC quasi-JD and returns TAI
    tai1, tai2 = call_erfa(erfa.utctai, utc1, utc2, what=f"epoch {epoch}")
    return float(tai1), float(tai2)


def epoch_tai_jd(epoch) -> tuple[float, float]:
    """TAI two-part Julian date of a UTC epoch (computed once per epoch and cached).

    Parameters
    ----------
    epoch : str, datetime or numpy.datetime64
        The UTC epoch; see :func:`parse_utc`.

    Returns
    -------
    tai1, tai2 : float
        ``tai1 + tai2`` is the TAI Julian date; ``tai1`` is the JD of 0h of the epoch's date.
    """
    epoch = parse_utc(epoch)
    return _epoch_tai_jd_cached(int(epoch.astype(np.int64)))


def _seconds_array(seconds) -> np.ndarray:
    t = np.asarray(seconds, dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise InputError("times (seconds since the epoch) hold NaN or infinite values")
    return t


def _add_seconds(jd1: float, jd2: float, seconds: np.ndarray):
    """``(jd1, jd2) + seconds`` keeping precision: whole days go to ``jd1``, the rest to ``jd2``."""
    whole_days = np.floor(seconds / DAY_S)
    rest_s = seconds - whole_days * DAY_S  # exact for |seconds| < 2**53 / 86400 days
    return jd1 + whole_days, jd2 + rest_s / DAY_S


def tai_jd(epoch, seconds):
    """TAI two-part Julian dates of ``epoch + seconds``.

    Parameters
    ----------
    epoch : str, datetime or numpy.datetime64
        UTC scene epoch.
    seconds : array_like of float
        Elapsed SI seconds since the epoch, any shape.

    Returns
    -------
    jd1, jd2 : ndarray, shape of ``seconds``
        TAI Julian date in two parts (``jd1`` whole days ending in .5, ``jd2`` the rest).
    """
    tai1, tai2 = epoch_tai_jd(epoch)
    return _add_seconds(tai1, tai2, _seconds_array(seconds))


def tai_to_tt_jd(tai1, tai2):
    """TT from TAI: ``TT = TAI + 32.184 s`` (added to the second part; same as ``erfa.taitt``).

    Parameters
    ----------
    tai1, tai2 : array_like of float
        TAI two-part Julian date.

    Returns
    -------
    tt1, tt2 : ndarray
        TT two-part Julian date, same shapes.
    """
    tt1 = np.array(tai1, dtype=np.float64)
    tt2 = np.asarray(tai2, dtype=np.float64) + TT_MINUS_TAI_S / DAY_S
    return tt1, tt2


def tai_to_utc_jd(tai1, tai2):
    """UTC quasi-JD from TAI via ``erfa.taiutc`` (takes TAI, returns UTC; ERFA leap seconds).

    Parameters
    ----------
    tai1, tai2 : array_like of float
        TAI two-part Julian date.

    Returns
    -------
    utc1, utc2 : ndarray
        UTC two-part quasi-Julian date (ERFA convention on leap-second days).
    """
    return call_erfa(erfa.taiutc, tai1, tai2, what="TAI -> UTC")


def utc_jd_to_mjd(utc1, utc2) -> np.ndarray:
    """Single float MJD(UTC) from a two-part UTC quasi-JD (~1 µs resolution; for table lookups).

    Parameters
    ----------
    utc1, utc2 : array_like of float
        UTC two-part quasi-Julian date.

    Returns
    -------
    ndarray of float
        ``utc1 - 2400000.5 + utc2``.
    """
    return (np.asarray(utc1) - MJD_ZERO_JD) + np.asarray(utc2)


def utc_to_ut1_jd(utc1, utc2, eop: EarthOrientation | None = None):
    """UT1 two-part JD from a UTC quasi-JD: ``UT1 = UTC + (UT1 - UTC)``.

    ``UT1 - UTC`` is interpolated in the IERS tables at MJD(UTC); ``erfa.utcut1`` (takes UTC
    and ``UT1 - UTC`` in seconds, returns UT1) applies it across leap-second days correctly.

    Parameters
    ----------
    utc1, utc2 : array_like of float
        UTC two-part quasi-Julian date.
    eop : EarthOrientation, optional
        IERS tables; default :func:`default_eop`.

    Returns
    -------
    ut11, ut12 : ndarray
        UT1 two-part Julian date.
    """
    eop = default_eop() if eop is None else eop
    day_mjd, day_fraction = utc_jd_to_day(utc1, utc2)
    dut1_s = eop.ut1_minus_utc_s(day_mjd, day_fraction=day_fraction)
    return call_erfa(erfa.utcut1, utc1, utc2, dut1_s, what="UTC -> UT1")


def utc_jd_to_day(utc1, utc2):
    """Split a UTC quasi-JD into the MJD of its UTC day and the fraction of that day.

    The day is the one ERFA assigns (``erfa.jd2cal``), so that table lookups and ERFA's
    leap-second bookkeeping (``erfa.utcut1`` looks up TAI-UTC on that day) agree even for an
    instant that rounds to the day boundary. A single float MJD cannot guarantee this: the
    last representable instant of a day rounds up to the next day's MJD.

    Parameters
    ----------
    utc1, utc2 : array_like of float
        UTC two-part quasi-Julian date.

    Returns
    -------
    day_mjd : ndarray of float
        Whole MJD(UTC) of the day.
    day_fraction : ndarray of float
        Fraction of the day in [0, 1) (ERFA quasi-fraction on a leap-second day).
    """
    year, month, day, fraction = call_erfa(erfa.jd2cal, utc1, utc2, what="UTC calendar date")
    _, day_mjd = erfa.cal2jd(year, month, day)
    return day_mjd, fraction


def tt_jd(epoch, seconds):
    """TT two-part Julian dates of ``epoch + seconds`` (TT = TAI + 32.184 s).

    Parameters
    ----------
    epoch : str, datetime or numpy.datetime64
        UTC scene epoch.
    seconds : array_like of float
        Elapsed SI seconds since the epoch, any shape.

    Returns
    -------
    jd1, jd2 : ndarray, shape of ``seconds``
        TT Julian date in two parts.
    """
    return tai_to_tt_jd(*tai_jd(epoch, seconds))


def utc_jd(epoch, seconds):
    """UTC two-part quasi-Julian dates of ``epoch + seconds`` (ERFA convention on leap days).

    Parameters
    ----------
    epoch : str, datetime or numpy.datetime64
        UTC scene epoch.
    seconds : array_like of float
        Elapsed SI seconds since the epoch, any shape.

    Returns
    -------
    utc1, utc2 : ndarray, shape of ``seconds``
        UTC quasi-Julian date in two parts.
    """
    return tai_to_utc_jd(*tai_jd(epoch, seconds))


def utc_mjd(epoch, seconds) -> np.ndarray:
    """MJD(UTC) of ``epoch + seconds`` as one float64 (for IERS table lookups).

    Parameters
    ----------
    epoch : str, datetime or numpy.datetime64
        UTC scene epoch.
    seconds : array_like of float
        Elapsed SI seconds since the epoch, any shape.

    Returns
    -------
    ndarray, shape of ``seconds``
        ``JD(UTC) - 2400000.5``; resolution about 1 µs near 2020, ample for tables given daily.
    """
    return utc_jd_to_mjd(*utc_jd(epoch, seconds))


def ut1_jd(epoch, seconds, eop: EarthOrientation | None = None):
    """UT1 two-part Julian dates of ``epoch + seconds``.

    Parameters
    ----------
    epoch, seconds
        As :func:`tai_jd`.
    eop : EarthOrientation, optional
        Earth orientation tables; default :func:`default_eop`.

    Returns
    -------
    jd1, jd2 : ndarray
        UT1 Julian date in two parts.

    Raises
    ------
    OutOfRangeError
        A time outside the IERS tables.
    """
    return utc_to_ut1_jd(*utc_jd(epoch, seconds), eop=eop)


# --------------------------------------------------------------------------------------------
# IERS Earth orientation tables
# --------------------------------------------------------------------------------------------
def _mjd_to_date(mjd: float) -> str:
    return str(np.datetime64("1858-11-17", "D") + np.timedelta64(int(np.floor(mjd)), "D"))


def _fixed_width_floats(lines: list[str], start: int, stop: int) -> np.ndarray:
    """Column ``[start, stop)`` (0-based, half-open) of fixed-width text as floats, blank -> NaN."""
    fields = [line[start:stop].strip() for line in lines]
    return np.array([float(f) if f else np.nan for f in fields], dtype=np.float64)


def _read_finals2000a(path: Path) -> dict[str, np.ndarray]:
    """Read USNO ``finals2000A.*`` (byte layout in ``ReadMe.finals2000A`` beside it)."""
    lines = path.read_text(encoding="ascii").splitlines()
    lines = [line.ljust(187) for line in lines if line.strip()]
    try:
        # ReadMe bytes are 1-based inclusive: bytes a-b -> slice [a-1, b)
        table = {
            "mjd": _fixed_width_floats(lines, 7, 15),
            "pm_flag_a": np.array([line[16] for line in lines]),
            "pm_x_a": _fixed_width_floats(lines, 18, 27),
            "pm_y_a": _fixed_width_floats(lines, 37, 46),
            "ut1_flag_a": np.array([line[57] for line in lines]),
            "ut1_utc_a": _fixed_width_floats(lines, 58, 68),
            "pm_x_b": _fixed_width_floats(lines, 134, 144),
            "pm_y_b": _fixed_width_floats(lines, 144, 154),
            "ut1_utc_b": _fixed_width_floats(lines, 154, 165),
        }
    except ValueError as err:
        raise InputError(f"not a finals2000A table: {err}", path=str(path)) from None
    return table


def _read_eopc04(path: Path) -> dict[str, np.ndarray]:
    """Read an IERS 20 C04 ``eopc04.*`` file (layout in ``ReadMe.eopc04`` beside it)."""
    try:
        data = np.loadtxt(path, comments="#", usecols=(4, 5, 6, 7), dtype=np.float64, ndmin=2)
    except ValueError as err:
        raise InputError(f"not an IERS C04 table: {err}", path=str(path)) from None
    return {"mjd": data[:, 0], "pm_x": data[:, 1], "pm_y": data[:, 2], "ut1_utc": data[:, 3]}


def _combine_like_astropy(finals: dict, c04: dict, finals_path: Path):
    """Combine finals2000A and IERS C04 the way astropy's ``IERS_Auto`` does (astropy 6-8).

    1. Keep finals rows that hold a Bulletin A UT1-UTC and a polar-motion flag (the trailing
       rows hold only dates).
    2. Over the MJD range where finals has Bulletin B values, overwrite them with the C04
       values of the same days (C04 is the official, most recent series).
    3. Use the (substituted) B values where present, else the Bulletin A values.

    gcpcal adds one step astropy lacks: C04 days before the first finals row (1962-1972) are
    prepended, so those years are covered instead of being clamped to the first value.
    """
    keep = np.isfinite(finals["ut1_utc_a"]) & (finals["pm_flag_a"] != " ")
    f = {k: v[keep] for k, v in finals.items()}
    mjd = f["mjd"]
    if mjd.size < 2 or np.any(np.diff(mjd) <= 0):
        raise InputError("MJD column is not strictly increasing", path=str(finals_path))
    ut1_b, pm_x_b, pm_y_b = f["ut1_utc_b"].copy(), f["pm_x_b"].copy(), f["pm_y_b"].copy()
    has_b = np.isfinite(ut1_b)
    if np.any(has_b):
        lo, hi = mjd[has_b][0], mjd[has_b][-1]
        in_c04 = (c04["mjd"] >= lo) & (c04["mjd"] <= hi)
        rows = np.searchsorted(mjd, c04["mjd"][in_c04])
        rows = np.clip(rows, 0, mjd.size - 1)
        if not np.array_equal(mjd[rows], c04["mjd"][in_c04]):
            raise InputError(
                "IERS C04 days do not line up with the finals2000A days", path=str(finals_path)
            )
        ut1_b[rows] = c04["ut1_utc"][in_c04]
        pm_x_b[rows] = c04["pm_x"][in_c04]
        pm_y_b[rows] = c04["pm_y"][in_c04]
    b_ut1 = np.isfinite(ut1_b)
    ut1_utc = np.where(b_ut1, ut1_b, f["ut1_utc_a"])
    b_pm = np.isfinite(pm_x_b) & np.isfinite(pm_y_b)
    pm_x = np.where(b_pm, pm_x_b, f["pm_x_a"])
    pm_y = np.where(b_pm, pm_y_b, f["pm_y_a"])
    predicted = (f["ut1_flag_a"] == "P") | (f["pm_flag_a"] == "P")
    first_predicted_mjd = float(mjd[np.argmax(predicted)]) if np.any(predicted) else np.inf
    # gcpcal extension: C04 days before the first finals day
    early = c04["mjd"] < mjd[0]
    return (
        np.concatenate([c04["mjd"][early], mjd]),
        np.concatenate([c04["ut1_utc"][early], ut1_utc]),
        np.concatenate([c04["pm_x"][early], pm_x]),
        np.concatenate([c04["pm_y"][early], pm_y]),
        first_predicted_mjd,
    )


class EarthOrientation:
    """IERS Earth orientation parameters, linearly interpolated at MJD(UTC).

    The tables give, at 0h UTC of each day, the pole coordinates ``xp, yp`` (arcsec) and
    ``UT1 - UTC`` (s) [1]_. Values between days are interpolated linearly in MJD(UTC), as
    astropy does; the step of a leap second in ``UT1 - UTC`` is removed from the difference
    before interpolating. The diurnal and semidiurnal ocean-tide and libration terms of the
    IERS Conventions (2010) section 5.5.1 (up to ~0.1 mas in the pole and ~0.05 ms in UT1) are
    not added, again as in astropy.

    Parameters
    ----------
    mjd_utc : array_like, shape (K,)
        Table days, MJD(UTC), strictly increasing.
    ut1_minus_utc_s : array_like, shape (K,)
        UT1 - UTC in seconds.
    xp_arcsec, yp_arcsec : array_like, shape (K,)
        Pole coordinates in arcseconds.
    first_predicted_mjd : float, optional
        First day holding predicted (Bulletin A "P") values; ``inf`` if none.
    source : str, optional
        Where the values came from (shown in error messages).

    See Also
    --------
    EarthOrientation.from_iers_files : the usual constructor.
    default_eop : a cached instance read from ``astropy-iers-data``.

    References
    ----------
    .. [1] IERS Conventions (2010), chapter 5, sections 5.4.1 and 5.5.
    """

    def __init__(
        self,
        mjd_utc,
        ut1_minus_utc_s,
        xp_arcsec,
        yp_arcsec,
        *,
        first_predicted_mjd: float = np.inf,
        source: str = "user-supplied table",
    ):
        mjd = np.asarray(mjd_utc, dtype=np.float64)
        columns = {
            "ut1_minus_utc_s": np.asarray(ut1_minus_utc_s, dtype=np.float64),
            "xp_arcsec": np.asarray(xp_arcsec, dtype=np.float64),
            "yp_arcsec": np.asarray(yp_arcsec, dtype=np.float64),
        }
        if mjd.ndim != 1 or mjd.size < 2:
            raise InputError(f"needs at least 2 table rows, got shape {mjd.shape}", field="mjd_utc")
        if not np.all(np.isfinite(mjd)) or np.any(np.diff(mjd) <= 0):
            raise InputError("must be finite and strictly increasing", field="mjd_utc")
        for name, col in columns.items():
            if col.shape != mjd.shape:
                raise InputError(f"expected shape {mjd.shape}, got {col.shape}", field=name)
            if not np.all(np.isfinite(col)):
                raise InputError("holds NaN or infinite values", field=name)
        self.mjd_utc = mjd
        self.ut1_minus_utc_table_s = columns["ut1_minus_utc_s"]
        self.xp_table_arcsec = columns["xp_arcsec"]
        self.yp_table_arcsec = columns["yp_arcsec"]
        self.first_predicted_mjd = float(first_predicted_mjd)
        self.source = source
        # per-interval steps; UT1-UTC steps lose the whole seconds of leap seconds
        dut1_step = np.diff(self.ut1_minus_utc_table_s)
        self._dut1_step = dut1_step - np.round(dut1_step)
        self._xp_step = np.diff(self.xp_table_arcsec)
        self._yp_step = np.diff(self.yp_table_arcsec)
        self._inv_day_step = 1.0 / np.diff(mjd)
        for arr in (self.mjd_utc, self.ut1_minus_utc_table_s, self.xp_table_arcsec,
                    self.yp_table_arcsec):
            arr.flags.writeable = False

    @classmethod
    def from_iers_files(cls, finals_path=None, c04_path=None) -> EarthOrientation:
        """Read and combine the IERS tables of ``astropy-iers-data`` (offline).

        Parameters
        ----------
        finals_path : path-like, optional
            USNO ``finals2000A.all`` (IERS Bulletin A with Bulletin B columns and one year of
            predictions). Default: ``astropy_iers_data.IERS_A_FILE``.
        c04_path : path-like, optional
            IERS 20 C04 series ``eopc04.1962-now``. Default: ``astropy_iers_data.IERS_B_FILE``.

        Notes
        -----
        The combination reproduces astropy's default ``IERS_Auto`` table (so gcpcal and astropy
        agree): C04 values where finals has Bulletin B values, then Bulletin B, then Bulletin
        A (including predictions). C04 days before 1973-01-02 are prepended.

        Returns
        -------
        EarthOrientation
            Daily UT1 - UTC (s) and pole coordinates (arcsec) on MJD(UTC) knots.
        """
        if finals_path is None or c04_path is None:
            try:
                import astropy_iers_data
            except ImportError:
                raise InputError(
                    "the IERS tables come from the 'astropy-iers-data' package; install it "
                    "(pip install astropy-iers-data) or pass finals_path and c04_path"
                ) from None
            finals_path = astropy_iers_data.IERS_A_FILE if finals_path is None else finals_path
            c04_path = astropy_iers_data.IERS_B_FILE if c04_path is None else c04_path
        finals_path, c04_path = Path(finals_path), Path(c04_path)
        for p in (finals_path, c04_path):
            if not p.is_file():
                raise InputError("IERS table not found", path=str(p))
        mjd, dut1, xp, yp, first_pred = _combine_like_astropy(
            _read_finals2000a(finals_path), _read_eopc04(c04_path), finals_path
        )
        return cls(
            mjd, dut1, xp, yp, first_predicted_mjd=first_pred,
            source=f"{finals_path.name} + {c04_path.name}",
        )

    @property
    def span_mjd(self) -> tuple[float, float]:
        """First and last table days, MJD(UTC)."""
        return float(self.mjd_utc[0]), float(self.mjd_utc[-1])

    def _locate(self, mjd_utc, day_fraction):
        mjd = np.asarray(mjd_utc, dtype=np.float64)
        if day_fraction is not None:
            whole = mjd
            fraction = np.asarray(day_fraction, dtype=np.float64)
            mjd = whole + fraction
        lo, hi = self.span_mjd
        outside = ~((mjd >= lo) & (mjd <= hi))  # also catches NaN
        if np.any(outside):
            bad = float(mjd[outside].reshape(-1)[0])
            shown = _mjd_to_date(bad) if np.isfinite(bad) else "NaN"
            raise OutOfRangeError(
                f"MJD(UTC) {bad:.5f} ({shown}) lies outside the IERS Earth-orientation tables "
                f"({self.source}: MJD {lo:.0f} to {hi:.0f}, {_mjd_to_date(lo)} to "
                f"{_mjd_to_date(hi)}); update the astropy-iers-data package "
                "(pip install -U astropy-iers-data)"
            )
        # interval i covers [mjd_utc[i], mjd_utc[i+1]]; the last day falls in the last interval
        last = self.mjd_utc.size - 2
        if day_fraction is None:
            i = np.clip(np.searchsorted(self.mjd_utc, mjd, side="right") - 1, 0, last)
            return i, (mjd - self.mjd_utc[i]) * self._inv_day_step[i]
        # two-part: the interval is chosen by the whole day, never by a rounded sum
        i = np.clip(np.searchsorted(self.mjd_utc, whole, side="right") - 1, 0, last)
        return i, ((whole - self.mjd_utc[i]) + fraction) * self._inv_day_step[i]

    def ut1_minus_utc_s(self, mjd_utc, *, day_fraction=None) -> np.ndarray:
        """UT1 - UTC in seconds at MJD(UTC), linearly interpolated.

        Parameters
        ----------
        mjd_utc : array_like of float
            MJD(UTC), any shape (see :func:`utc_mjd`); the whole day when ``day_fraction``
            is given.
        day_fraction : array_like of float, optional
            Fraction of the UTC day, for a two-part MJD (see :func:`utc_jd_to_day`).

        Returns
        -------
        ndarray, shape of ``mjd_utc``

        Raises
        ------
        OutOfRangeError
            A time outside the tables (gcpcal never extrapolates Earth orientation).
        """
        i, frac = self._locate(mjd_utc, day_fraction)
        return self.ut1_minus_utc_table_s[i] + frac * self._dut1_step[i]

    def polar_motion_rad(self, mjd_utc, *, day_fraction=None):
        """Pole coordinates ``(xp, yp)`` in radians at MJD(UTC), linearly interpolated.

        Parameters
        ----------
        mjd_utc : array_like of float
            MJD(UTC), any shape; the whole day when ``day_fraction`` is given.
        day_fraction : array_like of float, optional
            Fraction of the UTC day, for a two-part MJD (see :func:`utc_jd_to_day`).

        Returns
        -------
        xp, yp : ndarray, shape of ``mjd_utc``
            Coordinates of the CIP in the ITRS (IERS Conventions 2010, eq. 5.3), radians.
        """
        i, frac = self._locate(mjd_utc, day_fraction)
        xp = self.xp_table_arcsec[i] + frac * self._xp_step[i]
        yp = self.yp_table_arcsec[i] + frac * self._yp_step[i]
        return xp * ARCSEC_TO_RAD, yp * ARCSEC_TO_RAD

    def __repr__(self) -> str:
        lo, hi = self.span_mjd
        return (
            f"EarthOrientation({self.source}, {_mjd_to_date(lo)} to {_mjd_to_date(hi)}, "
            f"predicted from MJD {self.first_predicted_mjd:.0f})"
        )


@functools.lru_cache(maxsize=1)
def default_eop() -> EarthOrientation:
    """The IERS tables of the installed ``astropy-iers-data``, read once on first use.

    Returns
    -------
    EarthOrientation
        Shared (cached) instance of :meth:`EarthOrientation.from_iers_files`.
    """
    return EarthOrientation.from_iers_files()
