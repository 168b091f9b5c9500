"""Vendor readers check the model they build against what the product states about itself.

A vendor product carries, besides the metadata a rigorous model is built from, the producer's
own localization of some of its pixels: the frame vertices and scene centre of a SPOT 1-5 DIMAP
file, the ``Dataset_Extent`` of a DIMAP v2 product, the ``IMD`` corners and the ``RPB`` rational
polynomials of a DigitalGlobe XML. The producer computed them from the same metadata, so a model
that reads the metadata with the right conventions (time scale and line dating, pixel origin,
quaternion order and direction, frames, look angles) lands on them; a wrong convention misses
them by a line (metres) or by kilometres. Every vendor reader runs a :class:`ProductCheck` when it
opens a product:

* **stated points** (corners, vertices, centre) are localized at their stated heights (or, where
  the product states none, at the one common height that fits them best, within -500 to 9000 m)
  and their horizontal distances to the stated coordinates are measured;
* **the vendor RPC**, where the product carries one, is compared with the model over a grid of
  ``RPC_GRID_SIDE`` x ``RPC_GRID_SIDE`` image points at ``RPC_GRID_HEIGHTS`` heights spanning the
  RPC's height range: both localize each point at each height, and the horizontal distances are
  measured.

Each comparison holds one statistic (``max`` for stated points, ``rms`` for the RPC grid, whose
stated error is an rms) against a tolerance in metres. The tolerance is derived from the
product's own statement of that accuracy where it makes one (the RPC's ``ERRRAND``: RMS random
error per horizontal axis), else half a ground pixel (a statement tied to a pixel locates it to
its half-width), combined in quadrature with the rounding of the stated coordinates and the
reader's documented modelling limit. Absolute accuracy statements (``ERRBIAS``, a CE90 against
the ground) are not tolerances here: they describe the product's error against the Earth, which
the metadata and the producer's corners share, not the corners' agreement with the metadata.

Beyond the tolerance the reader refuses (:class:`~sensor_models.errors.ProductDisagreementError`,
one line naming the product, the satellite and the disagreement) unless the user asked
``self_check="warn"``: then the model is returned with the check, which records the disagreement
(``Scene.product_check`` of :func:`~sensor_models.readers.scene_input.open_scene`; also logged at
INFO level). Summaries of the commands that open a product write
:meth:`ProductCheck.to_dict`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from decimal import Decimal

import numpy as np

from sensor_models.errors import InputError, OutOfRangeError, ProductDisagreementError

__all__ = [
    "PLAUSIBLE_HEIGHT_M",
    "POLICIES",
    "RPC_GRID_HEIGHTS",
    "RPC_GRID_SIDE",
    "Comparison",
    "ProductCheck",
    "Tolerance",
    "check_policy",
    "compare",
    "coordinate_rounding_m",
    "enforce",
    "fit_common_height",
    "ground_pixel_m",
    "horizontal_distance_m",
    "localization_misses_m",
    "rpc_grid_misses_m",
    "view_tangent",
]

_log = logging.getLogger(__name__)

#: what a reader does when the product disagrees with its model: raise, or proceed and record
POLICIES = ("refuse", "warn")
#: image points per side of the RPC comparison grid, and heights over the RPC's height range
RPC_GRID_SIDE = 11
RPC_GRID_HEIGHTS = 5
#: ellipsoidal heights a fitted common height of stated points may take (m): Earth's surface
PLAUSIBLE_HEIGHT_M = (-500.0, 9000.0)
#: half a pixel: the resolution of a statement tied to one pixel
HALF_PIXEL = 0.5


def check_policy(value) -> str:
    """Validate a ``self_check`` option.

    Parameters
    ----------
    value : str
        ``"refuse"`` (default of every reader) or ``"warn"``.

    Returns
    -------
    str
        ``value``.

    Raises
    ------
    InputError
        Any other value (field ``self_check``).
    """
    if value not in POLICIES:
        raise InputError(f"must be one of {POLICIES}, got {value!r}", field="self_check")
    return value


@dataclass(frozen=True)
class Tolerance:
    """A tolerance in metres and where it comes from.

    Attributes
    ----------
    metres : float
    source : str
        One line: the terms and their origin, e.g. ``"sqrt(2) x RPB ERRRAND 0.26 m (+) ..."``.
    """

    metres: float
    source: str

    @classmethod
    def combine(cls, *terms: tuple[float, str]) -> "Tolerance":
        """Terms ``(metres, what)`` added in quadrature (terms of 0 m are left out of the text)."""
        used = [(float(m), what) for m, what in terms if m > 0.0]
        total = float(np.sqrt(sum(m * m for m, _ in used)))
        return cls(total, " (+) ".join(f"{what} {m:.3g} m" for m, what in used) + " (in quadrature)")


@dataclass(frozen=True)
class Comparison:
    """One comparison of the model with a statement of the product.

    Attributes
    ----------
    name : str
        ``"corners"``, ``"frame"``, ``"rpc_grid"``.
    description : str
        What was compared, e.g. ``"IMD corners at their HAE heights"``.
    statistic : {"max", "rms"}
        The figure held against the tolerance.
    n_points : int
    mean_m, rms_m, max_m : float
        Horizontal distances between the model's and the statement's localizations (m);
        ``inf`` where the model's rays miss the Earth.
    tolerance : Tolerance
    """

    name: str
    description: str
    statistic: str
    n_points: int
    mean_m: float
    rms_m: float
    max_m: float
    tolerance: Tolerance

    @property
    def value_m(self) -> float:
        """The statistic held against the tolerance (m)."""
        return self.max_m if self.statistic == "max" else self.rms_m

    @property
    def passed(self) -> bool:
        """True when :attr:`value_m` is within the tolerance."""
        return bool(self.value_m <= self.tolerance.metres)

    def text(self) -> str:
        """``"IMD corners at their HAE heights: 0.54 m max (mean 0.53 m, 4 points), tolerance 0.37 m"``."""
        if not np.isfinite(self.value_m):
            return f"{self.description}: the model's lines of sight miss the Earth"
        other = f"mean {_metres(self.mean_m)}" if self.statistic == "max" else f"max {_metres(self.max_m)}"
        return (f"{self.description}: {_metres(self.value_m)} {self.statistic} ({other}, {self.n_points} points), "
                f"tolerance {_metres(self.tolerance.metres)}")

    def to_dict(self) -> dict:
        """JSON-ready mapping (non-finite distances as None)."""
        def num(x):
            return float(x) if np.isfinite(x) else None

        return {"name": self.name, "description": self.description, "statistic": self.statistic,
                "n_points": self.n_points, "mean_m": num(self.mean_m), "rms_m": num(self.rms_m),
                "max_m": num(self.max_m), "tolerance_m": self.tolerance.metres,
                "tolerance_source": self.tolerance.source, "passed": self.passed}


def _metres(x: float) -> str:
    """``0.0502 m``, ``1.21 m``, ``98.3 m``, ``1237 m``: three significant digits, no exponent."""
    if not np.isfinite(x):
        return "inf m"
    return f"{x:.3g} m" if abs(x) < 100.0 else f"{x:.0f} m"


def compare(name: str, description: str, distances_m, statistic: str, tolerance: Tolerance) -> Comparison:
    """A :class:`Comparison` from horizontal distances.

    Parameters
    ----------
    name, description : str
    distances_m : array_like, shape (N,)
        Horizontal distances (m); NaN (a ray that missed the Earth) counts as infinite.
    statistic : {"max", "rms"}
    tolerance : Tolerance

    Returns
    -------
    Comparison
    """
    d = np.asarray(distances_m, dtype=np.float64).ravel()
    d = np.where(np.isfinite(d), d, np.inf)
    return Comparison(name, description, statistic, int(d.size), float(np.mean(d)),
                      float(np.sqrt(np.mean(d * d))), float(np.max(d)), tolerance)


@dataclass(frozen=True)
class ProductCheck:
    """The self-check of a vendor product: every comparison, the policy, the verdict.

    Attributes
    ----------
    product : str
        The metadata file.
    reader : str
        ``"SPOT 1-5 DIMAP"``, ``"DIMAP v2"``, ``"DigitalGlobe XML"``.
    satellite : str
        As the product names it (``SPOT5``, ``SPOT6``, ``WV02`` ...).
    policy : {"refuse", "warn"}
    comparisons : tuple of Comparison
    notes : tuple of str
        Facts of the check (a fitted height, the attitude the frame was computed with ...).
    caveat : str
        Added to the refusal (e.g. that a satellite's conventions are verified nowhere else).
    """

    product: str
    reader: str
    satellite: str
    policy: str
    comparisons: tuple
    notes: tuple = ()
    caveat: str = field(default="")

    @property
    def passed(self) -> bool:
        """True when every comparison is within its tolerance."""
        return all(c.passed for c in self.comparisons)

    def disagreement(self) -> str:
        """One line naming the satellite and every failed comparison ("" when all passed)."""
        failed = [c.text() for c in self.comparisons if not c.passed]
        if not failed:
            return ""
        text = f"{self.reader} product of {self.satellite} disagrees with its own statements: " + "; ".join(failed)
        if self.caveat:
            text += f"; {self.caveat}"
        return text

    def to_dict(self) -> dict:
        """JSON-ready mapping for the summaries."""
        return {"product": self.product, "reader": self.reader, "satellite": self.satellite,
                "policy": self.policy, "passed": self.passed,
                "comparisons": [c.to_dict() for c in self.comparisons], "notes": list(self.notes),
                "disagreement": self.disagreement() or None}


def enforce(check: ProductCheck) -> ProductCheck:
    """Refuse a product that disagrees with itself, or record and warn (``policy="warn"``).

    Parameters
    ----------
    check : ProductCheck

    Returns
    -------
    ProductCheck
        ``check``, when it passed or the policy is ``"warn"`` (the disagreement is logged at INFO level).

    Raises
    ------
    ProductDisagreementError
        When it failed and the policy is ``"refuse"``; the message says how to proceed anyway.
    """
    if check.passed:
        return check
    if check.policy == "refuse":
        raise ProductDisagreementError(
            check.disagreement() + " (open it with self_check='warn', gcpcal --accept-product-disagreement, "
            "to proceed and record the disagreement)", path=check.product)
    _log.info("%s: %s (proceeding: self_check='warn')", check.product, check.disagreement())
    return check


# ---------------------------------------------------------------------------------------------
# geometry of the comparisons


def horizontal_distance_m(lon_a, lat_a, lon_b, lat_b, h_m) -> np.ndarray:
    """Distances between points of equal heights (m, chord in ECEF; NaN where an input is NaN).

    Parameters
    ----------
    lon_a, lat_a, lon_b, lat_b : array_like
        Degrees, WGS84.
    h_m : array_like
        Their common ellipsoidal heights (m).

    Returns
    -------
    ndarray
        Broadcast shape.
    """
    from sensor_models.geometry.geodesy import geodetic_to_ecef

    a = geodetic_to_ecef(lon_a, lat_a, h_m)
    b = geodetic_to_ecef(lon_b, lat_b, h_m)
    return np.linalg.norm(a - b, axis=-1)


def _localize(model, row, col, h_m, band):
    """``image_to_ground`` at heights; NaN (not an exception) where the rays miss or leave the data."""
    row, col = np.asarray(row, dtype=np.float64), np.asarray(col, dtype=np.float64)
    h = np.broadcast_to(np.asarray(h_m, dtype=np.float64), row.shape)
    try:
        lon, lat, _ = model.image_to_ground(row, col, height=h, band=band)
    except OutOfRangeError:
        return np.full(row.shape, np.nan), np.full(row.shape, np.nan)
    return lon, lat


def localization_misses_m(model, row, col, lon, lat, h_m, *, band=None) -> np.ndarray:
    """Horizontal distances between the model's localization of pixels and stated coordinates.

    Parameters
    ----------
    model : SensorModel
    row, col : array_like, shape (N,)
        The stated pixels (gcpcal convention, first pixel centre 0.5).
    lon, lat : array_like, shape (N,)
        The stated coordinates (degrees).
    h_m : float or array_like
        The heights to localize at (m above the ellipsoid).
    band : str, optional

    Returns
    -------
    ndarray, shape (N,)
        Metres; NaN where the model's ray misses the Earth.
    """
    h = np.broadcast_to(np.asarray(h_m, dtype=np.float64), np.shape(row))
    lon_m, lat_m = _localize(model, row, col, h, band)
    return horizontal_distance_m(lon_m, lat_m, lon, lat, h)


def fit_common_height(model, row, col, lon, lat, *, band=None) -> tuple[float, np.ndarray]:
    """The one height at which the model lands nearest the stated points, and the misses there.

    For products that state points without heights (DIMAP v2 ``Dataset_Extent``): the height
    minimizing the sum of squared horizontal misses, searched within :data:`PLAUSIBLE_HEIGHT_M`.

    Parameters
    ----------
    model : SensorModel
    row, col, lon, lat : array_like, shape (N,)
    band : str, optional

    Returns
    -------
    height_m : float
    misses_m : ndarray, shape (N,)
        NaN where the rays miss the Earth.
    """
    from scipy.optimize import minimize_scalar

    def cost(h):
        d = localization_misses_m(model, row, col, lon, lat, h, band=band)
        return float(np.sum(np.where(np.isfinite(d), d, 1e12) ** 2))

    lo, hi = PLAUSIBLE_HEIGHT_M
    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    h = float(res.x)
    return h, localization_misses_m(model, row, col, lon, lat, h, band=band)


def rpc_grid_misses_m(model, rpc, n_rows: float, n_cols: float, heights_m, *, band=None,
                      side: int = RPC_GRID_SIDE) -> np.ndarray:
    """Horizontal distances between the model's and an RPC's localizations over a grid.

    Parameters
    ----------
    model : SensorModel
    rpc : RpcModel
        In the same pixel convention as ``model`` (gcpcal's).
    n_rows, n_cols : float
        The extent the grid spans: pixel centres from ``0.5`` to ``n - 0.5``.
    heights_m : array_like, shape (K,)
        Ellipsoidal heights.
    band : str, optional
    side : int
        Grid points per side.

    Returns
    -------
    ndarray, shape (K * side * side,)
        Metres; NaN where either localization fails.
    """
    r, c = np.meshgrid(np.linspace(0.5, n_rows - 0.5, side), np.linspace(0.5, n_cols - 0.5, side), indexing="ij")
    r, c = r.ravel(), c.ravel()
    out = []
    for h in np.asarray(heights_m, dtype=np.float64):
        hh = np.full(r.shape, h)
        lon_m, lat_m = _localize(model, r, c, hh, band)
        lon_r, lat_r, _ = rpc.image_to_ground(r, c, height=hh)
        out.append(horizontal_distance_m(lon_m, lat_m, lon_r, lat_r, hh))
    return np.concatenate(out)


def ground_pixel_m(model, row: float, col: float, h_m: float, *, band=None) -> float:
    """The larger side of a pixel on the ground (m), from the model at one pixel and height.

    Parameters
    ----------
    model : SensorModel
    row, col : float
        Where (e.g. the scene centre).
    h_m : float
    band : str, optional

    Returns
    -------
    float
        ``max(|P(r+1/2, c) - P(r-1/2, c)|, |P(r, c+1/2) - P(r, c-1/2)|)`` on the ground.
    """
    rows = np.array([row - 0.5, row + 0.5, row, row])
    cols = np.array([col, col, col - 0.5, col + 0.5])
    lon, lat = _localize(model, rows, cols, h_m, band)
    along = horizontal_distance_m(lon[0], lat[0], lon[1], lat[1], h_m)
    across = horizontal_distance_m(lon[2], lat[2], lon[3], lat[3], h_m)
    return float(max(along, across))


def view_tangent(model, row: float, col: float, h_m: float, *, band=None) -> float:
    """``tan`` of the view's zenith angle at the ground: metres of displacement per metre of height.

    Parameters
    ----------
    model : SensorModel
    row, col, h_m : float
    band : str, optional

    Returns
    -------
    float
        From the localizations at ``h_m`` and ``h_m + 100`` (NaN if the rays miss the Earth).
    """
    rows, cols = np.array([row, row]), np.array([col, col])
    lon, lat = _localize(model, rows, cols, np.array([h_m, h_m + 100.0]), band)
    return float(horizontal_distance_m(lon[0], lat[0], lon[1], lat[1], h_m) / 100.0)


def _half_unit(value: float) -> float:
    """Half the unit of the last decimal a value carries (``948.3`` -> 0.05; ``35.26358901`` -> 5e-9)."""
    exponent = Decimal(repr(float(value))).normalize().as_tuple().exponent
    return 0.5 * 10.0 ** min(int(exponent), 0)


def _list_half_unit(values) -> float:
    """Half the unit of the finest decimal among values printed together (one formatter, one precision)."""
    return min(_half_unit(v) for v in np.atleast_1d(values).ravel())


def coordinate_rounding_m(lon, lat, h_m=None, *, view_tangent_value: float = 0.0) -> float:
    """The ground effect of the rounding of stated coordinates (m).

    The values of one list (all longitudes, all latitudes, all heights) are printed by one
    formatter: each list is taken to be rounded to the finest decimal any of its values carries
    (``948.3, 776.31`` -> 0.005). The height's rounding moves a localization by
    ``view_tangent`` metres per metre.

    Parameters
    ----------
    lon, lat : array_like, shape (N,)
        Stated coordinates (degrees).
    h_m : array_like, shape (N,), optional
        Stated heights (m).
    view_tangent_value : float
        ``tan`` of the view's zenith angle.

    Returns
    -------
    float
        ``hypot(dlon * m/deg * cos(lat), dlat * m/deg) + dh * tan z`` at the highest latitude.
    """
    lon, lat = np.atleast_1d(lon).astype(float), np.atleast_1d(lat).astype(float)
    m_per_deg = np.pi / 180.0 * 6_378_137.0
    total = float(np.hypot(_list_half_unit(lon) * m_per_deg * np.cos(np.radians(np.min(np.abs(lat)))),
                           _list_half_unit(lat) * m_per_deg))
    if h_m is not None and np.isfinite(view_tangent_value):
        total += _list_half_unit(h_m) * view_tangent_value
    return total
