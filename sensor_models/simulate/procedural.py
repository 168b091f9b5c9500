"""Procedural reference data: a Landsat-like panchromatic orthoimage (DOM) and its DEM.

:func:`generate_reference` draws, from one seed, the reference a scene is matched against:

* a DEM (default 30 m, float32, heights in metres above the WGS84 ellipsoid), and
* a DOM (default 15 m, uint16, 12-bit digital numbers 1..4095, like the Landsat 8/9 OLI
  panchromatic band [8]_), both in the UTM zone of the area centre, and
* a water mask (sea, lakes and rivers) and a land-cover map on the DOM grid.

Grids
-----
Both grids are centred on the UTM coordinates of ``(center_lon_deg, center_lat_deg)``, north-up,
with ``n = ceil(size / resolution)`` pixels along each axis: they cover the requested
``width_m x height_m`` exactly when the size is a multiple of the resolution, and otherwise
overhang it by less than one pixel, shared equally between both sides. The zone is the standard
6-degree zone ``floor((lon + 180) / 6) + 1`` (no Norway / Svalbard exceptions); EPSG 326zz north
of the equator, 327zz south of it.

Terrain
-------
The terrain shape is built on the DEM grid plus a 4-node margin, as
``s = 0.45 (0.35 + 0.65 m) f + m r``:

* ``f``: fractional Brownian surface by spectral synthesis [1]_: white noise filtered in the
  Fourier domain by ``(k^2 + k0^2)^(-beta/4) exp(-(k / k1)^2)``, ``beta = 2 H + 2`` with
  ``H = 0.8``, ``1/k0 = 40 km`` and ``1/k1 = 400 m``, so the power spectrum falls as
  ``k^-3.6`` like that of real relief and the surface is smooth at the DEM spacing;
* ``r``: ridged multifractal [2]_ from band-pass Gaussian fields ``n_j`` (unit variance, one
  octave wide) at wavelengths 12, 6, 3, 1.5 and 0.75 km:
  ``r = sum_j 2^(-1.5 j) w_j max(1 - |n_j| / 2, 0)^2``, each octave weighted by
  ``w_j = clip(2 * previous octave, 0, 1)`` so that detail lives on the crests;
* ``m`` in [0, 1]: a 30 km mountain mask (smoothed value noise), so that plains and ranges
  alternate.

With a sea, a coast field ``c`` (metres: a ramp along a random direction plus fractal value
noise) is thresholded at its ``sea_fraction`` quantile; land rises from the coast over a few km
(factor ``tau = smoothstep(0, w, c - c0)``). The normalised land shape ``u`` in [0, 1] (0 at
the coast or the lowest point, 1 at the highest) becomes ``h = base + relief_m * u^gamma``:

* with a sea, ``base = sea_level_m`` (the coast is at sea level) and ``gamma`` is solved by
  bisection in [0.2, 8] so that the mean land height is ``mean_height_m`` (when that mean is not
  reachable the nearest reachable one is taken);
* without a sea, ``gamma = 1.6`` (flat valley floors, steeper crests) and ``base`` puts the mean
  land height at ``mean_height_m``.

The range of the DEM is therefore ``relief_m`` (up to the 1/16 m quantisation; lakes and river
carving only lower it by a few metres). Lakes fill local basins to a level where they reach a
random target area without spilling out of their window (the DEM is flat at the lake level);
rivers form a dendritic network draining to the sea, the lakes or the border, found by
Priority-Flood [9]_ on cells of about 120 m, smoothed and given irregular meanders [3]_, and
are carved into the DEM with a bed that never rises downstream. At the default relief over a
30 x 22 km area, the median slope is about 10 degrees and 1 to 5 % of the DEM is steeper than
35 degrees. The sea surface is flat at ``sea_level_m``
(ellipsoidal height, i.e. the geoid undulation there; 0 by default).

Image
-----
Reflectances (panchromatic, top of atmosphere, typical values) are assigned per land-cover
class: agricultural parcels (blocks of a domain-warped 1.5 km grid, each block cut into rotated
rectangular parcels with their own crop/soil reflectance, mild row stripes and field
boundaries), forest (dark, with 1 to 3-pixel crown texture), urban blocks (bright roofs, dark
streets), natural grass and shrub, bare rock above the tree line, beaches, roads (bright
concrete or dark asphalt, a few curving ones), rivers, lakes and the sea (dark, nearly flat:
only a 0.5 % low-frequency variation and the sensor noise). Land reflectance is modulated by
Lambertian shading with a diffuse sky term [4]_ computed from the DEM and the sun direction, so
that the DOM correlates with the DEM as real imagery does. The radiance image is blurred by a
Gaussian point-spread function (sigma 0.6 pixel), converted to DN = 200 + 9000 * reflectance,
added a Gaussian sensor noise (sigma 2.5 DN) and rounded to 1..4095. There is no nodata value:
every pixel is valid and 0 never occurs.

Determinism: every random value comes either from ``numpy.random.default_rng(seed)`` (consumed
in a fixed order) or from a 32-bit integer hash [5]_ of a key drawn from it and the integer
coordinates of a lattice node, parcel or block; FFTs run on one worker. The same arguments give
byte-identical arrays and files.

Smooth noise ("value noise") is an i.i.d. uniform lattice blended by the uniform cubic B-spline;
fields defined on the DEM grid are carried to the DOM grid by Keys cubic convolution [6]_.

Modules
-------
This module holds the entry point, the argument checks, the grids, the DEM assembly and the
GeoTIFF output; the phases live beside it: :mod:`~sensor_models.simulate.procedural_noise`
(hashing, value noise, resampling), :mod:`~sensor_models.simulate.procedural_terrain` (terrain
shape, lakes), :mod:`~sensor_models.simulate.procedural_rivers` (river network),
:mod:`~sensor_models.simulate.procedural_cover` (land-cover codes, shading, class scores,
roads) and :mod:`~sensor_models.simulate.procedural_dom` (the orthoimage).

References
----------
.. [1] R. F. Voss, "Fractals in nature: from characterization to simulation", in H.-O. Peitgen
   and D. Saupe (eds.), The Science of Fractal Images, Springer, 1988, pp. 21-70.
.. [2] F. K. Musgrave, "Methods for realistic landscape imaging", PhD thesis, Yale University,
   1993; and D. S. Ebert et al., Texturing and Modeling: A Procedural Approach, 3rd ed., 2003,
   ch. 16 (ridged multifractal terrain).
.. [3] W. B. Langbein and L. B. Leopold, "River meanders: theory of minimum variance", USGS
   Professional Paper 422-H, 1966 (the sine-generated curve).
.. [4] B. K. P. Horn, "Hill shading and the reflectance map", Proc. IEEE 69(1), 14-47, 1981.
.. [5] C. Wellons, "Prospecting for hash functions", 2018 (the ``lowbias32`` integer mixer).
.. [6] R. Keys, "Cubic convolution interpolation for digital image processing", IEEE Trans.
   ASSP 29(6), 1153-1160, 1981.
.. [7] J. R. Irons, J. L. Dwyer and J. A. Barsi, "The next Landsat satellite: the Landsat Data
   Continuity Mission", Remote Sensing of Environment 122, 11-21, 2012.
.. [8] USGS, Landsat 8-9 OLI/TIRS Collection 2 Level-1 Data Format Control Book (15 m
   panchromatic band 8, 12-bit quantisation), 2020.
.. [9] R. Barnes, C. Lehman and D. Mulla, "Priority-flood: an optimal depression-filling and
   watershed-labeling algorithm for digital elevation models", Computers & Geosciences 62,
   117-127, 2014.
"""

from __future__ import annotations

import itertools
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyproj
from affine import Affine

from sensor_models.errors import InputError
from sensor_models.files.atomic import temporary_beside
from sensor_models.maps.dom_inputs import ACCURACY_TAG
from sensor_models.simulate.procedural_cover import cover_fields, draw_roads
from sensor_models.simulate.procedural_dom import dom_strips, render_dom
from sensor_models.simulate.procedural_noise import hash32
from sensor_models.simulate.procedural_rivers import draw_rivers, draw_segments
from sensor_models.simulate.procedural_terrain import MARGIN_NODES, draw_terrain, fill_lakes

__all__ = ["generate_reference", "ReferenceData"]

#: Version of the generator, written into the files' provenance tag.
GENERATOR_VERSION = 1

#: DEM heights are rounded to multiples of this (a power of two: exact in float32).
_DEM_QUANTUM_M = 1.0 / 16.0
#: At most this many DOM pixels (about 4 GB of working memory).
_MAX_DOM_PIXELS = 150_000_000


@dataclass(frozen=True, eq=False)
class ReferenceData:
    """A procedural reference orthoimage and DEM with their masks.

    Attributes
    ----------
    dom : ndarray, shape (rows, cols), uint16
        Panchromatic digital numbers in 1..4095 (no nodata).
    dom_transform : affine.Affine
        Pixel-corner affine of the DOM (rasterio convention), UTM metres.
    dem_m : ndarray, shape (dem_rows, dem_cols), float32
        Heights in metres above the WGS84 ellipsoid, multiples of 1/16 m.
    dem_transform : affine.Affine
        Pixel-corner affine of the DEM, UTM metres.
    crs : pyproj.CRS
        WGS84 / UTM zone of the area centre (EPSG 326zz or 327zz).
    water_mask : ndarray, shape (rows, cols), bool
        Sea, lakes and rivers on the DOM grid (bridges are not water).
    land_cover : ndarray, shape (rows, cols), uint8
        :class:`~sensor_models.simulate.procedural_cover.LandCover` codes on the DOM grid.
    parameters : dict
        The arguments that produced the data (written into the files' provenance tag).
    """

    dom: np.ndarray
    dom_transform: Affine
    dem_m: np.ndarray
    dem_transform: Affine
    crs: pyproj.CRS
    water_mask: np.ndarray
    land_cover: np.ndarray | None = None
    parameters: dict = field(default_factory=dict)

    def write(self, out_dir, *, dom_name: str = "dom.tif", dem_name: str = "dem.tif"):
        """Write the DOM and the DEM as tiled, DEFLATE-compressed GeoTIFFs.

        Both files are written to temporaries beside their targets and renamed only once both
        are complete, so a failure leaves no partial file. The DEM carries the metadata item
        ``VERTICAL_DATUM=ellipsoid``, so :meth:`sensor_models.terrain.dem.Dem.open` reads it
        without arguments; the DOM states its geolocation accuracy, 0 m
        (``GEOLOCATION_RMSE_M``, :mod:`sensor_models.maps.dom_inputs`: a scene rendered from this DOM
        sees it without error); both carry ``GCPCAL_PROCEDURAL`` (JSON of the generator's
        arguments). No timestamp is written: the same data give the same bytes.

        Parameters
        ----------
        out_dir : str or os.PathLike
            Folder (created if needed).
        dom_name, dem_name : str
            File names inside ``out_dir``.

        Returns
        -------
        dom_path, dem_path : pathlib.Path

        Raises
        ------
        InputError
            When a file cannot be written (the message names it).
        """
        out_dir = Path(out_dir)
        dom_path, dem_path = out_dir / dom_name, out_dir / dem_name
        if dom_path == dem_path:
            raise InputError("dom_name and dem_name must differ", field="dem_name")
        provenance = json.dumps(self.parameters, sort_keys=True)
        jobs = [
            (dom_path, self.dom, self.dom_transform, 2,
             {"GCPCAL_PROCEDURAL": provenance, ACCURACY_TAG: "0.0"}),
            (dem_path, self.dem_m, self.dem_transform, 3,
             {"VERTICAL_DATUM": "ellipsoid", "GCPCAL_PROCEDURAL": provenance}),
        ]
        temporaries = []
        try:
            for path, data, transform, predictor, tags in jobs:
                tmp = _temporary(path)
                temporaries.append(tmp)
                _write_geotiff(tmp, data, transform, self.crs, predictor=predictor, tags=tags,
                               target=path)
            for (path, *_), tmp in zip(jobs, temporaries):
                try:
                    os.replace(tmp, path)
                except OSError as err:
                    raise InputError(f"cannot replace the file ({err})", path=str(path)) from err
        except BaseException:
            for tmp in temporaries:
                tmp.unlink(missing_ok=True)
            raise
        return dom_path, dem_path


# ---------------------------------------------------------------------------------------------
# Public entry point
# ---------------------------------------------------------------------------------------------


def generate_reference(
    center_lon_deg: float,
    center_lat_deg: float,
    width_m: float,
    height_m: float,
    *,
    seed: int = 0,
    dom_resolution_m: float = 15.0,
    dem_resolution_m: float = 30.0,
    relief_m: float = 1500.0,
    mean_height_m: float = 400.0,
    sea_fraction: float = 0.15,
    sea_level_m: float = 0.0,
    sun_azimuth_deg: float = 135.0,
    sun_elevation_deg: float = 45.0,
    urban_fraction: float = 0.05,
    forest_fraction: float = 0.30,
    n_lakes: int | None = None,
    n_rivers: int | None = None,
    n_roads: int | None = None,
    progress=None,
) -> ReferenceData:
    """Generate a procedural reference orthoimage (DOM), DEM and water mask.

    Parameters
    ----------
    center_lon_deg, center_lat_deg : float
        WGS84 longitude in [-180, 180] and latitude in [-84, 84] of the area centre, degrees.
    width_m, height_m : float
        Extent east-west and north-south, metres (> 0). See the module notes for the snapping
        of the extent to whole pixels.
    seed : int
        Seed (>= 0) of ``numpy.random.default_rng``; same seed and arguments, same bytes.
    dom_resolution_m, dem_resolution_m : float
        Pixel sizes of the DOM and the DEM, metres (> 0).
    relief_m : float
        Range of the DEM heights (max - min), metres (>= 0; 0 gives flat terrain).
    mean_height_m : float
        Mean ellipsoidal height of the land, metres (see the module notes when there is a sea).
    sea_fraction : float
        Fraction of the DEM area covered by open sea, on one side of a coastline, in [0, 0.9]
        (0: no sea).
    sea_level_m : float
        Ellipsoidal height of the sea surface, metres.
    sun_azimuth_deg, sun_elevation_deg : float
        Sun direction for the shading: azimuth clockwise from grid north, elevation in (0, 90].
    urban_fraction, forest_fraction : float
        Target fractions of the land covered by towns and by forest (each in [0, 0.8], sum
        <= 0.95).
    n_lakes, n_rivers, n_roads : int, optional
        Numbers of lakes, of channel heads of the river network (each a source; rivers join
        downstream) and of major roads; by default about one lake per 200 km^2, one river
        source per 250 km^2 and one road per 150 km^2 (plus one). Lakes and rivers may be
        fewer where the terrain offers no room for them.
    progress : callable(done, total), optional
        Called as the phases end: the terrain, lakes, rivers, heights, land cover and roads
        (one part each), then every strip of DOM rows rendered
        (:func:`~sensor_models.simulate.procedural_dom.dom_strips`), then the blur and noise.

    Returns
    -------
    ReferenceData

    Raises
    ------
    InputError
        On a bad argument (the message names it).
    """
    given = dict(locals())
    del given["progress"]
    args = _validated(given)
    crs, dom_grid, dem_grid, dom, dem_m, water, land_cover = _synthesize(args, progress)
    for a in (dom, dem_m, water, land_cover):
        a.setflags(write=False)
    return ReferenceData(
        dom=dom,
        dom_transform=dom_grid.transform,
        dem_m=dem_m,
        dem_transform=dem_grid.transform,
        crs=crs,
        water_mask=water,
        land_cover=land_cover,
        parameters={"generator": "sensor_models.simulate.procedural",
                    "generator_version": GENERATOR_VERSION, **args},
    )


#: phases of the terrain, water, cover and roads counted before the DOM's strips (progress)
_PHASES = 6


def _synthesize(args, progress=None):
    """Every phase of :func:`generate_reference` in order, on one random stream.

    ``progress(done, total)`` (optional) counts the phases and the DOM's strips. Returns
    ``(crs, dom_grid, dem_grid, dom, dem_m, water, land_cover)``.
    """
    rng = np.random.default_rng(args["seed"])
    base_key = int(rng.integers(0, 2**32, dtype=np.uint64))
    keys = (int(hash32(base_key, np.array([i]))[0]) for i in itertools.count())
    crs, centre, dom_grid, dem_grid = _reference_grids(args)
    ext = dem_grid.grown(MARGIN_NODES)
    area_km2 = args["width_m"] * args["height_m"] / 1e6

    total = _PHASES + dom_strips(dom_grid.n_rows, dom_grid.n_cols) + 1
    done = [0]

    def step(n=1):
        done[0] += n
        if progress is not None:
            progress(done[0], total)

    if progress is not None:
        progress(0, total)
    terrain = draw_terrain(args, ext, centre, rng, keys)
    step()
    lakes = fill_lakes(args, ext, terrain, rng, area_km2)
    step()
    rivers = draw_rivers(args, ext, terrain, lakes, rng, area_km2)
    step()
    heights_ext = _heights(args, ext, terrain, lakes, rivers)
    step()

    inner = ext.inner(MARGIN_NODES)
    dem_m = np.ascontiguousarray(heights_ext[inner])
    cover = cover_fields(args, ext, terrain, heights_ext, keys)
    step()
    roads = draw_roads(args, dom_grid, rng, area_km2)
    step()
    dom, water, land_cover = render_dom(
        args, dom_grid, ext, centre, terrain, lakes, rivers, roads, cover, rng, keys, strip_done=step
    )
    step()
    return crs, dom_grid, dem_grid, dom, dem_m, water, land_cover


def _reference_grids(args):
    """``(crs, (cx_m, cy_m), dom_grid, dem_grid)``: the UTM zone and the DOM and DEM grids."""
    crs, cx_m, cy_m = _utm(args["center_lon_deg"], args["center_lat_deg"])
    size = (args["width_m"], args["height_m"])
    dom_grid = _Grid.centred(cx_m, cy_m, *size, args["dom_resolution_m"])
    dem_grid = _Grid.centred(cx_m, cy_m, *size, args["dem_resolution_m"])
    if dom_grid.n_rows * dom_grid.n_cols > _MAX_DOM_PIXELS:
        raise InputError(
            f"the DOM would have {dom_grid.n_rows} x {dom_grid.n_cols} pixels, more than "
            f"{_MAX_DOM_PIXELS}; use a coarser dom_resolution_m or a smaller area",
            field="width_m",
        )
    return crs, (cx_m, cy_m), dom_grid, dem_grid


# ---------------------------------------------------------------------------------------------
# Validation and grids
# ---------------------------------------------------------------------------------------------


def _validated(given) -> dict:
    """The arguments as plain Python values; InputError naming the first bad one."""
    out = {}

    def number(name, *, low=None, high=None, low_open=False, high_open=False):
        value = given[name]
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
            raise InputError(f"must be a number, got {value!r}", field=name)
        value = float(value)
        bad = not math.isfinite(value)
        bad |= low is not None and (value <= low if low_open else value < low)
        bad |= high is not None and (value >= high if high_open else value > high)
        if bad:
            lo = "" if low is None else ("(" if low_open else "[") + f"{low:g}"
            hi = "" if high is None else f"{high:g}" + (")" if high_open else "]")
            interval = f"{lo or '(-inf'}, {hi or 'inf)'}"
            raise InputError(f"must be finite and in {interval}, got {given[name]!r}", field=name)
        out[name] = value

    def count(name):
        value = given[name]
        if value is None:
            out[name] = None
            return
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise InputError(f"must be an integer or None, got {value!r}", field=name)
        if not 0 <= int(value) <= 10_000:
            raise InputError(f"must be in [0, 10000], got {value!r}", field=name)
        out[name] = int(value)

    number("center_lon_deg", low=-180.0, high=180.0)
    number("center_lat_deg", low=-84.0, high=84.0)
    number("width_m", low=0.0, high=2_000_000.0, low_open=True)
    number("height_m", low=0.0, high=2_000_000.0, low_open=True)
    seed = given["seed"]
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"must be an integer >= 0, got {seed!r}", field="seed")
    out["seed"] = int(seed)
    number("dom_resolution_m", low=0.0, low_open=True)
    number("dem_resolution_m", low=0.0, low_open=True)
    number("relief_m", low=0.0, high=9000.0)
    number("mean_height_m", low=-500.0, high=9000.0)
    number("sea_fraction", low=0.0, high=0.9)
    number("sea_level_m", low=-200.0, high=200.0)
    number("sun_azimuth_deg", low=-360.0, high=360.0)
    number("sun_elevation_deg", low=0.0, high=90.0, low_open=True)
    number("urban_fraction", low=0.0, high=0.8)
    number("forest_fraction", low=0.0, high=0.8)
    if out["urban_fraction"] + out["forest_fraction"] > 0.95:
        raise InputError("urban_fraction + forest_fraction must be <= 0.95",
                         field="forest_fraction")
    for name in ("n_lakes", "n_rivers", "n_roads"):
        count(name)
    for size in ("width_m", "height_m"):
        for res in ("dom_resolution_m", "dem_resolution_m"):
            if out[size] < 8.0 * out[res]:
                raise InputError(
                    f"must hold at least 8 pixels of {res} = {out[res]:g} m, got {out[size]:g} m",
                    field=size,
                )
    return out


def _utm(lon_deg, lat_deg):
    """UTM CRS of the standard zone holding the point, and the point's easting and northing."""
    zone = int(math.floor((lon_deg + 180.0) / 6.0)) % 60 + 1
    epsg = (32600 if lat_deg >= 0.0 else 32700) + zone
    crs = pyproj.CRS.from_epsg(epsg)
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    x, y = to_utm.transform(lon_deg, lat_deg)
    return crs, float(x), float(y)


@dataclass(frozen=True)
class _Grid:
    """A north-up grid: ``n_rows x n_cols`` square pixels of ``res_m`` from corner (x0, y0)."""

    n_rows: int
    n_cols: int
    res_m: float
    x0_m: float
    y0_m: float

    @classmethod
    def centred(cls, cx_m, cy_m, width_m, height_m, res_m):
        n_cols = max(1, math.ceil(width_m / res_m - 1e-9))
        n_rows = max(1, math.ceil(height_m / res_m - 1e-9))
        return cls(n_rows, n_cols, res_m, cx_m - 0.5 * n_cols * res_m, cy_m + 0.5 * n_rows * res_m)

    def grown(self, m):
        return _Grid(self.n_rows + 2 * m, self.n_cols + 2 * m, self.res_m,
                     self.x0_m - m * self.res_m, self.y0_m + m * self.res_m)

    def inner(self, m):
        return (slice(m, self.n_rows - m), slice(m, self.n_cols - m))

    @property
    def shape(self):
        return (self.n_rows, self.n_cols)

    @property
    def transform(self) -> Affine:
        return Affine(self.res_m, 0.0, self.x0_m, 0.0, -self.res_m, self.y0_m)

    def x_m(self):
        """Eastings of the pixel centres, shape (n_cols,)."""
        return self.x0_m + (np.arange(self.n_cols) + 0.5) * self.res_m

    def y_m(self):
        """Northings of the pixel centres, shape (n_rows,)."""
        return self.y0_m - (np.arange(self.n_rows) + 0.5) * self.res_m

    def node_index(self, x_m, y_m):
        """Fractional node indices ``(col, row)`` (first node centre at 0) of coordinates."""
        return ((np.asarray(x_m) - self.x0_m) / self.res_m - 0.5,
                (self.y0_m - np.asarray(y_m)) / self.res_m - 0.5)


# ---------------------------------------------------------------------------------------------
# The DEM: terrain shape, flat lakes, carved river beds
# ---------------------------------------------------------------------------------------------


def _heights(args, ext, terrain, lakes, rivers):
    """Ellipsoidal heights on the extended DEM grid: lakes flat, river beds carved."""
    shape = lakes.shape.copy()
    relief = args["relief_m"]
    if relief > 0.0 and rivers:
        carve = np.full(ext.shape, np.inf, dtype=np.float32)
        for extra, bank_m in ((6, 8.0), (2, 2.0), (0, 0.0)):
            layer = np.full(ext.shape, np.inf, dtype=np.float32)
            for river in rivers:
                col, row = ext.node_index(river.xy_m[:, 0], river.xy_m[:, 1])
                pts = np.stack([col + 0.5, row + 0.5], axis=1)
                thick = np.maximum(1, np.round(river.width_m / ext.res_m)).astype(int) + extra
                draw_segments(layer, pts, river.bed[1:] + bank_m / relief, thick[1:])
            np.minimum(carve, layer, out=carve)
        np.minimum(shape, carve, out=shape)
        shape[~terrain.land] = 0.0
    land_area = terrain.land & terrain.in_area
    if args["sea_fraction"] > 0.0:
        base = args["sea_level_m"]
    else:
        base = args["mean_height_m"] - relief * float(shape[land_area].mean(dtype=np.float64))
    h = base + relief * shape.astype(np.float64)
    h[~terrain.land] = args["sea_level_m"]
    return (np.round(h / _DEM_QUANTUM_M) * _DEM_QUANTUM_M).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# GeoTIFF output
# ---------------------------------------------------------------------------------------------


def _temporary(path: Path) -> Path:
    try:
        return temporary_beside(path, ".tif")
    except OSError as err:
        raise InputError(f"cannot create a file there ({err})", path=str(path)) from err


def _write_geotiff(tmp, data, transform, crs, *, predictor, tags, target):
    """One band, tiled 256 x 256, DEFLATE with ``predictor``; no nodata, no timestamp."""
    import rasterio
    from rasterio.crs import CRS as RioCRS
    from rasterio.errors import RasterioError

    n_rows, n_cols = data.shape
    profile = dict(
        driver="GTiff", width=n_cols, height=n_rows, count=1, dtype=data.dtype.name,
        crs=RioCRS.from_wkt(crs.to_wkt()), transform=transform, tiled=True,
        blockxsize=256, blockysize=256, compress="deflate", predictor=predictor, zlevel=9,
        interleave="band",
    )
    try:
        with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
            with rasterio.open(tmp, "w", **profile) as dst:
                dst.update_tags(**tags)
                dst.write(data, 1)
    except (RasterioError, OSError) as err:
        raise InputError(f"cannot write the GeoTIFF ({err})", path=str(target)) from err
