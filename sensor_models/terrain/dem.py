"""Terrain: geoid grids, DEM access and the intersection of lines of sight with the ground.

Every height this module returns is an ellipsoidal height: metres above the WGS84 ellipsoid.
A DEM whose heights are orthometric (EGM96, as SRTM) is converted once, when it is loaded, by
adding the geoid undulation ``N`` at each DEM node (``h = H + N``); a missing geoid grid is an
error, never a silent ``N = 0`` (at the Ventoux SRTM tile ``N`` is about +51 m, which moves a
Pleiades orthoimage by about 40 lines).

Grids are sampled with bilinear interpolation between node centres. Continuous pixel
coordinates follow GDAL/rasterio (the first pixel's centre is ``(0.5, 0.5)``); internally a
*node index* ``(col, row)`` puts the first node at ``(0, 0)``, i.e. ``col = x_pixel - 0.5``.

Ray / terrain intersection (:meth:`Dem.intersect`)
--------------------------------------------------
A ray ``p(t) = o + t d`` (ITRF, ``|d| = 1``) is bracketed between its intersections with the
heights ``h_max + 1 m`` and ``h_min - 1 m`` of the DEM (:func:`intersect_ellipsoid`, solved on
the ``(a + h, b + h)`` ellipsoid whose distance to the true geodetic-height surface is below
1.3 cm up to 9 km). On that bracket the geodetic height ``h(t)`` and the node index
``(col(t), row(t))`` of the ray are smooth; each is replaced by its cubic interpolant through
four exactly computed points (error far below 1e-6 m for brackets of a few km). The ray is
then marched in steps of at most 0.45 node spacing in both ``col`` and ``row``; a step
``[t_k, t_k+1]`` is skipped only when the ray stays above the highest DEM node that the step can
reach (a 4 x 4-node maximum precomputed at load), which cannot miss a crossing. A step that may
hold one is split where it crosses grid lines; inside each DEM cell the bilinear surface along
the ray is a quadratic in ``t``, so the first root of ``f(t) = h(t) - z(col(t), row(t))`` is
found in closed form, then made exact on the model by two Newton steps. That root is finally
checked with exact evaluations (:func:`~sensor_models.geometry.geodesy.ecef_to_geodetic`, the DEM's
own CRS transform, bilinear interpolation); where ``|f| >= 1e-4 m`` (not seen in practice:
model roots are within 1e-8 m on SRTM and 2e-6 m at 70 degrees over 8 km of relief) it is
polished by bracketed Illinois (regula falsi) steps. The point returned is ``o + t d``:
exactly on the ray, so an image -> ground -> image round trip is exact.

Before marching, the bracket is narrowed with a min/max pyramid of the DEM (extrema over
blocks of 2**l cells): the ray cannot meet the surface while above the highest node under
its track, and has met it once below the lowest. A "crossing" includes touching: a ray
tangent to the surface (to ~1e-8 m) stops there. Auxiliary bounds are kept in float32
rounded outwards: a Dem takes about 2.8 times the memory of its float64 height grid.

References
----------
.. [1] J. Amanatides and A. Woo, "A fast voxel traversal algorithm for ray tracing",
   Eurographics 1987 (grid traversal; here replaced by bounded uniform steps plus exact
   per-cell roots).
.. [2] M. Dowell and P. Jarratt, "A modified regula falsi method for computing the root of an
   equation", BIT 11, 168-174 (1971) (the Illinois algorithm).
.. [3] NGA, "EGM96: the NASA GSFC and NIMA joint geopotential model", undulation grid at 15
   arc-minutes as distributed in PROJ-data (``egm96_15.gtx``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pyproj
from affine import Affine
from scipy import ndimage

from sensor_models.errors import DemError, GeoidGridMissingError, InputError
from sensor_models.geometry.geodesy import WGS84_A_M, WGS84_B_M, ecef_to_geodetic, geodetic_to_ecef

__all__ = ["MAX_FOOTPRINT_VOID_FRACTION", "MIN_FOOTPRINT_COVERAGE", "Dem", "Geoid", "VERTICAL_DATUMS",
           "check_dem_footprint", "find_egm96_grid", "footprint_sample_lonlat", "intersect_ellipsoid", "proj_data_dirs"]

#: Least share of a scene's footprint a DEM must cover; below it a command refuses the DEM, above
#: it (and below 1) the command says how much is covered. Half, not all: the footprint of an
#: uncalibrated (LAB) model is off by up to hundreds of pixels, so a DEM cut to the true scene
#: covers only part of it (74.5 % for the embedded hy1c_czi fixture).
MIN_FOOTPRINT_COVERAGE = 0.5
#: Largest share of voids (no height) under a scene's footprint a command accepts; any void is
#: reported, more than this is refused.
MAX_FOOTPRINT_VOID_FRACTION = 0.05

#: Vertical datums a DEM may declare: heights above the WGS84 ellipsoid, or EGM96 orthometric.
VERTICAL_DATUMS = ("ellipsoid", "egm96")

#: EPSG codes of vertical reference systems recognised in raster metadata.
_EPSG_EGM96_HEIGHT = 5773
#: Tolerance on the geodetic height of :func:`intersect_ellipsoid`, metres.
_ELLIPSOID_TOL_M = 1e-6
#: Tolerance on ``h_ray - h_dem`` of :meth:`Dem.intersect`, metres.
_SURFACE_TOL_M = 1e-4
#: Margin added above the DEM maximum and below its minimum for the ray bracket, metres.
_BRACKET_PAD_M = 1.0
#: Longest march step, in node spacings (both along columns and along rows).
_MAX_STEP_NODES = 0.45
#: Rays processed together: bounds memory to a few tens of MB whatever the number of rays.
_CHUNK_RAYS = 1 << 15
#: Rounds of bracket narrowing with the min/max pyramid before marching.
_NARROWING_ROUNDS = 1
#: March steps evaluated together for each ray still marching.
_BLOCK_STEPS = 8
#: Cubic interpolation nodes along the bracket and the inverse of their Vandermonde matrix.
_MODEL_S = np.array([0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0])
_MODEL_VINV = np.linalg.inv(np.vander(_MODEL_S, 4, increasing=True))

# Outcome of each ray inside Dem.intersect.
_PENDING, _HIT, _LEFT_DEM, _MISSED, _UNDERGROUND = 0, 1, 2, 3, 4


# ---------------------------------------------------------------------------------------------
# Raster access: the only place that talks to rasterio; its errors become ours here.
# ---------------------------------------------------------------------------------------------


def _read_raster(path, *, what, window_from=None, missing_error=DemError):
    """Read band 1 of a raster as float64 with nodata as NaN.

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file is ("DEM", "geoid grid"), for messages.
    window_from : callable, optional
        ``window_from(transform, crs, width, height) -> (row0, row1, col0, col1)``: the node
        rows and columns to read (half-open). Whole raster when None.
    missing_error : type
        Exception raised when the file is missing or unreadable.

    Returns
    -------
    values : ndarray, shape (rows, cols), float64
    transform : affine.Affine
        Of the part read (pixel-corner convention).
    crs : pyproj.CRS or None
    """
    import rasterio
    from rasterio.errors import RasterioError
    from rasterio.windows import Window

    path = os.fspath(path)
    if not Path(path).is_file():
        raise missing_error(f"{path}: {what} file not found")
    try:
        with rasterio.open(path) as ds:
            crs = None if ds.crs is None else pyproj.CRS.from_wkt(ds.crs.to_wkt())
            if window_from is None:
                window = Window(0, 0, ds.width, ds.height)
            else:
                row0, row1, col0, col1 = window_from(ds.transform, crs, ds.width, ds.height)
                window = Window(col0, row0, col1 - col0, row1 - row0)
            band = ds.read(1, window=window, masked=True)
            scale = ds.scales[0] if ds.scales else 1.0
            offset = ds.offsets[0] if ds.offsets else 0.0
            transform = ds.window_transform(window)
    except RasterioError as err:
        raise missing_error(f"{path}: cannot be read as a {what} raster ({err})") from err
    values = np.ma.filled(band.astype(np.float64), np.nan)
    if scale != 1.0 or offset != 0.0:
        values = values * scale + offset
    return np.ascontiguousarray(values), transform, crs


def _dem_source(path):
    """``(path GDAL opens, name for messages)`` of a DEM file, or of the tiles named by ``path``.

    Several tiles are mosaicked through a GDAL VRT (:func:`sensor_models.maps.mosaic.mosaic_path`);
    messages then name the first tile and their count, not the private VRT.
    """
    from sensor_models.errors import GcpcalError
    from sensor_models.maps.mosaic import mosaic_path, raster_inputs

    if isinstance(path, (str, os.PathLike)) and Path(path).is_file():
        return os.fspath(path), os.fspath(path)
    try:
        files = raster_inputs(path, what="DEM")
        label = files[0] if len(files) == 1 else f"{files[0]} (and {len(files) - 1} more DEM tiles)"
        return mosaic_path(files, what="DEM"), label
    except GcpcalError as exc:
        if isinstance(path, (str, os.PathLike)) and "not found" in str(exc):
            raise DemError(f"{os.fspath(path)}: DEM file not found") from None
        raise


def _as_affine(transform) -> Affine:
    if isinstance(transform, Affine):
        return transform
    coeffs = tuple(float(c) for c in transform)
    if len(coeffs) not in (6, 9):
        raise InputError(
            f"transform needs the 6 affine coefficients (a, b, c, d, e, f), got {len(coeffs)}"
        )
    return Affine(*coeffs[:6])


def _apply_affine(transform: Affine, x, y):
    """``transform`` applied to arrays ``x``, ``y`` (pixel <-> CRS coordinates)."""
    return (transform.a * x + transform.b * y + transform.c,
            transform.d * x + transform.e * y + transform.f)


def _node_index_affine(transform: Affine):
    """Coefficients of ``(x, y) -> (col, row)`` node indices (first node centre at 0, 0)."""
    inv = ~transform
    return (inv.a, inv.b, inv.c - 0.5, inv.d, inv.e, inv.f - 0.5)


# ---------------------------------------------------------------------------------------------
# Geoid
# ---------------------------------------------------------------------------------------------


class Geoid:
    """A geoid undulation grid ``N(lon, lat)``: ellipsoidal height = orthometric height + N.

    Parameters
    ----------
    undulation_m : array_like, shape (rows, cols)
        Undulations in metres at the node centres; NaN where unknown.
    transform : affine.Affine or sequence of 6 floats
        Pixel-corner affine of the grid in WGS84 ``(lon, lat)`` degrees; north-up (no rotation).
        Grids over 0..360 or -180..180 degrees of longitude are both accepted.
    source : str, optional
        Where the grid came from (shown in messages).

    Notes
    -----
    Interpolation is bilinear between nodes. A grid that spans 360 degrees of longitude is
    periodic: the cell between its last and first column is interpolated across the
    antimeridian (the PROJ ``egm96_15.gtx`` grid has columns at -180, ..., 179.75 degrees).
    """

    def __init__(self, undulation_m, transform, *, source: str | None = None):
        values = np.ascontiguousarray(np.asarray(undulation_m, dtype=np.float64))
        transform = _as_affine(transform)
        if values.ndim != 2 or min(values.shape) < 2:
            raise InputError(f"a geoid grid needs at least 2 x 2 nodes, got shape {values.shape}")
        if transform.b != 0.0 or transform.d != 0.0 or transform.a <= 0.0:
            raise InputError(
                "a geoid grid must be north-up with longitude increasing along columns "
                f"(got transform {tuple(transform)[:6]})",
                path=source,
            )
        self._values = values
        self._values.setflags(write=False)
        self.transform = transform
        self.source = source
        n_rows, n_cols = values.shape
        self._dlon_deg = transform.a
        self._dlat_deg = transform.e
        self._lon0_deg = transform.c + 0.5 * transform.a
        self._lat0_deg = transform.f + 0.5 * transform.e
        self._periodic = abs(n_cols * transform.a - 360.0) < 1e-6 * transform.a

    @classmethod
    def open(cls, path) -> "Geoid":
        """Read a geoid grid (PROJ GTX, GeoTIFF, or any raster GDAL reads) in WGS84 degrees.

        Parameters
        ----------
        path : str or os.PathLike
            The grid file (e.g. ``egm96_15.gtx``): undulations in metres on a geographic grid.

        Returns
        -------
        Geoid

        Raises
        ------
        GeoidGridMissingError
            If the file is missing or cannot be read (the message names the path).
        """
        values, transform, crs = _read_raster(
            path, what="geoid grid", missing_error=GeoidGridMissingError
        )
        if crs is not None and not crs.is_geographic:
            raise GeoidGridMissingError(
                f"{os.fspath(path)}: a geoid grid must be in geographic degrees, got {crs.name}"
            )
        return cls(values, transform, source=os.fspath(path))

    def undulation_m(self, lon_deg, lat_deg) -> np.ndarray:
        """Geoid undulation ``N`` in metres, bilinear between grid nodes.

        Parameters
        ----------
        lon_deg, lat_deg : array_like
            WGS84 longitude (any branch: -180..180 or 0..360) and latitude in degrees.

        Returns
        -------
        undulation_m : ndarray
            Broadcast shape of the inputs; NaN outside the grid or next to unknown nodes.
        """
        lon, lat = np.broadcast_arrays(
            np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64)
        )
        n_rows, n_cols = self._values.shape
        col = np.mod(lon - self._lon0_deg, 360.0) / self._dlon_deg
        row = (lat - self._lat0_deg) / self._dlat_deg
        eps = 1e-9
        row_ok = (row >= -eps) & (row <= n_rows - 1 + eps)
        row = np.clip(row, 0.0, n_rows - 1)
        j0 = np.minimum(row.astype(np.intp), n_rows - 2)
        fr = row - j0
        if self._periodic:
            col_ok = np.isfinite(col)
            col = np.where(col_ok, col, 0.0)
            i0 = np.minimum(col.astype(np.intp), n_cols - 1)
            i1 = (i0 + 1) % n_cols
        else:
            col_ok = col <= n_cols - 1 + eps
            col = np.where(col_ok, np.minimum(col, n_cols - 1), 0.0)
            i0 = np.minimum(col.astype(np.intp), n_cols - 2)
            i1 = i0 + 1
        fc = col - i0
        v = self._values
        top = v[j0, i0] + fc * (v[j0, i1] - v[j0, i0])
        bottom = v[j0 + 1, i0] + fc * (v[j0 + 1, i1] - v[j0 + 1, i0])
        out = top + fr * (bottom - top)
        return np.where(row_ok & col_ok, out, np.nan)

    def __repr__(self) -> str:
        return f"Geoid(shape={self._values.shape}, source={self.source!r})"


#: File names of the EGM96 15' undulation grid in PROJ's data directories (PROJ-data's current
#: GeoTIFF name first, then the older GTX name).
PROJ_EGM96_NAMES = ("us_nga_egm96_15.tif", "egm96_15.gtx")


def proj_data_dirs() -> list[str]:
    """PROJ's data directories, in the order PROJ searches them.

    Returns
    -------
    list of str
        ``pyproj.datadir.get_data_dir()`` (may list several, separated by ``os.pathsep``) and
        ``pyproj.datadir.get_user_data_dir()``.
    """
    from pyproj import datadir

    dirs = [d for d in datadir.get_data_dir().split(os.pathsep) if d]
    dirs.append(datadir.get_user_data_dir())
    return list(dict.fromkeys(dirs))


def find_egm96_grid(dirs=None) -> str | None:
    """The EGM96 undulation grid installed in PROJ's data directories, or None.

    Parameters
    ----------
    dirs : sequence of str, optional
        Folders to look in (default :func:`proj_data_dirs`).

    Returns
    -------
    str or None
        The first of :data:`PROJ_EGM96_NAMES` found in the first folder holding one.
    """
    for folder in proj_data_dirs() if dirs is None else dirs:
        for name in PROJ_EGM96_NAMES:
            candidate = os.path.join(folder, name)
            if os.path.isfile(candidate):
                return candidate
    return None


def _as_geoid(geoid, *, dem_source) -> Geoid:
    if geoid is None:
        found = find_egm96_grid()
        if found is not None:
            return Geoid.open(found)
        where = f"{dem_source}: " if dem_source else ""
        raise GeoidGridMissingError(
            f"{where}heights are EGM96 orthometric and no geoid grid was given; none of "
            f"{', '.join(PROJ_EGM96_NAMES)} is in PROJ's data directories ({', '.join(proj_data_dirs())}); "
            "give one with --geoid GRID (geoid=<path> in Python), e.g. egm96_15.gtx from PROJ-data, or install it "
            "there (projsync --file us_nga_egm96_15.tif)"
        )
    if isinstance(geoid, Geoid):
        return geoid
    if isinstance(geoid, (str, os.PathLike)):
        return Geoid.open(geoid)
    raise InputError(f"geoid must be a path or a Geoid, got {type(geoid).__name__}")


# ---------------------------------------------------------------------------------------------
# Vertical datum from metadata
# ---------------------------------------------------------------------------------------------


def _check_datum_name(vertical_datum):
    if vertical_datum is None:
        return None
    name = str(vertical_datum).lower()
    if name not in VERTICAL_DATUMS:
        raise InputError(
            f"vertical_datum must be one of {', '.join(VERTICAL_DATUMS)}, got {vertical_datum!r}"
        )
    return name


def _declared_datum(crs: pyproj.CRS | None, *, source):
    """The vertical datum a CRS declares: 'ellipsoid', 'egm96' or None (declares nothing)."""
    if crs is None:
        return None
    if crs.is_compound:
        vertical = [c for c in crs.sub_crs_list if c.is_vertical]
        if not vertical:
            return None
        vcrs = vertical[0]
        if vcrs.to_epsg() == _EPSG_EGM96_HEIGHT or "egm96" in vcrs.name.lower():
            return "egm96"
        raise DemError(
            f"{source}: heights refer to {vcrs.name!r}, which gcpcal cannot convert; "
            "convert the DEM to WGS84 ellipsoidal or EGM96 heights first"
        )
    if crs.is_geographic and len(crs.axis_info) == 3:
        return "ellipsoid"
    return None


#: GDAL metadata item by which a raster in a projected CRS declares its vertical datum
VERTICAL_DATUM_TAG = "VERTICAL_DATUM"


def _tagged_datum(path):
    """The datum declared by the raster's ``VERTICAL_DATUM`` metadata item, or None.

    A projected CRS cannot carry "heights above the WGS84 ellipsoid" in a standard compound
    CRS, so gcpcal's own DEMs (and any user's) may say ``VERTICAL_DATUM=ellipsoid`` (or
    ``egm96``) in the dataset's default metadata domain.
    """
    import rasterio

    with rasterio.open(path) as ds:
        value = ds.tags().get(VERTICAL_DATUM_TAG)
    if value is None:
        return None
    name = value.strip().lower()
    if name not in VERTICAL_DATUMS:
        raise DemError(
            f"{path}: metadata {VERTICAL_DATUM_TAG}={value!r} is not one of {', '.join(VERTICAL_DATUMS)}"
        )
    return name


def _horizontal_crs(crs: pyproj.CRS) -> pyproj.CRS:
    if crs.is_compound:
        return crs.sub_crs_list[0]
    if len(crs.axis_info) == 3:
        return crs.to_2d()
    return crs


# ---------------------------------------------------------------------------------------------
# Ray / ellipsoid
# ---------------------------------------------------------------------------------------------


def _rays(origin_m, direction, name_o="origin_m", name_d="direction"):
    """Validate rays: (N, 3) float64 origins and unit directions, plus the batch shape."""
    o = np.asarray(origin_m, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    if o.shape[-1:] != (3,) or d.shape[-1:] != (3,):
        raise InputError(
            f"{name_o} and {name_d} need a last axis of length 3, got {o.shape} and {d.shape}"
        )
    shape = np.broadcast_shapes(o.shape, d.shape)[:-1]
    o = np.broadcast_to(o, shape + (3,)).reshape(-1, 3)
    d = np.broadcast_to(d, shape + (3,)).reshape(-1, 3)
    for label, a in ((name_o, o), (name_d, d)):
        if not np.all(np.isfinite(a)):
            raise InputError(f"{label} holds NaN or infinite values")
    norm = np.sqrt(np.einsum("ij,ij->i", d, d))
    if np.any(norm == 0.0):
        raise InputError(f"{name_d} holds zero-length vectors")
    return np.ascontiguousarray(o), d / norm[:, None], shape


def _scaled_ellipsoid(o, d, height_m):
    """Quadratic ``A t^2 + 2 B t + C = 0`` of the ray with the (a + h, b + h) ellipsoid."""
    ax = WGS84_A_M + height_m
    bz = WGS84_B_M + height_m
    ox, oy, oz = o[:, 0] / ax, o[:, 1] / ax, o[:, 2] / bz
    dx, dy, dz = d[:, 0] / ax, d[:, 1] / ax, d[:, 2] / bz
    a_ = dx * dx + dy * dy + dz * dz
    b_ = ox * dx + oy * dy + oz * dz
    c_ = ox * ox + oy * oy + oz * oz - 1.0
    return a_, b_, c_, b_ * b_ - a_ * c_


def _first_root_t(a_, b_, c_, disc):
    """Smallest root ``t >= 0`` (near root from outside, exit from inside); NaN if none."""
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -(b_ + np.copysign(sq, b_))
        t1 = q / a_
        t2 = c_ / q
        near = np.fmin(t1, t2)
        far = np.fmax(t1, t2)
        t = np.where(c_ > 0.0, np.where(near >= 0.0, near, np.nan), far)
    return np.where(disc >= 0.0, t, np.nan)


def _up(lon_deg, lat_deg):
    lon = np.radians(lon_deg)
    lat = np.radians(lat_deg)
    cl = np.cos(lat)
    return np.stack([cl * np.cos(lon), cl * np.sin(lon), np.sin(lat)], axis=-1)


def intersect_ellipsoid(origin_m, direction, height_m, *, max_iter: int = 10) -> np.ndarray:
    """Intersect rays with the surface of constant geodetic height ``height_m`` (WGS84).

    The start is the near root of the ray with the ellipsoid of semi-axes ``(a + h, b + h)``;
    Newton steps along the ray on the true geodetic height then run until
    ``|h(p) - height_m| < 1e-6 m``. The gradient of the geodetic height in ECEF is the unit
    ellipsoid normal ``n`` at the foot point, so each step is ``t -= (h(p) - height_m) / (n . d)``.

    Parameters
    ----------
    origin_m : array_like, shape (..., 3)
        Ray origins in ITRF metres (e.g. satellite positions).
    direction : array_like, shape (..., 3)
        Ray directions in ITRF (normalised here).
    height_m : float or array_like, shape (...)
        Geodetic height above the WGS84 ellipsoid of the surface to hit, per ray or scalar.
    max_iter : int
        Newton steps at most (one or two are needed except for grazing rays).

    Returns
    -------
    xyz_m : ndarray, shape (..., 3)
        ``origin + t * direction / |direction|`` with the smallest ``t >= 0`` on the surface:
        the near intersection for an origin above the surface (the exit for one below it).
        NaN for rays that miss the surface, point away from it, or graze it so closely that
        the Newton steps do not converge.

    Raises
    ------
    InputError
        On malformed shapes, non-finite inputs or zero directions.
    """
    o, d, shape = _rays(origin_m, direction)
    h_target = np.asarray(height_m, dtype=np.float64)
    try:
        h_target = np.broadcast_to(h_target, shape).reshape(-1)
    except ValueError as err:
        raise InputError(
            f"height_m of shape {np.shape(height_m)} does not match {shape} rays"
        ) from err
    if not np.all(np.isfinite(h_target)):
        raise InputError("height_m holds NaN or infinite values")
    t = _newton_on_height(o, d, h_target, _first_root_t(*_scaled_ellipsoid(o, d, h_target)),
                          max_iter=max_iter)
    xyz = o + t[:, None] * d
    return xyz.reshape(shape + (3,))


def _newton_on_height(o, d, h_target, t, *, max_iter):
    t = t.copy()
    todo = np.nonzero(np.isfinite(t))[0]
    for _ in range(max_iter):
        if todo.size == 0:
            break
        p = o[todo] + t[todo, None] * d[todo]
        lon, lat, h = ecef_to_geodetic(p)
        dh = h - h_target[todo]
        done = np.abs(dh) < _ELLIPSOID_TOL_M
        todo, dh, lon, lat = todo[~done], dh[~done], lon[~done], lat[~done]
        slope = np.einsum("ij,ij->i", _up(lon, lat), d[todo])
        with np.errstate(divide="ignore", invalid="ignore"):
            t[todo] -= dh / slope
        bad = ~np.isfinite(t[todo])
        t[todo[bad]] = np.nan
        todo = todo[~bad]
    if todo.size:
        p = o[todo] + t[todo, None] * d[todo]
        still = np.abs(ecef_to_geodetic(p)[2] - h_target[todo]) >= _ELLIPSOID_TOL_M
        t[todo[still]] = np.nan
    return t


# ---------------------------------------------------------------------------------------------
# DEM
# ---------------------------------------------------------------------------------------------


class _GridGeometry:
    """WGS84 lon/lat <-> node indices ``(col, row)`` of a grid (first node centre at 0, 0).

    A grid in a geographic CRS that PROJ maps identically from WGS84 uses its affine alone
    (fast path, with longitudes wrapped onto the grid's 360-degree branch when the grid runs
    past +-180); any other CRS goes through a PROJ transformation first.
    """

    def __init__(self, transform: Affine, crs: pyproj.CRS, shape):
        self.transform = transform
        self.index_coeffs = _node_index_affine(transform)
        self.to_grid = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        self.from_grid = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
        self.plain_lonlat = False
        self.wrap_west_deg = None
        if crs.is_geographic:
            n_rows, n_cols = shape
            xs, ys = _apply_affine(transform, np.array([0.5, n_cols - 0.5, 0.5, n_cols - 0.5]),
                                   np.array([0.5, 0.5, n_rows - 0.5, n_rows - 0.5]))
            lon, lat = self.from_grid.transform(xs, ys)
            if (np.allclose(lon, xs, rtol=0.0, atol=1e-10)
                    and np.allclose(lat, ys, rtol=0.0, atol=1e-10)):
                self.plain_lonlat = True
                west = float(np.min(xs)) - 0.5 * abs(transform.a)
                if west < -180.0 or float(np.max(xs)) > 180.0:
                    self.wrap_west_deg = west

    def lonlat_to_index(self, lon_deg, lat_deg):
        """Node indices ``(col, row)`` of WGS84 points; inf where PROJ cannot map them."""
        if self.plain_lonlat:
            x, y = lon_deg, lat_deg
            if self.wrap_west_deg is not None:
                x = self.wrap_west_deg + np.mod(x - self.wrap_west_deg, 360.0)
        else:
            x, y = self.to_grid.transform(lon_deg, lat_deg)
            x = np.asarray(x, dtype=np.float64)
            y = np.asarray(y, dtype=np.float64)
        a, b, c, d, e, f = self.index_coeffs
        return a * x + b * y + c, d * x + e * y + f

    def index_to_lonlat(self, col, row):
        """WGS84 ``(lon, lat)`` in degrees of node indices."""
        x, y = _apply_affine(self.transform, np.asarray(col, dtype=np.float64) + 0.5,
                             np.asarray(row, dtype=np.float64) + 0.5)
        if self.plain_lonlat:
            return x, y
        lon, lat = self.from_grid.transform(x, y)
        return np.asarray(lon), np.asarray(lat)


class Dem:
    """A digital elevation model holding WGS84 ellipsoidal heights, with ray intersection.

    Build one with :meth:`open` (a raster file) or :meth:`from_array` (synthetic terrain).
    Heights are converted to ellipsoidal heights once, at construction.

    Parameters
    ----------
    heights_m : array_like, shape (rows, cols)
        Ellipsoidal heights in metres at the node centres; NaN where there are no data.
    transform : affine.Affine or sequence of 6 floats
        Pixel-corner affine ``(a, b, c, d, e, f)`` from (col, row) pixel coordinates to the
        DEM's horizontal CRS, as rasterio and GDAL give it.
    crs : pyproj.CRS or anything pyproj accepts
        Horizontal CRS of the grid, geographic or projected, any datum PROJ transforms from
        WGS84.
    source : str, optional
        Where the heights came from (shown in messages).

    Attributes
    ----------
    transform : affine.Affine
    crs : pyproj.CRS
    shape : tuple of int
    source : str or None
    """

    def __init__(self, heights_m, transform, crs, *, source: str | None = None):
        z = np.ascontiguousarray(np.asarray(heights_m, dtype=np.float64))
        if z.ndim != 2 or min(z.shape) < 2:
            raise InputError(f"a DEM needs at least 2 x 2 nodes, got shape {z.shape}", path=source)
        self.source = source
        self.transform = _as_affine(transform)
        self.crs = _horizontal_crs(pyproj.CRS.from_user_input(crs))
        self.shape = z.shape
        valid = np.isfinite(z)
        if not valid.any():
            raise DemError(f"{source or 'DEM'}: holds no valid height (all nodata)")
        self._z = z
        self._z.setflags(write=False)
        self._z_flat = z.reshape(-1)
        self._h_min = float(z[valid].min())
        self._h_max = float(z[valid].max())
        self._geometry = _GridGeometry(self.transform, self.crs, self.shape)
        # Upper bound of the bilinear surface over any march step starting in cell (j, i):
        # such a step stays within cells j-1..j+1, i-1..i+1, i.e. nodes j-1..j+2, i-1..i+2.
        z_inf = np.where(valid, z, np.inf)
        dmax = ndimage.maximum_filter(z_inf, size=4, mode="constant", cval=np.inf, origin=-1)
        self._cell_max_flat = _float32_bound(dmax[:-1, :-1], upper=True).reshape(-1)
        self._pyramid = _RangePyramid(z)
        self._bounds_lonlat = self._lonlat_box()
        lon0, lat0, lon1, lat1 = self._bounds_lonlat
        if not (np.isfinite([lon0, lon1]).all() and -90.0 <= lat0 <= lat1 <= 90.0):
            raise DemError(
                f"{source or 'DEM'}: its grid does not map to valid WGS84 coordinates through "
                f"{self.crs.name!r} (lat {lat0}..{lat1}); check the transform and CRS"
            )
        self._resolution_m = self._ground_spacing_m()

    # -- construction ---------------------------------------------------------------------

    @classmethod
    def open(
        cls,
        path,
        *,
        vertical_datum: str | None = None,
        geoid=None,
        bounds=None,
        margin_deg: float = 0.05,
    ) -> "Dem":
        """Read a DEM raster (any format and CRS rasterio reads), optionally a window of it.

        Parameters
        ----------
        path : str, os.PathLike or sequence of them
            A raster; or tiles (SRTM ``.hgt``, Copernicus GLO-30 ``*_DEM.tif``, any GeoTIFF)
            given as a list, a comma list, a folder, a glob or a ``.vrt``: mosaicked through a
            GDAL VRT (:func:`sensor_models.maps.mosaic.mosaic_path`) and read by window.
        vertical_datum : {"ellipsoid", "egm96"}, optional
            What the heights refer to. When None it is taken from the raster's CRS if that
            declares one (a compound CRS whose vertical part is EPSG:5773 "EGM96 height", or a
            3-D geographic CRS meaning ellipsoidal heights); SRTM ``.hgt`` declares nothing, so
            the caller must say ``"egm96"``. A value contradicting the metadata is an error.
        geoid : str, os.PathLike or Geoid, optional
            EGM96 undulation grid for EGM96 heights (default: :func:`find_egm96_grid` in PROJ's
            data directories; an error naming them when absent), refused when the caller says
            ``"ellipsoid"``, unused when the file itself declares ellipsoidal heights.
        bounds : tuple of 4 floats, optional
            ``(lon_min, lat_min, lon_max, lat_max)`` in WGS84 degrees: read only the part of
            the raster covering this box plus ``margin_deg`` (windowed read).
        margin_deg : float
            Margin around ``bounds`` in degrees (0.05 deg ~ 5 km leaves room for oblique rays).

        Returns
        -------
        Dem

        Raises
        ------
        DemError
            File missing or unreadable, no vertical datum declared or given, ``bounds`` outside
            the raster, no valid heights, geoid grid not covering the DEM.
        GeoidGridMissingError
            EGM96 heights and no (or a missing) geoid grid.
        InputError
            Unknown ``vertical_datum``, malformed ``bounds``, a geoid with ``"ellipsoid"``.
        """
        gdal_path, source = _dem_source(path)
        datum = _check_datum_name(vertical_datum)
        if datum == "ellipsoid" and geoid is not None:
            raise InputError("geoid is only used with vertical_datum='egm96'", path=source)
        window_from = None
        if bounds is not None:
            window_from = _window_for_bounds(bounds, margin_deg, source=source)
        values, transform, crs = _read_raster(gdal_path, what="DEM", window_from=window_from)
        if crs is None:
            raise DemError(f"{source}: the DEM declares no coordinate reference system")
        declared = _declared_datum(crs, source=source)
        if declared is None:
            declared = _tagged_datum(gdal_path)
        if datum is None:
            if declared is None:
                raise DemError(
                    f"{source}: the DEM does not declare its vertical datum; say --dem-datum egm96 "
                    "(orthometric heights, e.g. SRTM) or --dem-datum ellipsoid (heights above WGS84); "
                    "in Python: vertical_datum='egm96' or 'ellipsoid'"
                )
            datum = declared
        elif declared is not None and declared != datum:
            raise DemError(
                f"{source}: vertical_datum={datum!r} contradicts the datum the file declares "
                f"({declared!r})"
            )
        return cls._with_datum(values, transform, crs, datum, geoid, source=source)

    @classmethod
    def from_array(
        cls, heights_m, transform, crs, *, vertical_datum: str = "ellipsoid", geoid=None
    ) -> "Dem":
        """A DEM from an in-memory height grid (synthetic terrain, simulation, tests).

        Parameters
        ----------
        heights_m : array_like, shape (rows, cols)
            Heights in metres at the node centres; NaN for no data.
        transform : affine.Affine or sequence of 6 floats
            Pixel-corner affine of the grid, as rasterio gives it.
        crs : pyproj.CRS or anything pyproj accepts
            CRS of the grid; a compound CRS's vertical part must agree with ``vertical_datum``.
        vertical_datum : {"ellipsoid", "egm96"}
            Datum of ``heights_m``: ellipsoidal heights, or EGM96 orthometric heights converted
            with ``geoid``.
        geoid : str, os.PathLike or Geoid, optional
            Required when ``vertical_datum="egm96"``.

        Returns
        -------
        Dem
            Holding ellipsoidal heights.
        """
        datum = _check_datum_name(vertical_datum)
        if datum is None:
            raise InputError("vertical_datum must be given for an in-memory DEM")
        if datum == "ellipsoid" and geoid is not None:
            raise InputError("geoid is only used with vertical_datum='egm96'")
        crs = pyproj.CRS.from_user_input(crs)
        declared = _declared_datum(crs, source="in-memory DEM")
        if declared is not None and declared != datum:
            raise DemError(
                f"vertical_datum={datum!r} contradicts the datum of the CRS {crs.name!r} "
                f"({declared!r})"
            )
        values = np.array(heights_m, dtype=np.float64)
        return cls._with_datum(values, transform, crs, datum, geoid, source=None)

    @classmethod
    def _with_datum(cls, values, transform, crs, datum, geoid, *, source):
        if datum == "egm96":
            grid = _as_geoid(geoid, dem_source=source)
            geometry = _GridGeometry(_as_affine(transform), _horizontal_crs(crs), values.shape)
            n_rows, n_cols = values.shape
            cols, rows = np.meshgrid(np.arange(n_cols, dtype=np.float64),
                                     np.arange(n_rows, dtype=np.float64))
            lon, lat = geometry.index_to_lonlat(cols, rows)
            undulation = grid.undulation_m(lon, lat)
            uncovered = np.isfinite(values) & ~np.isfinite(undulation)
            if uncovered.any():
                raise DemError(
                    f"{source or 'DEM'}: the geoid grid {grid.source or ''} does not cover "
                    f"{int(uncovered.sum())} DEM nodes"
                )
            values = values + undulation
        return cls(values, transform, crs, source=source)

    # -- geometry of the grid -------------------------------------------------------------

    def _lonlat_to_index(self, lon_deg, lat_deg):
        """WGS84 lon/lat (deg) to node indices ``(col, row)`` (first node centre at 0, 0)."""
        return self._geometry.lonlat_to_index(lon_deg, lat_deg)

    def _ground_spacing_m(self) -> float:
        n_rows, n_cols = self.shape
        j, i = (n_rows - 1) // 2, (n_cols - 1) // 2
        lon, lat = self._geometry.index_to_lonlat(np.array([i, i + 1, i]), np.array([j, j, j + 1]))
        p = geodetic_to_ecef(lon, lat, 0.0)
        return float(min(np.linalg.norm(p[1] - p[0]), np.linalg.norm(p[2] - p[0])))

    def _lonlat_box(self):
        n_rows, n_cols = self.shape
        # Border of the node-centre hull, densified so that projected edges are followed.
        c = np.linspace(0.0, n_cols - 1.0, 33)
        r = np.linspace(0.0, n_rows - 1.0, 33)
        cols = np.concatenate([c, c, np.zeros(33), np.full(33, n_cols - 1.0)])
        rows = np.concatenate([np.zeros(33), np.full(33, n_rows - 1.0), r, r])
        lon, lat = self._geometry.index_to_lonlat(cols, rows)
        return (float(np.min(lon)), float(np.min(lat)), float(np.max(lon)), float(np.max(lat)))

    # -- public properties ----------------------------------------------------------------

    @property
    def bounds_lonlat(self) -> tuple[float, float, float, float]:
        """``(lon_min, lat_min, lon_max, lat_max)`` in degrees enclosing the node centres.

        Heights are defined between node centres (bilinear), so this is the area where
        :meth:`height_m` can be finite. For a projected DEM it is the box enclosing the
        (non-rectangular) covered area.
        """
        return self._bounds_lonlat

    @property
    def height_range_m(self) -> tuple[float, float]:
        """``(min, max)`` of the valid ellipsoidal heights in metres."""
        return (self._h_min, self._h_max)

    def height_range_over_m(self, lon_deg, lat_deg, *, margin_nodes: int = 2) -> tuple[float, float] | None:
        """``(min, max)`` of the valid node heights over the node box that holds the given points.

        Parameters
        ----------
        lon_deg, lat_deg : array_like, shape (N,)
            WGS84 degrees (e.g. a footprint localized at the DEM's lowest and highest heights).
        margin_nodes : int
            Nodes added on every side of the points' bounding box in node indices.

        Returns
        -------
        tuple of float or None
            Metres above the ellipsoid; None when no point maps onto the grid or the box holds
            no valid node.
        """
        col, row = self._lonlat_to_index(np.ravel(np.asarray(lon_deg, dtype=np.float64)),
                                         np.ravel(np.asarray(lat_deg, dtype=np.float64)))
        ok = np.isfinite(col) & np.isfinite(row)
        if not ok.any():
            return None
        n_rows, n_cols = self.shape
        c0 = int(np.clip(np.floor(col[ok].min()) - margin_nodes, 0, n_cols))
        c1 = int(np.clip(np.ceil(col[ok].max()) + margin_nodes + 1, 0, n_cols))
        r0 = int(np.clip(np.floor(row[ok].min()) - margin_nodes, 0, n_rows))
        r1 = int(np.clip(np.ceil(row[ok].max()) + margin_nodes + 1, 0, n_rows))
        z = self._z[r0:r1, c0:c1]
        z = z[np.isfinite(z)]
        return None if z.size == 0 else (float(z.min()), float(z.max()))

    @property
    def resolution_m(self) -> float:
        """Approximate ground spacing of the nodes in metres (the smaller of the two axes)."""
        return self._resolution_m

    @property
    def heights_m(self) -> np.ndarray:
        """Ellipsoidal heights at the nodes, shape (rows, cols), NaN for no data (read-only)."""
        return self._z

    def __repr__(self) -> str:
        return (
            f"Dem(shape={self.shape}, crs={self.crs.name!r}, bounds_lonlat={self.bounds_lonlat}, "
            f"height_range_m={self.height_range_m}, source={self.source!r})"
        )

    # -- sampling -------------------------------------------------------------------------

    def height_m(self, lon_deg, lat_deg) -> np.ndarray:
        """Ellipsoidal height of the DEM surface, bilinear between nodes.

        Parameters
        ----------
        lon_deg, lat_deg : array_like
            WGS84 longitude and latitude in degrees.

        Returns
        -------
        h_m : ndarray
            Broadcast shape of the inputs. NaN outside the node-centre hull and wherever one
            of the four surrounding nodes has no data.
        """
        lon, lat = np.broadcast_arrays(
            np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64)
        )
        col, row = self._lonlat_to_index(lon.reshape(-1), lat.reshape(-1))
        return self._bilinear(col, row).reshape(lon.shape)

    def coverage_fraction(self, lon_deg, lat_deg) -> float:
        """Share of the points that lie inside the DEM's grid (voids count as covered).

        Parameters
        ----------
        lon_deg, lat_deg : array_like, shape (N,)
            WGS84 longitude and latitude in degrees, e.g. a grid over a scene's footprint
            (non-finite points count as not covered).

        Returns
        -------
        float
            In ``[0, 1]``: 1 when every point lies within the node-centre hull of the grid.
        """
        lon, lat = np.broadcast_arrays(np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64))
        if lon.size == 0:
            return 0.0
        with np.errstate(invalid="ignore"):
            col, row = self._lonlat_to_index(lon.reshape(-1), lat.reshape(-1))
        n_rows, n_cols = self.shape
        inside = (col >= 0.0) & (col <= n_cols - 1) & (row >= 0.0) & (row <= n_rows - 1)
        return float(np.count_nonzero(inside) / lon.size)

    def void_fraction(self, lon_deg, lat_deg) -> float:
        """Share of the covered points where the DEM has no height (a void next to a node).

        Parameters
        ----------
        lon_deg, lat_deg : array_like, shape (N,)
            WGS84 longitude and latitude in degrees.

        Returns
        -------
        float
            In ``[0, 1]``, among the points inside the grid (:meth:`coverage_fraction`); 0 when
            none is inside.
        """
        lon, lat = np.broadcast_arrays(np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64))
        with np.errstate(invalid="ignore"):
            col, row = self._lonlat_to_index(lon.reshape(-1), lat.reshape(-1))
        n_rows, n_cols = self.shape
        inside = (col >= 0.0) & (col <= n_cols - 1) & (row >= 0.0) & (row <= n_rows - 1)
        if not inside.any():
            return 0.0
        h = self._bilinear(col[inside], row[inside])
        return float(np.count_nonzero(~np.isfinite(h)) / h.size)

    def _bilinear(self, col, row):
        n_rows, n_cols = self.shape
        inside = (col >= 0.0) & (col <= n_cols - 1) & (row >= 0.0) & (row <= n_rows - 1)
        col = np.where(inside, col, 0.0)
        row = np.where(inside, row, 0.0)
        i = np.minimum(col.astype(np.intp), n_cols - 2)
        j = np.minimum(row.astype(np.intp), n_rows - 2)
        z = self._cell_values(i, j, col - i, row - j)
        return np.where(inside, z, np.nan)

    def _cell_values(self, i, j, fc, fr):
        """Bilinear polynomial of cell (j, i) at fractional offsets (may lie outside [0, 1])."""
        n_cols = self.shape[1]
        k = j * n_cols + i
        zf = self._z_flat
        z00 = zf.take(k)
        z01 = zf.take(k + 1)
        z10 = zf.take(k + n_cols)
        z11 = zf.take(k + n_cols + 1)
        top = z00 + fc * (z01 - z00)
        bottom = z10 + fc * (z11 - z10)
        return top + fr * (bottom - top)

    def _residual_exact(self, o, d, t):
        """``h_ray - h_dem`` at ``o + t d`` with exact geodetic and CRS conversions."""
        xyz = o + t[:, None] * d
        lon, lat, h = ecef_to_geodetic(xyz)
        col, row = self._lonlat_to_index(lon, lat)
        return h - self._bilinear(col, row), lon, lat, h, xyz

    # -- ray intersection -----------------------------------------------------------------

    def intersect(self, origin_m, direction, *, outside="nan"):
        """Intersect ITRF rays with the DEM surface: the first crossing along each ray.

        Parameters
        ----------
        origin_m : array_like, shape (..., 3)
            Ray origins in ITRF metres, above the terrain (e.g. satellite positions).
        direction : array_like, shape (..., 3)
            Ray directions in ITRF, towards the Earth (normalised here).
        outside : {"nan", "raise"} or float
            What to do with a ray that has no valid crossing: its path between the DEM's
            highest height and the surface leaves the DEM or passes over nodata ("left the
            DEM"), it does not reach the DEM's height range ("missed"), or its origin lies
            under the surface. ``"nan"``: NaN outputs for those rays. ``"raise"``:
            :class:`DemError` saying how many rays failed and the DEM's bounds. A float:
            intersect those rays with the ellipsoidal height ``outside`` in metres instead
            (:func:`intersect_ellipsoid`; NaN if they miss that too).

        Returns
        -------
        lon_deg, lat_deg, h_m : ndarray, shape (...)
            Geodetic coordinates of the intersection; ``h_m`` is ellipsoidal and equals
            :meth:`height_m` there to better than 1e-4 m.
        xyz_m : ndarray, shape (..., 3)
            ITRF point ``origin + t * direction / |direction|``, exactly on the ray.

        Notes
        -----
        The first crossing is the first ``t`` where ``h_ray(t) - h_dem(t)`` changes sign
        going from the satellite down: the visible surface, on slopes steeper than the ray
        and on one-pixel spikes alike (see the module docstring for the method). Memory is
        bounded by processing rays in chunks of 32 768.
        """
        fallback_h = None
        if isinstance(outside, str):
            if outside not in ("nan", "raise"):
                raise InputError(f"outside must be 'nan', 'raise' or a height in metres, "
                                 f"got {outside!r}")
        else:
            try:
                fallback_h = float(outside)
            except (TypeError, ValueError) as err:
                raise InputError(f"outside must be 'nan', 'raise' or a height in metres, "
                                 f"got {outside!r}") from err
            if not math.isfinite(fallback_h):
                raise InputError("outside must be a finite height in metres")
        o, d, shape = _rays(origin_m, direction)
        n = o.shape[0]
        t = np.full(n, np.nan)
        status = np.zeros(n, dtype=np.int8)
        geo = np.full((n, 3), np.nan)
        for start in range(0, n, _CHUNK_RAYS):
            sl = slice(start, min(start + _CHUNK_RAYS, n))
            t[sl], status[sl], geo[sl] = self._intersect_chunk(o[sl], d[sl])
        failed = status != _HIT
        if failed.any():
            if outside == "raise":
                counts = {k: int(np.count_nonzero(status == k))
                          for k in (_LEFT_DEM, _MISSED, _UNDERGROUND)}
                lon0, lat0, lon1, lat1 = self.bounds_lonlat
                raise DemError(
                    f"{int(failed.sum())} of {n} rays have no ground point on the DEM "
                    f"{self.source or ''} (lon {lon0:.6f}..{lon1:.6f}, lat {lat0:.6f}..{lat1:.6f} "
                    f"deg): {counts[_LEFT_DEM]} leave it or meet nodata before reaching the "
                    f"surface, {counts[_MISSED]} miss its height range, {counts[_UNDERGROUND]} "
                    "start under it; read a larger DEM or pass outside='nan' or a fallback height"
                )
            if fallback_h is not None:
                idx = np.nonzero(failed)[0]
                a_, b_, c_, disc = _scaled_ellipsoid(o[idx], d[idx], fallback_h)
                h_fb = np.full(idx.size, fallback_h)
                t[idx] = _newton_on_height(o[idx], d[idx], h_fb, _first_root_t(a_, b_, c_, disc),
                                           max_iter=10)
                geo[idx] = np.stack(ecef_to_geodetic(o[idx] + t[idx, None] * d[idx]), axis=1)
            else:
                t[failed] = np.nan
        xyz = o + t[:, None] * d
        return (geo[:, 0].reshape(shape), geo[:, 1].reshape(shape), geo[:, 2].reshape(shape),
                xyz.reshape(shape + (3,)))

    def _intersect_chunk(self, o, d):
        """First crossing for a chunk of rays.

        Returns ``t`` (n,), ``status`` (n,) and ``lon, lat, h`` of the hits, shape (n, 3).
        """
        n = o.shape[0]
        status = np.zeros(n, dtype=np.int8)
        t_hit = np.full(n, np.nan)
        geo = np.full((n, 3), np.nan)

        # 1. Bracket between the DEM's top and bottom heights (padded).
        t_top, t_bot = self._bracket(o, d, status)
        idx = np.nonzero(status == _PENDING)[0]
        if idx.size == 0:
            return t_hit, status, geo
        o_a, d_a, t0, t1 = o[idx], d[idx], t_top[idx], t_bot[idx]

        # 2. Cubic model of (h, col, row) along the bracket from 4 exact points; an origin
        # inside the bracket may already be under the surface.
        coef, under = self._ray_model(o_a, d_a, t0, t1)
        status[idx[under]] = _UNDERGROUND

        # 3. Narrow the bracket to where the ray may meet the surface.
        s0, ds, n_steps = self._narrow(coef, under)

        # 4. March: skip steps that stay above the local DEM maximum; solve the others.
        s_hit = self._march(coef, s0, ds, n_steps, under, status, idx)

        # 5. Exact check and polish on the true geometry.
        hit = np.nonzero(status[idx] == _HIT)[0]
        t_root = t0[hit] + s_hit[hit] * (t1[hit] - t0[hit])
        t_root, geo_root = self._polish(o_a[hit], d_a[hit], t_root,
                                        (t1[hit] - t0[hit]) * ds[hit] / n_steps[hit])
        t_hit[idx[hit]] = t_root
        geo[idx[hit]] = geo_root
        lost = ~np.isfinite(t_root)
        status[idx[hit[lost]]] = _LEFT_DEM
        return t_hit, status, geo

    def _bracket(self, o, d, status):
        """Ray parameters ``(t_top, t_bot)`` (n,) at the padded highest and lowest DEM heights.

        Marks rays starting under the lowest height ``_UNDERGROUND`` and rays that never reach
        the height range ``_MISSED`` in ``status`` (n,), in place.
        """
        top = _scaled_ellipsoid(o, d, self._h_max + _BRACKET_PAD_M)
        t_top = np.where(top[2] <= 0.0, 0.0, _first_root_t(*top))
        bot = _scaled_ellipsoid(o, d, self._h_min - _BRACKET_PAD_M)
        t_bot = _first_root_t(*bot)
        with np.errstate(invalid="ignore", divide="ignore"):
            vertex = -bot[1] / bot[0]
        t_bot = np.where(np.isnan(t_bot) & (bot[3] < 0.0), vertex, t_bot)
        status[bot[2] <= 0.0] = _UNDERGROUND
        status[(status == _PENDING) & ~(np.isfinite(t_top) & (t_bot > t_top))] = _MISSED
        return t_top, t_bot

    def _ray_model(self, o_a, d_a, t0, t1):
        """Cubic model in ``s`` of (h, col, row) on ``[t0, t1]`` and the rays starting underground.

        Returns ``coef`` (m, 3, 4), monomial coefficients in ``s = (t - t0) / (t1 - t0)``, and
        ``under`` (m,) bool: the ray's first node lies on or under the surface.
        """
        t_nodes = t0[:, None] + _MODEL_S[None, :] * (t1 - t0)[:, None]
        p_nodes = o_a[:, None, :] + t_nodes[:, :, None] * d_a[:, None, :]
        lon, lat, h = ecef_to_geodetic(p_nodes)
        col, row = self._lonlat_to_index(lon.reshape(-1), lat.reshape(-1))
        values = np.stack([h, col.reshape(h.shape), row.reshape(h.shape)], axis=1)  # (m, 3, 4)
        coef = values @ _MODEL_VINV.T  # monomial coefficients in s, (m, 3, 4)
        f_start = h[:, 0] - self._bilinear(values[:, 1, 0], values[:, 2, 0])
        return coef, f_start <= 0.0

    def _narrow(self, coef, under):
        """Narrow ``[0, 1]`` in ``s`` and cut it into march steps.

        The ray cannot meet the surface while it is above the highest node under its remaining
        path, and has met it once below the lowest one. Returns ``s0`` (m,), ``ds`` (m,) and
        ``n_steps`` (m,) int: steps under ``_MAX_STEP_NODES`` DEM nodes each.
        """
        s0 = np.zeros(coef.shape[0])
        s1 = np.ones(coef.shape[0])
        for _ in range(_NARROWING_ROUNDS):
            _, c01, r01 = _eval_model(coef, np.stack([s0, s1], axis=1))
            top_m, bottom_m = self._pyramid.range_over_box(c01, r01)
            s0_new = _solve_model_height(coef, top_m + _BRACKET_PAD_M, s0, s1)
            s1_new = _solve_model_height(coef, bottom_m - _BRACKET_PAD_M, s0, s1)
            s0 = np.where(np.isfinite(s0_new), s0_new, s0)
            s1 = np.where(np.isfinite(s1_new), np.maximum(s1_new, s0), s1)
        s0 = np.where(under, 0.0, s0)
        _, c01, r01 = _eval_model(coef, np.stack([s0, s1], axis=1))
        variation = np.maximum(np.abs(c01[:, 1] - c01[:, 0]), np.abs(r01[:, 1] - r01[:, 0]))
        n_steps = np.maximum(1, np.ceil(variation / _MAX_STEP_NODES)).astype(np.int64)
        return s0, s1 - s0, n_steps

    def _march(self, coef, s0, ds, n_steps, under, status, idx):
        """March every ray not ``under`` along its steps, blocks of steps at once.

        Sets ``status[idx]`` to ``_HIT``, ``_LEFT_DEM`` or ``_MISSED`` in place and returns
        ``s_hit`` (m,): the root's ``s`` for hits, NaN otherwise.
        """
        s_hit = np.full(idx.size, np.nan)
        k_cur = np.zeros(idx.size, dtype=np.int64)
        active = np.nonzero(~under)[0]
        while active.size:
            # Steps evaluated together: a block, or fewer when every ray is nearly done.
            block = int(min(_BLOCK_STEPS, np.max(n_steps[active] - k_cur[active])))
            ks = k_cur[active, None] + np.arange(block + 1)
            ka = n_steps[active, None]
            maybe = self._steps_that_may_cross(coef[active], s0[active, None] + ds[active, None] * (np.minimum(ks, ka) / ka))
            maybe &= ks[:, :-1] < ka
            found_any = maybe.any(axis=1)
            first = maybe.argmax(axis=1)

            # Rays with nothing in this block move on (or, past their last step, missed).
            quiet = active[~found_any]
            k_cur[quiet] += block
            ended = quiet[k_cur[quiet] >= n_steps[quiet]]
            status[idx[ended]] = _MISSED

            cand = active[found_any]
            k = k_cur[cand] + first[found_any]
            ka_c = n_steps[cand]
            got, left, s_root = self._first_root_in_step(
                coef[cand], s0[cand] + ds[cand] * (k / ka_c), s0[cand] + ds[cand] * ((k + 1) / ka_c)
            )
            s_hit[cand[got]] = s_root[got]
            status[idx[cand[got]]] = _HIT
            status[idx[cand[left]]] = _LEFT_DEM
            none = ~got & ~left
            k_cur[cand[none]] = k[none] + 1
            ended = cand[none][k_cur[cand[none]] >= ka_c[none]]
            status[idx[ended]] = _MISSED
            active = np.nonzero(status[idx] == _PENDING)[0]
            active = active[~under[active]]
        return s_hit

    def _steps_that_may_cross(self, coef, s):
        """For step ends ``s`` (m, k + 1): steps (m, k) whose lower end is not above the cell maximum."""
        n_rows, n_cols = self.shape
        hs, cs, rs = _eval_model(coef, s)
        ci = np.floor(cs)
        ri = np.floor(rs)
        inside = (ci >= 0) & (ci <= n_cols - 2) & (ri >= 0) & (ri <= n_rows - 2)
        cell = np.where(inside, ri * (n_cols - 1) + ci, 0).astype(np.intp)
        bound = np.where(inside, self._cell_max_flat.take(cell), np.inf)
        return np.minimum(hs[:, :-1], hs[:, 1:]) <= bound[:, :-1]

    def _first_root_in_step(self, coef, s_a, s_b):
        """First root of ``h - z`` on the model between ``s_a`` and ``s_b`` (one march step).

        The step is split where the ray's track crosses grid lines (at most one column and one
        row line: steps are under half a node spacing). Each piece lies in one cell, where
        ``f = h - z`` is close to a quadratic in the parameter: the quadratic through the
        piece's ends and middle locates the first root, and two Newton steps on the model
        ``f`` itself make it exact (to the model's accuracy, far below 1e-6 m).

        Returns
        -------
        found, left : ndarray of bool, shape (m,)
            A root was found; the step left the grid or met nodata before any root.
        s_root : ndarray, shape (m,)
        """
        n_rows, n_cols = self.shape
        ends = np.stack([s_a, s_b], axis=1)
        _, c_ab, r_ab = _eval_model(coef, ends)
        u_col = _grid_line_crossing(coef, 1, s_a, s_b, c_ab[:, 0], c_ab[:, 1])
        u_row = _grid_line_crossing(coef, 2, s_a, s_b, r_ab[:, 0], r_ab[:, 1])
        breaks = [np.zeros_like(s_a), np.fmin(u_col, u_row), np.fmax(u_col, u_row),
                  np.ones_like(s_a)]
        m = s_a.size
        found = np.zeros(m, dtype=bool)
        left = np.zeros(m, dtype=bool)
        s_root = np.full(m, np.nan)
        s_lo = np.full(m, np.nan)
        s_hi = np.full(m, np.nan)
        cell_i = np.zeros(m, dtype=np.intp)
        cell_j = np.zeros(m, dtype=np.intp)
        ds = s_b - s_a
        for p in range(3):
            ua, ub = breaks[p], breaks[p + 1]
            pending = ~found & ~left & (ub > ua)  # empty pieces: their point was just tested
            if not pending.any():
                continue
            sp = s_a[:, None] + np.stack([ua, 0.5 * (ua + ub), ub], axis=1) * ds[:, None]
            h, col, row = _eval_model(coef, sp)
            i = np.floor(col[:, 1])
            j = np.floor(row[:, 1])
            inside = (i >= 0) & (i <= n_cols - 2) & (j >= 0) & (j <= n_rows - 2)
            i = np.where(inside, i, 0).astype(np.intp)
            j = np.where(inside, j, 0).astype(np.intp)
            z = self._cell_values(i[:, None], j[:, None], col - i[:, None], row - j[:, None])
            f = h - z
            bad = pending & ~(inside & np.isfinite(f).all(axis=1))
            left |= bad
            root = _first_quadratic_root(f[:, 0], f[:, 1], f[:, 2])
            new = pending & ~bad & np.isfinite(root)
            s_root[new] = (sp[:, 0] + root * (sp[:, 2] - sp[:, 0]))[new]
            s_lo[new] = sp[new, 0]
            s_hi[new] = sp[new, 2]
            cell_i[new] = i[new]
            cell_j[new] = j[new]
            found |= new
        hit = np.nonzero(found)[0]
        s_root[hit] = self._newton_on_model(coef[hit], s_root[hit], s_lo[hit], s_hi[hit],
                                            cell_i[hit], cell_j[hit])
        return found, left, s_root

    def _newton_on_model(self, coef, s, s_lo, s_hi, i, j, n_iter=2):
        """Newton steps on ``f(s) = h(s) - z(col(s), row(s))`` in one cell, kept in [s_lo, s_hi]."""
        n_cols = self.shape[1]
        k = j * n_cols + i
        zf = self._z_flat
        z00, z01 = zf.take(k), zf.take(k + 1)
        z10, z11 = zf.take(k + n_cols), zf.take(k + n_cols + 1)
        d_col = z01 - z00
        d_row = z10 - z00
        twist = z11 - z10 - z01 + z00
        for _ in range(n_iter):
            (h, col, row), (dh, dcol, drow) = _eval_model_d(coef, s)
            fc = col - i
            fr = row - j
            f = h - (z00 + fc * d_col + fr * d_row + fc * fr * twist)
            df = dh - (d_col + fr * twist) * dcol - (d_row + fc * twist) * drow
            with np.errstate(invalid="ignore", divide="ignore"):
                s_new = s - f / df
            s = np.where(np.isfinite(s_new), np.clip(s_new, s_lo, s_hi), s)
        return s

    def _polish(self, o, d, t, step_t):
        """Exact check of model roots; bracketed Illinois where ``|h - z| >= 1e-4 m``.

        Returns
        -------
        t : ndarray, shape (m,)
            Ray parameters (NaN where no root could be confirmed).
        lon_lat_h : ndarray, shape (m, 3)
            Geodetic coordinates of ``o + t d``.
        """
        f, lon, lat, h, _ = self._residual_exact(o, d, t)
        geo = np.stack([lon, lat, h], axis=1)
        todo = np.nonzero(~(np.abs(f) < _SURFACE_TOL_M))[0]
        if todo.size == 0:
            return t, geo
        t = t.copy()
        o, d, tr, w = o[todo], d[todo], t[todo], np.minimum(0.05, 0.5 * step_t[todo])
        ta, tb = tr - w, tr + w
        fa, *_ = self._residual_exact(o, d, ta)
        fb, *_ = self._residual_exact(o, d, tb)
        fr = f[todo]
        # Keep the first sub-bracket holding a sign change.
        first_half = (fa > 0.0) & (fr <= 0.0)
        tb = np.where(first_half, tr, tb)
        fb = np.where(first_half, fr, fb)
        ta = np.where(first_half, ta, tr)
        fa = np.where(first_half, fa, fr)
        bracketed = (fa > 0.0) & (fb <= 0.0)
        best = tr.copy()
        side = np.zeros(todo.size, dtype=np.int8)
        active = bracketed.copy()
        for it in range(60):
            if not active.any():
                break
            with np.errstate(invalid="ignore", divide="ignore"):
                tn = (ta * fb - tb * fa) / (fb - fa)
            bisect = ~((tn > ta) & (tn < tb)) | (it % 4 == 3)
            tn = np.where(bisect, 0.5 * (ta + tb), tn)
            fn, *_ = self._residual_exact(o, d, tn)
            best = np.where(active, tn, best)
            done = active & (np.abs(fn) < _SURFACE_TOL_M)
            low = active & (fn > 0.0)
            high = active & ~(fn > 0.0)
            # Illinois: halve the retained end's value when the same end is kept twice.
            fb = np.where(low & (side == 1), 0.5 * fb, fb)
            fa = np.where(high & (side == -1), 0.5 * fa, fa)
            ta = np.where(low, tn, ta)
            fa = np.where(low, fn, fa)
            tb = np.where(high, tn, tb)
            fb = np.where(high, fn, fb)
            side = np.where(low, 1, np.where(high, -1, side)).astype(np.int8)
            active &= ~done & ((tb - ta) > 1e-9)
        # Unbracketed: a graze within the model error; keep the model root.
        f_best, lon, lat, h, _ = self._residual_exact(o, d, best)
        ok = np.abs(f_best) < max(100.0 * _SURFACE_TOL_M, 1e-2)
        t[todo] = np.where(ok, best, np.nan)
        geo[todo] = np.stack([lon, lat, h], axis=1)
        return t, geo


class _RangePyramid:
    """Minima and maxima of a node grid over square blocks of 2**l x 2**l cells, all levels l.

    Block ``(J, I)`` of level ``l`` spans the nodes ``J 2^l .. (J + 1) 2^l`` by
    ``I 2^l .. (I + 1) 2^l`` (inclusive: neighbouring blocks share their edge nodes), so its
    range bounds the bilinear surface over its cells. Nodes without data count as ``+inf`` in
    the maxima and ``-inf`` in the minima (no bound there).
    """

    def __init__(self, z):
        valid = np.isfinite(z)
        self._n_cells = (z.shape[0] - 1, z.shape[1] - 1)
        flats = []
        for reduce, fill in ((np.maximum, np.inf), (np.minimum, -np.inf)):
            zz = np.where(valid, z, fill)
            level = reduce(reduce(zz[:-1, :-1], zz[:-1, 1:]), reduce(zz[1:, :-1], zz[1:, 1:]))
            blocks, offsets, widths, offset = [], [], [], 0
            while True:
                blocks.append(level.reshape(-1))
                offsets.append(offset)
                widths.append(level.shape[1])
                offset += level.size
                if max(level.shape) == 1:
                    break
                rows, cols = level.shape
                padded = np.full((rows + rows % 2, cols + cols % 2), -fill)
                padded[:rows, :cols] = level
                level = reduce(reduce(padded[0::2, 0::2], padded[0::2, 1::2]),
                               reduce(padded[1::2, 0::2], padded[1::2, 1::2]))
            flats.append(_float32_bound(np.concatenate(blocks), upper=reduce is np.maximum))
        self._max_flat, self._min_flat = flats
        self._offsets = np.array(offsets, dtype=np.intp)
        self._widths = np.array(widths, dtype=np.intp)

    def range_over_box(self, col, row):
        """Lower and upper bounds of the surface over the bounding box of points, per ray.

        Parameters
        ----------
        col, row : ndarray, shape (m, k)
            Node indices of ``k`` points along each ray's (straight) track.

        Returns
        -------
        top_m, bottom_m : ndarray, shape (m,)
            ``+inf`` and ``-inf`` where the box leaves the grid or touches nodata.
        """
        n_rows, n_cols = self._n_cells
        c_lo, c_hi = col.min(axis=1), col.max(axis=1)
        r_lo, r_hi = row.min(axis=1), row.max(axis=1)
        inside = (c_lo >= 0.0) & (r_lo >= 0.0) & (c_hi <= n_cols) & (r_hi <= n_rows)
        # Cells under the box; a range of at most 2**l cells spans at most two blocks.
        i_lo, i_hi, j_lo, j_hi = (
            np.clip(np.floor(np.where(inside, v, 0.0)), 0, n - 1).astype(np.intp)
            for v, n in ((c_lo, n_cols), (c_hi, n_cols), (r_lo, n_rows), (r_hi, n_rows))
        )
        extent = np.maximum(i_hi - i_lo, j_hi - j_lo) + 1
        level = np.minimum(np.ceil(np.log2(extent)).astype(np.intp), self._offsets.size - 1)
        off, width = self._offsets[level], self._widths[level]
        i_lo, i_hi, j_lo, j_hi = (v >> level for v in (i_lo, i_hi, j_lo, j_hi))
        corners = [off + j * width + i for j in (j_lo, j_hi) for i in (i_lo, i_hi)]
        top = self._max_flat.take(corners[0])
        bottom = self._min_flat.take(corners[0])
        for k in corners[1:]:
            top = np.maximum(top, self._max_flat.take(k))
            bottom = np.minimum(bottom, self._min_flat.take(k))
        return np.where(inside, top, np.inf), np.where(inside, bottom, -np.inf)


def _float32_bound(values, *, upper):
    """``values`` as float32 rounded outwards (up for upper bounds), halving their memory."""
    out = np.ascontiguousarray(values, dtype=np.float32)
    if upper:
        return np.where(out < values, np.nextafter(out, np.float32(np.inf)), out)
    return np.where(out > values, np.nextafter(out, np.float32(-np.inf)), out)


def _solve_model_height(coef, h_target, s_lo, s_hi):
    """Parameter in [s_lo, s_hi] where the model height equals ``h_target`` (h decreasing).

    A chord estimate then one Newton step on the cubic (the chord is off by the ray's
    curvature in height, under a metre for brackets of a few km; Newton removes that).
    Clipped to the interval; NaN where ``h_target`` is not finite.
    """
    c0, c1, c2, c3 = (coef[:, 0, k] for k in range(4))
    h_lo = ((c3 * s_lo + c2) * s_lo + c1) * s_lo + c0
    h_hi = ((c3 * s_hi + c2) * s_hi + c1) * s_hi + c0
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.clip(s_lo + (h_lo - h_target) / (h_lo - h_hi) * (s_hi - s_lo), s_lo, s_hi)
        h = ((c3 * s + c2) * s + c1) * s + c0
        dh = (3.0 * c3 * s + 2.0 * c2) * s + c1
        s = np.clip(s - (h - h_target) / dh, s_lo, s_hi)
    return np.where(np.isfinite(h_target), s, np.nan)


def _eval_model(coef, s):
    """Cubic model at ``s``: coef (m, 3, 4) monomial coefficients, s (m, k) -> 3 x (m, k)."""
    out = []
    for q in range(3):
        c0, c1, c2, c3 = (coef[:, q, k, None] for k in range(4))
        out.append(((c3 * s + c2) * s + c1) * s + c0)
    return out


def _eval_model_d(coef, s):
    """Cubic model and its derivative at ``s`` of shape (m,): two lists of 3 x (m,)."""
    values, slopes = [], []
    for q in range(3):
        c0, c1, c2, c3 = (coef[:, q, k] for k in range(4))
        values.append(((c3 * s + c2) * s + c1) * s + c0)
        slopes.append((3.0 * c3 * s + 2.0 * c2) * s + c1)
    return values, slopes


def _grid_line_crossing(coef, q, s_a, s_b, v_a, v_b):
    """Fraction ``u`` in [0, 1] of a step where model quantity ``q`` crosses an integer.

    ``v_a``, ``v_b`` are its values at the step's ends; at most one integer lies between
    them. The chord gives a first estimate, one Newton step on the cubic makes it exact.
    Returns 1 where no integer is crossed.
    """
    n = np.floor(np.maximum(v_a, v_b))
    crosses = (np.minimum(v_a, v_b) < n) & (v_b != v_a)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.clip((n - v_a) / (v_b - v_a), 0.0, 1.0)
        ds = s_b - s_a
        s = s_a + u * ds
        c0, c1, c2, c3 = (coef[:, q, k] for k in range(4))
        value = ((c3 * s + c2) * s + c1) * s + c0
        slope = ((3.0 * c3 * s + 2.0 * c2) * s + c1) * ds
        u_newton = u - (value - n) / slope
    u = np.where(np.isfinite(u_newton), np.clip(u_newton, 0.0, 1.0), u)
    return np.where(crosses, u, 1.0)


def _first_quadratic_root(f0, fm, f1):
    """Smallest ``u`` in [0, 1] where the quadratic through (0, f0), (1/2, fm), (1, f1) is 0.

    ``f(u) = f0 + b u + c u^2`` with ``c = 2 (f0 - 2 fm + f1)``, ``b = f1 - f0 - c``. Roots by
    the cancellation-free pair ``q / c`` and ``f0 / q`` with
    ``q = -(b + sign(b) sqrt(b^2 - 4 c f0)) / 2``, which also covers the linear case ``c = 0``.
    NaN where there is none.
    """
    c = 2.0 * (f0 - 2.0 * fm + f1)
    b = f1 - f0 - c
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = b * b - 4.0 * c * f0
        q = -0.5 * (b + np.copysign(np.sqrt(disc), b))
        r1 = q / c
        r2 = f0 / q
    eps = 1e-12
    r1 = np.where((r1 >= -eps) & (r1 <= 1.0 + eps), r1, np.nan)
    r2 = np.where((r2 >= -eps) & (r2 <= 1.0 + eps), r2, np.nan)
    root = np.clip(np.fmin(r1, r2), 0.0, 1.0)
    root = np.where(f0 <= 0.0, 0.0, root)
    # An end at zero or below that rounding hid from the formula still counts.
    root = np.where(np.isnan(root) & (f1 <= 0.0), 1.0, root)
    return root


def _window_for_bounds(bounds, margin_deg, *, source):
    """A window function for :func:`_read_raster` covering lon/lat ``bounds`` plus a margin."""
    try:
        lon0, lat0, lon1, lat1 = (float(v) for v in bounds)
    except (TypeError, ValueError) as err:
        raise InputError("bounds must be (lon_min, lat_min, lon_max, lat_max)") from err
    margin = float(margin_deg)
    if not (np.all(np.isfinite([lon0, lat0, lon1, lat1, margin])) and lon0 < lon1
            and lat0 < lat1 and margin >= 0.0):
        raise InputError(
            f"bounds must be finite with lon_min < lon_max, lat_min < lat_max and margin_deg "
            f">= 0, got {tuple(bounds)} and {margin_deg}"
        )
    lon0, lat0 = lon0 - margin, max(lat0 - margin, -90.0)
    lon1, lat1 = lon1 + margin, min(lat1 + margin, 90.0)

    def window_from(transform, crs, width, height):
        lon = np.concatenate([np.linspace(lon0, lon1, 21), np.linspace(lon0, lon1, 21),
                              np.full(21, lon0), np.full(21, lon1)])
        lat = np.concatenate([np.full(21, lat0), np.full(21, lat1),
                              np.linspace(lat0, lat1, 21), np.linspace(lat0, lat1, 21)])
        if crs is None:
            raise DemError(f"{source}: the DEM declares no coordinate reference system")
        to_grid = pyproj.Transformer.from_crs("EPSG:4326", _horizontal_crs(crs), always_xy=True)
        x, y = to_grid.transform(lon, lat)
        cols, rows = _apply_affine(~transform, np.asarray(x), np.asarray(y))
        ok = np.isfinite(cols) & np.isfinite(rows)
        if not ok.any():
            raise DemError(f"{source}: bounds {tuple(bounds)} cannot be placed on the DEM")
        col0 = max(int(np.floor(cols[ok].min())) - 1, 0)
        col1 = min(int(np.ceil(cols[ok].max())) + 1, width)
        row0 = max(int(np.floor(rows[ok].min())) - 1, 0)
        row1 = min(int(np.ceil(rows[ok].max())) + 1, height)
        if col1 - col0 < 2 or row1 - row0 < 2:
            raise DemError(
                f"{source}: bounds {tuple(bounds)} (plus {margin_deg} deg) do not overlap the DEM"
            )
        return row0, row1, col0, col1

    return window_from


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
