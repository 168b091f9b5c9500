"""The DEM: a grid of WGS84 ellipsoidal heights, read from rasters, sampled, and hit by rays.

Every height a :class:`Dem` returns is an ellipsoidal height: metres above the WGS84 ellipsoid.
A DEM whose heights are orthometric (EGM96, as SRTM) is converted once, when it is loaded, by
adding the geoid undulation ``N`` at each DEM node (``h = H + N``,
:mod:`sensor_models.terrain.geoid`); a missing geoid grid is an error, never a silent ``N = 0``
(at the Ventoux SRTM tile ``N`` is about +51 m, which moves a Pleiades orthoimage by about 40
lines). What the heights refer to is read from the file or given by the caller
(:mod:`sensor_models.terrain.datum`).

Grids are sampled with bilinear interpolation between node centres. Continuous pixel
coordinates follow GDAL/rasterio (the first pixel's centre is ``(0.5, 0.5)``); internally a
*node index* ``(col, row)`` puts the first node at ``(0, 0)``, i.e. ``col = x_pixel - 0.5``
(:class:`~sensor_models.terrain.grid_geometry.GridGeometry`).

:meth:`Dem.intersect` finds the first crossing of lines of sight with the surface; the method
and its code are in :mod:`sensor_models.terrain.los_intersect`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyproj
from scipy import ndimage

from sensor_models.errors import DemError, InputError
from sensor_models.geometry.geodesy import geodetic_to_ecef
from sensor_models.terrain.datum import check_datum_name, declared_datum, horizontal_crs, tagged_datum
from sensor_models.terrain.geoid import as_geoid
from sensor_models.terrain.grid_geometry import GridGeometry, apply_affine, as_affine
from sensor_models.terrain.height_bounds import RangePyramid, node_bounds
from sensor_models.terrain.los_intersect import intersect_rays
from sensor_models.terrain.raster_read import read_raster

__all__ = ["Dem"]


def _dem_source(path):
    """``(path GDAL opens, name for messages)`` of a DEM file, or of the tiles named by ``path``.

    Several tiles are mosaicked through a GDAL VRT (:func:`sensor_models.maps.mosaic.mosaic_path`);
    messages then name the first tile and their count, not the private VRT.
    """
    from sensor_models.errors import GcpcalError
    from sensor_models.files.gdal_paths import is_gdal_virtual, virtual_exists
    from sensor_models.maps.mosaic import mosaic_path, raster_inputs

    if isinstance(path, (str, os.PathLike)) and (Path(path).is_file()
                                                 or (is_gdal_virtual(path) and virtual_exists(path))):
        return os.fspath(path), os.fspath(path)
    try:
        files = raster_inputs(path, what="DEM")
        label = files[0] if len(files) == 1 else f"{files[0]} (and {len(files) - 1} more DEM tiles)"
        return mosaic_path(files, what="DEM"), label
    except GcpcalError as exc:
        if isinstance(path, (str, os.PathLike)) and "not found" in str(exc):
            raise DemError(f"{os.fspath(path)}: DEM file not found") from None
        raise


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
    source_datum : {"ellipsoid", "egm96"}
        The vertical datum of the heights as read (they are held as ellipsoidal heights).
    geoid_source : str, optional
        The geoid grid that converted EGM96 heights (None for ellipsoidal ones).

    Attributes
    ----------
    transform : affine.Affine
    crs : pyproj.CRS
    shape : tuple of int
    source : str or None
    source_datum : str
    geoid_source : str or None
    """

    def __init__(self, heights_m, transform, crs, *, source: str | None = None, source_datum: str = "ellipsoid",
                 geoid_source: str | None = None):
        z = np.ascontiguousarray(np.asarray(heights_m, dtype=np.float64))
        if z.ndim != 2 or min(z.shape) < 2:
            raise InputError(f"a DEM needs at least 2 x 2 nodes, got shape {z.shape}", path=source)
        self.source = source
        self.source_datum = source_datum
        self.geoid_source = geoid_source
        self.transform = as_affine(transform)
        self.crs = horizontal_crs(pyproj.CRS.from_user_input(crs))
        self.shape = z.shape
        valid = np.isfinite(z)
        if not valid.any():
            raise DemError(f"{source or 'DEM'}: holds no valid height (all nodata)")
        self._z = z
        self._z.setflags(write=False)
        self._z_flat = z.reshape(-1)
        self._h_min = float(np.min(z, where=valid, initial=np.inf))
        self._h_max = float(np.max(z, where=valid, initial=-np.inf))
        del valid
        self._geometry = GridGeometry(self.transform, self.crs, self.shape)
        # float32 bounds of the heights, rounded outwards (+-inf without data): a maximum of them
        # is the bound of the float64 maximum, bit for bit (height_bounds.node_bounds)
        upper, lower = node_bounds(z)
        # Upper bound of the bilinear surface over any march step starting in cell (j, i):
        # such a step stays within cells j-1..j+1, i-1..i+1, i.e. nodes j-1..j+2, i-1..i+2.
        dmax = ndimage.maximum_filter(upper, size=4, mode="constant", cval=np.inf, origin=-1)
        self._cell_max_flat = np.ascontiguousarray(dmax[:-1, :-1]).reshape(-1)
        del dmax
        self._pyramid = RangePyramid(z, bounds=(upper, lower))
        del upper, lower
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
            EGM96 undulation grid for EGM96 heights (default:
            :func:`~sensor_models.terrain.geoid.find_egm96_grid` in PROJ's data directories; an
            error naming them when absent), refused when the caller says ``"ellipsoid"``, unused
            when the file itself declares ellipsoidal heights.
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
        datum = check_datum_name(vertical_datum)
        if datum == "ellipsoid" and geoid is not None:
            raise InputError("geoid is only used with vertical_datum='egm96'", path=source)
        window_from = None
        if bounds is not None:
            window_from = _window_for_bounds(bounds, margin_deg, source=source)
        values, transform, crs = read_raster(gdal_path, what="DEM", window_from=window_from)
        if crs is None:
            raise DemError(f"{source}: the DEM declares no coordinate reference system")
        declared = declared_datum(crs, source=source)
        if declared is None:
            declared = tagged_datum(gdal_path)
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
        datum = check_datum_name(vertical_datum)
        if datum is None:
            raise InputError("vertical_datum must be given for an in-memory DEM")
        if datum == "ellipsoid" and geoid is not None:
            raise InputError("geoid is only used with vertical_datum='egm96'")
        crs = pyproj.CRS.from_user_input(crs)
        declared = declared_datum(crs, source="in-memory DEM")
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
            grid = as_geoid(geoid, dem_source=source)
            geometry = GridGeometry(as_affine(transform), horizontal_crs(crs), values.shape)
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
            return cls(values, transform, crs, source=source, source_datum="egm96",
                       geoid_source=None if grid.source is None else str(grid.source))
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

    def height_and_slope_m(self, lon_deg, lat_deg):
        """Ellipsoidal height of the DEM surface (bilinear) and its derivatives in lon and lat.

        Parameters
        ----------
        lon_deg, lat_deg : ndarray, shape (N,)
            WGS84 longitude and latitude in degrees.

        Returns
        -------
        h_m, dh_dlon, dh_dlat : ndarray, shape (N,)
            Metres and metres per degree: the height of :meth:`height_m` and the slope of the
            bilinear patch of the cell holding each point (one-sided on a cell edge). NaN where
            :meth:`height_m` is NaN.
        """
        geo = self._geometry
        col, row = geo.lonlat_to_index(lon_deg, lat_deg)
        if geo.plain_lonlat:
            c_lon, c_lat, _, r_lon, r_lat, _ = geo.index_coeffs
        else:  # through PROJ: the index mapping's derivatives by finite differences
            eps = 1e-6
            c1, r1 = geo.lonlat_to_index(lon_deg + eps, lat_deg)
            c2, r2 = geo.lonlat_to_index(lon_deg, lat_deg + eps)
            c_lon, r_lon, c_lat, r_lat = (c1 - col) / eps, (r1 - row) / eps, (c2 - col) / eps, (r2 - row) / eps
        n_rows, n_cols = self.shape
        inside = (col >= 0.0) & (col <= n_cols - 1) & (row >= 0.0) & (row <= n_rows - 1)
        col = np.where(inside, col, 0.0)
        row = np.where(inside, row, 0.0)
        i = np.minimum(col.astype(np.intp), n_cols - 2)
        j = np.minimum(row.astype(np.intp), n_rows - 2)
        fc, fr = col - i, row - j
        k = j * n_cols + i
        zf = self._z_flat
        z00 = zf.take(k)
        z01 = zf.take(k + 1)
        z10 = zf.take(k + n_cols)
        z11 = zf.take(k + n_cols + 1)
        d_top = z01 - z00
        top = z00 + fc * d_top
        d_rows = (z10 + fc * (z11 - z10)) - top
        h = np.where(inside, top + fr * d_rows, np.nan)
        dz_dc = d_top + fr * ((z11 - z10) - d_top)
        return h, dz_dc * c_lon + d_rows * r_lon, dz_dc * c_lat + d_rows * r_lat

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
            (:func:`~sensor_models.terrain.ellipsoid.intersect_ellipsoid`; NaN if they miss that too).

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
        and on one-pixel spikes alike (the method: :mod:`sensor_models.terrain.los_intersect`).
        Memory is bounded by processing rays in chunks of 32 768.
        """
        return intersect_rays(self, origin_m, direction, outside=outside)


def _window_for_bounds(bounds, margin_deg, *, source):
    """A window function for :func:`~sensor_models.terrain.raster_read.read_raster`.

    It covers the lon/lat ``bounds`` plus a margin of ``margin_deg``.
    """
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
        to_grid = pyproj.Transformer.from_crs("EPSG:4326", horizontal_crs(crs), always_xy=True)
        x, y = to_grid.transform(lon, lat)
        cols, rows = apply_affine(~transform, np.asarray(x), np.asarray(y))
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


