"""Whether a DEM covers a scene: its footprint sampled on the ground, coverage and voids checked.

:func:`footprint_sample_lonlat` localizes a grid of pixels at one height;
:func:`check_dem_footprint` refuses a DEM that covers less than :data:`MIN_FOOTPRINT_COVERAGE`
of those points or has more than :data:`MAX_FOOTPRINT_VOID_FRACTION` of voids there, and
describes the rest as warnings.
"""

from __future__ import annotations

import numpy as np

from sensor_models.errors import DemError
from sensor_models.terrain.dem import Dem

__all__ = ["MAX_FOOTPRINT_VOID_FRACTION", "MIN_FOOTPRINT_COVERAGE", "check_dem_footprint",
           "footprint_sample_lonlat"]


#: Least share of a scene's footprint a DEM must cover; below it a command refuses the DEM, above
#: it (and below 1) the command says how much is covered. Half, not all: the footprint of an
#: uncalibrated (LAB) model is off by up to hundreds of pixels, so a DEM cut to the true scene
#: covers only part of it (74.5 % for the embedded hy1c_czi fixture).
MIN_FOOTPRINT_COVERAGE = 0.5
#: Largest share of voids (no height) under a scene's footprint a command accepts; any void is
#: reported, more than this is refused.
MAX_FOOTPRINT_VOID_FRACTION = 0.05


def footprint_sample_lonlat(model, height_m: float, *, n_side: int = 33, band=None):
    """Ground points of a regular grid of pixels over a model's image, at one height.

    Parameters
    ----------
    model : SensorModel
        Any model (``image_shape``, ``image_to_ground``).
    height_m : float
        Ellipsoidal height of the localization, metres.
    n_side : int
        Grid points per image side (pixel centres, corners included).
    band : str, optional
        Band of a multi-band model; default: the reference band.

    Returns
    -------
    lon_deg, lat_deg : ndarray, shape (M,)
        WGS84 degrees of the points that localize (points off the Earth dropped).
    """
    n_rows, n_cols = model.image_shape
    r, c = np.meshgrid(np.linspace(0.5, n_rows - 0.5, n_side), np.linspace(0.5, n_cols - 0.5, n_side),
                       indexing="ij")
    kwargs = {} if band is None else {"band": band}
    lon, lat, _ = model.image_to_ground(r.reshape(-1), c.reshape(-1), height=float(height_m), **kwargs)
    lon, lat = np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
    ok = np.isfinite(lon) & np.isfinite(lat)
    return lon[ok], lat[ok]


def check_dem_footprint(dem: Dem, lon_deg, lat_deg, *, min_coverage: float = MIN_FOOTPRINT_COVERAGE,
                        max_void_fraction: float = MAX_FOOTPRINT_VOID_FRACTION) -> dict:
    """Refuse a DEM that misses a scene's footprint or is mostly void there; describe the rest.

    Parameters
    ----------
    dem : Dem
        The DEM.
    lon_deg, lat_deg : array_like, shape (N,)
        WGS84 degrees of points over the footprint (:func:`footprint_sample_lonlat`).
    min_coverage : float
        Least share of the points the DEM must cover, in ``[0, 1]``.
    max_void_fraction : float
        Largest share of the covered points that may fall in voids, in ``[0, 1]``.

    Returns
    -------
    dict
        ``dem_coverage`` and ``dem_void_fraction`` (floats in ``[0, 1]``; None without points)
        and ``warnings`` (list of one-line str: the part not covered, the voids).

    Raises
    ------
    DemError
        When the DEM covers less than ``min_coverage`` of the footprint, or its voids exceed
        ``max_void_fraction`` of it; the message gives both percentages.
    """
    lon, lat = np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64)
    if lon.size == 0:
        return {"dem_coverage": None, "dem_void_fraction": None, "warnings": []}
    coverage, voids = dem.coverage_fraction(lon, lat), dem.void_fraction(lon, lat)
    name = dem.source or "DEM"
    where = f"footprint lon {lon.min():.4f}..{lon.max():.4f}, lat {lat.min():.4f}..{lat.max():.4f}"
    if coverage < min_coverage:
        b = dem.bounds_lonlat
        raise DemError(f"{name}: the DEM covers {100 * coverage:.1f} % of the scene footprint ({where}; the DEM "
                       f"spans lon {b[0]:.4f}..{b[2]:.4f}, lat {b[1]:.4f}..{b[3]:.4f}); at least "
                       f"{100 * min_coverage:.0f} % is needed: give a DEM under the scene")
    if voids > max_void_fraction:
        raise DemError(f"{name}: {100 * voids:.1f} % of the scene footprint falls in DEM voids (at most "
                       f"{100 * max_void_fraction:.0f} % accepted): fill the voids or give another DEM")
    warnings = []
    if coverage < 1.0:
        warnings.append(f"{name}: the DEM covers {100 * coverage:.1f} % of the scene footprint ({where})")
    if voids > 0.0:
        warnings.append(f"{name}: {100 * voids:.1f} % of the scene footprint falls in DEM voids")
    return {"dem_coverage": coverage, "dem_void_fraction": voids, "warnings": warnings}
