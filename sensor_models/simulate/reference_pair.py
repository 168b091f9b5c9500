"""The reference a user matches against is not what rendered the scene (``realistic`` profile).

From the scene's source radiance and the TRUE DEM, :func:`degrade_dom` and :func:`degrade_dem`
make what a user would download:

DOM (another date, another sensor, its own geolocation error), in this order:

1. geolocation error: the DOM shows the ground point ``p + e(p)`` at ``p``, with ``e`` a bias
   ``dom_bias_m`` plus a smooth field of ``dom_field_rms_m`` rms per axis and correlation length
   ``dom_field_scale_m`` (a feature's DOM coordinates are off by ``-e``);
2. another date: a multiplicative change ``1 + seasonal_change f`` (``f`` a unit smooth field of
   correlation length ``seasonal_scale_m``: crops, phenology) and an additive haze veil of mean
   ``haze`` (times ``1 + 0.5 f'``, 5 km);
3. another sensor: the non-linear mapping ``x^reference_gamma``, the reference's own Gaussian
   MTF (``reference_mtf_sigma_px`` reference pixels) and an area average onto the reference grid
   (``reference_resolution_m``, Landsat-like);
4. 12-bit digital numbers ``1 + 3000 x``.

DEM (SRTM-like): area average of the true DEM onto ``dem_resolution_m`` plus a smooth error of
``dem_error_rms_m`` rms (correlation ``dem_error_scale_m``) and voids (nodata) over
``dem_void_fraction`` of the nodes, in blobs.

Every draw is seeded from ``(pass seed, purpose)``: the same seed gives the same files.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from affine import Affine

from sensor_models.simulate.radiometry import smooth_field
from sensor_models.simulate.source_windows import read_window

__all__ = ["DegradedRaster", "degrade_dem", "degrade_dom", "displacement_field_m", "write_raster"]

#: source pixels :func:`degrade_dom` resamples at a time (whole rows)
_STRIP_PIXELS = 1 << 18
#: nodata of the degraded DEM
DEM_NODATA = -32768.0


@dataclass(frozen=True)
class DegradedRaster:
    """A raster a user receives and what was done to it.

    Attributes
    ----------
    values : ndarray, shape (rows, cols)
        uint16 digital numbers (DOM) or float32 heights with NaN voids (DEM).
    transform : affine.Affine
        Pixel-corner affine (rasterio convention), metres of ``crs``.
    figures : dict
        Measured magnitudes of what was injected (JSON-safe).
    """

    values: np.ndarray
    transform: Affine
    figures: dict


def _seed(seed: int, purpose: int):
    return np.random.SeedSequence([int(seed), 40, int(purpose)])


def displacement_field_m(shape, resolution_m: float, *, bias_m, field_rms_m: float, field_scale_m: float, seed: int):
    """Geolocation error ``e = (east, north)`` of a DOM on its grid, metres.

    Parameters
    ----------
    shape : (int, int)
        Grid rows and columns.
    resolution_m : float
        Grid spacing, metres.
    bias_m : (float, float)
        East and north bias, metres.
    field_rms_m : float
        Standard deviation of the smooth part, per axis, metres.
    field_scale_m : float
        Correlation length of the smooth part, metres.
    seed : int
        Pass seed.

    Returns
    -------
    east_m, north_m : ndarray of float32, shape ``shape``
    """
    fields = _displacement_fields(shape, resolution_m, field_rms_m=field_rms_m, field_scale_m=field_scale_m, seed=seed)
    return tuple((np.float32(b) + np.float32(field_rms_m) * f.rows(0, shape[0])).astype(np.float32)
                 for b, f in zip(bias_m, fields))


def _displacement_fields(shape, resolution_m: float, *, field_rms_m: float, field_scale_m: float, seed: int):
    """The unit east and north fields of :func:`displacement_field_m`, as :class:`_Upsampled`."""
    coarse = 8
    cshape = (shape[0] // coarse + 2, shape[1] // coarse + 2)
    scale = max(field_scale_m / (resolution_m * coarse), 1.0)
    return [_Upsampled(smooth_field(cshape, scale, _seed(seed, 1 + k)) if field_rms_m > 0
                       else np.zeros(cshape, np.float32), coarse, shape[1]) for k in range(2)]


class _Upsampled:
    """A coarse field enlarged ``factor`` times (OpenCV bilinear), cropped to ``n_cols``, row range by row range.

    ``rows(r0, r1)`` equals rows ``r0:r1`` of ``cv2.resize(coarse, (W factor, H factor),
    INTER_LINEAR)[:, :n_cols]``: it enlarges only the coarse rows those output rows reach, one
    more on each side (the bilinear weights of an output row depend on its position modulo
    ``factor`` only), so no whole-grid field is held.
    """

    def __init__(self, coarse: np.ndarray, factor: int, n_cols: int):
        self.coarse, self.factor, self.n_cols = coarse, int(factor), int(n_cols)

    def rows(self, r0: int, r1: int) -> np.ndarray:
        f, c = self.factor, self.coarse
        c0, c1 = max(0, r0 // f - 1), min(c.shape[0], (r1 - 1) // f + 2)
        up = cv2.resize(c[c0:c1], (c.shape[1] * f, (c1 - c0) * f), interpolation=cv2.INTER_LINEAR)
        return up[r0 - c0 * f:r1 - c0 * f, :self.n_cols]


def _smooth_rows(shape, scale_px: float, seed: int, purpose: int) -> _Upsampled:
    """The field of :func:`_smooth`, as :class:`_Upsampled`."""
    coarse = max(1, int(scale_px // 8))
    cshape = (shape[0] // coarse + 2, shape[1] // coarse + 2)
    return _Upsampled(smooth_field(cshape, max(scale_px / coarse, 1.0), _seed(seed, purpose)), coarse, shape[1])


def _smooth(shape, scale_px: float, seed: int, purpose: int) -> np.ndarray:
    return _smooth_rows(shape, scale_px, seed, purpose).rows(0, shape[0])


def _area_average(values: np.ndarray, transform: Affine, out_res_m: float):
    """Area average onto a coarser north-up grid with the same corner; NaN-aware."""
    res = abs(transform.a)
    n_rows = max(2, int(round(values.shape[0] * res / out_res_m)))
    n_cols = max(2, int(round(values.shape[1] * res / out_res_m)))
    out_transform = Affine(values.shape[1] * res / n_cols, 0.0, transform.c, 0.0, -values.shape[0] * res / n_rows,
                           transform.f)
    # the weights first, their full-size mask let go before the sums are made (the output grid may
    # be finer than the input's)
    finite = np.isfinite(values)
    if finite.all() and _ones_stay_ones(values.shape, n_rows, n_cols):
        # every weight would be exactly 1 (the sums divided by 1): the area average is the resize itself
        return cv2.resize(np.asarray(values, np.float32), (n_cols, n_rows), interpolation=cv2.INTER_AREA), out_transform
    w = cv2.resize(finite.astype(np.float32), (n_cols, n_rows), interpolation=cv2.INTER_AREA)
    # all finite (a procedural source): the values themselves, no filled copy
    filled = np.asarray(values, np.float32) if finite.all() else np.where(finite, values, 0.0).astype(np.float32)
    del finite
    s = cv2.resize(filled, (n_cols, n_rows), interpolation=cv2.INTER_AREA)
    del filled
    void = (w <= 0.5) if float(w.min()) <= 0.5 else None
    out = np.divide(s, np.maximum(w, np.float32(1e-6), out=w), out=s)  # in place: no further full-size copies
    if void is not None:
        out[void] = np.nan
    return out, out_transform


def _ones_stay_ones(shape, n_rows: int, n_cols: int) -> bool:
    """Whether ``cv2.resize`` (``INTER_AREA``) of ones of ``shape`` to ``(n_rows, n_cols)`` gives exactly ones.

    OpenCV resizes along the rows and then along the columns; on ones each pass gives, per
    output index, the sum of its own weights, whatever the other axis, so two thin probes
    (``shape[0] x 2`` and ``2 x shape[1]``) answer for the whole grid. An enlargement
    (OpenCV's area enlargement is a linear interpolation) gives exact ones; a reduction may
    miss by a unit in the last place.
    """
    ones = np.ones((shape[0], 2), np.float32)
    down = cv2.resize(ones, (2, n_rows), interpolation=cv2.INTER_AREA)
    across = cv2.resize(np.ones((2, shape[1]), np.float32), (n_cols, 2), interpolation=cv2.INTER_AREA)
    return bool((down == 1.0).all() and (across == 1.0).all())


def degrade_dom(radiance: np.ndarray, transform: Affine, profile, *, seed: int) -> DegradedRaster:
    """The reference DOM a user receives, from the scene's source radiance (see the module docstring).

    Parameters
    ----------
    radiance : ndarray of float32, shape (H, W), or RowFile
        Source radiance, 0..1 (NaN: no data), on a north-up grid; a
        :class:`sensor_models.simulate.source_windows.RowFile` is read by strips of rows.
    transform : affine.Affine
        Its pixel-corner affine, metres.
    profile : PushbroomProfile
        Magnitudes (``dom_*``, ``seasonal_*``, ``haze``, ``reference_*``).
    seed : int
        Pass seed.

    Returns
    -------
    DegradedRaster
        uint16 DN on the reference grid; ``figures``: ``geolocation_rms_m``,
        ``geolocation_bias_m``, ``geolocation_max_m``, ``resolution_m``.
    """
    v = profile.value
    res = abs(transform.a)
    (bias_e, bias_n), rms = v("dom_bias_m"), np.float32(v("dom_field_rms_m"))
    unit_e, unit_n = _displacement_fields(radiance.shape, res, field_rms_m=v("dom_field_rms_m"),
                                          field_scale_m=v("dom_field_scale_m"), seed=seed)
    change = _smooth_rows(radiance.shape, v("seasonal_scale_m") / res, seed, 10)
    haze = _smooth_rows(radiance.shape, 5000.0 / res, seed, 11)
    shape = radiance.shape
    x = np.empty(shape, dtype=np.float32)
    cols = np.arange(shape[1], dtype=np.float32)[None, :]
    sums = np.zeros(3)  # east, north, squared magnitude (float64 sums over the strips)
    mag_max = 0.0
    step = max(1, _STRIP_PIXELS // shape[1])
    for r0 in range(0, shape[0], step):  # pixel by pixel: no whole-raster field or map is held
        r1 = min(r0 + step, shape[0])
        east = (np.float32(bias_e) + rms * unit_e.rows(r0, r1)).astype(np.float32)
        north = (np.float32(bias_n) + rms * unit_n.rows(r0, r1)).astype(np.float32)
        mag = np.hypot(east, north)
        sums += [east.sum(dtype=np.float64), north.sum(dtype=np.float64), np.square(mag, dtype=np.float64).sum()]
        mag_max = max(mag_max, float(mag.max()))
        r = np.arange(r0, r1, dtype=np.float32)[:, None]
        # the DOM pixel at p shows the ground at p + e (north is up: row decreases northwards)
        xs = _remap_window(radiance, cols + east / np.float32(res), r - north / np.float32(res))
        xs = (xs * (1.0 + np.float32(v("seasonal_change")) * change.rows(r0, r1))
              + np.float32(v("haze")) * (1.0 + 0.5 * haze.rows(r0, r1)))
        x[r0:r1] = np.power(np.clip(xs, 0.0, None), np.float32(v("reference_gamma")))
    n = float(shape[0] * shape[1])
    figures = {"geolocation_rms_m": float(np.sqrt(sums[2] / n)), "geolocation_max_m": mag_max,
               "geolocation_bias_m": [float(sums[0] / n), float(sums[1] / n)]}
    sigma_src = v("reference_mtf_sigma_px") * v("reference_resolution_m") / res
    if sigma_src > 0:
        _blur_in_place(x, sigma_src)
    x, out_transform = _area_average(x, transform, v("reference_resolution_m"))
    # DN = clip(rint(1 + 3000 x), 1, 4095), in place: the reference grid may be finer than the source's
    x = np.nan_to_num(x, nan=0.0, copy=False)
    x *= np.float32(3000.0)
    x += np.float32(1.0)
    dn = np.clip(np.rint(x, out=x), 1, 4095, out=x).astype(np.uint16)
    figures["resolution_m"] = float(abs(out_transform.a))
    return DegradedRaster(dn, out_transform, figures)


#: output columns :func:`_remap_window` remaps at a time (OpenCV's remap: less than 32 767 a side)
_REMAP_COLS = 16_384


def _remap_window(radiance, map_col: np.ndarray, map_row: np.ndarray) -> np.ndarray:
    """``cv2.remap(radiance, map_col, map_row, INTER_LINEAR, BORDER_REPLICATE)`` from only the pixels the maps reach.

    ``radiance``: an array or a :class:`sensor_models.simulate.source_windows.RowFile`. By chunks
    of at most :data:`_REMAP_COLS` output columns, each from the window of the source its maps
    span plus 2 pixels on each side (clipped to the raster, whose edge the border replicates);
    the maps are shifted by the window's first row and column after they are computed, which is
    exact in float32, so the pixels are those of the remap of the whole raster.
    """
    out = np.empty(map_col.shape, dtype=np.float32)
    for c in range(0, map_col.shape[1], _REMAP_COLS):
        cols = slice(c, c + _REMAP_COLS)
        (a0, a1), (b0, b1) = (_span(m[:, cols], n) for m, n in ((map_row, radiance.shape[0]),
                                                                  (map_col, radiance.shape[1])))
        window = read_window(radiance, a0, a1, b0, b1)
        mc, mr = map_col[:, cols], map_row[:, cols]
        mc = mc - np.float32(b0) if b0 > 0 else mc
        mr = mr - np.float32(a0) if a0 > 0 else mr
        out[:, cols] = cv2.remap(window, mc, mr, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out


def _span(coords: np.ndarray, n: int) -> tuple:
    """``(first, stop)`` of the ``n`` pixels within 2 of ``coords``' range (at least the nearest edge pixel)."""
    first = min(max(0, int(np.floor(float(np.nanmin(coords)))) - 2), n - 1)
    return first, max(min(n, int(np.floor(float(np.nanmax(coords)))) + 3), first + 1)


def _blur_in_place(x: np.ndarray, sigma_px: float) -> None:
    """``cv2.GaussianBlur(x, (0, 0), sigma_px, borderType=BORDER_REPLICATE)`` written back into ``x``.

    Strip by strip, each blurred with the rows its kernel reaches (OpenCV's radius for float
    images is round(4 sigma)); the original rows a strip needs above it are kept aside before
    they are overwritten. Same pixels as one blur of the whole raster, without a second copy.
    """
    halo = int(np.ceil(4.0 * sigma_px)) + 2
    tail = x[:0].copy()  # the last (up to ``halo``) original rows above the next strip
    step = max(4 * halo, _STRIP_PIXELS // x.shape[1])
    for r0 in range(0, x.shape[0], step):
        r1 = min(r0 + step, x.shape[0])
        a0, a1 = max(0, r0 - halo), min(x.shape[0], r1 + halo)
        block = x[a0:a1].copy()
        block[:r0 - a0] = tail[tail.shape[0] - (r0 - a0):]
        tail = np.concatenate([tail, x[r0:r1]])[-halo:]
        x[r0:r1] = cv2.GaussianBlur(block, (0, 0), sigmaX=sigma_px, sigmaY=sigma_px,
                                    borderType=cv2.BORDER_REPLICATE)[r0 - a0:r1 - a0]


def degrade_dem(dem_m: np.ndarray, transform: Affine, profile, *, seed: int) -> DegradedRaster:
    """The SRTM-like DEM a user receives, from the TRUE DEM (see the module docstring).

    Parameters
    ----------
    dem_m : ndarray of float32, shape (H, W)
        True ellipsoidal heights, metres, north-up grid.
    transform : affine.Affine
        Its pixel-corner affine, metres.
    profile : PushbroomProfile
        ``dem_resolution_m``, ``dem_error_rms_m``, ``dem_error_scale_m``, ``dem_void_fraction``.
    seed : int
        Pass seed.

    Returns
    -------
    DegradedRaster
        float32 heights (NaN voids); ``figures``: ``added_error_rms_m``, ``void_fraction``,
        ``resolution_m``.
    """
    v = profile.value
    coarse, out_transform = _area_average(np.asarray(dem_m, np.float32), transform, v("dem_resolution_m"))
    res = abs(out_transform.a)
    err = np.float32(v("dem_error_rms_m")) * _smooth(coarse.shape, v("dem_error_scale_m") / res, seed, 20)
    out = coarse + err
    frac = float(v("dem_void_fraction"))
    if frac > 0:
        blobs = _smooth(coarse.shape, 3.0, seed, 21)
        out[blobs > np.quantile(blobs, 1.0 - frac)] = np.nan
    figures = {"added_error_rms_m": float(np.sqrt(np.mean(err**2))), "void_fraction": float(np.isnan(out).mean()),
               "resolution_m": float(res)}
    return DegradedRaster(out.astype(np.float32), out_transform, figures)


def write_raster(path, values: np.ndarray, transform: Affine, crs, *, tags=None, nodata=None) -> None:
    """Write one band as a DEFLATE GeoTIFF (NaN becomes ``nodata`` when given).

    Parameters
    ----------
    path : str or Path
        Target file.
    values : ndarray, shape (rows, cols)
        uint16 or float32.
    transform : affine.Affine
        Pixel-corner affine.
    crs : pyproj.CRS or rasterio CRS
        Its CRS.
    tags : dict, optional
        Metadata items (e.g. ``VERTICAL_DATUM=ellipsoid``).
    nodata : float, optional
        Nodata value.
    """
    import rasterio
    from rasterio.crs import CRS as RioCRS

    data = values
    if nodata is not None:
        data = np.where(np.isfinite(values), values, nodata).astype(values.dtype)
    crs = crs if isinstance(crs, RioCRS) else RioCRS.from_wkt(crs.to_wkt())
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1,
                       dtype=data.dtype.name, crs=crs, transform=transform, tiled=True, blockxsize=256,
                       blockysize=256, compress="deflate", nodata=nodata) as dst:
        if tags:
            dst.update_tags(**tags)
        dst.write(data, 1)
