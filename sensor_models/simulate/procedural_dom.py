"""The procedural reference orthoimage: reflectance per class, textures, PSF, noise, DN.

:func:`render_dom` renders the DOM strip by strip: land-cover classes from the fields of
:mod:`~sensor_models.simulate.procedural_cover`, reflectance per class (agricultural parcels and
town blocks drawn from hashed lattices), roads and rivers, shading, then the Gaussian
point-spread function, the sensor noise and the 12-bit quantisation (notes of
:mod:`sensor_models.simulate.procedural`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from sensor_models.simulate.procedural_cover import SHARP_FIELDS, SMOOTH_FIELDS, CoverFields, LandCover
from sensor_models.simulate.procedural_noise import hash32, mix32, resample, unit_float, value_noise
from sensor_models.simulate.procedural_rivers import draw_segments
from sensor_models.simulate.procedural_terrain import LakeFields, TerrainFields

#: Digital number of reflectance 0 (path radiance) and DN per unit reflectance.
_DN_OFFSET = 200.0
_DN_GAIN = 9000.0
#: Largest DN (12-bit) and standard deviation of the sensor noise, DN.
_DN_MAX = 4095
_NOISE_DN = 2.5
#: Gaussian point-spread function of the sensor, pixels.
_PSF_SIGMA_PX = 0.6
#: its kernel's reach, standard deviations
_PSF_TRUNCATE = 3.0
#: DOM rows processed together at most, and DOM pixels (the texture synthesis holds about 130
#: bytes a pixel of its strip: narrower strips on wider grids bound that memory)
_STRIP_ROWS = 256
_STRIP_PIXELS = 1 << 18


def strip_rows(n_cols: int) -> int:
    """Rows of each strip :func:`render_dom` renders on a DOM of ``n_cols`` columns: 256, fewer
    above 1024 columns (at most ``_STRIP_PIXELS`` pixels, at least 8 rows). The pixels do not
    depend on it."""
    return max(8, min(_STRIP_ROWS, _STRIP_PIXELS // max(1, int(n_cols))))


def dom_strips(n_rows: int, n_cols: int) -> int:
    """Strips of rows :func:`render_dom` renders for a DOM of ``n_rows x n_cols`` (its progress count)."""
    return -(-int(n_rows) // strip_rows(n_cols))


def render_dom(args, grid, ext, centre, terrain, lakes, rivers, roads, cover, rng, keys, strip_done=None):
    """Reflectance per land-cover class, shaded, blurred, noised and quantised (notes of
    :mod:`sensor_models.simulate.procedural`); ``strip_done()`` (optional) is called after each
    strip of rows (:func:`dom_strips` in all).

    Returns
    -------
    dom : ndarray, shape grid.shape, uint16
    water : ndarray, bool
    land_cover : ndarray, uint8
    """
    ctx = _dom_context(args, grid, ext, centre, terrain, lakes, rivers, roads, cover, keys)
    step = strip_rows(grid.n_cols)
    radiance = np.empty(grid.shape, dtype=np.float32)
    water = np.zeros(grid.shape, dtype=bool)
    cover_map = np.zeros(grid.shape, dtype=np.uint8)
    for r0 in range(0, grid.n_rows, step):
        rows = slice(r0, min(r0 + step, grid.n_rows))
        radiance[rows], water[rows], cover_map[rows] = _render_strip(ctx, rows, rng)
        if strip_done is not None:
            strip_done()
    del ctx  # its whole-grid overlays (rivers, riparian strips, roads: 4 bytes a pixel) are drawn in

    # the PSF blurred strip by strip, each with the rows its kernel reaches (scipy's radius
    # int(truncate sigma + 0.5)): the same pixels as one blur of the whole radiance
    halo = int(_PSF_TRUNCATE * _PSF_SIGMA_PX + 0.5) + 1
    dom = np.empty(grid.shape, dtype=np.uint16)
    for r0 in range(0, grid.n_rows, step):
        r1 = min(r0 + step, grid.n_rows)
        a0, a1 = max(0, r0 - halo), min(grid.n_rows, r1 + halo)
        noisy = ndimage.gaussian_filter(radiance[a0:a1], _PSF_SIGMA_PX, mode="nearest",
                                        truncate=_PSF_TRUNCATE)[r0 - a0:r1 - a0]
        rows = slice(r0, r1)
        noisy += rng.standard_normal(noisy.shape, dtype=np.float32) * np.float32(_NOISE_DN)
        dom[rows] = np.clip(np.rint(noisy), 1, _DN_MAX).astype(np.uint16)
    return dom, water, cover_map


@dataclass
class _DomContext:
    """What every strip of :func:`render_dom` reads: noise keys, coordinates, overlays."""

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
    terrain: TerrainFields
    lakes: LakeFields
    cover: CoverFields


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
        lake_rho=np.float32(0.032 + 0.012 * unit_float(hash32(k["lake"], np.arange(1)))[0]),
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
    f = dict(zip(SHARP_FIELDS, resample(cover.sharp, ctx.row_f[rows], ctx.col_f, "keys")))
    f.update(zip(SMOOTH_FIELDS, resample(cover.smooth, ctx.row_f[rows], ctx.col_f, "linear")))
    lake_level = ctx.lakes.level[ctx.near_r[rows][:, None], ctx.near_c[None, :]]
    shape = f["shape_pre"].shape
    fine1 = np.clip(rng.standard_normal(shape, dtype=np.float32), -3.0, 3.0)
    fine2 = value_noise(ctx.k["fine2"], ctx.x_all, ctx.y_all[rows], 2.5 * ctx.res)
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
        draw_segments(riparian, pts, np.full(thick.size, 255.0), thick + max(2, int(60.0 / res)))
        draw_segments(river_cov, pts, np.full(thick.size, 255.0), thick, antialias=True)
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
    hb = hash32(k["block"], bi.astype(np.int32), bj.astype(np.int32))
    o = (hb & np.uint32(31)).astype(np.intp)
    ct, st = _COS_32[o], _SIN_32[o]
    pu = x * ct + y * st
    pv = y * ct - x * st
    width = 90.0 + 260.0 * unit_float(mix32(hb ^ np.uint32(0x5BD1E995)))
    height = width * (1.2 + 2.0 * unit_float(mix32(hb ^ np.uint32(0x27D4EB2F))))
    gu = pu / width
    su = np.floor(gu)
    stagger = unit_float(hash32(k["stagger"], hb, su.astype(np.int32)))
    gv = pv / height + stagger
    sv = np.floor(gv)
    hp = hash32(k["parcel"], hb, su.astype(np.int32), sv.astype(np.int32))
    kind = unit_float(hp)
    tone = unit_float(mix32(hp ^ np.uint32(0x165667B1)))
    rho = np.where(kind < 0.35, 0.055 + 0.04 * tone,
          np.where(kind < 0.65, 0.12 + 0.10 * tone,
          np.where(kind < 0.85, 0.18 + 0.12 * tone, 0.08 + 0.05 * tone)))  # fmt: skip
    period = 25.0 + 50.0 * unit_float(mix32(hp ^ np.uint32(0x85EBCA77)))
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
    hc = hash32(k["city"], np.floor(y / city_m).astype(np.int32),
               np.floor(x / city_m).astype(np.int32))
    o = (hc & np.uint32(31)).astype(np.intp)
    ct, st = _COS_32[o], _SIN_32[o]
    pu = x * ct + y * st
    pv = y * ct - x * st
    pitch_u = 100.0 + 80.0 * unit_float(mix32(hc ^ np.uint32(0x5BD1E995)))
    pitch_v = 80.0 + 60.0 * unit_float(mix32(hc ^ np.uint32(0x27D4EB2F)))
    gu, gv = pu / pitch_u, pv / pitch_v
    bu, bv = np.floor(gu), np.floor(gv)
    fu, fv = (gu - bu) * pitch_u, (gv - bv) * pitch_v
    street_m = 18.0
    hb = hash32(k["cblock"], hc, bu.astype(np.int32), bv.astype(np.int32))
    kind = unit_float(hb)
    quarter = ((fu > 0.5 * (pitch_u + street_m)).astype(np.int32)
               + 2 * (fv > 0.5 * (pitch_v + street_m)).astype(np.int32))
    roof = 0.12 + 0.22 * unit_float(hash32(k["building"], hb, quarter))
    rho = np.where(kind < 0.08, 0.06, np.where(kind > 0.9, 0.36 + 0.08 * unit_float(mix32(hb)), roof))
    rho = rho * (1.0 + 0.06 * fine1)
    main = (((bu.astype(np.int64) % 5 == 0) & (fu < 1.6 * street_m))
            | ((bv.astype(np.int64) % 5 == 0) & (fv < 1.6 * street_m)))
    street = (fu < street_m) | (fv < street_m)
    rho = np.where(main, 0.11, np.where(street, 0.075, rho))
    return rho.astype(np.float32)
