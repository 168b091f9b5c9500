"""Geoid undulation grids: :class:`Geoid`, and where PROJ keeps the EGM96 grid.

Ellipsoidal height = orthometric height + ``N``, with the undulation ``N(lon, lat)``
interpolated bilinearly in a grid such as PROJ-data's EGM96 15' grid [1]_. A DEM of EGM96
heights is converted with one when it is loaded (:meth:`sensor_models.terrain.dem.Dem.open`);
:func:`as_geoid` finds the installed grid when the caller gives none, and a missing grid is an
error that says where to get one.

References
----------
.. [1] NGA, "EGM96: the NASA GSFC and NIMA joint geopotential model", undulation grid at 15
   arc-minutes as distributed in PROJ-data (``egm96_15.gtx``).
"""

from __future__ import annotations

import os

import numpy as np

from sensor_models.errors import GeoidGridMissingError, InputError
from sensor_models.terrain.grid_geometry import as_affine
from sensor_models.terrain.raster_read import read_raster

__all__ = ["Geoid", "PROJ_EGM96_NAMES", "as_geoid", "find_egm96_grid", "proj_data_dirs"]


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
        transform = as_affine(transform)
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
        values, transform, crs = read_raster(
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


def as_geoid(geoid, *, dem_source) -> Geoid:
    """The geoid grid to convert a DEM's EGM96 heights with.

    Parameters
    ----------
    geoid : str, os.PathLike, Geoid or None
        A grid file, a grid, or None for the EGM96 grid in PROJ's data directories
        (:func:`find_egm96_grid`).
    dem_source : str or None
        The DEM the grid is for, named in messages.

    Returns
    -------
    Geoid

    Raises
    ------
    GeoidGridMissingError
        When ``geoid`` is None and no EGM96 grid is installed (the message says where to get
        one), or the file named cannot be read.
    InputError
        When ``geoid`` is of another type.
    """
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
