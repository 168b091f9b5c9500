"""What the DIMAP readers share: the pixel convention, strict access to the tree, time and ephemeris checks.

Used by the SPOT 1-5 parser (DIMAP 1.1, :mod:`sensor_models.readers.dimap_parse`) and the SPOT
6/7-Pleiades one (DIMAP v2, :mod:`sensor_models.readers._dimap_v2_parse`):

* :func:`dimap_to_pixel`, :func:`pixel_to_dimap`: DIMAP's 1-based pixel centres and ours
  (first pixel centre at 0.5);
* :class:`DimapXml`: typed access to a ``Dimap_Document`` whose errors name the file and the
  XML path, with UTC times;
* :func:`seconds_since`, :func:`check_increasing`: time lists as SI seconds from the scene
  epoch, strictly increasing;
* :func:`ephemeris_velocity_kind`: whether the file's velocities are Earth-relative or
  inertial (``EARTH_ROTATION_RAD_S``, ``VELOCITY_TOLERANCE_M_S``).
"""

from __future__ import annotations

import re

import numpy as np

from sensor_models.errors import InputError
from sensor_models.readers._xml import StrictXml

__all__ = [
    "DIMAP_ROOT",
    "DimapXml",
    "EARTH_ROTATION_RAD_S",
    "VELOCITY_TOLERANCE_M_S",
    "check_increasing",
    "dimap_to_pixel",
    "ephemeris_velocity_kind",
    "pixel_to_dimap",
    "seconds_since",
]

#: WGS84 nominal mean angular velocity of the Earth (rad/s)
EARTH_ROTATION_RAD_S = 7.292115e-5
#: largest disagreement (m/s) tolerated between the file's velocities and dP/dt (or dP/dt + w x P)
VELOCITY_TOLERANCE_M_S = 1.0

#: root element of a DIMAP document (1.1 and v2)
DIMAP_ROOT = "Dimap_Document"
_TIME_RE = re.compile(r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(\.\d{1,9})?Z?$")


def dimap_to_pixel(dimap_row_or_col):
    """DIMAP 1-based pixel-centre coordinates -> gcpcal's (first pixel centre at 0.5).

    Parameters
    ----------
    dimap_row_or_col : array_like
        Rows or columns as DIMAP counts them (the first pixel's centre is 1).

    Returns
    -------
    ndarray of float64
        The same positions in gcpcal's convention (``value - 0.5``), same shape.
    """
    return np.asarray(dimap_row_or_col, dtype=np.float64) - 0.5


def pixel_to_dimap(row_or_col):
    """gcpcal pixel coordinates -> DIMAP 1-based pixel-centre coordinates.

    Parameters
    ----------
    row_or_col : array_like
        Rows or columns in gcpcal's convention (the first pixel's centre is 0.5).

    Returns
    -------
    ndarray of float64
        The same positions as DIMAP counts them (``value + 0.5``), same shape.
    """
    return np.asarray(row_or_col, dtype=np.float64) + 0.5


class DimapXml(StrictXml):
    """Strict typed access to the DIMAP tree; errors name the file and the XML path."""

    ROOT = DIMAP_ROOT
    DOCUMENT = "DIMAP document"

    def nodes(self, parent, rel: str, where: str, *, minimum: int = 1):
        found = parent.findall(rel)
        if len(found) < minimum:
            what = "is missing" if not found else f"needs at least {minimum} entries, got {len(found)}"
            raise self.error(where, what)
        return found

    def flag(self, parent, rel: str, where: str, *, optional: bool = False):
        value = self.text(parent, rel, where, optional=optional)
        if value is None:
            return None
        if value not in ("Y", "N"):
            raise self.error(where, f"must be 'Y' or 'N', got {value!r}")
        return value == "Y"

    def time(self, parent, rel: str, where: str) -> np.datetime64:
        value = self.text(parent, rel, where)
        return self.parse_time(value, where)

    def parse_time(self, value: str, where: str) -> np.datetime64:
        from sensor_models.geometry.timescales import parse_utc

        if not _TIME_RE.match(value):
            raise self.error(where, f"must be a UTC time YYYY-MM-DDThh:mm:ss[.ffffff], got {value!r}")
        try:
            return parse_utc(value)
        except InputError as exc:
            raise self.error(where, exc.reason) from None


def seconds_since(times, epoch) -> np.ndarray:
    """SI seconds from ``epoch`` (UTC; no leap second falls inside a SPOT scene's data)."""
    return (np.asarray(times, dtype="datetime64[ns]") - epoch).astype(np.int64) * 1e-9


def check_increasing(x: DimapXml, seconds: np.ndarray, where: str) -> None:
    """Raise the error of ``x`` at ``where`` unless ``seconds`` increase strictly (naming the first bad entry)."""
    bad = np.nonzero(np.diff(seconds) <= 0.0)[0]
    if bad.size:
        i = int(bad[0])
        raise x.error(
            where,
            f"times must increase strictly; entry {i + 2} ({seconds[i + 1]:+.6f} s from the scene "
            f"centre) does not follow entry {i + 1} ({seconds[i]:+.6f} s)",
        )


def ephemeris_velocity_kind(x: DimapXml, seconds, position, velocity, where: str) -> str:
    """Tell Earth-relative from inertial velocities by comparing them with ``dP/dt``.

    ``dP/dt`` comes from a polynomial fitted to the positions (degree up to 8, well below the
    0.1 m/s level for a LEO orbit sampled every 30-60 s over a few minutes).
    """
    t = (seconds - seconds.mean()) / max(np.ptp(seconds), 1.0)
    deg = min(seconds.size - 1, 8)
    dpdt = np.empty_like(position)
    for k in range(3):
        c = np.polynomial.polynomial.polyfit(t, position[:, k], deg)
        dpdt[:, k] = np.polynomial.polynomial.polyval(t, np.polynomial.polynomial.polyder(c))
    dpdt /= max(np.ptp(seconds), 1.0)
    spin = np.cross([0.0, 0.0, EARTH_ROTATION_RAD_S], position)
    err_rel = float(np.abs(velocity - dpdt).max())
    err_in = float(np.abs(velocity - spin - dpdt).max())
    if min(err_rel, err_in) > VELOCITY_TOLERANCE_M_S:
        raise x.error(
            where,
            f"velocities agree neither with dP/dt (off by {err_rel:.1f} m/s) nor with dP/dt + "
            f"omega x P (off by {err_in:.1f} m/s): the ephemeris is inconsistent",
        )
    return "earth_relative" if err_rel <= err_in else "inertial"
