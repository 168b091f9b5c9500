"""Land cover of the procedural reference: class codes, shading, class scores and roads.

:class:`LandCover` codes the classes of the reference's land-cover map; :func:`illumination`
is the Lambertian incidence [4]_ on a height grid; :func:`cover_fields` computes, on the DEM grid,
the shading, slope, urban and forest scores (with their class thresholds) and medium-scale
noises that the DOM renderer carries to the DOM grid; :func:`draw_roads` draws the major roads.

References
----------
.. [4] B. K. P. Horn, "Hill shading and the reflectance map", Proc. IEEE 69(1), 14-47, 1981.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from sensor_models.simulate.procedural_noise import smoothstep, value_noise

#: Fraction of diffuse (sky) irradiance in the shading.
_DIFFUSE = 0.25


class LandCover(IntEnum):
    """Codes of :attr:`sensor_models.simulate.procedural.ReferenceData.land_cover` (0 is not used)."""

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


@dataclass
class CoverFields:
    """Fields on the extended DEM grid carried to the DOM grid, and class thresholds."""

    sharp: np.ndarray      # (2, R, C): SHARP_FIELDS fields, Keys-interpolated (boundaries)
    smooth: np.ndarray     # (8, R, C): SMOOTH_FIELDS fields, linearly interpolated
    urban_t: float
    forest_t: float


#: Names of the fields of :attr:`CoverFields.sharp` and :attr:`CoverFields.smooth`, in order.
SHARP_FIELDS = ("shape_pre", "coast")
SMOOTH_FIELDS = ("shade", "slope_deg", "urban", "forest", "med", "low", "warp_x", "warp_y")


def cover_fields(args, ext, terrain, heights, keys) -> CoverFields:
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

    urban = (0.8 * value_noise(next(keys), x, y, 9000.0)
             + 0.5 * value_noise(next(keys), x, y, 2500.0))
    urban -= 1.2 * terrain.u + slope_deg / 8.0
    if args["sea_fraction"] > 0.0:
        urban += 0.3 * np.exp(-np.maximum(terrain.coast - terrain.c0, 0.0) / 3000.0)
    forest = (value_noise(next(keys), x, y, 3000.0) + 0.6 * value_noise(next(keys), x, y, 1000.0)
              + 0.4 * value_noise(next(keys), x, y, 350.0))
    forest += slope_deg / 12.0 + 1.2 * smoothstep(0.05, 0.3, terrain.u)

    land = terrain.land & terrain.in_area
    urban_t = forest_t = math.inf
    if land.sum() > 16:
        if args["urban_fraction"] > 0.0:
            urban_t = float(np.quantile(urban[land], 1.0 - args["urban_fraction"]))
        rest = land & ~(urban > urban_t)
        if args["forest_fraction"] > 0.0 and rest.any():
            q = min(args["forest_fraction"] * land.sum() / rest.sum(), 1.0)
            forest_t = float(np.quantile(forest[rest], 1.0 - q))
    smooth = np.empty((len(SMOOTH_FIELDS),) + ext.shape, dtype=np.float32)
    smooth[0], smooth[1], smooth[2], smooth[3] = shade, slope_deg, urban, forest
    del shade, slope_deg, urban, forest
    for i, spacing in zip(range(4, 8), (300.0, 2000.0, 1200.0, 1200.0)):
        smooth[i] = value_noise(next(keys), x, y, spacing)
    sharp = np.stack([terrain.shape, terrain.coast]).astype(np.float32)
    return CoverFields(sharp=sharp, smooth=smooth, urban_t=urban_t, forest_t=forest_t)


@dataclass
class _Road:
    xy_m: np.ndarray       # (n, 2)
    width_px: int
    reflectance: float


def draw_roads(args, grid, rng, area_km2):
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
