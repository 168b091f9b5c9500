"""The map grid of an orthoimage: its CRS (the scene's UTM zone), its resolution (the scene's
GSD) and the bounding box of the scene's footprint on the DEM.

:func:`ortho_grid` is the grid :func:`sensor_models.imaging.ortho.orthorectify_to_file` writes;
:func:`scene_gsd_m` measures the ground sampling distance at the image centre.
"""

from __future__ import annotations

import numpy as np
import pyproj
from affine import Affine

from sensor_models.errors import InputError

__all__ = ["MAX_SIDE_PX", "band_kwargs", "ortho_grid", "scene_gsd_m", "utm_crs"]


#: largest output raster accepted (either side, pixels)
MAX_SIDE_PX = 200_000


def utm_crs(lon_deg: float, lat_deg: float) -> pyproj.CRS:
    """The WGS84 UTM zone CRS (EPSG:326zz north, 327zz south) containing ``(lon, lat)``.

    Parameters
    ----------
    lon_deg, lat_deg : float
        WGS84 longitude and latitude, degrees.

    Returns
    -------
    pyproj.CRS
    """
    zone = int(np.floor((float(lon_deg) + 180.0) / 6.0)) % 60 + 1
    return pyproj.CRS.from_epsg((32600 if lat_deg >= 0.0 else 32700) + zone)


def _centre_column(model, band) -> float:
    """A column at the middle of the image that is not on a CCD seam."""
    arrays = model.detector_arrays(band)  # one array covering the image for area arrays and RPCs
    middle = arrays[len(arrays) // 2]
    return middle.first_col + 0.5 * middle.n_detectors


def band_kwargs(band):
    """``{"band": band}`` for a model's localization methods, or ``{}`` when ``band`` is None."""
    return {} if band is None else {"band": band}


def scene_gsd_m(model, *, band=None, height_m: float = 0.0) -> float:
    """Ground sampling distance (m) at the image centre: ``sqrt(d_row * d_col)``.

    ``d_row`` and ``d_col`` are the ground distances between the centre pixel and its
    neighbours one line and one column away, localized at ``height_m`` (ellipsoidal).

    Parameters
    ----------
    model : SensorModel
        Any model with ``image_shape`` and ``image_to_ground``; push-broom models are measured
        in the middle of their central CCD.
    band : str, optional
        Band of the geometry.
    height_m : float
        Ellipsoidal height of the localization, metres.

    Returns
    -------
    float
        GSD in metres.
    """
    from sensor_models.geometry.geodesy import geodetic_to_ecef

    row = 0.5 * model.image_shape[0]
    col = _centre_column(model, band)
    lon, lat, h = model.image_to_ground(np.array([row, row + 1.0, row]), np.array([col, col, col + 1.0]),
                                        height=float(height_m), **band_kwargs(band))
    p = geodetic_to_ecef(lon, lat, h)
    d_row, d_col = np.linalg.norm(p[1] - p[0]), np.linalg.norm(p[2] - p[0])
    gsd = float(np.sqrt(d_row * d_col))
    if not (np.isfinite(gsd) and gsd > 0.0):
        raise InputError("cannot measure the ground sampling distance at the image centre")
    return gsd


def _border(n_rows: int, n_cols: int, per_side: int = 64):
    """Points along the image border (pixel-edge coordinates), corners included."""
    r = np.linspace(0.0, float(n_rows), per_side + 1)
    c = np.linspace(0.0, float(n_cols), per_side + 1)
    rows = np.concatenate([np.zeros_like(c), np.full_like(c, n_rows), r, r])
    cols = np.concatenate([c, c, np.zeros_like(r), np.full_like(r, n_cols)])
    return rows, cols


def _footprint_lonlat(model, dem, band):
    """WGS84 ``lon, lat`` of the image border on the DEM (mean DEM height where it misses)."""
    rows, cols = _border(*model.image_shape)
    lon, lat, _ = model.image_to_ground(rows, cols, dem=dem, **band_kwargs(band))
    miss = ~(np.isfinite(lon) & np.isfinite(lat))
    if miss.any():
        h_mean = float(np.nanmean(dem.heights_m))
        lon_m, lat_m, _ = model.image_to_ground(rows[miss], cols[miss], height=h_mean, **band_kwargs(band))
        lon, lat = lon.copy(), lat.copy()
        lon[miss], lat[miss] = lon_m, lat_m
    return lon, lat


def ortho_grid(model, dem, *, crs=None, resolution_m=None, band=None):
    """The map grid of an orthoimage: the scene footprint's bounding box in ``crs``.

    Parameters
    ----------
    model : SensorModel
    dem : sensor_models.terrain.dem.Dem
        The image border is localized on it (its mean height where a ray misses it).
    crs : anything pyproj accepts, optional
        Output CRS (projected, metres); default: the UTM zone of the footprint's centre.
    resolution_m : float, optional
        Pixel size in CRS units; default: the scene's GSD (:func:`scene_gsd_m` at the DEM's
        mean height) rounded to 3 significant digits.
    band : str, optional

    Returns
    -------
    MapGrid
        North-up grid whose corners lie on multiples of the resolution.
    """
    from sensor_models.maps.grid import MapGrid

    lon, lat = _footprint_lonlat(model, dem, band)
    if crs is None:
        crs = utm_crs(float(np.mean([lon.min(), lon.max()])), float(np.mean([lat.min(), lat.max()])))
    try:
        crs = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError as exc:
        raise InputError(f"unknown CRS {crs!r} ({exc})", field="crs") from None
    if crs.is_geographic:
        raise InputError(f"the output CRS {crs.name!r} is geographic; give a projected CRS (metres)", field="crs")
    if resolution_m is None:
        gsd = scene_gsd_m(model, band=band, height_m=float(np.nanmean(dem.heights_m)))
        resolution_m = float(f"{gsd:.3g}")
    resolution_m = float(resolution_m)
    if not (np.isfinite(resolution_m) and resolution_m > 0.0):
        raise InputError(f"must be a positive number, got {resolution_m}", field="resolution_m")
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    x, y = np.asarray(x), np.asarray(y)
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise InputError(f"the scene footprint does not map into {crs.name!r}", field="crs")
    x0, x1 = np.floor(x.min() / resolution_m), np.ceil(x.max() / resolution_m)
    y0, y1 = np.floor(y.min() / resolution_m), np.ceil(y.max() / resolution_m)
    shape = (int(y1 - y0), int(x1 - x0))
    if max(shape) > MAX_SIDE_PX:
        raise InputError(f"the orthoimage would be {shape[0]} x {shape[1]} px; choose a coarser resolution "
                         f"than {resolution_m} m", field="resolution_m")
    transform = Affine(resolution_m, 0.0, round(x0 * resolution_m, 6), 0.0, -resolution_m, round(y1 * resolution_m, 6))
    return MapGrid(transform, crs, shape)
