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
from enum import IntEnum
from pathlib import Path

import numpy as np
import pyproj
from affine import Affine
from scipy import fft as sp_fft
from scipy import ndimage

from sensor_models.maps.dom_inputs import ACCURACY_TAG
from sensor_models.files.atomic import temporary_beside
from sensor_models.errors import InputError

__all__ = ["LandCover", "ReferenceData", "generate_reference", "illumination"]

#: Version of the generator, written into the files' provenance tag.
GENERATOR_VERSION = 1

#: Digital number of reflectance 0 (path radiance) and DN per unit reflectance.
_DN_OFFSET = 200.0
_DN_GAIN = 9000.0
#: Largest DN (12-bit) and standard deviation of the sensor noise, DN.
_DN_MAX = 4095
_NOISE_DN = 2.5
#: Gaussian point-spread function of the sensor, pixels.
_PSF_SIGMA_PX = 0.6
#: DEM heights are rounded to multiples of this (a power of two: exact in float32).
_DEM_QUANTUM_M = 1.0 / 16.0
#: Nodes added around the DEM grid while generating (Keys interpolation needs 2).
_MARGIN_NODES = 4
#: DOM rows processed together (bounds the memory of the texture synthesis).
_STRIP_ROWS = 256
#: Exponent of u in the height of the land when there is no sea.
_GAMMA_NO_SEA = 1.6
#: At most this many DOM pixels (about 4 GB of working memory).
_MAX_DOM_PIXELS = 150_000_000
#: Hurst exponent of the fBm relief and wavelength below which it is rolled off, metres.
_HURST = 0.8
_ROLL_OFF_M = 400.0
#: Fraction of diffuse (sky) irradiance in the shading.
_DIFFUSE = 0.25
#: Standard deviation of B-spline value noise made of uniform(-1, 1) nodes:
#: sqrt(1/3) * (integral of the sum of squared cubic B-spline weights = 151/315) per axis.
_VALUE_NOISE_STD = math.sqrt(1.0 / 3.0) * (151.0 / 315.0)


class LandCover(IntEnum):
    """Codes of :attr:`ReferenceData.land_cover` (0 is not used)."""

    SEA = 1
    LAKE = 2
    RIVER = 3
    FIELD = 4
    FOREST = 5
    URBAN = 6
    GRASS = 7
    ROCK = 8
    ROAD = 9
    BEACH = 10


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
        :class:`LandCover` codes on the DOM grid.
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

    Returns
    -------
    ReferenceData

    Raises
    ------
    InputError
        On a bad argument (the message names it).
    """
    args = _validated(locals())
    crs, dom_grid, dem_grid, dom, dem_m, water, land_cover = _synthesize(args)
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


def _synthesize(args):
    """Every phase of :func:`generate_reference` in order, on one random stream.

    Returns ``(crs, dom_grid, dem_grid, dom, dem_m, water, land_cover)``.
    """
    rng = np.random.default_rng(args["seed"])
    base_key = int(rng.integers(0, 2**32, dtype=np.uint64))
    keys = (int(_hash(base_key, np.array([i]))[0]) for i in itertools.count())
    crs, centre, dom_grid, dem_grid = _reference_grids(args)
    ext = dem_grid.grown(_MARGIN_NODES)
    area_km2 = args["width_m"] * args["height_m"] / 1e6

    terrain = _terrain(args, ext, centre, rng, keys)
    lakes = _lakes(args, ext, terrain, rng, area_km2)
    rivers = _rivers(args, ext, terrain, lakes, rng, area_km2)
    heights_ext = _heights(args, ext, terrain, lakes, rivers)

    inner = ext.inner(_MARGIN_NODES)
    dem_m = np.ascontiguousarray(heights_ext[inner])
    cover = _cover_fields(args, ext, terrain, heights_ext, keys)
    roads = _roads(args, dom_grid, rng, area_km2)
    dom, water, land_cover = _render_dom(
        args, dom_grid, ext, centre, terrain, lakes, rivers, roads, cover, rng, keys
    )
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


def illumination(heights_m, resolution_m, *, sun_azimuth_deg, sun_elevation_deg):
    """Cosine of the solar incidence angle on a north-up height grid (Lambert, [4]_).

    ``cos i = (-h_x sin(A) cos(E) - h_y cos(A) cos(E) + sin(E)) / sqrt(1 + h_x^2 + h_y^2)``
    with ``h_x = dh/dx`` (east) and ``h_y = dh/dy`` (north) by central differences (one-sided
    at the border), ``A`` the sun azimuth clockwise from north and ``E`` its elevation.

    Parameters
    ----------
    heights_m : array_like, shape (rows, cols)
        Heights on a north-up grid (row 0 is the northern edge), metres.
    resolution_m : float
        Grid spacing, metres.
    sun_azimuth_deg, sun_elevation_deg : float
        Sun direction, degrees.

    Returns
    -------
    cos_incidence : ndarray, shape (rows, cols), float32
        Negative where the slope faces away from the sun (self-shadow).
    """
    h = np.asarray(heights_m, dtype=np.float64)
    dh_drow, dh_dcol = np.gradient(h, float(resolution_m))
    hx, hy = dh_dcol, -dh_drow
    az, el = math.radians(sun_azimuth_deg), math.radians(sun_elevation_deg)
    num = (-hx * (math.sin(az) * math.cos(el)) - hy * (math.cos(az) * math.cos(el))
           + math.sin(el))
    return (num / np.sqrt(1.0 + hx * hx + hy * hy)).astype(np.float32)


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
# Hashing, value noise and separable cubic resampling
# ---------------------------------------------------------------------------------------------


def _mix32(h):
    """Wellons' lowbias32 integer mixer on a uint32 array (wrapping arithmetic), in place."""
    h ^= h >> np.uint32(16)
    h *= np.uint32(0x7FEB352D)
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x846CA68B)
    h ^= h >> np.uint32(16)
    return h


def _hash(key, *ints):
    """uint32 hash of a key and integer arrays (broadcast together); at least 1-D."""
    shape = np.broadcast_shapes(*(np.shape(a) for a in ints)) or (1,)
    h = np.full(shape, key & 0xFFFFFFFF, dtype=np.uint32)
    for a in ints:
        a = np.asarray(a)
        if a.dtype != np.uint32:
            a = (a.astype(np.int64) & 0xFFFFFFFF).astype(np.uint32)
        h ^= a
        _mix32(h)
        h += np.uint32(0x9E3779B9)
    return _mix32(h)


def _unit(h):
    """Uniform [0, 1) float32 from the top 24 bits of a uint32 hash."""
    return (h >> np.uint32(8)).astype(np.float32) * np.float32(2.0**-24)


def _taps(t, kind):
    """Node offsets and weights at fraction ``t`` in [0, 1) of the interpolation kernels.

    ``"keys"``: Keys cubic convolution with ``a = -1/2`` [6]_ (interpolating, C1);
    ``"bspline"``: uniform cubic B-spline (smoothing, C2); ``"linear"``: two taps.
    """
    t = t.astype(np.float32)
    if kind == "linear":
        return (0, 1), (1.0 - t, t)
    t2 = t * t
    t3 = t2 * t
    if kind == "bspline":
        s = 1.0 - t
        return (-1, 0, 1, 2), (s * s * s / 6.0, (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
                               (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0, t3 / 6.0)
    return (-1, 0, 1, 2), (-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0,
                           -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2)


def _resample(grid, row_f, col_f, kind="keys"):
    """Separable resampling of node grids at the outer product of rows and columns.

    Parameters
    ----------
    grid : ndarray, shape (..., R, C), float32
        Values at integer node indices.
    row_f, col_f : ndarray, shape (m,) and (n,)
        Fractional node indices of the output rows and columns (nodes clamped at the edges).
    kind : {"keys", "bspline", "linear"}
        Kernel (see :func:`_taps`).

    Returns
    -------
    ndarray, shape (..., m, n), float32
    """
    n_r, n_c = grid.shape[-2:]
    r0 = np.floor(row_f).astype(np.intp)
    c0 = np.floor(col_f).astype(np.intp)
    lo = max(int(r0.min()) - 1, 0)
    hi = min(int(r0.max()) + 3, n_r)
    sub = grid[..., lo:hi, :]
    tmp = None
    for k, w in zip(*_taps(col_f - c0, kind)):
        term = np.take(sub, np.clip(c0 + k, 0, n_c - 1), axis=-1)
        term *= w
        tmp = term if tmp is None else np.add(tmp, term, out=tmp)
    out = None
    for k, w in zip(*_taps(row_f - r0, kind)):
        term = np.take(tmp, np.clip(r0 + k, 0, n_r - 1) - lo, axis=-2)
        term *= w[:, None]
        out = term if out is None else np.add(out, term, out=out)
    return out


def _value_noise(key, x_m, y_m, spacing_m):
    """Smooth noise of unit standard deviation (on average) on a separable grid of points.

    Uniform(-1, 1) values at the nodes of a square lattice of ``spacing_m`` (offset by a
    key-dependent fraction of a cell), blended by the cubic B-spline. The value at a point
    depends only on ``key`` and its coordinates, whatever the grid it is evaluated on.

    Parameters
    ----------
    key : int
    x_m : ndarray, shape (n,)
        Eastings of the columns (any origin), metres.
    y_m : ndarray, shape (m,)
        Northings of the rows, metres.
    spacing_m : float

    Returns
    -------
    ndarray, shape (m, n), float32
    """
    off = (key % 997) / 997.0
    gx = np.asarray(x_m, dtype=np.float64) / spacing_m + off
    gy = np.asarray(y_m, dtype=np.float64) / spacing_m + off
    jx0 = int(np.floor(gx.min())) - 1
    jx1 = int(np.floor(gx.max())) + 2
    jy0 = int(np.floor(gy.min())) - 1
    jy1 = int(np.floor(gy.max())) + 2
    jx = np.arange(jx0, jx1 + 1)
    jy = np.arange(jy0, jy1 + 1)
    nodes = _unit(_hash(key, jy[:, None], jx[None, :])) * np.float32(2.0) - np.float32(1.0)
    out = _resample(nodes, gy - jy0, gx - jx0, "bspline")
    out *= np.float32(1.0 / _VALUE_NOISE_STD)
    return out


def _smoothstep(a, b, x):
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# ---------------------------------------------------------------------------------------------
# Terrain
# ---------------------------------------------------------------------------------------------


@dataclass
class _Terrain:
    """Fields on the extended DEM grid (float32, shape of ``ext``)."""

    u: np.ndarray          # normalised land shape in [0, 1] (0 over the sea)
    shape: np.ndarray      # u ** gamma before lakes and rivers
    coast: np.ndarray      # coast field c, metres (sea where c < c0)
    c0: float
    tau: np.ndarray        # coastal taper in [0, 1]
    land: np.ndarray       # bool
    gamma: float
    in_area: np.ndarray    # bool: the nodes of the output DEM


def _terrain(args, ext, centre, rng, keys) -> _Terrain:
    res = ext.res_m
    x = ext.x_m() - centre[0]
    y = ext.y_m() - centre[1]
    fbm, ridged = _spectral_relief(rng, ext.shape, res)
    mountains = _smoothstep(-0.3, 1.0, _value_noise(next(keys), x, y, 30_000.0))
    s = 0.45 * (0.35 + 0.65 * mountains) * fbm + mountains * ridged
    del fbm, ridged

    in_area = np.zeros(ext.shape, dtype=bool)
    in_area[ext.inner(_MARGIN_NODES)] = True
    diag_m = math.hypot(args["width_m"], args["height_m"])
    if args["sea_fraction"] > 0.0:
        phi = rng.uniform(0.0, 2.0 * math.pi)
        coast = (np.cos(phi) * x)[None, :] + (np.sin(phi) * y)[:, None]
        spacing, amp = 0.5 * diag_m, 0.09 * diag_m
        while spacing >= 2.0 * res:
            coast += amp * _value_noise(next(keys), x, y, spacing)
            spacing, amp = 0.5 * spacing, amp * 0.5**0.8
        coast = coast.astype(np.float32)
        c0 = float(np.quantile(coast[in_area], args["sea_fraction"]))
        land = coast >= c0
        tau = _smoothstep(0.0, min(5000.0, 0.2 * diag_m), coast - c0).astype(np.float32)
    else:
        coast = np.full(ext.shape, np.float32(1e9), dtype=np.float32)
        c0 = -math.inf
        land = np.ones(ext.shape, dtype=bool)
        tau = np.ones(ext.shape, dtype=np.float32)

    land_area = land & in_area
    if not land_area.any():
        land_area = in_area
    s_lo = float(s[land_area].min())
    s_span = float(s[land_area].max()) - s_lo
    u = (s - s_lo + 0.03 * s_span) * tau
    u_hi = float(u[land_area].max())
    u = np.clip(u / u_hi if u_hi > 0.0 else u * 0.0, 0.0, 1.0).astype(np.float32)
    u[~land] = 0.0

    if args["sea_fraction"] > 0.0 and args["relief_m"] > 0.0:
        sample = u[land_area][::7].astype(np.float64)
        target = (args["mean_height_m"] - args["sea_level_m"]) / args["relief_m"]
        lo, hi = 0.2, 8.0
        for _ in range(40):
            mid = math.sqrt(lo * hi)
            if float(np.mean(sample**mid)) > target:
                lo = mid
            else:
                hi = mid
        gamma = math.sqrt(lo * hi)
    else:
        gamma = _GAMMA_NO_SEA
    shape = np.power(u, np.float32(gamma)).astype(np.float32)
    return _Terrain(u=u, shape=shape, coast=coast, c0=c0, tau=tau, land=land, gamma=gamma,
                    in_area=in_area)


def _spectral_relief(rng, shape, res_m):
    """Fractional Brownian surface and ridged multifractal, unit scale, float32 (Voss; Musgrave).

    Returns
    -------
    fbm : ndarray, shape ``shape``
        Zero mean, unit standard deviation; power spectrum ``(k^2 + k0^2)^(-beta/2)``.
    ridged : ndarray, shape ``shape``
        In [0, ~1.6]: crests where the band-pass fields cross zero.
    """
    n_r, n_c = shape
    ky = sp_fft.fftfreq(n_r, d=res_m).astype(np.float32)[:, None]
    kx = sp_fft.rfftfreq(n_c, d=res_m).astype(np.float32)[None, :]
    k = np.sqrt(ky * ky + kx * kx)
    k[0, 0] = np.float32(1e-12)
    beta, k0, k1 = 2.0 * _HURST + 2.0, 1.0 / 40_000.0, 1.0 / _ROLL_OFF_M
    spectrum = sp_fft.rfft2(rng.standard_normal(shape, dtype=np.float32), workers=1)
    filt = (k * k + np.float32(k0 * k0)) ** np.float32(-beta / 4.0)
    filt *= np.exp(-((k / np.float32(k1)) ** 2))
    filt[0, 0] = 0.0
    fbm = sp_fft.irfft2(spectrum * filt, s=shape, workers=1)
    fbm = _standardised(fbm)

    spectrum = sp_fft.rfft2(rng.standard_normal(shape, dtype=np.float32), workers=1)
    log2k = np.log2(k)
    ridged = np.zeros(shape, dtype=np.float32)
    weight = np.ones(shape, dtype=np.float32)
    for j, wavelength in enumerate((12_000.0, 6000.0, 3000.0, 1500.0, 750.0)):
        if wavelength < 4.0 * res_m:
            break
        band = np.exp(-0.5 * ((log2k + np.float32(math.log2(wavelength))) / 0.6) ** 2)
        band[0, 0] = 0.0
        n = _standardised(sp_fft.irfft2(spectrum * band.astype(np.float32), s=shape, workers=1))
        signal = np.maximum(1.0 - 0.5 * np.abs(n), 0.0) ** 2
        signal *= weight
        weight = np.clip(2.0 * signal, 0.0, 1.0)
        ridged += np.float32(2.0 ** (-1.5 * j)) * signal
    return fbm.astype(np.float32), ridged


def _standardised(a):
    a = a.astype(np.float32, copy=False)
    a -= np.float32(a.mean(dtype=np.float64))
    std = float(a.std(dtype=np.float64))
    if std > 0.0:
        a *= np.float32(1.0 / std)
    return a


# ---------------------------------------------------------------------------------------------
# Lakes
# ---------------------------------------------------------------------------------------------


@dataclass
class _Lakes:
    level: np.ndarray      # lake level (shape units) near each lake, NaN elsewhere (ext grid)
    mask: np.ndarray       # bool: lake nodes (ext grid)
    shape: np.ndarray      # terrain shape with flat lakes


def _lakes(args, ext, terrain, rng, area_km2) -> _Lakes:
    """Fill local basins of the terrain to random areas without spilling (module notes)."""
    shape = terrain.shape.copy()
    level = np.full(ext.shape, np.nan, dtype=np.float32)
    mask = np.zeros(ext.shape, dtype=bool)
    n_lakes = args["n_lakes"]
    if n_lakes is None:
        n_lakes = int(round(area_km2 / 200.0))
    res = ext.res_m
    size = max(3, int(round(1500.0 / res)) | 1)
    if n_lakes == 0 or min(ext.shape) < 2 * size:
        return _Lakes(level, mask, shape)
    minima = ndimage.minimum_filter(shape, size=size, mode="nearest") == shape
    candidates = (minima & terrain.land & terrain.in_area & (terrain.tau > 0.6)
                  & (terrain.u < 0.6) & (terrain.coast - terrain.c0 > 500.0))
    rows, cols = np.nonzero(candidates)
    if rows.size == 0:
        return _Lakes(level, mask, shape)
    order = rng.permutation(rows.size)[: 4 * n_lakes]
    made = 0
    for i in order:
        if made == n_lakes:
            break
        target_nodes = rng.uniform(0.1, min(2.5, 0.02 * area_km2)) * 1e6 / res**2
        half = int(3.0 * math.sqrt(target_nodes / math.pi)) + 3
        r, c = int(rows[i]), int(cols[i])
        r0, r1 = max(r - half, 0), min(r + half + 1, ext.n_rows)
        c0, c1 = max(c - half, 0), min(c + half + 1, ext.n_cols)
        window = shape[r0:r1, c0:c1]
        blocked = ~terrain.land[r0:r1, c0:c1] | mask[r0:r1, c0:c1]
        component, value = _fill_basin(window, blocked, (r - r0, c - c0), target_nodes)
        if component is None:
            continue
        made += 1
        shape[r0:r1, c0:c1][component] = value
        mask[r0:r1, c0:c1] |= component
        # The level is kept on the lake and on the shore nodes above it, so the DOM's
        # shoreline (interpolated terrain = level) is drawn there and nowhere else.
        near = ndimage.binary_dilation(component, iterations=2) & (component | (window > value))
        lv = level[r0:r1, c0:c1]
        lv[near & np.isnan(lv)] = value
    return _Lakes(level, mask, shape)


def _fill_basin(window, blocked, seed_rc, target_nodes):
    """Highest level whose basin around ``seed_rc`` stays under ``target_nodes`` and inside.

    Binary search over the sorted heights of the window; a basin touching the window's edge
    or a blocked node (sea, another lake) has spilled. Returns (component, level) or
    (None, None) when the basin is smaller than 4 nodes.
    """
    heights = np.unique(window[~blocked])
    structure = np.ones((3, 3), dtype=bool)

    def basin(level):
        labels, _ = ndimage.label(window <= level, structure=structure)
        lab = labels[seed_rc]
        if lab == 0:
            return None
        comp = labels == lab
        edge = comp[0].any() or comp[-1].any() or comp[:, 0].any() or comp[:, -1].any()
        if edge or (comp & blocked).any() or comp.sum() > target_nodes:
            return None
        return comp

    lo, hi = 0, heights.size - 1
    best = None
    while lo <= hi:
        mid = (lo + hi) // 2
        comp = basin(heights[mid])
        if comp is None:
            hi = mid - 1
        else:
            best = (comp, float(heights[mid]))
            lo = mid + 1
    if best is None or best[0].sum() < 4:
        return None, None
    return best


# ---------------------------------------------------------------------------------------------
# Rivers
# ---------------------------------------------------------------------------------------------


@dataclass
class _River:
    xy_m: np.ndarray       # (n, 2) eastings and northings of the centre line
    width_m: np.ndarray    # (n,)
    bed: np.ndarray        # (n,) monotone bed level in shape units


def _rivers(args, ext, terrain, lakes, rng, area_km2):
    """A dendritic river network draining the terrain to the sea, lakes or the border.

    On cells of about 120 m (coarser for large areas, at most ~60 000 cells), the smoothed
    terrain shape is drained by Priority-Flood [9]_ from the outlets (sea, lakes and the border
    ring): each cell flows to the cell it was reached from, so every closed basin spills over
    its lowest pass. Drainage areas accumulate down these links; channels are the cells whose
    area exceeds the threshold giving ``n_rivers`` channel heads (about one per 250 km^2 by
    default, and at least 5 km^2). Each channel, from its head down to an outlet or a
    confluence, is smoothed (Chaikin corner cutting) and given irregular meanders (a lateral
    offset of about 2 widths with a wavelength of about 12 widths, see :func:`_meander` and
    [3]_), the width being ``w = clip(8 sqrt(A / km^2), 15, 100) m``. The bed is the running
    minimum of the terrain along the channel, so it never rises downstream.
    """
    n_heads = args["n_rivers"]
    if n_heads is None:
        n_heads = int(round(area_km2 / 250.0))
    res = ext.res_m
    cell_m = max(120.0, math.sqrt(area_km2 * 1e6 / 60_000.0), res)
    f = max(1, int(round(cell_m / res)))
    cell_m = f * res
    nr, nc = ext.n_rows // f, ext.n_cols // f
    if n_heads == 0 or min(nr, nc) < 8:
        return []

    def blocks(a, how):
        a = a[: nr * f, : nc * f].reshape(nr, f, nc, f)
        return a.mean(axis=(1, 3), dtype=np.float64) if how == "mean" else a.any(axis=(1, 3))

    height = ndimage.gaussian_filter(blocks(lakes.shape, "mean"), 1.0, mode="nearest")
    outlet = blocks(~terrain.land | lakes.mask, "any")
    ring = max(1, int(math.ceil(_MARGIN_NODES / f)))
    outlet[:ring], outlet[-ring:], outlet[:, :ring], outlet[:, -ring:] = True, True, True, True
    parent, order = _priority_flood(height, outlet)
    area = np.ones(nr * nc, dtype=np.float64)
    for i in order[::-1]:
        if parent[i] >= 0:
            area[parent[i]] += area[i]
    area *= cell_m * cell_m / 1e6  # km^2
    heads = _channel_heads(area, parent, outlet.ravel(), n_heads, min_km2=5.0)
    if heads.size == 0:
        return []

    owner = np.full(nr * nc, -1, dtype=np.intp)
    rivers, paths = [], []
    for head in heads:
        cells = [head]
        while parent[cells[-1]] >= 0 and owner[cells[-1]] < 0 and not outlet.flat[cells[-1]]:
            cells.append(parent[cells[-1]])
        cells = np.asarray(cells)
        join = owner[cells[-1]]
        own = cells if join < 0 else cells[:-1]
        owner[own] = len(paths)
        r, c = np.divmod(cells, nc)
        node_r = r * f + 0.5 * (f - 1)
        node_c = c * f + 0.5 * (f - 1)
        xy = np.stack([ext.x0_m + (node_c + 0.5) * res, ext.y0_m - (node_r + 0.5) * res], axis=1)
        width = np.clip(8.0 * np.sqrt(area[cells]), 15.0, 100.0)
        xy, width = _chaikin(xy, width, 3)
        xy, width = _meander(xy, width, rng, fixed_end=join >= 0)
        if join >= 0:
            # End on the (meandering) centre line of the river joined.
            other = paths[join]
            k = int(np.argmin(np.sum((other - xy[-1]) ** 2, axis=1)))
            xy = np.concatenate([xy, other[k:k + 1]])
            width = np.concatenate([width, width[-1:]])
        paths.append(xy)
        col, row = ext.node_index(xy[:, 0], xy[:, 1])
        bed = ndimage.map_coordinates(lakes.shape, [row, col], order=1, mode="nearest")
        rivers.append(_River(xy, width, np.minimum.accumulate(bed.astype(np.float64))))
    return rivers


def _priority_flood(height, outlet):
    """Drainage links of a grid by Priority-Flood from outlet cells (Barnes et al. 2014).

    Cells are taken from a priority queue in order of their filled height (ties first in,
    first out, so flats drain towards their spill point); each unvisited 8-neighbour is
    linked to the cell it was reached from and queued at ``max(own height, that height)``.

    Returns
    -------
    parent : ndarray, shape (rows * cols,), intp
        Flat index of the cell each cell drains to; -1 for outlets.
    order : ndarray, shape (rows * cols,), intp
        Cells in the order they left the queue (every cell after the one it drains to).
    """
    import heapq

    nr, nc = height.shape
    h = height.ravel().tolist()
    parent = np.full(nr * nc, -1, dtype=np.intp)
    parent_list = parent.tolist()
    closed = bytearray(outlet.ravel().astype(np.uint8).tobytes())
    queue = [(h[i], i, i) for i in np.flatnonzero(outlet.ravel()).tolist()]
    heapq.heapify(queue)
    counter = nr * nc
    order = []
    steps = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))
    while queue:
        level, _, i = heapq.heappop(queue)
        order.append(i)
        r, c = divmod(i, nc)
        for dr, dc in steps:
            rr, cc = r + dr, c + dc
            if 0 <= rr < nr and 0 <= cc < nc:
                j = rr * nc + cc
                if not closed[j]:
                    closed[j] = 1
                    parent_list[j] = i
                    heapq.heappush(queue, (max(h[j], level), counter, j))
                    counter += 1
    return np.asarray(parent_list, dtype=np.intp), np.asarray(order, dtype=np.intp)


def _channel_heads(area_km2, parent, outlet, n_heads, *, min_km2):
    """Channel heads for the drainage-area threshold giving about ``n_heads`` of them.

    A head is a land cell whose area reaches the threshold while none of its upstream
    neighbours does. Returned in decreasing order of drainage area (largest rivers first).
    """
    land = ~outlet

    def heads_for(threshold):
        big = (area_km2 >= threshold) & land
        fed = np.zeros(area_km2.size, dtype=bool)
        up = np.flatnonzero(big & (parent >= 0))
        fed[parent[up]] = True
        return np.flatnonzero(big & ~fed)

    candidates = np.unique(area_km2[land & (area_km2 >= min_km2)])
    if candidates.size == 0:
        return np.zeros(0, dtype=np.intp)
    lo, hi = 0, candidates.size - 1  # more heads at lower thresholds
    while lo < hi:
        mid = (lo + hi) // 2
        if heads_for(candidates[mid]).size > n_heads:
            lo = mid + 1
        else:
            hi = mid
    heads = heads_for(candidates[lo])
    return heads[np.argsort(-area_km2[heads], kind="stable")]


def _chaikin(xy, width, iterations):
    """Chaikin corner cutting of a polyline (end points kept) and of its per-vertex widths."""
    for _ in range(iterations):
        if xy.shape[0] < 3:
            break
        q = 0.75 * xy[:-1] + 0.25 * xy[1:]
        r = 0.25 * xy[:-1] + 0.75 * xy[1:]
        wq = 0.75 * width[:-1] + 0.25 * width[1:]
        wr = 0.25 * width[:-1] + 0.75 * width[1:]
        inner = np.stack([q, r], axis=1).reshape(-1, 2)[1:-1]
        inner_w = np.stack([wq, wr], axis=1).reshape(-1)[1:-1]
        xy = np.concatenate([xy[:1], inner, xy[-1:]])
        width = np.concatenate([width[:1], inner_w, width[-1:]])
    return xy, width


def _meander(xy, width, rng, *, fixed_end):
    """Resample a centre line every ~w/2 and offset it laterally into meanders.

    Returns the new vertices ``(m, 2)`` and their widths ``(m,)``.

    The offset is ``a(s) sin(phi(s))`` with ``phi' = 2 pi / lambda(s)``, a wavelength
    ``lambda = 12 w (1 + 0.3 sin(...))`` and an amplitude ``a = w (1.8 + 1.2 sin(...))``, both
    slowly modulated with random phases so that the bends are irregular; it fades in over the
    first wavelength and, when the river ends on another one (``fixed_end``), out over the last.
    """
    phases = rng.uniform(0.0, 2.0 * math.pi, 3)
    seg = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0.0:
        return xy, width
    step = max(0.5 * float(width.min()), 5.0)
    s_new = np.linspace(0.0, s[-1], max(2, int(s[-1] / step) + 1))
    xy = np.stack([np.interp(s_new, s, xy[:, 0]), np.interp(s_new, s, xy[:, 1])], axis=1)
    w = np.interp(s_new, s, width)
    base = 12.0 * w
    wavelength = base * (1.0 + 0.3 * np.sin(2.0 * math.pi * s_new / (4.1 * base) + phases[1]))
    amplitude = w * (1.8 + 1.2 * np.sin(2.0 * math.pi * s_new / (7.3 * base) + phases[2]))
    ds = np.diff(s_new, prepend=0.0)
    phi = phases[0] + np.cumsum(2.0 * math.pi * ds / wavelength)
    fade = np.clip(s_new / base, 0.0, 1.0)
    if fixed_end:
        fade = np.minimum(fade, np.clip((s_new[-1] - s_new) / base, 0.0, 1.0))
    tangent = np.gradient(xy, axis=0)
    tangent /= np.maximum(np.hypot(tangent[:, 0], tangent[:, 1]), 1e-12)[:, None]
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    return xy + (amplitude * np.sin(phi) * fade)[:, None] * normal, w


def _draw_segments(canvas, pts_px, values, thickness, *, antialias=False):
    """Draw consecutive segments of a polyline (pixel-centre coordinates) with OpenCV.

    ``values[i]`` and ``thickness[i]`` apply to segment ``i`` (points i, i+1); points are in
    continuous pixel coordinates (first pixel centre at 0.5, 0.5), columns then rows.
    """
    import cv2

    fixed = np.round((pts_px - 0.5) * 16.0).astype(np.int32)
    line = cv2.LINE_AA if antialias else cv2.LINE_8
    for i in range(fixed.shape[0] - 1):
        cv2.line(canvas, (int(fixed[i, 0]), int(fixed[i, 1])),
                 (int(fixed[i + 1, 0]), int(fixed[i + 1, 1])), float(values[i]),
                 thickness=int(thickness[i]), lineType=line, shift=4)


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
                _draw_segments(layer, pts, river.bed[1:] + bank_m / relief, thick[1:])
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
# Land-cover fields on the DEM grid
# ---------------------------------------------------------------------------------------------


@dataclass
class _Cover:
    """Fields on the extended DEM grid carried to the DOM grid, and class thresholds."""

    sharp: np.ndarray      # (2, R, C): _SHARP fields, Keys-interpolated (boundaries)
    smooth: np.ndarray     # (8, R, C): _SMOOTH fields, linearly interpolated
    urban_t: float
    forest_t: float


_SHARP = ("shape_pre", "coast")
_SMOOTH = ("shade", "slope_deg", "urban", "forest", "med", "low", "warp_x", "warp_y")


def _cover_fields(args, ext, terrain, heights, keys) -> _Cover:
    """Shading, slope, land-cover scores and medium-scale noises on the DEM grid.

    ``shade = ((1 - d) max(cos i, 0) + d (1 + cos slope) / 2) / ((1 - d) sin E + d)`` with the
    diffuse fraction ``d`` (1 on flat ground). The urban score favours low, flat land near
    the coast; the forest score slopes and mid heights; each is thresholded at the quantile
    that gives ``urban_fraction`` and ``forest_fraction`` of the land.
    """
    res = ext.res_m
    x = ext.x_m() - ext.x_m().mean()
    y = ext.y_m() - ext.y_m().mean()
    cos_i = illumination(heights, res, sun_azimuth_deg=args["sun_azimuth_deg"],
                         sun_elevation_deg=args["sun_elevation_deg"])
    dh_r, dh_c = np.gradient(heights, np.float32(res))
    cos_slope = 1.0 / np.sqrt(1.0 + dh_r * dh_r + dh_c * dh_c)
    del dh_r, dh_c
    slope_deg = np.degrees(np.arccos(np.minimum(cos_slope, 1.0))).astype(np.float32)
    sin_el = math.sin(math.radians(args["sun_elevation_deg"]))
    shade = ((1.0 - _DIFFUSE) * np.maximum(cos_i, 0.0) + _DIFFUSE * 0.5 * (1.0 + cos_slope))
    shade = (shade / ((1.0 - _DIFFUSE) * sin_el + _DIFFUSE)).astype(np.float32)
    del cos_slope, cos_i

    urban = (0.8 * _value_noise(next(keys), x, y, 9000.0)
             + 0.5 * _value_noise(next(keys), x, y, 2500.0))
    urban -= 1.2 * terrain.u + slope_deg / 8.0
    if args["sea_fraction"] > 0.0:
        urban += 0.3 * np.exp(-np.maximum(terrain.coast - terrain.c0, 0.0) / 3000.0)
    forest = (_value_noise(next(keys), x, y, 3000.0) + 0.6 * _value_noise(next(keys), x, y, 1000.0)
              + 0.4 * _value_noise(next(keys), x, y, 350.0))
    forest += slope_deg / 12.0 + 1.2 * _smoothstep(0.05, 0.3, terrain.u)

    land = terrain.land & terrain.in_area
    urban_t = forest_t = math.inf
    if land.sum() > 16:
        if args["urban_fraction"] > 0.0:
            urban_t = float(np.quantile(urban[land], 1.0 - args["urban_fraction"]))
        rest = land & ~(urban > urban_t)
        if args["forest_fraction"] > 0.0 and rest.any():
            q = min(args["forest_fraction"] * land.sum() / rest.sum(), 1.0)
            forest_t = float(np.quantile(forest[rest], 1.0 - q))
    smooth = np.empty((len(_SMOOTH),) + ext.shape, dtype=np.float32)
    smooth[0], smooth[1], smooth[2], smooth[3] = shade, slope_deg, urban, forest
    del shade, slope_deg, urban, forest
    for i, spacing in zip(range(4, 8), (300.0, 2000.0, 1200.0, 1200.0)):
        smooth[i] = _value_noise(next(keys), x, y, spacing)
    sharp = np.stack([terrain.shape, terrain.coast]).astype(np.float32)
    return _Cover(sharp=sharp, smooth=smooth, urban_t=urban_t, forest_t=forest_t)


@dataclass
class _Road:
    xy_m: np.ndarray       # (n, 2)
    width_px: int
    reflectance: float


def _roads(args, grid, rng, area_km2):
    """Major roads between two random points of different sides of the area."""
    n_roads = args["n_roads"]
    if n_roads is None:
        n_roads = int(round(area_km2 / 150.0)) + 1
    w, h = grid.n_cols * grid.res_m, grid.n_rows * grid.res_m
    x0, y1 = grid.x0_m, grid.y0_m
    roads = []
    for _ in range(n_roads):
        sides = rng.choice(4, size=2, replace=False)
        ends = []
        for side in sides:
            t = rng.uniform(0.1, 0.9)
            ends.append({0: (x0 + t * w, y1), 1: (x0 + w, y1 - t * h),
                         2: (x0 + t * w, y1 - h), 3: (x0, y1 - t * h)}[int(side)])
        (xa, ya), (xb, yb) = ends
        length = math.hypot(xb - xa, yb - ya)
        n_ctrl = max(2, int(length / 3000.0) + 1)
        t = np.linspace(0.0, 1.0, n_ctrl + 1)
        ctrl = np.stack([xa + t * (xb - xa), ya + t * (yb - ya)], axis=1)
        curvy = rng.uniform() < 0.7
        if curvy and n_ctrl > 1:
            normal = np.array([-(yb - ya), xb - xa]) / length
            offset = rng.normal(0.0, 0.08 * length / n_ctrl, size=n_ctrl + 1)
            offset[[0, -1]] = 0.0
            ctrl = ctrl + offset[:, None] * normal[None, :]
        pts = _catmull_rom(ctrl, max(2, int(length / (0.5 * grid.res_m))))
        bright = rng.uniform() < 0.5
        roads.append(_Road(pts, int(rng.integers(1, 3)),
                           float(rng.uniform(0.20, 0.27) if bright else rng.uniform(0.05, 0.07))))
    return roads


def _catmull_rom(ctrl, n_out):
    """``n_out`` points on the centripetal-free (uniform) Catmull-Rom spline through ``ctrl``."""
    p = np.concatenate([2 * ctrl[:1] - ctrl[1:2], ctrl, 2 * ctrl[-1:] - ctrl[-2:-1]])
    n_seg = ctrl.shape[0] - 1
    s = np.linspace(0.0, n_seg, n_out)
    i = np.minimum(s.astype(int), n_seg - 1)
    t = (s - i)[:, None]
    p0, p1, p2, p3 = p[i], p[i + 1], p[i + 2], p[i + 3]
    return 0.5 * ((2 * p1) + (-p0 + p2) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2
                  + (-p0 + 3 * p1 - 3 * p2 + p3) * t**3)


# ---------------------------------------------------------------------------------------------
# The orthoimage
# ---------------------------------------------------------------------------------------------


def _render_dom(args, grid, ext, centre, terrain, lakes, rivers, roads, cover, rng, keys):
    """Reflectance per land-cover class, shaded, blurred, noised and quantised (module notes).

    Returns
    -------
    dom : ndarray, shape grid.shape, uint16
    water : ndarray, bool
    land_cover : ndarray, uint8
    """
    ctx = _dom_context(args, grid, ext, centre, terrain, lakes, rivers, roads, cover, keys)
    radiance = np.empty(grid.shape, dtype=np.float32)
    water = np.zeros(grid.shape, dtype=bool)
    cover_map = np.zeros(grid.shape, dtype=np.uint8)
    for r0 in range(0, grid.n_rows, _STRIP_ROWS):
        rows = slice(r0, min(r0 + _STRIP_ROWS, grid.n_rows))
        radiance[rows], water[rows], cover_map[rows] = _render_strip(ctx, rows, rng)

    radiance = ndimage.gaussian_filter(radiance, _PSF_SIGMA_PX, mode="nearest", truncate=3.0)
    dom = np.empty(grid.shape, dtype=np.uint16)
    for r0 in range(0, grid.n_rows, _STRIP_ROWS):
        rows = slice(r0, min(r0 + _STRIP_ROWS, grid.n_rows))
        noisy = radiance[rows]
        noisy += rng.standard_normal(noisy.shape, dtype=np.float32) * np.float32(_NOISE_DN)
        dom[rows] = np.clip(np.rint(noisy), 1, _DN_MAX).astype(np.uint16)
    return dom, water, cover_map


@dataclass
class _DomContext:
    """What every strip of :func:`_render_dom` reads: noise keys, coordinates, overlays."""

    k: dict
    res: float
    x_all: np.ndarray
    y_all: np.ndarray
    col_f: np.ndarray
    row_f: np.ndarray
    near_c: np.ndarray
    near_r: np.ndarray
    overlays: tuple
    lake_rho: np.float32
    rock_scale: np.float32
    terrain: _Terrain
    lakes: _Lakes
    cover: _Cover


def _dom_context(args, grid, ext, centre, terrain, lakes, rivers, roads, cover, keys) -> _DomContext:
    k = {name: next(keys) for name in (
        "fine2", "block", "stagger", "parcel", "city", "cblock", "building", "lake")}
    col_f, row_f = ext.node_index(grid.x_m(), grid.y_m())
    return _DomContext(
        k=k,
        res=grid.res_m,
        x_all=grid.x_m() - centre[0],
        y_all=grid.y_m() - centre[1],
        col_f=col_f,
        row_f=row_f,
        near_c=np.clip(np.round(col_f).astype(np.intp), 0, ext.n_cols - 1),
        near_r=np.clip(np.round(row_f).astype(np.intp), 0, ext.n_rows - 1),
        overlays=_overlays(grid, rivers, roads),
        lake_rho=np.float32(0.032 + 0.012 * _unit(_hash(k["lake"], np.arange(1)))[0]),
        rock_scale=np.float32(args["relief_m"] / 1500.0),
        terrain=terrain,
        lakes=lakes,
        cover=cover,
    )


def _render_strip(ctx: _DomContext, rows: slice, rng):
    """Radiance (DN, float32), water mask and land-cover codes of one strip of DOM rows."""
    cover, terrain = ctx.cover, ctx.terrain
    x = ctx.x_all.astype(np.float32)[None, :]
    y = ctx.y_all[rows].astype(np.float32)[:, None]
    f = dict(zip(_SHARP, _resample(cover.sharp, ctx.row_f[rows], ctx.col_f, "keys")))
    f.update(zip(_SMOOTH, _resample(cover.smooth, ctx.row_f[rows], ctx.col_f, "linear")))
    lake_level = ctx.lakes.level[ctx.near_r[rows][:, None], ctx.near_c[None, :]]
    shape = f["shape_pre"].shape
    fine1 = np.clip(rng.standard_normal(shape, dtype=np.float32), -3.0, 3.0)
    fine2 = _value_noise(ctx.k["fine2"], ctx.x_all, ctx.y_all[rows], 2.5 * ctx.res)
    med, low = f["med"], f["low"]
    riparian = ctx.overlays[1]

    sea = f["coast"] < terrain.c0
    with np.errstate(invalid="ignore"):
        lake = ~sea & (f["shape_pre"] < lake_level)
    land = ~(sea | lake)
    urban = land & (f["urban"] > cover.urban_t)
    rock = (land & ~urban & (f["shape_pre"] * ctx.rock_scale + 0.12 * med + 0.05 * fine2 > 0.72)
            & (f["slope_deg"] > 8.0))
    forest = land & ~urban & ~rock & (
        (f["forest"] + 0.25 * fine2 > cover.forest_t) | (riparian[rows] > 0))
    field_ = (land & ~(urban | rock | forest) & (f["slope_deg"] < 14.0)
              & (f["shape_pre"] * ctx.rock_scale < 0.45))
    beach = land & ~urban & (f["coast"] - terrain.c0 < 45.0) & (low > -0.3)
    classes = dict(field_=field_, forest=forest, rock=rock, urban=urban, beach=beach)

    rho, code = _land_reflectance(ctx.k, x, y, f, classes, fine1, fine2)
    rho, code, river = _roads_and_rivers(ctx.overlays, rows, rho, code, land)
    rho = rho * np.where(land & ~river, f["shade"], np.float32(1.0))

    rho = np.where(sea, 0.038 * (1.0 + 0.005 * low), rho)
    rho = np.where(lake, ctx.lake_rho * (1.0 + 0.005 * low), rho)
    code[sea] = LandCover.SEA
    code[lake] = LandCover.LAKE
    return _DN_OFFSET + _DN_GAIN * rho, sea | lake | river, code


def _land_reflectance(k, x, y, f, classes, fine1, fine2):
    """Reflectance and land-cover code of land pixels: grass by default, then each class."""
    med = f["med"]
    field_, forest, rock, urban, beach = (classes[n] for n in ("field_", "forest", "rock", "urban", "beach"))
    shape = fine1.shape
    # Natural grass and shrub is the default land reflectance.
    rho = 0.105 * (1.0 + 0.22 * med + 0.10 * fine2 + 0.03 * fine1)
    code = np.full(shape, LandCover.GRASS, dtype=np.uint8)
    if field_.any():
        xs, ys = np.broadcast_to(x, shape)[field_], np.broadcast_to(y, shape)[field_]
        rho[field_] = _fields_texture(
            k, xs, ys, f["warp_x"][field_], f["warp_y"][field_], fine1[field_],
            fine2[field_], med[field_])
        code[field_] = LandCover.FIELD
    if forest.any():
        rho_f = 0.052 * (1.0 + 0.25 * med) * (1.0 + 0.18 * fine1 + 0.22 * fine2)
        rho = np.where(forest, rho_f, rho)
        code[forest] = LandCover.FOREST
    if rock.any():
        rho = np.where(rock, 0.17 * (1.0 + 0.2 * med + 0.2 * fine2 + 0.08 * fine1), rho)
        code[rock] = LandCover.ROCK
    if urban.any():
        xs, ys = np.broadcast_to(x, shape)[urban], np.broadcast_to(y, shape)[urban]
        rho[urban] = _urban_texture(k, xs, ys, fine1[urban])
        code[urban] = LandCover.URBAN
    if beach.any():
        rho = np.where(beach, 0.29 * (1.0 + 0.08 * fine2), rho)
        code[beach] = LandCover.BEACH
    return rho, code


def _roads_and_rivers(overlays, rows, rho, code, land):
    """Roads, then rivers (under bridges), on land only; returns ``(rho, code, river mask)``."""
    river_cov, _, road_cov, road_id, road_rho = overlays
    a_road = road_cov[rows].astype(np.float32) * np.float32(1.0 / 255.0)
    a_road[~land] = 0.0
    ids = road_id[rows]
    rho = rho * (1.0 - a_road) + np.where(ids > 0, road_rho[ids], rho) * a_road
    a_river = river_cov[rows].astype(np.float32) * np.float32(1.0 / 255.0)
    a_river[~land | (a_road >= 0.5)] = 0.0
    rho = rho * (1.0 - a_river) + np.float32(0.045) * a_river
    river = a_river >= 0.5
    code[a_road >= 0.5] = LandCover.ROAD
    code[river] = LandCover.RIVER
    return rho, code, river


def _overlays(grid, rivers, roads):
    """Rivers, riparian strips and roads drawn on the DOM grid (OpenCV, anti-aliased).

    Returns
    -------
    river_cov, riparian, road_cov : ndarray, shape grid.shape, uint8
        Coverage 0..255.
    road_id : ndarray, shape grid.shape, uint8
        1 + index of the road drawn there (0: none).
    road_rho : ndarray, shape (n_roads + 1,), float32
        Reflectance by road id.
    """
    import cv2

    res = grid.res_m
    river_cov = np.zeros(grid.shape, dtype=np.uint8)
    riparian = np.zeros(grid.shape, dtype=np.uint8)
    for river in rivers:
        col, row = grid.node_index(river.xy_m[:, 0], river.xy_m[:, 1])
        pts = np.stack([col + 0.5, row + 0.5], axis=1)
        thick = np.maximum(1, np.round(river.width_m / res)).astype(int)[1:]
        _draw_segments(riparian, pts, np.full(thick.size, 255.0), thick + max(2, int(60.0 / res)))
        _draw_segments(river_cov, pts, np.full(thick.size, 255.0), thick, antialias=True)
    road_cov = np.zeros(grid.shape, dtype=np.uint8)
    road_id = np.zeros(grid.shape, dtype=np.uint8)
    roads = roads[:255]
    road_rho = np.zeros(len(roads) + 1, dtype=np.float32)
    for i, road in enumerate(roads):
        col, row = grid.node_index(road.xy_m[:, 0], road.xy_m[:, 1])
        fixed = np.round(np.stack([col, row], axis=1) * 16.0).astype(np.int32)
        cv2.polylines(road_cov, [fixed], False, 255, thickness=road.width_px,
                      lineType=cv2.LINE_AA, shift=4)
        cv2.polylines(road_id, [fixed], False, i + 1, thickness=road.width_px + 2,
                      lineType=cv2.LINE_8, shift=4)
        road_rho[i + 1] = road.reflectance
    return river_cov, riparian, road_cov, road_id, road_rho


_COS_32 = np.cos(np.arange(32) * (math.pi / 32.0)).astype(np.float32)
_SIN_32 = np.sin(np.arange(32) * (math.pi / 32.0)).astype(np.float32)


def _fields_texture(k, x, y, warp_x, warp_y, fine1, fine2, med):
    """Agricultural parcels at points ``(x, y)`` (1-D arrays, metres from the centre).

    Blocks of a 1.5 km grid warped by smooth noise (farm boundaries, drawn as tracks) are cut
    into rectangular parcels along one of 32 orientations, staggered from strip to strip;
    each parcel draws a kind (green crop, bare soil, dry crop or stubble, pasture), a tone
    and a row period from the hash of its indices. Returns reflectances, float32.
    """
    block_m = 1500.0
    xw = x + (0.25 * block_m) * warp_x
    yw = y + (0.25 * block_m) * warp_y
    bi = np.floor(yw / block_m)
    bj = np.floor(xw / block_m)
    hb = _hash(k["block"], bi.astype(np.int32), bj.astype(np.int32))
    o = (hb & np.uint32(31)).astype(np.intp)
    ct, st = _COS_32[o], _SIN_32[o]
    pu = x * ct + y * st
    pv = y * ct - x * st
    width = 90.0 + 260.0 * _unit(_mix32(hb ^ np.uint32(0x5BD1E995)))
    height = width * (1.2 + 2.0 * _unit(_mix32(hb ^ np.uint32(0x27D4EB2F))))
    gu = pu / width
    su = np.floor(gu)
    stagger = _unit(_hash(k["stagger"], hb, su.astype(np.int32)))
    gv = pv / height + stagger
    sv = np.floor(gv)
    hp = _hash(k["parcel"], hb, su.astype(np.int32), sv.astype(np.int32))
    kind = _unit(hp)
    tone = _unit(_mix32(hp ^ np.uint32(0x165667B1)))
    rho = np.where(kind < 0.35, 0.055 + 0.04 * tone,
          np.where(kind < 0.65, 0.12 + 0.10 * tone,
          np.where(kind < 0.85, 0.18 + 0.12 * tone, 0.08 + 0.05 * tone)))  # fmt: skip
    period = 25.0 + 50.0 * _unit(_mix32(hp ^ np.uint32(0x85EBCA77)))
    stripes = np.sin((2.0 * math.pi) * pu / period)
    rho = rho * (1.0 + 0.04 * stripes + 0.07 * med + 0.04 * fine2 + 0.02 * fine1)
    # Parcel boundaries (hedges or tracks) and block boundaries (farm tracks).
    fu, fv = gu - su, gv - sv
    edge_m = np.minimum(np.minimum(fu, 1.0 - fu) * width, np.minimum(fv, 1.0 - fv) * height)
    hedge = ((hb >> np.uint32(27)) & np.uint32(1)) == 1
    rho = np.where(edge_m < 6.0, np.where(hedge, 0.05, 0.2), rho)
    bu, bv = xw / block_m - bj, yw / block_m - bi
    track_m = np.minimum(np.minimum(bu, 1.0 - bu), np.minimum(bv, 1.0 - bv)) * block_m
    return np.where(track_m < 7.0, 0.22, rho).astype(np.float32)


def _urban_texture(k, x, y, fine1):
    """Town blocks at points ``(x, y)`` (1-D arrays): bright roofs, dark streets, parks.

    Each 12 km cell has its own street-grid orientation and block pitch; a block draws its
    kind (8 % parks, 10 % large bright roofs, the rest four buildings of their own tone);
    streets are 18 m wide, every fifth one wider and brighter. Returns reflectances.
    """
    city_m = 12_000.0
    hc = _hash(k["city"], np.floor(y / city_m).astype(np.int32),
               np.floor(x / city_m).astype(np.int32))
    o = (hc & np.uint32(31)).astype(np.intp)
    ct, st = _COS_32[o], _SIN_32[o]
    pu = x * ct + y * st
    pv = y * ct - x * st
    pitch_u = 100.0 + 80.0 * _unit(_mix32(hc ^ np.uint32(0x5BD1E995)))
    pitch_v = 80.0 + 60.0 * _unit(_mix32(hc ^ np.uint32(0x27D4EB2F)))
    gu, gv = pu / pitch_u, pv / pitch_v
    bu, bv = np.floor(gu), np.floor(gv)
    fu, fv = (gu - bu) * pitch_u, (gv - bv) * pitch_v
    street_m = 18.0
    hb = _hash(k["cblock"], hc, bu.astype(np.int32), bv.astype(np.int32))
    kind = _unit(hb)
    quarter = ((fu > 0.5 * (pitch_u + street_m)).astype(np.int32)
               + 2 * (fv > 0.5 * (pitch_v + street_m)).astype(np.int32))
    roof = 0.12 + 0.22 * _unit(_hash(k["building"], hb, quarter))
    rho = np.where(kind < 0.08, 0.06, np.where(kind > 0.9, 0.36 + 0.08 * _unit(_mix32(hb)), roof))
    rho = rho * (1.0 + 0.06 * fine1)
    main = (((bu.astype(np.int64) % 5 == 0) & (fu < 1.6 * street_m))
            | ((bv.astype(np.int64) % 5 == 0) & (fv < 1.6 * street_m)))
    street = (fu < street_m) | (fv < street_m)
    rho = np.where(main, 0.11, np.where(street, 0.075, rho))
    return rho.astype(np.float32)


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
